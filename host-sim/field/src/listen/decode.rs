//! Bytes in, map and counters out: the listener's decoding of the robot's stream.

use std::io::Write;

use ogm_core::wire::WireError;
use ogm_firmware::sizes::MPS2_AN386 as FW;

use super::stats::{Gap, Notice};
use super::{Listener, MAX_CELLS, MAX_GAPS_KEPT};
use crate::stream::{host_frame, BuildingError, BuildingMap, DeviceEvent};

impl Listener {
    /// Feeds bytes from the robot; returns what deserves a line of its own.
    pub fn push(&mut self, data: &[u8]) -> Vec<Notice> {
        if let Some((path, file)) = &mut self.capture {
            if let Err(e) = file.write_all(data) {
                let msg = format!(
                    "{}: capture write failed ({e}); capture stopped (the map goes on)",
                    path.display()
                );
                self.capture = None;
                let mut out = vec![Notice::Warning(msg)];
                out.extend(self.decode(data));
                return out;
            }
        }
        self.decode(data)
    }

    fn decode(&mut self, data: &[u8]) -> Vec<Notice> {
        let mut notices = Vec::new();
        if data.is_empty() {
            return notices;
        }
        self.dirty = true;
        self.live_dirty = true;
        // Split at each 0x00 so that every frame's bytes are known (for the garbage count).
        for segment in data.split_inclusive(|&b| b == 0) {
            let before = self.decoder.stats();
            let results = self.decoder.push(segment);
            self.pending += segment.len() as u64;
            let ended = segment.last() == Some(&0);
            let after = self.decoder.stats();
            self.stats.bytes = after.bytes;
            self.stats.frames = after.frames;
            self.stats.bad_frames = after.bad_frames;
            self.stats.oversized = after.oversized;
            let mut good = false;
            for r in results {
                match r {
                    Ok(ev) => {
                        good = true;
                        self.event(ev, &mut notices);
                    }
                    Err(WireError::Crc) => self.stats.crc_errors += 1,
                    Err(_) => {}
                }
            }
            if ended {
                // A lone 0x00 is a delimiter, not garbage; a run that ended an oversized skip or
                // a bad frame is.
                if !good && (self.pending > 1 || after.oversized > before.oversized) {
                    self.stats.garbage_bytes += self.pending;
                }
                self.pending = 0;
            }
            if good {
                if let Some(g0) = self.resync_from.take() {
                    notices.push(Notice::Resynced(self.stats.garbage_bytes - g0));
                }
            }
        }
        notices
    }

    fn event(&mut self, ev: DeviceEvent, notices: &mut Vec<Notice>) {
        match ev {
            DeviceEvent::Hello(h) => {
                let cells = usize::from(h.width) * usize::from(h.height);
                if cells == 0 || cells > MAX_CELLS || h.tile_edge == 0 {
                    self.stats.bad_hellos += 1;
                    notices.push(Notice::Warning(format!(
                        "Hello announces a {}x{} grid of {}-cell tiles: refused",
                        h.width, h.height, h.tile_edge
                    )));
                    return;
                }
                self.stats.hellos += 1;
                self.map = Some(BuildingMap::new(
                    usize::from(h.width),
                    usize::from(h.height),
                    usize::from(h.tile_edge),
                ));
                self.stats.window = None;
                self.samples = 0;
                self.stats.last_seq = None;
                self.stats.config = None;
                self.stats.robot = None;
                self.stats.done = None;
                self.stats.hello = Some(h.clone());
                self.last_pose = None;
                notices.push(Notice::Hello(h));
            }
            DeviceEvent::Configured(c) => {
                self.stats.config = Some(c);
                notices.push(Notice::Configured(c));
            }
            DeviceEvent::Scan(r) => {
                self.stats.scans_seen += 1;
                self.stats.corrections.add(&r.correction);
                let p = r.pose;
                let heading = f64::from(p.heading.0) * std::f64::consts::TAU / 65_536.0;
                let (x, y) = (f64::from(p.x_mm) / 1000.0, f64::from(p.y_mm) / 1000.0);
                let t = crate::recording::now_ns();
                if let Some(rec) = self.recording.as_mut() {
                    if let Err(e) = rec.pose(x, y, heading, t) {
                        notices.push(Notice::Warning(format!("{e:#}; recording stopped")));
                        self.recording = None;
                    }
                }
                if let Some(live) = self.live.as_ref() {
                    let m = crate::recording::pose_message(x, y, heading, t);
                    live.publish(crate::recording::Channel::Pose, t, &m);
                }
                self.last_pose = Some((r.seq, (x, y, heading)));
                let expected = self.stats.last_seq.map_or(0, |s| s.wrapping_add(1));
                if r.seq > expected {
                    let gap = Gap {
                        first: expected,
                        last: r.seq - 1,
                    };
                    self.stats.scans_missed += gap.len();
                    if self.stats.gaps.len() >= MAX_GAPS_KEPT {
                        self.stats.gaps.remove(0);
                    }
                    self.stats.gaps.push(gap);
                    notices.push(Notice::Gap(gap));
                } else if self.stats.last_seq.is_some_and(|s| r.seq < s) {
                    self.stats.seq_restarts += 1;
                }
                self.stats.last_seq = Some(r.seq);
            }
            DeviceEvent::Tile(t) => {
                if self.map.is_none() {
                    // Started mid-run with no capture: assume the reference firmware's grid.
                    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
                    self.map = Some(BuildingMap::new(w, h, usize::from(FW.tile_edge)));
                    if !self.warned_no_hello {
                        self.warned_no_hello = true;
                        notices.push(Notice::Warning(format!(
                            "tiles before any Hello: assuming the firmware's {w}x{h} grid of {}-cell tiles",
                            FW.tile_edge
                        )));
                    }
                }
                let Some(map) = self.map.as_mut() else { return };
                match map.apply(&t) {
                    Ok(()) => self.stats.tiles += 1,
                    Err(e) => {
                        self.stats.bad_tiles += 1;
                        if matches!(e, BuildingError::TooLarge { .. }) {
                            self.stats.tiles_refused += 1;
                        }
                        if self.stats.bad_tiles <= 3 {
                            notices.push(Notice::Warning(format!("tile dropped: {e}")));
                        }
                    }
                }
            }
            DeviceEvent::Sampler(s) => self.samples = s.samples,
            DeviceEvent::Counters(c) => self.stats.robot = Some(c),
            DeviceEvent::Error(e) => {
                self.stats.device_errors += 1;
                self.stats.last_device_error = Some(e);
                notices.push(Notice::DeviceError(e));
            }
            DeviceEvent::Done(d) => {
                self.stats.done = Some(d);
                notices.push(Notice::Done(d));
            }
            DeviceEvent::Idle(_) => {}
            // A rolling window: the tiles carry building coordinates, so the map needs nothing
            // from the report; it goes to status.json.
            DeviceEvent::Window(w) => {
                if let Some(map) = self.map.as_mut() {
                    map.note_window(w);
                    // The stored tiles that came back into the window go back to the robot
                    // before it can map there (docs/wire.md "Restoring stored tiles").
                    if self.send_back {
                        let tiles = map.entered().to_vec();
                        let msgs = map.restore_msgs(&tiles);
                        self.stats.tiles_sent_back += tiles.len() as u64;
                        self.outgoing.extend(msgs.iter().map(host_frame));
                    }
                    // After a shift, also without tiles to send: a robot with `window_hold`
                    // waits for this before it maps the turn that shifted; one without
                    // ignores it.
                    if w.shifts > self.stats.window.map_or(0, |p| p.shifts) {
                        self.outgoing
                            .push(host_frame(&ogm_core::wire::HostMsg::Resume));
                    }
                    self.stats.revisits = Some(map.revisits().clone());
                }
                self.stats.window = Some(w);
            }
            DeviceEvent::Ranges(r) => self.scan_ranges(&r, notices),
        }
    }

    /// A scan's ranges: its points, placed at the pose of the report with the same `seq`, to
    /// the recording and the live view (dropped if that report was missed).
    fn scan_ranges(&mut self, r: &crate::stream::OwnedRanges, notices: &mut Vec<Notice>) {
        let bins = match r.bins() {
            Ok(b) => b,
            Err(e) => {
                self.stats.bad_ranges += 1;
                if self.stats.bad_ranges <= 3 {
                    notices.push(Notice::Warning(format!("scan {}: {e}", r.seq)));
                }
                return;
            }
        };
        let Some((_, (x, y, heading))) = self.last_pose.filter(|(seq, _)| *seq == r.seq) else {
            return;
        };
        let points = crate::recording::scan_points(&bins, x, y, heading);
        self.stats.ranges_placed += 1;
        self.stats.scan_points = points.len();
        let t = crate::recording::now_ns();
        if let Some(rec) = self.recording.as_mut() {
            if let Err(e) = rec.scan(&points, t) {
                notices.push(Notice::Warning(format!("{e:#}; recording stopped")));
                self.recording = None;
            }
        }
        if let Some(live) = self.live.as_ref() {
            let m = crate::recording::points_message(&points, t);
            live.publish(crate::recording::Channel::Scan, t, &m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_stream::{cobs, config, frame, hello, hello_of, stream};
    use super::*;
    use ogm_core::wire::{self, DeviceMsg, Done, Hello, Layer, ScanReport, Tile};

    #[test]
    fn any_chunking_gives_the_same_map_and_counters() {
        let s = stream(&[0, 1, 2, 3, 4, 5, 6]);
        let mut whole = Listener::new();
        whole.push(&s);
        assert_eq!(whole.stats().frames, 2 + 7 * 5);
        assert_eq!(whole.stats().scans_seen, 7);
        assert_eq!(whole.stats().tiles, 14);
        assert_eq!(
            (whole.stats().bad_frames, whole.stats().garbage_bytes),
            (0, 0)
        );
        for n in [1, 2, 7, 100, 545] {
            let mut l = Listener::new();
            for c in s.chunks(n) {
                l.push(c);
            }
            assert_eq!(l.map(), whole.map(), "chunks of {n}");
            assert_eq!(l.have_counts(), whole.have_counts());
            assert_eq!(
                serde_json::to_string(l.stats()).unwrap(),
                serde_json::to_string(whole.stats()).unwrap(),
                "chunks of {n}"
            );
        }
        // The map is the tiles: tile (1, 0) was last sent by scan 1, tile (1, 1) by scan 4.
        let m = whole.map().unwrap();
        assert_eq!((m.width, m.height), (40, 24));
        assert_eq!(m.log_odds[16], 101 - 1500);
        assert_eq!(m.log_odds[16 * 40 + 16], 4 * 101 - 1500);
    }

    #[test]
    fn corrupted_bytes_are_dropped_and_counted() {
        let clean = stream(&[0, 1, 2]);
        let mut s = vec![0x11, 0x22, 0x33, 0x00]; // garbage: a bad frame of 4 bytes
        s.extend(&clean);
        // Scan 1's report with one payload bit flipped: a CRC error (its tiles still apply).
        let scan1 = frame(&DeviceMsg::Scan(ScanReport {
            seq: 1,
            ..ScanReport::default()
        }));
        let at = s.windows(scan1.len()).position(|w| w == scan1).unwrap();
        let mut raw = scan1[..scan1.len() - 1].to_vec();
        let n = wire::cobs_decode_in_place(&mut raw).unwrap();
        raw.truncate(n);
        raw[2] ^= 0x40;
        let bad = cobs(&raw);
        s.splice(at..at + scan1.len(), bad.iter().copied());
        // An oversized run with no 0x00, then a clean Done.
        s.extend(std::iter::repeat_n(0x55u8, 3 * wire::MAX_DEVICE_FRAME));
        s.push(0);
        s.extend(frame(&DeviceMsg::Done(Done::default())));
        let mut l = Listener::new();
        let mut notices = Vec::new();
        for c in s.chunks(5) {
            notices.extend(l.push(c));
        }
        let st = l.stats();
        assert_eq!(st.bad_frames, 2, "{st:?}");
        assert_eq!(st.crc_errors, 1);
        assert_eq!(st.oversized, 1);
        assert_eq!(
            st.garbage_bytes,
            4 + bad.len() as u64 + 3 * wire::MAX_DEVICE_FRAME as u64 + 1
        );
        assert_eq!(st.frames, 2 + 3 * 5 - 1 + 1);
        // The lost report leaves a hole in the scan numbers that is not a gap: scan 2 follows
        // scan 0, so scan 1 counts as missed (its report did not arrive).
        assert_eq!(st.scans_missed, 1);
        assert!(notices.iter().any(|n| matches!(n, Notice::Done(_))));
        assert_eq!(st.tiles, 6);
    }

    #[test]
    fn gaps_are_counted_and_reconnects_resync() {
        let s = stream(&[0, 1, 2, 6, 7]);
        let mut l = Listener::new();
        let notices = l.push(&s);
        assert_eq!(l.stats().scans_missed, 3);
        assert_eq!(l.stats().gaps, vec![Gap { first: 3, last: 5 }]);
        assert!(notices.contains(&Notice::Gap(Gap { first: 3, last: 5 })));
        // Cut mid-frame, reconnect, resume mid-frame of another scan: the two halves are bad
        // frames, scans 8..=9 are missed, scan 10 resynchronises.
        let later = stream(&[10, 11]);
        let hello_len = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        let tail = &later[hello_len..];
        let scan8 = stream(&[8]);
        let cut = &scan8[hello_len..hello_len + 7];
        l.push(cut);
        l.reconnected();
        let junk_tail = [0x42u8, 0x17, 0x99];
        l.push(&junk_tail);
        l.push(&[0]);
        let n = l.push(tail);
        let st = l.stats();
        assert_eq!(st.reconnects, 1);
        assert_eq!(st.bad_frames, 2, "{st:?}");
        assert_eq!(st.garbage_bytes, 8 + 4);
        assert!(n.contains(&Notice::Resynced(8 + 4)), "{n:?}");
        assert!(n.contains(&Notice::Gap(Gap { first: 8, last: 9 })));
        assert_eq!(st.scans_missed, 5);
        assert_eq!(st.scans_seen, 7);
        assert_eq!(st.last_seq, Some(11));
        // A new boot starts a new map and a new count.
        l.push(&stream(&[0]));
        assert_eq!(l.stats().hellos, 2);
        assert_eq!(l.stats().scans_missed, 5);
        assert_eq!(l.map().unwrap().tiles, 2);
    }

    #[test]
    fn absurd_hello_is_refused_and_tiles_without_hello_assume_the_firmware_grid() {
        let big = frame(&DeviceMsg::Hello(Hello {
            firmware: "x",
            board: "y",
            tick_hz: 1,
            width: u16::MAX,
            height: u16::MAX,
            tile_edge: 16,
            max_beams: 1,
            ray_capacity: 1,
            scan_capacity: 1,
            local_capacity: 1,
            count_max: 255,
        }));
        let mut l = Listener::new();
        let n = l.push(&big);
        assert_eq!(l.stats().bad_hellos, 1);
        assert!(l.map().is_none());
        assert!(matches!(n.as_slice(), [Notice::Warning(_)]));
        // A tile absurdly far off the firmware grid is dropped (the building map would grow
        // past its cap), one on it applied.
        let data = vec![1u8; 256];
        let off = frame(&DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: i32::MIN,
            ty: 0,
            data: &data,
        }));
        let on = frame(&DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: 15,
            ty: 15,
            data: &data,
        }));
        l.push(&off);
        l.push(&on);
        let m = l.map().unwrap();
        assert_eq!((m.width, m.height), (256, 256));
        assert_eq!((l.stats().tiles, l.stats().bad_tiles), (1, 1));
        assert_eq!(l.stats().tiles_refused, 1);
        assert_eq!(m.counts[255 * 256 + 255], 1);
        // A tile beside the grid (a rolling window's) grows the map to the building.
        let beside = frame(&DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: -1,
            ty: 16,
            data: &data,
        }));
        l.push(&beside);
        let r = l.render().unwrap();
        assert_eq!((r.x0, r.y0, r.map.width, r.map.height), (-16, 0, 272, 272));
        assert_eq!(r.map.counts[271 * 272], 1);
        assert_eq!(r.map.counts[255 * 272 + 255 + 16], 1);
        assert_eq!((l.stats().tiles, l.stats().bad_tiles), (2, 1));
    }

    #[test]
    fn stored_tiles_go_back_when_the_window_returns_unless_told_not_to() {
        // A 32 × 32 window of 16-cell tiles; tile (0, 0) mapped, then the window moves east
        // and back.
        let hello = hello_of(32, 32);
        let lo = 300i16.to_le_bytes().repeat(256);
        let est = vec![40u8; 256];
        let mut s = hello;
        for (layer, data) in [(Layer::LogOdds, &lo[..]), (Layer::Counts, &est[..])] {
            s.extend(frame(&DeviceMsg::Tile(Tile {
                layer,
                tx: 0,
                ty: 0,
                data,
            })));
        }
        let window = |origin_x, shifts| {
            frame(&DeviceMsg::Window(wire::WindowReport {
                origin_x,
                shifts,
                ..wire::WindowReport::default()
            }))
        };
        s.extend(window(32, 0));
        s.extend(window(0, 1));
        for send_back in [true, false] {
            let mut l = Listener::new();
            l.set_send_back(send_back);
            l.push(&s);
            let out = l.take_outgoing();
            if !send_back {
                // `Resume` alone: nothing to send back, but the shift is answered.
                assert_eq!(out, [host_frame(&wire::HostMsg::Resume)]);
                continue;
            }
            // 8 log-odds and 4 estimate parts, decodable host frames carrying the stored cells,
            // then `Resume` (the window shifted).
            assert_eq!(out.len(), 13);
            assert_eq!(l.stats().tiles_sent_back, 1);
            let mut cells = Vec::new();
            for (i, f) in out.iter().enumerate() {
                // Between its 0x00 delimiters.
                let mut f: Vec<u8> = f.iter().copied().filter(|&b| b != 0).collect();
                match wire::decode::<wire::HostMsg>(&mut f) {
                    Ok(wire::HostMsg::Restore {
                        tx: 0,
                        ty: 0,
                        layer: Layer::LogOdds,
                        data,
                        ..
                    }) => cells.extend_from_slice(data.as_slice()),
                    Ok(wire::HostMsg::Restore {
                        layer: Layer::Counts,
                        ..
                    }) => {}
                    Ok(wire::HostMsg::Resume) => assert_eq!(i, 12),
                    other => panic!("{other:?}"),
                }
            }
            assert_eq!(cells, lo);
            assert!(l.take_outgoing().is_empty(), "taken once");
        }
    }
}
