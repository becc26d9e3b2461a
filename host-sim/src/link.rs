//! The host's side of the robot link (docs/wire.md):
//!
//! * **to the robot**: the simulator's scans as LD06 packets plus the host frames (settings,
//!   `ScanStart`/`ScanEnd` with the known pose, `Finish`) on one byte stream ([`RunInput`]);
//! * **from the robot**: the map stream decoder ([`StreamDecoder`]: COBS frames, resynchronises
//!   at the next `0x00` after garbage or a bad frame) and the map rebuilt from its tiles
//!   ([`StreamedMap`]).
//!
//! Everything framing-related is ogm-core's own code (`ogm_core::{ld06, wire}`), so host and
//! robot cannot disagree about the format.

use anyhow::{anyhow, bail, ensure};
use ogm_core::config::RunConfig;
use ogm_core::lidar::ld06::{self, theta_cdeg, PACKET_LEN};
use ogm_core::wire::{
    self, Counters, DeviceError, DeviceMsg, Done, Hello, HostMsg, Layer, SamplerReport, ScanReport,
    WireError,
};
use ogm_core::Beam;

use crate::explore::ScanRecord;

/// One host frame as it goes on the wire: a `0x00` (frame start for the robot's demultiplexer)
/// and the COBS frame with its terminating `0x00`.
pub fn host_frame(msg: &HostMsg) -> Vec<u8> {
    let mut buf = [0u8; wire::MAX_HOST_FRAME];
    let mut v = vec![0u8];
    match wire::encode(msg, &mut buf) {
        Ok(f) => v.extend_from_slice(f),
        // Unreachable: every HostMsg fits (tested in ogm-core).
        Err(e) => panic!("host frame does not fit: {e}"),
    }
    v
}

/// A scan's beams as LD06 packets, in the sensor's (clockwise) order. Needs a multiple of 12
/// beams, evenly spaced (as the simulator's are).
pub fn scan_packets(beams: &[Beam], timestamp_ms: &mut u16) -> anyhow::Result<Vec<u8>> {
    let mut sorted = beams.to_vec();
    sorted.sort_by_key(|b| theta_cdeg(b.angle));
    let packets = sorted.len() / ld06::POINTS;
    // 10 Hz: one turn in 100 ms.
    let ms = (100 / packets.max(1)).max(1) as u16;
    let mut out = Vec::with_capacity(packets * PACKET_LEN);
    let n = ld06::encode_scan(&sorted, 3600, *timestamp_ms, ms, |p| {
        out.extend_from_slice(p)
    })
    .map_err(|_| {
        anyhow!(
            "{} beams per scan: the LD06 format needs a multiple of 12",
            beams.len()
        )
    })?;
    *timestamp_ms = ((u32::from(*timestamp_ms) + 100) % 30_000) as u16;
    debug_assert_eq!(n, packets);
    Ok(out)
}

/// What a span of the robot's input is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnitKind {
    /// A host frame (leading `0x00` included).
    Frame,
    /// An LD06 packet of a scan.
    Packet,
    /// Deliberate garbage (`encode_run`'s `garbage`).
    Garbage,
}

/// One packet, frame or garbage burst of the input: `bytes[start..start + len]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// What it is.
    pub kind: UnitKind,
    /// First byte.
    pub start: usize,
    /// Length.
    pub len: usize,
}

/// The robot's whole input for a run, and where each of its units lies.
#[derive(Clone, Debug, Default)]
pub struct RunInput {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Scans sent.
    pub scans: usize,
    /// LD06 points sent inside scans.
    pub points: u64,
    /// Bytes of deliberate garbage mixed in.
    pub garbage_bytes: usize,
    /// Every frame, packet and garbage burst, in order (they tile `bytes`).
    pub units: Vec<Unit>,
}

impl RunInput {
    fn push(&mut self, kind: UnitKind, bytes: &[u8]) {
        self.units.push(Unit {
            kind,
            start: self.bytes.len(),
            len: bytes.len(),
        });
        self.bytes.extend_from_slice(bytes);
    }

    fn frame(&mut self, msg: &HostMsg, repeat: usize) {
        let f = host_frame(msg);
        for _ in 0..repeat.max(1) {
            self.push(UnitKind::Frame, &f);
        }
    }
}

/// Builds the input: `Config`, then per scan `ScanStart`, its LD06 packets and `ScanEnd`, then
/// `Finish`. With `garbage`, every fifth gap between scans also carries junk — random bytes,
/// stray `0x54`/`0x2C`/`0x00`, a truncated LD06 packet and a corrupted frame — which the robot
/// must skip (the replay on the host sees the same bytes).
pub fn encode_run(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
) -> anyhow::Result<RunInput> {
    encode_run_with(config, scans, garbage, 1)
}

/// [`encode_run`] sending every host frame `repeat_frames` times in a row (for a noisy link:
/// a frame is lost only if all its copies are; the robot ignores exact repeats, see
/// `ogm_core::lidar::link`).
pub fn encode_run_with(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
    repeat_frames: usize,
) -> anyhow::Result<RunInput> {
    encode_run_idle(config, scans, garbage, repeat_frames, &[])
}

/// [`encode_run_with`] with idle periods (`HostMsg::Idle`, µs of board time each) after the
/// last scan, before `Finish`.
pub fn encode_run_idle(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
    repeat_frames: usize,
    idle_us: &[u32],
) -> anyhow::Result<RunInput> {
    let mut input = RunInput::default();
    input.frame(&HostMsg::Config(*config), repeat_frames);
    let mut ts = 0u16;
    let mut x = 0x2545_F491u32;
    for (k, s) in scans.iter().enumerate() {
        let seq = u32::try_from(k)?;
        let packets = scan_packets(&s.beams, &mut ts)?;
        if garbage && k % 5 == 2 {
            // A truncated LD06 packet first, then random bytes, then a corrupted frame: the
            // 47-byte candidate the truncated header opens ends inside the random bytes. (Right
            // before a frame, it would take the frame's first bytes with it, and an 8-bit CRC
            // accepts such a false packet once in 256 — a limit of sharing one UART between
            // the lidar and the host, measured in docs/firmware.md.)
            let mut junk = packets[..20.min(packets.len())].to_vec();
            for _ in 0..64 {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                junk.push(match x % 9 {
                    0 => 0x54,
                    1 => 0x2C,
                    2 => 0x00,
                    _ => (x >> 16) as u8,
                });
            }
            let mut bad = host_frame(&HostMsg::ScanEnd {
                seq,
                points: 12_345,
            });
            if let Some(b) = bad.get_mut(4) {
                *b ^= 0x21;
            }
            junk.extend(bad);
            input.garbage_bytes += junk.len();
            input.push(UnitKind::Garbage, &junk);
        }
        input.frame(&HostMsg::ScanStart { seq, pose: s.pose }, repeat_frames);
        for p in packets.chunks(PACKET_LEN) {
            input.push(UnitKind::Packet, p);
        }
        input.frame(
            &HostMsg::ScanEnd {
                seq,
                points: s.beams.len() as u32,
            },
            repeat_frames,
        );
        input.scans += 1;
        input.points += s.beams.len() as u64;
    }
    for (seq, &period_us) in idle_us.iter().enumerate() {
        let seq = u32::try_from(seq)?;
        input.frame(&HostMsg::Idle { seq, period_us }, repeat_frames);
    }
    input.frame(&HostMsg::Finish, repeat_frames);
    Ok(input)
}

/// [`Hello`] with owned strings.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct HelloInfo {
    /// Firmware name and version.
    pub firmware: String,
    /// Board.
    pub board: String,
    /// Timer ticks per second.
    pub tick_hz: u32,
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Tile edge, cells.
    pub tile_edge: u16,
    /// Beams per scan buffer.
    pub max_beams: u32,
    /// Ray store rays.
    pub ray_capacity: u32,
    /// Ray store scans.
    pub scan_capacity: u32,
    /// Sampler's per-tile ray list.
    pub local_capacity: u32,
    /// Largest marginal count.
    pub count_max: u32,
}

impl From<&Hello<'_>> for HelloInfo {
    fn from(h: &Hello<'_>) -> Self {
        HelloInfo {
            firmware: h.firmware.to_string(),
            board: h.board.to_string(),
            tick_hz: h.tick_hz,
            width: h.width,
            height: h.height,
            tile_edge: h.tile_edge,
            max_beams: h.max_beams,
            ray_capacity: h.ray_capacity,
            scan_capacity: h.scan_capacity,
            local_capacity: h.local_capacity,
            count_max: h.count_max,
        }
    }
}

/// A [`wire::Tile`] with owned data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedTile {
    /// Which map.
    pub layer: Layer,
    /// Tile column.
    pub tx: u16,
    /// Tile row.
    pub ty: u16,
    /// Cells.
    pub data: Vec<u8>,
}

/// A [`wire::ScanRanges`] with owned data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedRanges {
    /// The scan's number.
    pub seq: u32,
    /// [`wire::SCAN_RANGES_LEN`] bytes (checked by [`OwnedRanges::bins`]).
    pub data: Vec<u8>,
}

impl OwnedRanges {
    /// The bins holding a reading: (direction in the robot's frame, reading); an error if the
    /// data has the wrong length.
    pub fn bins(&self) -> Result<Vec<(ogm_core::Angle, ogm_core::types::scan::Range)>, WireError> {
        let r = wire::ScanRanges {
            seq: self.seq,
            data: &self.data,
        };
        let bins = r.bins()?.collect();
        Ok(bins)
    }
}

/// A decoded device message with owned data.
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceEvent {
    /// Boot message.
    Hello(HelloInfo),
    /// Settings accepted.
    Configured(RunConfig),
    /// A scan was processed.
    Scan(ScanReport),
    /// Map data.
    Tile(OwnedTile),
    /// Sampler statistics.
    Sampler(SamplerReport),
    /// Counters.
    Counters(Counters),
    /// An error report.
    Error(DeviceError),
    /// End of run.
    Done(Done),
    /// An idle period ended.
    Idle(wire::IdleReport),
    /// A scan's ranges.
    Ranges(OwnedRanges),
}

impl From<DeviceMsg<'_>> for DeviceEvent {
    fn from(m: DeviceMsg<'_>) -> Self {
        match m {
            DeviceMsg::Hello(h) => DeviceEvent::Hello(HelloInfo::from(&h)),
            DeviceMsg::Configured(c) => DeviceEvent::Configured(c),
            DeviceMsg::Scan(s) => DeviceEvent::Scan(s),
            DeviceMsg::Tile(t) => DeviceEvent::Tile(OwnedTile {
                layer: t.layer,
                tx: t.tx,
                ty: t.ty,
                data: t.data.to_vec(),
            }),
            DeviceMsg::Sampler(s) => DeviceEvent::Sampler(s),
            DeviceMsg::Counters(c) => DeviceEvent::Counters(c),
            DeviceMsg::Error(e) => DeviceEvent::Error(e),
            DeviceMsg::Done(d) => DeviceEvent::Done(d),
            DeviceMsg::Idle(r) => DeviceEvent::Idle(r),
            DeviceMsg::Ranges(r) => DeviceEvent::Ranges(OwnedRanges {
                seq: r.seq,
                data: r.data.to_vec(),
            }),
        }
    }
}

/// Decoder counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DecoderStats {
    /// Bytes received.
    pub bytes: u64,
    /// Good frames.
    pub frames: u64,
    /// Frames that failed COBS/CRC/version/postcard.
    pub bad_frames: u64,
    /// Frames longer than any valid one (skipped to the next `0x00`).
    pub oversized: u64,
}

/// Decodes the robot's map stream: bytes in (any chunking), [`DeviceEvent`]s out. A bad or
/// oversized frame costs only itself: decoding resumes after the next `0x00`.
#[derive(Clone, Debug, Default)]
pub struct StreamDecoder {
    buf: Vec<u8>,
    skipping: bool,
    stats: DecoderStats,
}

impl StreamDecoder {
    /// A fresh decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Feeds bytes; returns what they completed, in order (errors included).
    pub fn push(&mut self, data: &[u8]) -> Vec<Result<DeviceEvent, WireError>> {
        let mut out = Vec::new();
        for &b in data {
            self.stats.bytes += 1;
            if b != 0 {
                if self.skipping {
                    continue;
                }
                self.buf.push(b);
                if self.buf.len() > 2 * wire::MAX_DEVICE_FRAME {
                    self.stats.oversized += 1;
                    self.buf.clear();
                    self.skipping = true;
                }
                continue;
            }
            if std::mem::take(&mut self.skipping) || self.buf.is_empty() {
                self.buf.clear();
                continue;
            }
            let mut frame = std::mem::take(&mut self.buf);
            match wire::decode::<DeviceMsg>(&mut frame) {
                Ok(m) => {
                    self.stats.frames += 1;
                    out.push(Ok(DeviceEvent::from(m)));
                }
                Err(e) => {
                    self.stats.bad_frames += 1;
                    out.push(Err(e));
                }
            }
        }
        out
    }
}

/// The map as rebuilt from the stream's tiles.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamedMap {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Tile edge.
    pub edge: usize,
    /// Log-odds (raw `i16`), row-major.
    pub log_odds: Vec<i16>,
    /// Marginal counts.
    pub counts: Vec<u8>,
    /// Current sample.
    pub sample: Vec<bool>,
    /// Tiles applied.
    pub tiles: u64,
}

impl StreamedMap {
    /// An all-unknown map.
    pub fn new(width: usize, height: usize, edge: usize) -> Self {
        StreamedMap {
            width,
            height,
            edge: edge.max(1),
            log_odds: vec![0; width * height],
            counts: vec![0; width * height],
            sample: vec![false; width * height],
            tiles: 0,
        }
    }

    /// Applies a tile ([`wire::decode_tile`], the stream's one tile codec); returns the cells
    /// it covered. A tile outside the map or of the wrong size changes nothing.
    pub fn apply(&mut self, t: &OwnedTile) -> anyhow::Result<wire::TileRect> {
        let tile = wire::Tile {
            layer: t.layer,
            tx: t.tx,
            ty: t.ty,
            data: &t.data,
        };
        let rect = wire::decode_tile(&tile, self.width, self.height, self.edge, self)
            .map_err(|e| anyhow!("tile {:?} ({}, {}): {e}", t.layer, t.tx, t.ty))?;
        self.tiles += 1;
        Ok(rect)
    }
}

impl wire::TileSink for StreamedMap {
    fn set_log_odds(&mut self, index: usize, raw: i16) {
        if let Some(c) = self.log_odds.get_mut(index) {
            *c = raw;
        }
    }

    fn set_count(&mut self, index: usize, count: u8) {
        if let Some(c) = self.counts.get_mut(index) {
            *c = count;
        }
    }

    fn set_occupied(&mut self, index: usize, occupied: bool) {
        if let Some(c) = self.sample.get_mut(index) {
            *c = occupied;
        }
    }
}

/// Reads a captured stream file (e.g. UART1 of `scripts/firmware.sh run`) and summarises it.
pub fn decode_file(path: &std::path::Path) -> anyhow::Result<Vec<DeviceEvent>> {
    let bytes = std::fs::read(path).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    ensure!(!bytes.is_empty(), "{}: file is empty", path.display());
    let mut d = StreamDecoder::new();
    let events: Vec<DeviceEvent> = d.push(&bytes).into_iter().filter_map(Result::ok).collect();
    let s = d.stats();
    if events.is_empty() {
        bail!(
            "{}: wrong format: not a map stream (no valid frame in {} bytes)",
            path.display(),
            s.bytes
        );
    }
    println!(
        "{}: {} bytes, {} frames, {} bad, {} oversized",
        path.display(),
        s.bytes,
        s.frames,
        s.bad_frames,
        s.oversized
    );
    Ok(events)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::config::Budget;
    use ogm_core::lidar::link::{LinkRx, Step};
    use ogm_core::{Angle, Pose, Range, ScanBuf};

    fn record(k: u32) -> ScanRecord {
        ScanRecord {
            pose: Pose {
                x_mm: 100 * k as i32,
                y_mm: 0,
                heading: Angle(1000 * k as u16),
            },
            beams: (0..360u32)
                .map(|i| Beam {
                    angle: Angle(((u64::from(i) << 16) / 360) as u16),
                    range: if i % 11 == 0 {
                        Range::NoReturn
                    } else {
                        Range::Hit(500 + 7 * i + k)
                    },
                })
                .collect(),
        }
    }

    #[test]
    fn input_round_trips_through_the_robots_demux_with_garbage() {
        let scans: Vec<ScanRecord> = (0..8).map(record).collect();
        let cfg = RunConfig::paper((0, 0), 3750, 3, Budget::Fixed { updates: 10 });
        let input = encode_run(&cfg, &scans, true).unwrap();
        assert!(input.garbage_bytes > 0);
        let mut rx = LinkRx::new();
        let mut buf: ScanBuf<512> = ScanBuf::new();
        let mut got = Vec::new();
        let mut config = None;
        let mut finished = false;
        for c in input.bytes.chunks(13) {
            rx.feed(c, &mut buf, |s| match s {
                Step::Scan {
                    seq, pose, beams, ..
                } => got.push((seq, pose, beams.to_vec())),
                Step::Host(HostMsg::Config(c)) => config = Some(c),
                Step::Host(HostMsg::Finish) => finished = true,
                Step::Host(_) | Step::Error(_) => {}
            });
        }
        assert!(finished);
        assert_eq!(config, Some(cfg));
        assert_eq!(got.len(), 8);
        for ((seq, pose, beams), s) in got.iter().zip(&scans) {
            assert_eq!(*pose, s.pose, "scan {seq}");
            assert_eq!(beams.len(), 360);
            // Same multiset of ranges; angles within the wire resolution.
            let mut a: Vec<(u16, Range)> = beams.iter().map(|b| (b.angle.0, b.range)).collect();
            let mut b: Vec<(u16, Range)> = s.beams.iter().map(|b| (b.angle.0, b.range)).collect();
            a.sort_by_key(|x| x.0);
            b.sort_by_key(|x| x.0);
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(x.1, y.1);
                assert!(Angle(x.0).signed_diff(Angle(y.0)).abs() <= 2);
            }
        }
        let c = rx.counters();
        assert!(c.garbage_bytes > 0 && c.frame_errors + c.frames_too_long > 0);
        assert_eq!(c.points_lost, 0);
    }

    #[test]
    fn decoder_resyncs_and_rebuilds_tiles() {
        let data: Vec<u8> = (0..512).map(|i| (i % 13) as u8).collect();
        let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
        let mut stream = vec![0x11, 0x22, 0x00, 0x33, 0x00]; // garbage: two bad frames
        stream.extend_from_slice(
            wire::encode(
                &DeviceMsg::Tile(wire::Tile {
                    layer: Layer::LogOdds,
                    tx: 1,
                    ty: 0,
                    data: &data,
                }),
                &mut buf,
            )
            .unwrap(),
        );
        let mut bad = wire::encode(&DeviceMsg::Done(Done::default()), &mut buf)
            .unwrap()
            .to_vec();
        bad[2] ^= 0xFF;
        stream.extend(bad);
        stream
            .extend_from_slice(wire::encode(&DeviceMsg::Done(Done::default()), &mut buf).unwrap());
        let mut d = StreamDecoder::new();
        let mut events = Vec::new();
        for c in stream.chunks(7) {
            events.extend(d.push(c));
        }
        let ok: Vec<&DeviceEvent> = events.iter().filter_map(|e| e.as_ref().ok()).collect();
        assert_eq!(ok.len(), 2);
        assert_eq!(d.stats().bad_frames, 3);
        let DeviceEvent::Tile(t) = ok[0] else {
            panic!("{ok:?}")
        };
        let mut m = StreamedMap::new(32, 16, 16);
        m.apply(t).unwrap();
        assert_eq!(m.log_odds[16], i16::from_le_bytes([0, 1]));
        assert_eq!(m.log_odds[17 + 32], i16::from_le_bytes([8, 9]));
        assert!(m.apply(&OwnedTile { tx: 2, ..t.clone() }).is_err());
    }
}
