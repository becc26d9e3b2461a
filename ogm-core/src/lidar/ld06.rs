//! The LDROBOT LD06 / LD19 lidar wire format: a sans-IO parser, a blocking scan reader over
//! [`embedded_io::Read`], and an encoder (for the simulator and tests). The same code runs on the
//! host and on the Cortex-M4.
//!
//! ## Packets
//! The sensor streams 47-byte packets at 230400 baud, 8N1, one way (no commands):
//!
//! | bytes | field | |
//! |---|---|---|
//! | 0 | header `0x54` | |
//! | 1 | ver/len `0x2C` | high 3 bits: type 1; low 5 bits: 12 points |
//! | 2–3 | speed, °/s (u16 LE) | 3600 = 10 Hz |
//! | 4–5 | start angle, 0.01° (u16 LE) | of point 0 |
//! | 6–41 | 12 × (distance mm u16 LE, intensity u8) | distance 0 = no return |
//! | 42–43 | end angle, 0.01° (u16 LE) | of point 11 |
//! | 44–45 | timestamp, ms (u16 LE, wraps at 30000) | |
//! | 46 | CRC-8 over bytes 0–45 | polynomial 0x4D, init 0, not reflected |
//!
//! Point `i`'s angle is interpolated, `start + span·i/11` with `span = (end − start) mod 360°`
//! (integer centidegrees, truncating, as in the vendor SDK). LD06 angles grow **clockwise** seen
//! from above, with 0° ahead; ogm-core's [`Angle`] grows counter-clockwise, so a point at θ has
//! the beam angle `−θ` ([`beam_angle`]).
//!
//! ## Robustness
//! Nothing here panics on input. [`Ld06Parser`] hunts for `0x54 0x2C`, waits for 47 bytes and
//! checks the CRC; after a bad header or a CRC failure it drops the first byte and resumes at the
//! next `0x54 0x2C` *inside the rejected bytes*, so a packet that follows a truncated one (or a
//! burst of garbage) is still found. It counts packets, CRC failures, bad headers, truncated
//! packets (a CRC failure with a new header inside: the packet was cut short) and bytes skipped
//! ([`Ld06Counters`]).

use crate::lidar::encode::EncodeError;
use crate::lidar::source::ReadError;
use crate::types::angle::Angle;
use crate::types::scan::{Beam, Range, ScanBuf};

/// Bytes per packet.
pub const PACKET_LEN: usize = 47;
/// First byte of every packet.
pub const HEADER: u8 = 0x54;
/// Second byte: packet type 1, 12 points.
pub const VER_LEN: u8 = 0x2C;
/// Points per packet.
pub const POINTS: usize = 12;
/// One turn in centidegrees.
pub const TURN_CDEG: u32 = 36_000;
/// Intensity the encoder writes for a return (the LD06 reports ~200 for white targets).
pub const HIT_INTENSITY: u8 = 200;

/// The LD06's CRC-8 table (polynomial 0x4D, MSB first), built at compile time.
static CRC_TABLE: [u8; 256] = crc8_table();

// Const-evaluated: an out-of-range index fails compilation, not at run time.
#[allow(clippy::indexing_slicing)]
const fn crc8_table() -> [u8; 256] {
    let mut t = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u8;
        let mut k = 0;
        while k < 8 {
            c = if c & 0x80 != 0 {
                (c << 1) ^ 0x4D
            } else {
                c << 1
            };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
}

/// The LD06 CRC-8 of `bytes`.
pub fn crc8(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |crc, &b| {
        CRC_TABLE.get(usize::from(crc ^ b)).copied().unwrap_or(0)
    })
}

/// One measurement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point {
    /// Distance in mm; 0 = no return.
    pub distance_mm: u16,
    /// Return strength (0–255).
    pub intensity: u8,
}

/// A decoded packet.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Packet {
    /// Rotation speed, degrees per second.
    pub speed_dps: u16,
    /// Angle of point 0, centidegrees clockwise.
    pub start_cdeg: u16,
    /// Angle of point 11, centidegrees clockwise.
    pub end_cdeg: u16,
    /// Sensor timestamp, ms (wraps at 30000).
    pub timestamp_ms: u16,
    /// The measurements.
    pub points: [Point; POINTS],
}

/// What can be wrong with a packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Ld06Error {
    /// `0x54` not followed by `0x2C`.
    BadHeader,
    /// The CRC did not match.
    Crc,
    /// The CRC did not match and a new header starts inside the packet: it was cut short.
    Truncated,
}

impl core::error::Error for Ld06Error {}

impl core::fmt::Display for Ld06Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Ld06Error::BadHeader => "LD06: bad header",
            Ld06Error::Crc => "LD06: CRC mismatch",
            Ld06Error::Truncated => "LD06: truncated packet",
        })
    }
}

#[inline]
fn le16(lo: u8, hi: u8) -> u16 {
    u16::from_le_bytes([lo, hi])
}

impl Packet {
    /// Decodes and checks 47 bytes.
    pub fn parse(b: &[u8; PACKET_LEN]) -> Result<Packet, Ld06Error> {
        if b[0] != HEADER || b[1] != VER_LEN {
            return Err(Ld06Error::BadHeader);
        }
        let body = b.get(..PACKET_LEN - 1).unwrap_or(&[]);
        if crc8(body) != b[PACKET_LEN - 1] {
            return Err(Ld06Error::Crc);
        }
        let mut points = [Point::default(); POINTS];
        for (p, c) in points
            .iter_mut()
            .zip(body.get(6..42).unwrap_or(&[]).chunks_exact(3))
        {
            if let [lo, hi, intensity] = *c {
                *p = Point {
                    distance_mm: le16(lo, hi),
                    intensity,
                };
            }
        }
        Ok(Packet {
            speed_dps: le16(b[2], b[3]),
            start_cdeg: le16(b[4], b[5]),
            end_cdeg: le16(b[42], b[43]),
            timestamp_ms: le16(b[44], b[45]),
            points,
        })
    }

    /// The 47 wire bytes, CRC included.
    pub fn to_bytes(&self) -> [u8; PACKET_LEN] {
        let mut b = [0u8; PACKET_LEN];
        b[0] = HEADER;
        b[1] = VER_LEN;
        [b[2], b[3]] = self.speed_dps.to_le_bytes();
        [b[4], b[5]] = self.start_cdeg.to_le_bytes();
        for (c, p) in b
            .get_mut(6..42)
            .unwrap_or(&mut [])
            .chunks_exact_mut(3)
            .zip(&self.points)
        {
            let [lo, hi] = p.distance_mm.to_le_bytes();
            c.copy_from_slice(&[lo, hi, p.intensity]);
        }
        [b[42], b[43]] = self.end_cdeg.to_le_bytes();
        [b[44], b[45]] = self.timestamp_ms.to_le_bytes();
        b[PACKET_LEN - 1] = crc8(b.get(..PACKET_LEN - 1).unwrap_or(&[]));
        b
    }

    /// Angle of point `i` (0..12), centidegrees clockwise in `0..36000`.
    pub fn angle_cdeg(&self, i: usize) -> u16 {
        let start = u32::from(self.start_cdeg) % TURN_CDEG;
        let end = u32::from(self.end_cdeg) % TURN_CDEG;
        let span = (end + TURN_CDEG - start) % TURN_CDEG;
        let i = (i.min(POINTS - 1)) as u32;
        ((start + span * i / (POINTS as u32 - 1)) % TURN_CDEG) as u16
    }

    /// Point `i` as a beam (ogm-core angle, no return for distance 0); `None` if `i ≥ 12`.
    pub fn beam(&self, i: usize) -> Option<Beam> {
        let p = self.points.get(i)?;
        Some(Beam {
            angle: beam_angle(self.angle_cdeg(i)),
            range: if p.distance_mm == 0 {
                Range::NoReturn
            } else {
                Range::Hit(u32::from(p.distance_mm))
            },
        })
    }
}

/// The ogm-core beam angle (counter-clockwise) of an LD06 angle (centidegrees clockwise).
pub fn beam_angle(theta_cdeg: u16) -> Angle {
    Angle::from_centidegrees(TURN_CDEG - u32::from(theta_cdeg) % TURN_CDEG)
}

/// The LD06 angle (centidegrees clockwise, `0..36000`) nearest to a beam angle.
pub fn theta_cdeg(angle: Angle) -> u16 {
    let ccw = (u32::from(angle.0) * TURN_CDEG + (1 << 15)) >> 16; // 0..=36000
    ((TURN_CDEG - ccw % TURN_CDEG) % TURN_CDEG) as u16
}

/// What the parser saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ld06Counters {
    /// Good packets.
    pub packets: u32,
    /// Packets with a CRC mismatch.
    pub crc_errors: u32,
    /// `0x54` not followed by `0x2C`.
    pub bad_headers: u32,
    /// Packets cut short (CRC mismatch with a new header inside, or unfinished at the end).
    pub truncated: u32,
    /// Bytes skipped while looking for a header.
    pub garbage_bytes: u32,
}

/// The sans-IO LD06 parser: feed it bytes as they arrive, get packets or errors back.
#[derive(Clone, Debug)]
pub struct Ld06Parser {
    buf: [u8; PACKET_LEN],
    len: usize,
    counters: Ld06Counters,
}

impl Default for Ld06Parser {
    fn default() -> Self {
        Self::new()
    }
}

impl Ld06Parser {
    /// A parser looking for its first header.
    pub const fn new() -> Self {
        Ld06Parser {
            buf: [0; PACKET_LEN],
            len: 0,
            counters: Ld06Counters {
                packets: 0,
                crc_errors: 0,
                bad_headers: 0,
                truncated: 0,
                garbage_bytes: 0,
            },
        }
    }

    /// Counters so far.
    pub fn counters(&self) -> Ld06Counters {
        self.counters
    }

    /// Bytes of an unfinished packet held back.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Feeds `data`, calling `f` for every packet or error, in stream order.
    pub fn feed(&mut self, data: &[u8], mut f: impl FnMut(Result<Packet, Ld06Error>)) {
        for &b in data {
            if let Some(r) = self.push(b) {
                f(r);
            }
        }
    }

    /// Feeds one byte. One byte completes at most one packet (after a rejection fewer than 47
    /// bytes are held back), so this returns at most one result.
    pub fn push(&mut self, byte: u8) -> Option<Result<Packet, Ld06Error>> {
        if self.len == 0 {
            if byte == HEADER {
                self.buf[0] = byte;
                self.len = 1;
            } else {
                self.counters.garbage_bytes = self.counters.garbage_bytes.saturating_add(1);
            }
            return None;
        }
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
        if self.len == 2 && byte != VER_LEN {
            self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
            self.resync();
            return Some(Err(Ld06Error::BadHeader));
        }
        if self.len < PACKET_LEN {
            return None;
        }
        match Packet::parse(&self.buf) {
            Ok(p) => {
                self.len = 0;
                self.counters.packets = self.counters.packets.saturating_add(1);
                Some(Ok(p))
            }
            Err(_) => {
                let e = if header_inside(&self.buf) {
                    self.counters.truncated = self.counters.truncated.saturating_add(1);
                    Ld06Error::Truncated
                } else {
                    self.counters.crc_errors = self.counters.crc_errors.saturating_add(1);
                    Ld06Error::Crc
                };
                self.resync();
                Some(Err(e))
            }
        }
    }

    /// End of stream: an unfinished packet counts as truncated (and is dropped).
    pub fn finish(&mut self) -> Option<Ld06Error> {
        if self.len == 0 {
            return None;
        }
        self.len = 0;
        self.counters.truncated = self.counters.truncated.saturating_add(1);
        Some(Ld06Error::Truncated)
    }

    /// Drops the rejected candidate's first byte and everything up to the next plausible
    /// header (`0x54` followed by `0x2C`, or by nothing yet).
    fn resync(&mut self) {
        let n = self.len.min(PACKET_LEN);
        let p = next_header(self.buf.get(..n).unwrap_or(&[]));
        self.counters.garbage_bytes = self
            .counters
            .garbage_bytes
            .saturating_add(p.saturating_sub(1) as u32);
        // Element by element rather than `copy_within(p..n, 0)`: the compiler cannot see that
        // `p <= n`, and its range check would pull a panic path (and `core::fmt`, ~3 KiB of
        // flash) into the firmware.
        let kept = n.saturating_sub(p);
        for i in 0..kept {
            let b = self.buf.get(p + i).copied().unwrap_or(0);
            if let Some(slot) = self.buf.get_mut(i) {
                *slot = b;
            }
        }
        self.len = kept;
    }
}

/// Index ≥ 1 of the first plausible header in `b`, or `b.len()`.
pub(crate) fn next_header(b: &[u8]) -> usize {
    (1..b.len())
        .find(|&p| b.get(p) == Some(&HEADER) && b.get(p + 1).is_none_or(|&v| v == VER_LEN))
        .unwrap_or(b.len())
}

/// Whether a full header pair starts somewhere after byte 0.
fn header_inside(b: &[u8]) -> bool {
    b.windows(2).skip(1).any(|w| matches!(w, [HEADER, VER_LEN]))
}

/// A blocking LD06 driver over any [`embedded_io::Read`] (a UART on the robot, a byte slice or a
/// pipe on the host): [`Ld06Reader::read_scan`] assembles one revolution per scan.
///
/// A revolution ends where the angle wraps (drops by more than 180°); the points after the wrap
/// start the next scan. The first scan after start-up is usually a partial turn. Bad packets are
/// skipped and counted ([`Ld06Reader::counters`]); no point of a good packet is lost.
pub struct Ld06Reader<R> {
    rx: R,
    parser: Ld06Parser,
    chunk: [u8; 64],
    chunk_len: usize,
    chunk_pos: usize,
    carry: [Beam; POINTS],
    n_carry: usize,
    last_theta: Option<u16>,
    revolutions: u32,
}

impl<R: embedded_io::Read> Ld06Reader<R> {
    /// A reader on `rx`.
    pub fn new(rx: R) -> Self {
        Ld06Reader {
            rx,
            parser: Ld06Parser::new(),
            chunk: [0; 64],
            chunk_len: 0,
            chunk_pos: 0,
            carry: [Beam {
                angle: Angle::ZERO,
                range: Range::NoReturn,
            }; POINTS],
            n_carry: 0,
            last_theta: None,
            revolutions: 0,
        }
    }

    /// Parser counters.
    pub fn counters(&self) -> Ld06Counters {
        self.parser.counters()
    }

    /// Completed revolutions (scans returned).
    pub fn revolutions(&self) -> u32 {
        self.revolutions
    }

    /// The byte source back.
    pub fn into_inner(self) -> R {
        self.rx
    }

    /// The next good packet.
    pub fn next_packet(&mut self) -> Result<Packet, ReadError<R::Error>> {
        loop {
            while self.chunk_pos < self.chunk_len {
                let b = self.chunk.get(self.chunk_pos).copied().unwrap_or(0);
                self.chunk_pos += 1;
                if let Some(Ok(p)) = self.parser.push(b) {
                    return Ok(p);
                }
            }
            let n = self.rx.read(&mut self.chunk).map_err(ReadError::Io)?;
            if n == 0 {
                self.parser.finish();
                return Err(ReadError::Eof);
            }
            (self.chunk_len, self.chunk_pos) = (n.min(self.chunk.len()), 0);
        }
    }
}

impl<R: embedded_io::Read> Ld06Reader<R> {
    /// Blocks until the next complete scan (one revolution) has been read and writes it into
    /// `scan`, which it clears first; beams beyond `scan`'s capacity are counted as its overflow.
    pub fn read_scan<const N: usize>(
        &mut self,
        scan: &mut ScanBuf<N>,
    ) -> Result<(), ReadError<R::Error>> {
        scan.clear();
        for b in self.carry.iter().take(self.n_carry) {
            scan.push(*b);
        }
        self.n_carry = 0;
        loop {
            let p = self.next_packet()?;
            let mut wrapped = false;
            for i in 0..POINTS {
                let theta = p.angle_cdeg(i);
                if let Some(last) = self.last_theta {
                    if theta < last && last - theta > 18_000 && !scan.beams().is_empty() {
                        wrapped = true;
                    }
                }
                self.last_theta = Some(theta);
                let Some(beam) = p.beam(i) else { continue };
                if wrapped {
                    if let Some(slot) = self.carry.get_mut(self.n_carry) {
                        *slot = beam;
                        self.n_carry += 1;
                    }
                } else {
                    scan.push(beam);
                }
            }
            if wrapped {
                self.revolutions = self.revolutions.saturating_add(1);
                return Ok(());
            }
        }
    }
}

/// Packs `beams` into LD06 packets, 12 per packet, in the given order (which should be
/// clockwise, i.e. increasing [`theta_cdeg`], as the sensor sends them), calling `out` with each
/// packet's bytes. A packet's start/end angles are its first/last beam's; the receiver
/// interpolates the ten in between (exact for evenly spaced beams up to the 0.01° wire
/// resolution). `Hit(0)` is sent as 1 mm, hits beyond 65535 mm as no return (distance 0).
/// Timestamps start at `timestamp_ms` and advance by `ms_per_packet`. Returns the packets sent.
pub fn encode_scan(
    beams: &[Beam],
    speed_dps: u16,
    timestamp_ms: u16,
    ms_per_packet: u16,
    mut out: impl FnMut(&[u8; PACKET_LEN]),
) -> Result<usize, EncodeError> {
    if beams.len() % POINTS != 0 {
        return Err(EncodeError::NotMultipleOf12);
    }
    let mut ts = u32::from(timestamp_ms);
    let mut n = 0;
    for group in beams.chunks_exact(POINTS) {
        let (Some(first), Some(last)) = (group.first(), group.last()) else {
            continue;
        };
        let mut points = [Point::default(); POINTS];
        for (p, b) in points.iter_mut().zip(group) {
            *p = match b.range {
                Range::Hit(mm) if mm <= u32::from(u16::MAX) => Point {
                    distance_mm: (mm as u16).max(1),
                    intensity: HIT_INTENSITY,
                },
                _ => Point::default(),
            };
        }
        let packet = Packet {
            speed_dps,
            start_cdeg: theta_cdeg(first.angle),
            end_cdeg: theta_cdeg(last.angle),
            timestamp_ms: (ts % 30_000) as u16,
            points,
        };
        out(&packet.to_bytes());
        ts += u32::from(ms_per_packet);
        n += 1;
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example packet of the LD06/LD19 development manual (CRC 0x50).
    const MANUAL: [u8; PACKET_LEN] = [
        0x54, 0x2C, 0x68, 0x08, 0xAB, 0x7E, 0xE0, 0x00, 0xE4, 0xDC, 0x00, 0xE2, 0xD9, 0x00, 0xE5,
        0xD5, 0x00, 0xE3, 0xD3, 0x00, 0xE4, 0xD0, 0x00, 0xE9, 0xCD, 0x00, 0xE4, 0xCA, 0x00, 0xE2,
        0xC7, 0x00, 0xE9, 0xC5, 0x00, 0xE5, 0xC2, 0x00, 0xE5, 0xC0, 0x00, 0xE5, 0xBE, 0x82, 0x3A,
        0x1A, 0x50,
    ];

    fn packet(start: u16, end: u16, d: u16) -> Packet {
        Packet {
            speed_dps: 3600,
            start_cdeg: start,
            end_cdeg: end,
            timestamp_ms: 1234,
            points: core::array::from_fn(|i| Point {
                distance_mm: d + i as u16,
                intensity: 100 + i as u8,
            }),
        }
    }

    #[test]
    fn crc_table_matches_the_datasheet() {
        assert_eq!(
            &CRC_TABLE[..16],
            &[
                0x00, 0x4d, 0x9a, 0xd7, 0x79, 0x34, 0xe3, 0xae, 0xf2, 0xbf, 0x68, 0x25, 0x8b, 0xc6,
                0x11, 0x5c
            ]
        );
        assert_eq!(crc8(&MANUAL[..46]), 0x50);
    }

    #[test]
    fn parses_the_manual_example() {
        let p = Packet::parse(&MANUAL).unwrap();
        assert_eq!(p.speed_dps, 2152);
        assert_eq!(p.start_cdeg, 32427);
        assert_eq!(p.end_cdeg, 33470);
        assert_eq!(p.timestamp_ms, 6714);
        assert_eq!(
            p.points[0],
            Point {
                distance_mm: 224,
                intensity: 228
            }
        );
        assert_eq!(p.points[11].distance_mm, 192);
        assert_eq!(p.angle_cdeg(0), 32427);
        assert_eq!(p.angle_cdeg(11), 33470);
        assert_eq!(p.angle_cdeg(1), 32427 + 1043 / 11);
        assert_eq!(p.to_bytes(), MANUAL);
    }

    #[test]
    fn angles_wrap_inside_a_packet() {
        let p = packet(35_900, 1_000, 500);
        assert_eq!(p.angle_cdeg(0), 35_900);
        assert_eq!(p.angle_cdeg(11), 1_000);
        assert_eq!(p.angle_cdeg(1), 0);
        assert!(p.angle_cdeg(2) < 1_000);
        // Clockwise 90° is counter-clockwise 270°.
        assert_eq!(beam_angle(9_000), Angle(49_152));
        assert_eq!(beam_angle(0), Angle(0));
        assert_eq!(theta_cdeg(Angle(49_152)), 9_000);
        assert_eq!(theta_cdeg(Angle(0)), 0);
        for a in (0..=u16::MAX).step_by(7) {
            let back = beam_angle(theta_cdeg(Angle(a)));
            assert!(back.signed_diff(Angle(a)).abs() <= 1, "{a} -> {back:?}");
        }
    }

    #[test]
    fn parser_resyncs_after_garbage_truncation_and_corruption() {
        let good = packet(0, 1100, 1000).to_bytes();
        let mut corrupt = good;
        corrupt[20] ^= 0x40;
        let mut stream = Vec::new();
        stream.extend_from_slice(&[0x00, 0x54, 0x54, 0x13, 0xFF]); // garbage + bad header
        stream.extend_from_slice(&good);
        stream.extend_from_slice(&good[..30]); // truncated
        stream.extend_from_slice(&good);
        stream.extend_from_slice(&corrupt);
        stream.extend_from_slice(&good);
        stream.extend_from_slice(&good[..10]); // unfinished at the end
        let mut p = Ld06Parser::new();
        let mut out = Vec::new();
        p.feed(&stream, |r| out.push(r));
        let goods = out.iter().filter(|r| r.is_ok()).count();
        assert_eq!(goods, 3);
        assert!(out.contains(&Err(Ld06Error::Truncated)));
        assert!(out.contains(&Err(Ld06Error::Crc)));
        assert!(out.contains(&Err(Ld06Error::BadHeader)));
        assert_eq!(p.finish(), Some(Ld06Error::Truncated));
        let c = p.counters();
        assert_eq!(c.packets, 3);
        assert_eq!((c.crc_errors, c.truncated, c.bad_headers), (1, 2, 2));
    }

    #[test]
    fn parser_never_panics_and_finds_packets_in_noise() {
        // Deterministic pseudo-random noise around good packets.
        let good = packet(100, 1200, 3000).to_bytes();
        let mut x = 0x1234_5678u32;
        let mut stream = Vec::new();
        for k in 0..200 {
            for _ in 0..(k % 17) {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                stream.push(if x % 5 == 0 { HEADER } else { x as u8 });
            }
            stream.extend_from_slice(&good);
        }
        let mut p = Ld06Parser::new();
        let mut n = 0;
        p.feed(&stream, |r| {
            if let Ok(pk) = r {
                assert_eq!(pk, Packet::parse(&good).unwrap());
                n += 1;
            }
        });
        // A garbage header right before a packet can swallow it only if the CRC then matches
        // by chance; with resync inside the rejected bytes every packet is recovered.
        assert_eq!(n, 200);
    }

    #[test]
    fn reader_assembles_revolutions() {
        // Two revolutions of 36 beams each (3 packets), plus the start of a third.
        let beams: Vec<Beam> = (0..36)
            .map(|i| Beam {
                angle: Angle::from_centidegrees(36_000 - i * 1000),
                range: if i % 5 == 0 {
                    Range::NoReturn
                } else {
                    Range::Hit(1000 + i)
                },
            })
            .collect();
        let mut bytes = Vec::new();
        for _ in 0..3 {
            encode_scan(&beams, 3600, 0, 3, |p| bytes.extend_from_slice(p)).unwrap();
        }
        let mut r = Ld06Reader::new(&bytes[..]);
        let mut scan: ScanBuf<64> = ScanBuf::new();
        for _ in 0..2 {
            r.read_scan(&mut scan).unwrap();
            assert_eq!(scan.beams().len(), 36);
            for (a, b) in scan.beams().iter().zip(&beams) {
                assert_eq!(a.range, b.range);
                assert!(a.angle.signed_diff(b.angle).abs() <= 1);
            }
        }
        assert_eq!(r.read_scan(&mut scan), Err(ReadError::Eof));
        assert_eq!(r.revolutions(), 2);
        assert_eq!(r.counters().packets, 9);
    }

    #[test]
    fn encoder_rejects_partial_packets() {
        let b = [Beam {
            angle: Angle::ZERO,
            range: Range::Hit(0),
        }; 13];
        assert_eq!(
            encode_scan(&b, 3600, 0, 1, |_| {}),
            Err(EncodeError::NotMultipleOf12)
        );
        let mut got = None;
        encode_scan(&b[..12], 3600, 0, 1, |p| got = Some(*p)).unwrap();
        let p = Packet::parse(&got.unwrap()).unwrap();
        assert_eq!(p.points[0].distance_mm, 1);
    }
}
