//! The robot's receive side: one UART carries the lidar's LD06 packets *and* the host's frames
//! (poses, settings), and [`LinkDemux`] separates them; [`LinkRx`] then turns them into
//! complete scans with their poses and hands the host's other messages on as they are
//! ([`Step::Host`]). Sans-IO: feed it whatever bytes arrived. The firmware and the
//! host's replay run this same code on the same bytes, so they see the same scans.
//!
//! ## Telling the two apart
//! * an LD06 packet starts with `0x54 0x2C` and is 47 bytes long (CRC-8 at the end);
//! * a host frame starts with `0x00` and ends with the next `0x00` ([`crate::wire`]: COBS, so no
//!   zero inside; version byte, postcard, CRC-32), at most [`MAX_HOST_FRAME`] bytes;
//! * anything else is garbage and skipped (counted).
//!
//! Every candidate is kept in a buffer until it is accepted. When one is rejected (bad LD06
//! header or CRC, bad frame, frame too long) only its *first byte* is dropped and the rest is
//! examined again, so a packet or frame hidden inside a rejected candidate — typically after a
//! burst of garbage or a truncated packet — is still found. Nothing panics; all outcomes are
//! counted in [`LinkCounters`] (sent in the map stream's statistics).
//!
//! ## Scans
//! `ScanStart { seq, pose }`, then the scan's LD06 packets, then `ScanEnd { seq, points }`:
//! the points in between are one scan taken at `pose` ([`Step::Scan`]). Points outside a scan,
//! an unmatched `ScanEnd`, a scan never ended and points announced but not received are counted
//! and reported ([`Step::Error`]); the scan itself is still delivered with what arrived.
//!
//! **Repeated frames.** On a noisy link the host may send every host frame more than once (a
//! frame is lost only if every copy is damaged). Exact repeats are idempotent here and cost
//! nothing: a `ScanStart` equal to the open scan's (same `seq` and pose) is ignored, and so is a
//! `ScanEnd` for the scan just delivered (same `seq`, no scan open); the firmware ignores a
//! `Config` equal to the one it runs with.

use crate::lidar::ld06::{Ld06Error, Packet, HEADER, PACKET_LEN, POINTS, VER_LEN};
use crate::types::geometry::Pose;
use crate::types::scan::{Beam, ScanBuf};
use crate::wire::{self, HostMsg, LinkCounters, WireError, MAX_HOST_FRAME};

/// What the demultiplexer found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkEvent {
    /// A good LD06 packet.
    Packet(Packet),
    /// A good host frame.
    Host(HostMsg),
    /// Something was rejected.
    Error(LinkError),
}

/// Rejections and framing problems.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LinkError {
    /// A bad LD06 packet.
    Ld06(Ld06Error),
    /// A bad host frame.
    Frame(WireError),
    /// No frame end within [`MAX_HOST_FRAME`] bytes.
    FrameTooLong,
    /// `ScanEnd` for another scan than the open one (its `seq`), or `ScanStart`/`Finish` while
    /// a scan was still open (the open one's `seq`; that scan is dropped).
    ScanSequence {
        /// The sequence number concerned.
        seq: u32,
    },
    /// `ScanEnd` announced more points than arrived.
    PointsLost {
        /// The scan.
        seq: u32,
        /// Missing points.
        lost: u32,
    },
    /// LD06 points with no scan open (dropped).
    PointsOutsideScan,
}

impl LinkError {
    /// How the device reports it: the [`wire::ErrorCode`] and its `detail`
    /// ([`wire::LinkFault`] for [`wire::ErrorCode::Link`]).
    pub fn code(&self) -> (wire::ErrorCode, u32) {
        use wire::{ErrorCode as E, LinkFault as F};
        let link = |f: F| (E::Link, f.detail());
        match *self {
            LinkError::Ld06(Ld06Error::Crc) => link(F::Ld06Crc),
            LinkError::Ld06(Ld06Error::Truncated) => link(F::Ld06Truncated),
            LinkError::Ld06(Ld06Error::BadHeader) => link(F::Ld06Header),
            LinkError::Frame(_) => link(F::Frame),
            LinkError::FrameTooLong => link(F::FrameTooLong),
            LinkError::ScanSequence { seq } => (E::ScanSequence, seq),
            LinkError::PointsLost { lost, .. } => (E::PointsLost, lost),
            LinkError::PointsOutsideScan => link(F::PointsOutsideScan),
        }
    }
}

impl From<Ld06Error> for LinkError {
    fn from(e: Ld06Error) -> Self {
        LinkError::Ld06(e)
    }
}

impl From<WireError> for LinkError {
    fn from(e: WireError) -> Self {
        LinkError::Frame(e)
    }
}

impl core::error::Error for LinkError {}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LinkError::Ld06(e) => write!(f, "{e}"),
            LinkError::Frame(e) => write!(f, "host frame: {e}"),
            LinkError::FrameTooLong => f.write_str("host frame too long"),
            LinkError::ScanSequence { seq } => write!(f, "scan framing broken at scan {seq}"),
            LinkError::PointsLost { seq, lost } => write!(f, "scan {seq}: {lost} points lost"),
            LinkError::PointsOutsideScan => f.write_str("LD06 points outside a scan"),
        }
    }
}

/// Splits one byte stream into LD06 packets and host frames (see the [module docs](self)).
#[derive(Clone, Debug)]
pub struct LinkDemux {
    buf: [u8; MAX_HOST_FRAME],
    len: usize,
    counters: LinkCounters,
}

impl Default for LinkDemux {
    fn default() -> Self {
        Self::new()
    }
}

fn bump(c: &mut u32) {
    *c = c.saturating_add(1);
}

impl LinkDemux {
    /// An empty demultiplexer.
    pub const fn new() -> Self {
        LinkDemux {
            buf: [0; MAX_HOST_FRAME],
            len: 0,
            counters: LinkCounters {
                rx_bytes: 0,
                garbage_bytes: 0,
                ld06_packets: 0,
                ld06_crc_errors: 0,
                ld06_bad_headers: 0,
                ld06_truncated: 0,
                frames: 0,
                frame_errors: 0,
                frames_bad_version: 0,
                frames_too_long: 0,
                points_outside_scan: 0,
                points_lost: 0,
                scan_seq_errors: 0,
            },
        }
    }

    /// Counters (the scan-level ones stay zero here; see [`LinkRx::counters`]).
    pub fn counters(&self) -> LinkCounters {
        self.counters
    }

    /// Feeds `data`, calling `f` for everything found, in stream order.
    pub fn feed(&mut self, data: &[u8], mut f: impl FnMut(LinkEvent)) {
        for &b in data {
            self.push(b, &mut f);
        }
    }

    /// Feeds one byte.
    pub fn push(&mut self, byte: u8, f: &mut impl FnMut(LinkEvent)) {
        bump(&mut self.counters.rx_bytes);
        if self.len == 0 && byte != HEADER && byte != 0 {
            bump(&mut self.counters.garbage_bytes);
            return;
        }
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
        self.process(f);
    }

    /// End of input: an unfinished packet or frame is dropped and counted.
    pub fn finish(&mut self, f: &mut impl FnMut(LinkEvent)) {
        match self.buf.first() {
            _ if self.len == 0 => {}
            Some(&HEADER) => {
                bump(&mut self.counters.ld06_truncated);
                f(LinkEvent::Error(LinkError::Ld06(Ld06Error::Truncated)));
            }
            _ if self.len == 1 => {} // a lone frame start: idle line
            _ => {
                bump(&mut self.counters.frame_errors);
                f(LinkEvent::Error(LinkError::Frame(WireError::TooShort)));
            }
        }
        self.len = 0;
    }

    fn drop_front(&mut self, k: usize) {
        let n = self.len.min(self.buf.len());
        let k = k.min(n);
        self.buf.copy_within(k..n, 0);
        self.len = n - k;
    }

    fn process(&mut self, f: &mut impl FnMut(LinkEvent)) {
        loop {
            let n = self.len.min(self.buf.len());
            let Some(&first) = self.buf.get(..n).and_then(|b| b.first()) else {
                return;
            };
            match first {
                HEADER => {
                    if n >= 2 && self.buf.get(1) != Some(&VER_LEN) {
                        bump(&mut self.counters.ld06_bad_headers);
                        f(LinkEvent::Error(LinkError::Ld06(Ld06Error::BadHeader)));
                        self.drop_front(1);
                        continue;
                    }
                    if n < PACKET_LEN {
                        return;
                    }
                    let mut pkt = [0u8; PACKET_LEN];
                    pkt.copy_from_slice(self.buf.get(..PACKET_LEN).unwrap_or(&[0; PACKET_LEN]));
                    match Packet::parse(&pkt) {
                        Ok(p) => {
                            bump(&mut self.counters.ld06_packets);
                            self.drop_front(PACKET_LEN);
                            f(LinkEvent::Packet(p));
                        }
                        Err(_) => {
                            let truncated = pkt
                                .windows(2)
                                .skip(1)
                                .any(|w| matches!(w, [HEADER, VER_LEN]));
                            let e = if truncated {
                                bump(&mut self.counters.ld06_truncated);
                                Ld06Error::Truncated
                            } else {
                                bump(&mut self.counters.ld06_crc_errors);
                                Ld06Error::Crc
                            };
                            f(LinkEvent::Error(LinkError::Ld06(e)));
                            self.drop_front(1);
                        }
                    }
                }
                0 => {
                    let end = self
                        .buf
                        .get(1..n)
                        .and_then(|b| b.iter().position(|&x| x == 0))
                        .map(|k| k + 1);
                    match end {
                        None if n >= self.buf.len() => {
                            bump(&mut self.counters.frames_too_long);
                            f(LinkEvent::Error(LinkError::FrameTooLong));
                            self.drop_front(1);
                        }
                        None => return,
                        // Two zeros in a row: an idle delimiter; the second one starts the frame.
                        Some(1) => self.drop_front(1),
                        Some(end) => {
                            let mut scratch = [0u8; MAX_HOST_FRAME];
                            let body = self.buf.get(1..end).unwrap_or(&[]);
                            let m = body.len().min(scratch.len());
                            let dst = scratch.get_mut(..m).unwrap_or(&mut []);
                            dst.copy_from_slice(body.get(..m).unwrap_or(&[]));
                            match wire::decode::<HostMsg>(dst) {
                                Ok(msg) => {
                                    bump(&mut self.counters.frames);
                                    self.drop_front(end + 1);
                                    f(LinkEvent::Host(msg));
                                }
                                Err(e) => {
                                    if matches!(e, WireError::Version(_)) {
                                        bump(&mut self.counters.frames_bad_version);
                                    } else {
                                        bump(&mut self.counters.frame_errors);
                                    }
                                    f(LinkEvent::Error(LinkError::Frame(e)));
                                    self.drop_front(1);
                                }
                            }
                        }
                    }
                }
                _ => {
                    bump(&mut self.counters.garbage_bytes);
                    self.drop_front(1);
                }
            }
        }
    }
}

/// What [`LinkRx`] delivers: the host's messages as they are, except the scan framing, which
/// it turns into complete scans.
#[derive(Debug, PartialEq, Eq)]
pub enum Step<'s> {
    /// A host message other than the scan framing: [`HostMsg::Config`], [`HostMsg::Pose`] (for
    /// the lidar turns read on the robot's own UART, [`crate::lidar::turn::Turns`]),
    /// [`HostMsg::Idle`] (a repeat of the last period's frame is not delivered again),
    /// [`HostMsg::Restore`] (a part of a stored tile, also inside an open scan),
    /// [`HostMsg::Resume`] or [`HostMsg::Finish`]. Never `ScanStart` or `ScanEnd`: those make a [`Step::Scan`].
    Host(HostMsg),
    /// A complete scan.
    Scan {
        /// Its sequence number.
        seq: u32,
        /// Where it was taken.
        pose: Pose,
        /// Its beams, in arrival order (LD06: clockwise).
        beams: &'s [Beam],
        /// Beams that did not fit the scan buffer.
        overflow: u32,
    },
    /// A problem (already counted); processing goes on.
    Error(LinkError),
}

/// [`LinkDemux`] plus scan framing: bytes in, [`Step`]s out.
#[derive(Clone, Debug, Default)]
pub struct LinkRx {
    demux: LinkDemux,
    open: Option<(u32, Pose)>,
    /// The scan delivered last, while no other is open (a repeat of its `ScanEnd` is ignored).
    closed: Option<u32>,
    received: u32,
    outside: u32,
    lost: u32,
    seq_errors: u32,
    /// The last idle period delivered.
    idle: Option<u32>,
}

impl LinkRx {
    /// Nothing received yet.
    pub const fn new() -> Self {
        LinkRx {
            demux: LinkDemux::new(),
            open: None,
            closed: None,
            received: 0,
            outside: 0,
            lost: 0,
            seq_errors: 0,
            idle: None,
        }
    }

    /// All receive-side counters.
    pub fn counters(&self) -> LinkCounters {
        LinkCounters {
            points_outside_scan: self.outside,
            points_lost: self.lost,
            scan_seq_errors: self.seq_errors,
            ..self.demux.counters()
        }
    }

    /// The scan being received, if any: (seq, pose).
    pub fn open_scan(&self) -> Option<(u32, Pose)> {
        self.open
    }

    /// Feeds `data`; scans are assembled in `scan` (which must not be touched between calls
    /// while a scan is open) and handed to `f` as [`Step::Scan`].
    pub fn feed<const N: usize>(
        &mut self,
        data: &[u8],
        scan: &mut ScanBuf<N>,
        mut f: impl FnMut(Step<'_>),
    ) {
        let LinkRx {
            demux,
            open,
            closed,
            received,
            outside,
            lost,
            seq_errors,
            idle,
        } = self;
        demux.feed(data, |ev| match ev {
            LinkEvent::Packet(p) => {
                if open.is_some() {
                    for i in 0..POINTS {
                        if let Some(b) = p.beam(i) {
                            scan.push(b);
                        }
                    }
                    *received = received.saturating_add(POINTS as u32);
                } else {
                    *outside = outside.saturating_add(POINTS as u32);
                    f(Step::Error(LinkError::PointsOutsideScan));
                }
            }
            LinkEvent::Host(HostMsg::ScanStart { seq, pose }) => {
                if *open == Some((seq, pose)) {
                    return; // a repeat of the open scan's start
                }
                *closed = None;
                if let Some((old, _)) = open.take() {
                    bump(seq_errors);
                    f(Step::Error(LinkError::ScanSequence { seq: old }));
                }
                scan.clear();
                *open = Some((seq, pose));
                *received = 0;
            }
            LinkEvent::Host(HostMsg::ScanEnd { seq, points }) => match open.take() {
                None if *closed == Some(seq) => {} // a repeat of the last scan's end
                Some((s, pose)) if s == seq => {
                    *closed = Some(seq);
                    if points > *received {
                        *lost = lost.saturating_add(points - *received);
                        f(Step::Error(LinkError::PointsLost {
                            seq,
                            lost: points - *received,
                        }));
                    }
                    f(Step::Scan {
                        seq,
                        pose,
                        beams: scan.beams(),
                        overflow: scan.overflow(),
                    });
                }
                _ => {
                    bump(seq_errors);
                    f(Step::Error(LinkError::ScanSequence { seq }));
                }
            },
            LinkEvent::Host(msg @ HostMsg::Config(_)) => f(Step::Host(msg)),
            LinkEvent::Host(msg @ HostMsg::Idle { seq, .. }) => {
                if *idle != Some(seq) {
                    *idle = Some(seq);
                    f(Step::Host(msg));
                }
            }
            LinkEvent::Host(HostMsg::Finish) => {
                if let Some((old, _)) = open.take() {
                    bump(seq_errors);
                    f(Step::Error(LinkError::ScanSequence { seq: old }));
                }
                f(Step::Host(HostMsg::Finish));
            }
            LinkEvent::Host(
                msg @ (HostMsg::Pose { .. } | HostMsg::Restore { .. } | HostMsg::Resume),
            ) => f(Step::Host(msg)),
            LinkEvent::Error(e) => f(Step::Error(e)),
        });
    }

    /// End of input (host replays): drops and counts anything unfinished.
    pub fn finish(&mut self, mut f: impl FnMut(Step<'_>)) {
        self.demux.finish(&mut |ev| {
            if let LinkEvent::Error(e) = ev {
                f(Step::Error(e));
            }
        });
        if let Some((old, _)) = self.open.take() {
            bump(&mut self.seq_errors);
            f(Step::Error(LinkError::ScanSequence { seq: old }));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Budget, RunConfig};
    use crate::lidar::ld06::{encode_scan, theta_cdeg};
    use crate::types::scan::Range;
    use crate::wire::encode;
    use crate::Angle;
    use crate::Pose;

    fn frame(m: &HostMsg) -> Vec<u8> {
        let mut buf = [0u8; 128];
        let mut v = vec![0u8];
        v.extend_from_slice(encode(m, &mut buf).unwrap());
        v
    }

    fn beams(n: usize, d: u32) -> Vec<Beam> {
        let mut b: Vec<Beam> = (0..n)
            .map(|i| Beam {
                angle: Angle((((i as u64) << 16) / n as u64) as u16),
                range: if i % 7 == 0 {
                    Range::NoReturn
                } else {
                    Range::Hit(d + i as u32)
                },
            })
            .collect();
        b.sort_by_key(|b| theta_cdeg(b.angle));
        b
    }

    fn scan_bytes(seq: u32, bs: &[Beam]) -> Vec<u8> {
        let mut v = frame(&HostMsg::ScanStart {
            seq,
            pose: Pose {
                x_mm: seq as i32 * 100,
                y_mm: -5,
                heading: crate::Angle(77),
            },
        });
        encode_scan(bs, 3600, 0, 3, |p| v.extend_from_slice(p)).unwrap();
        v.extend(frame(&HostMsg::ScanEnd {
            seq,
            points: bs.len() as u32,
        }));
        v
    }

    fn collect(bytes: &[u8], chunk: usize) -> (Vec<String>, LinkCounters) {
        let mut rx = LinkRx::new();
        let mut scan: ScanBuf<128> = ScanBuf::new();
        let mut out = Vec::new();
        for c in bytes.chunks(chunk) {
            rx.feed(c, &mut scan, |s| {
                out.push(match s {
                    Step::Scan {
                        seq, pose, beams, ..
                    } => format!("scan {seq} {} {}", pose.x_mm, beams.len()),
                    Step::Host(m) => format!("{m:?}"),
                    other => format!("{other:?}"),
                })
            });
        }
        rx.finish(|s| out.push(format!("{s:?}")));
        (out, rx.counters())
    }

    fn clean_stream() -> Vec<u8> {
        let cfg = RunConfig::PAPER
            .with_max_range_mm(3000)
            .with_budget(Budget::Fixed { updates: 5 });
        let mut v = frame(&HostMsg::Config(cfg));
        for k in 0..3 {
            v.extend(scan_bytes(k, &beams(48, 1000 * (k + 1))));
        }
        v.extend(frame(&HostMsg::Finish));
        v
    }

    #[test]
    fn clean_stream_gives_scans_in_any_chunking() {
        let v = clean_stream();
        for chunk in [1, 2, 7, 47, 1000] {
            let (out, c) = collect(&v, chunk);
            assert!(out[0].starts_with("Config("));
            assert_eq!(
                &out[1..],
                &["scan 0 0 48", "scan 1 100 48", "scan 2 200 48", "Finish"]
            );
            assert_eq!(c.ld06_packets, 12);
            assert_eq!(c.frames, 8);
            assert_eq!(c.garbage_bytes + c.frame_errors + c.ld06_crc_errors, 0);
        }
    }

    #[test]
    fn repeated_frames_are_idempotent() {
        // Every host frame three times (what the host sends on a noisy link): same steps, no
        // error, and one damaged copy of each changes nothing either.
        let cfg = RunConfig::PAPER
            .with_max_range_mm(3000)
            .with_budget(Budget::Fixed { updates: 5 });
        let bs = beams(48, 1500);
        let start = frame(&HostMsg::ScanStart {
            seq: 4,
            pose: Pose {
                x_mm: 400,
                y_mm: -5,
                heading: crate::Angle(77),
            },
        });
        let end = frame(&HostMsg::ScanEnd { seq: 4, points: 48 });
        let mut v = Vec::new();
        let mut damaged = Vec::new();
        for f in [frame(&HostMsg::Config(cfg)), start] {
            v.extend(f.repeat(3));
            // A payload byte (the last before the delimiter: CRC data, not a COBS code byte).
            let mut bad = f.clone();
            let last = bad.len() - 2;
            bad[last] ^= 0x40;
            damaged.extend(bad);
            damaged.extend(f.repeat(2));
        }
        let mut packets = Vec::new();
        encode_scan(&bs, 3600, 0, 3, |p| packets.extend_from_slice(p)).unwrap();
        v.extend(&packets);
        damaged.extend(&packets);
        v.extend(end.repeat(3));
        // The version byte, made another version (never 0: a zero would split the frame).
        let mut bad = end.clone();
        bad[2] ^= 0x80;
        damaged.extend(bad);
        damaged.extend(end.repeat(2));
        for (bytes, errors) in [(&v, 0), (&damaged, 3)] {
            let (out, c) = collect(bytes, 5);
            let configs = out.iter().filter(|o| o.starts_with("Config(")).count();
            assert_eq!(configs, 3 - errors / 3, "{out:?}");
            let rest: Vec<&String> = out.iter().filter(|o| !o.starts_with("Config(")).collect();
            // A rejected frame's bytes are searched again for LD06 packets; a 0x54 among them
            // is one more (harmless) LD06 error, so only frame errors are counted.
            let errs = rest.iter().filter(|o| o.starts_with("Error(Frame")).count();
            assert_eq!(errs, errors, "{out:?}");
            let other = rest
                .iter()
                .filter(|o| o.starts_with("Error(") && !o.starts_with("Error(Frame"))
                .count();
            assert!(errors > 0 || other == 0, "{out:?}");
            let scans: Vec<&&String> = rest.iter().filter(|o| o.starts_with("scan")).collect();
            assert_eq!(scans, [&"scan 4 400 48"], "{out:?}");
            assert_eq!((c.scan_seq_errors, c.points_lost), (0, 0));
        }
    }

    #[test]
    fn scan_beams_survive_the_link() {
        let bs = beams(48, 2000);
        let v = scan_bytes(0, &bs);
        let mut rx = LinkRx::new();
        let mut scan: ScanBuf<64> = ScanBuf::new();
        let mut got = Vec::new();
        rx.feed(&v, &mut scan, |s| {
            if let Step::Scan { beams, pose, .. } = s {
                got = beams.to_vec();
                assert_eq!(pose.heading, Angle(77));
            }
        });
        assert_eq!(got.len(), 48);
        for (a, b) in got.iter().zip(&bs) {
            assert_eq!(a.range, b.range);
            assert!(a.angle.signed_diff(b.angle).abs() <= 2, "{a:?} {b:?}");
        }
    }

    #[test]
    fn resyncs_after_garbage_truncation_and_bad_frames() {
        let cfg = RunConfig::PAPER
            .with_max_range_mm(3000)
            .with_budget(Budget::Fixed { updates: 5 });
        let mut v = frame(&HostMsg::Config(cfg));
        v.extend_from_slice(&[0x54, 0x54, 0x2C, 0x99, 0x00, 0x13, 0x00, 0x00]); // junk
        let s0 = scan_bytes(0, &beams(48, 1000));
        v.extend_from_slice(&s0);
        // A frame with a flipped bit, a truncated packet, random bytes, then a good scan.
        let mut bad = frame(&HostMsg::ScanStart {
            seq: 9,
            pose: Pose::default(),
        });
        bad[3] ^= 0x10;
        v.extend(bad);
        let p = &s0[s0.len() - 200..];
        let pk = p.windows(2).position(|w| w == [0x54, 0x2C]).unwrap();
        v.extend_from_slice(&p[pk..pk + 20]);
        v.extend_from_slice(&[0x00; 3]);
        v.extend((0..150u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
        v.extend(scan_bytes(1, &beams(48, 1500)));
        v.extend(frame(&HostMsg::Finish));
        let (out, c) = collect(&v, 5);
        let scans: Vec<&String> = out.iter().filter(|s| s.starts_with("scan")).collect();
        assert_eq!(scans, ["scan 0 0 48", "scan 1 100 48"], "{out:#?}");
        assert_eq!(out.last().unwrap(), "Finish");
        assert!(c.garbage_bytes > 0);
        assert!(c.frame_errors + c.frames_too_long >= 1);
        assert_eq!(c.ld06_packets, 8);
        assert_eq!(c.points_lost, 0);
    }

    #[test]
    fn framing_errors_are_counted() {
        let bs = beams(24, 1000);
        let mut v = Vec::new();
        // Points before any scan.
        encode_scan(&bs, 3600, 0, 3, |p| v.extend_from_slice(p)).unwrap();
        // A scan that loses a packet (corrupted) and one that ends with the wrong seq.
        let mut s = scan_bytes(0, &bs);
        let first_pkt = s.windows(2).position(|w| w == [0x54, 0x2C]).unwrap();
        s[first_pkt + 10] ^= 1;
        v.extend(s);
        v.extend(frame(&HostMsg::ScanStart {
            seq: 1,
            pose: Pose::default(),
        }));
        v.extend(frame(&HostMsg::ScanEnd { seq: 2, points: 0 }));
        v.extend(frame(&HostMsg::ScanStart {
            seq: 3,
            pose: Pose::default(),
        }));
        let (out, c) = collect(&v, 3);
        assert_eq!(c.points_outside_scan, 24);
        assert_eq!(c.points_lost, 12);
        assert_eq!(c.ld06_crc_errors, 1);
        assert_eq!(c.scan_seq_errors, 2, "{out:#?}"); // seq 2 ≠ 1, and 3 never ended
        assert!(out.contains(&"scan 0 0 12".to_string()));
    }

    #[test]
    fn never_panics_on_noise() {
        let mut x = 0x9E37_79B9u32;
        let mut rx = LinkRx::new();
        let mut scan: ScanBuf<16> = ScanBuf::new();
        let clean = clean_stream();
        for round in 0..50 {
            let mut data = Vec::new();
            for _ in 0..2000 {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                data.push(match x % 11 {
                    0 => 0,
                    1 => 0x54,
                    2 => 0x2C,
                    _ => (x >> 8) as u8,
                });
            }
            if round % 5 == 0 {
                data.extend_from_slice(&clean);
            }
            rx.feed(&data, &mut scan, |_| {});
        }
        assert!(rx.counters().rx_bytes > 100_000);
        assert!(rx.counters().ld06_packets >= 100, "{:?}", rx.counters());
    }
}
