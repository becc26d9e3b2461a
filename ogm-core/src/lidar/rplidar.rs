//! The Slamtec RPLIDAR A1 / A2 serial protocol (standard `SCAN` mode): request builders, a sans-IO
//! response parser, a blocking scan reader over [`embedded_io::Read`], and an encoder (for the
//! simulator and tests). The same code runs on the host and on the Cortex-M4.
//!
//! ## Link
//! 115200 baud, 8N1, for the A1 (A1M8) and the A2M8 — the only rate that matters here; the A2M12
//! and the A3 use 256000 baud (same protocol, the parser does not care). Unlike the LD06 the
//! sensor is commanded: the host sends a request, the sensor answers with a response descriptor
//! and then one response (`GET_INFO`, `GET_HEALTH`, `GET_SAMPLERATE`) or an endless stream of
//! nodes (`SCAN`, `FORCE_SCAN`) until `STOP`. The A1's motor is not commanded over the link: it
//! runs from the `MOTOCTL` pin (PWM or high; on the USB adapter, DTR low). A2 units behind the
//! accessory board take [`set_motor_pwm_request`] instead.
//!
//! ## Requests (host → sensor)
//!
//! | bytes | |
//! |---|---|
//! | `A5 cmd` | requests without payload ([`request`]) |
//! | `A5 cmd n payload[n] checksum` | `checksum` = XOR of every byte before it, `A5` included ([`request_with_payload`]) |
//!
//! | command | code | response |
//! |---|---|---|
//! | `STOP` | `0x25` | none; wait ≥ 1 ms before the next request |
//! | `RESET` | `0x40` | none (reboots; prints a text banner, which the parser skips); wait ≥ 2 ms |
//! | `SCAN` | `0x20` | descriptor [`SCAN_DESCRIPTOR`], then 5-byte nodes until `STOP` |
//! | `FORCE_SCAN` | `0x21` | as `SCAN`, but also while the motor is not at speed |
//! | `GET_INFO` | `0x50` | descriptor type `0x04`, 20 bytes ([`DeviceInfo`]) |
//! | `GET_HEALTH` | `0x52` | descriptor type `0x06`, 3 bytes ([`Health`]) |
//! | `GET_SAMPLERATE` | `0x59` | descriptor type `0x15`, 4 bytes ([`SampleRate`]; firmware ≥ 1.17) |
//! | `EXPRESS_SCAN` | `0x82` | 5-byte payload ([`express_scan_request`]); descriptor type `0x82`, 84-byte capsules — **not supported** by the parser |
//!
//! ## Response descriptor (sensor → host)
//!
//! | bytes | field | |
//! |---|---|---|
//! | 0–1 | `A5 5A` | |
//! | 2–5 | u32 LE | bits 0–29: bytes per response (per node for a stream); bits 30–31: send mode (0 single, 1 multiple) |
//! | 6 | data type | `0x81` scan nodes, `0x04` info, `0x06` health, `0x15` sample rate |
//!
//! `SCAN`'s descriptor is `A5 5A 05 00 00 40 81`: length 5, mode 1 (multiple), type `0x81`.
//!
//! ## Scan nodes
//!
//! | byte | bits 7…0 | |
//! |---|---|---|
//! | 0 | `quality[5:0]`, `!S`, `S` | `S` = first node of a new 360° scan; bit 1 must be the inverse of bit 0 |
//! | 1 | `angle_q6[6:0]`, `C` | `C` = check bit, always 1 |
//! | 2 | `angle_q6[14:7]` | |
//! | 3–4 | `distance_q2` (u16 LE) | mm × 4; 0 = no return (invalid measurement) |
//!
//! The angle is `angle_q6 / 64` degrees, growing **clockwise** seen from above, 0° ahead (like
//! the LD06); ogm-core's [`Angle`] grows counter-clockwise, so a node at θ has the beam angle `−θ`
//! ([`beam_angle`]). `angle_q6` has 15 bits, so values of 360° and more are representable; a
//! locked parser passes them on and [`beam_angle`] wraps them. Distances become whole millimetres,
//! rounded to nearest (a non-zero `distance_q2` below 2 still counts as a 1 mm return).
//!
//! Resolution (the round-trip tolerance of [`encode_scan`] → [`RplidarParser`]): an angle
//! survives beam → node → beam within ±1 [`Angle`] unit (1/65536 turn; a `q6` step is 2.84 units)
//! and node → beam → node exactly; `Hit(mm)` survives exactly for 1 ≤ mm ≤ [`MAX_RANGE_MM`].
//!
//! ## Robustness
//! Nothing here panics on input. There is no CRC: a node carries only three check bits (`S`
//! vs `!S`, `C`), so a random 5-byte window passes with probability 1/4. [`RplidarParser`]
//! therefore has two ways to find node boundaries:
//!
//! * **descriptor**: after `A5 5A 05 00 00 40 81` (or any type-`0x81` descriptor of length 5) the
//!   next byte starts a node — the normal start-up after sending [`REQ_SCAN`];
//! * **lock-on** (started mid-stream, or after losing sync): a candidate boundary is accepted only
//!   when [`LOCK_NODES`] consecutive nodes pass the check bits *and* look like a scan — every
//!   angle below 360°, only the first node may carry `S = 1`, and each angle is 1…
//!   [`MAX_LOCK_STEP_Q6`] q6 units (10°) clockwise of the previous one. Real sensors step ≈ 1°
//!   per node; a misaligned window almost never passes (e.g. one shifted by a byte has `S = 1` on
//!   every node). The confirmed nodes are then all delivered, so lock-on loses nothing (except
//!   fewer than [`LOCK_NODES`] nodes at the very end of a stream, which it cannot confirm).
//!
//! Once locked, every 5 bytes are one node; a node whose check bits fail is reported
//! ([`RplidarError::StartFlags`] / [`RplidarError::CheckBit`]) and the parser goes back to
//! lock-on from that node's first byte, so the node boundaries after a bit flip, a lost byte or a
//! burst of garbage are found again. Without a CRC some damage goes through: a flipped distance
//! or quality bit is undetectable, and after a lost byte a few misaligned nodes may pass the check
//! bits before one fails (each passes with probability ≈ 1/4…1/2, depending on the data; the
//! lock-on that follows is as strict as at start-up). A descriptor (`A5 5A` can never start a valid node) is
//! recognised anywhere a node could start. Unknown or unsupported descriptors (express scan) are
//! reported and the parser keeps hunting. It counts nodes, bad nodes, scan starts, descriptors,
//! responses, lock-ons, skipped bytes and truncated responses ([`RplidarCounters`]).

use crate::lidar::source::{RangeSensor, ReadError};
use crate::types::angle::{Angle, FULL_TURN};
use crate::types::scan::{Beam, Range, ScanBuf};

/// First byte of every request, and of every response descriptor.
pub const SYNC1: u8 = 0xA5;
/// Second byte of every response descriptor.
pub const SYNC2: u8 = 0x5A;

/// `STOP`: leave scanning; no response.
pub const CMD_STOP: u8 = 0x25;
/// `RESET`: reboot the sensor core; no response.
pub const CMD_RESET: u8 = 0x40;
/// `SCAN`: start the standard node stream.
pub const CMD_SCAN: u8 = 0x20;
/// `FORCE_SCAN`: like `SCAN`, without waiting for the motor to reach speed.
pub const CMD_FORCE_SCAN: u8 = 0x21;
/// `GET_INFO`: model, firmware, hardware, serial number.
pub const CMD_GET_INFO: u8 = 0x50;
/// `GET_HEALTH`: status and error code.
pub const CMD_GET_HEALTH: u8 = 0x52;
/// `GET_SAMPLERATE`: time per sample in standard and express mode.
pub const CMD_GET_SAMPLERATE: u8 = 0x59;
/// `EXPRESS_SCAN` (5-byte payload). Its capsule stream is not supported by the parser.
pub const CMD_EXPRESS_SCAN: u8 = 0x82;
/// `SET_MOTOR_PWM` (2-byte payload): A2 with accessory board only.
pub const CMD_SET_MOTOR_PWM: u8 = 0xF0;

/// The `STOP` request.
pub const REQ_STOP: [u8; 2] = request(CMD_STOP);
/// The `RESET` request.
pub const REQ_RESET: [u8; 2] = request(CMD_RESET);
/// The `SCAN` request.
pub const REQ_SCAN: [u8; 2] = request(CMD_SCAN);
/// The `FORCE_SCAN` request.
pub const REQ_FORCE_SCAN: [u8; 2] = request(CMD_FORCE_SCAN);
/// The `GET_INFO` request.
pub const REQ_GET_INFO: [u8; 2] = request(CMD_GET_INFO);
/// The `GET_HEALTH` request.
pub const REQ_GET_HEALTH: [u8; 2] = request(CMD_GET_HEALTH);
/// The `GET_SAMPLERATE` request.
pub const REQ_GET_SAMPLERATE: [u8; 2] = request(CMD_GET_SAMPLERATE);

/// Descriptor data type of the standard scan node stream.
pub const TYPE_SCAN: u8 = 0x81;
/// Descriptor data type of the express scan capsule stream (not supported).
pub const TYPE_EXPRESS_SCAN: u8 = 0x82;
/// Descriptor data type of the `GET_INFO` response.
pub const TYPE_INFO: u8 = 0x04;
/// Descriptor data type of the `GET_HEALTH` response.
pub const TYPE_HEALTH: u8 = 0x06;
/// Descriptor data type of the `GET_SAMPLERATE` response.
pub const TYPE_SAMPLERATE: u8 = 0x15;

/// Send mode: one response follows the descriptor.
pub const MODE_SINGLE: u8 = 0;
/// Send mode: responses follow until `STOP`.
pub const MODE_MULTIPLE: u8 = 1;

/// Bytes per response descriptor.
pub const DESCRIPTOR_LEN: usize = 7;
/// Bytes per scan node.
pub const NODE_LEN: usize = 5;
/// Bytes of the `GET_INFO` response.
pub const INFO_LEN: usize = 20;
/// Bytes of the `GET_HEALTH` response.
pub const HEALTH_LEN: usize = 3;
/// Bytes of the `GET_SAMPLERATE` response.
pub const SAMPLERATE_LEN: usize = 4;

/// The descriptor that answers `SCAN` and `FORCE_SCAN`: length 5, mode 1, type `0x81`.
pub const SCAN_DESCRIPTOR: [u8; DESCRIPTOR_LEN] = [SYNC1, SYNC2, 0x05, 0x00, 0x00, 0x40, TYPE_SCAN];

/// One turn in `angle_q6` units (1/64°).
pub const TURN_Q6: u32 = 360 * 64;
/// The longest distance a node can carry as a return, mm (`distance_q2` is a u16 of mm × 4).
pub const MAX_RANGE_MM: u32 = (u16::MAX as u32) / 4;
/// Quality the encoder writes for a return. 47 (`0x2F`, the 6-bit field nearly full) is what A1 /
/// A2 units typically report for a solid return in standard mode; 0 goes with no return.
pub const HIT_QUALITY: u8 = 47;

/// Consecutive nodes that must look like a scan before the parser locks on without a descriptor.
/// Three: a window of random bytes passes with probability ≈ 10⁻⁶ (first node ≈ 1/6; each
/// further node 1/8 for its flags and check bit times 640/32768 for its angle step).
pub const LOCK_NODES: usize = 3;
/// Largest clockwise step between consecutive nodes accepted while locking on, q6 units (10°).
/// Sensors step ≈ 1° (A1: 2000 samples/s at 5.5 Hz) and at most ≈ 3° (15 Hz).
pub const MAX_LOCK_STEP_Q6: u32 = 10 * 64;

/// The request `A5 cmd` (commands without payload).
pub const fn request(cmd: u8) -> [u8; 2] {
    [SYNC1, cmd]
}

/// XOR of `bytes`: the request checksum, computed over `A5 cmd n payload…`.
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |c, &b| c ^ b)
}

/// Writes the request `A5 cmd n payload[n] checksum` into `out`; returns its length
/// (`payload.len() + 4`).
pub fn request_with_payload(cmd: u8, payload: &[u8], out: &mut [u8]) -> Result<usize, EncodeError> {
    let n = u8::try_from(payload.len()).map_err(|_| EncodeError::PayloadTooLong)?;
    let len = payload.len() + 4;
    let Some(dst) = out.get_mut(..len) else {
        return Err(EncodeError::BufferTooSmall { needed: len });
    };
    let (head, rest) = dst.split_at_mut(3);
    head.copy_from_slice(&[SYNC1, cmd, n]);
    let (body, sum) = rest.split_at_mut(payload.len());
    body.copy_from_slice(payload);
    let c = checksum(&[SYNC1, cmd, n]) ^ checksum(payload);
    sum.copy_from_slice(&[c]);
    Ok(len)
}

/// The `EXPRESS_SCAN` request for `working_mode` (0: the legacy express mode), with the two
/// reserved u16 fields zero. Provided for completeness: the parser does not decode the capsules
/// that follow. Mode 0 gives `A5 82 05 00 00 00 00 00 22`.
pub const fn express_scan_request(working_mode: u8) -> [u8; 9] {
    let c = SYNC1 ^ CMD_EXPRESS_SCAN ^ 5 ^ working_mode;
    [SYNC1, CMD_EXPRESS_SCAN, 5, working_mode, 0, 0, 0, 0, c]
}

/// The `SET_MOTOR_PWM` request (A2 with the accessory board; the A1's motor is driven by its
/// `MOTOCTL` pin instead). PWM 0…1023; the vendor SDK's default is 660 (`A5 F0 02 94 02 C1`).
pub const fn set_motor_pwm_request(pwm: u16) -> [u8; 6] {
    let [lo, hi] = pwm.to_le_bytes();
    [
        SYNC1,
        CMD_SET_MOTOR_PWM,
        2,
        lo,
        hi,
        SYNC1 ^ CMD_SET_MOTOR_PWM ^ 2 ^ lo ^ hi,
    ]
}

/// What can be wrong on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum RplidarError {
    /// Node byte 0: bit 1 (`!S`) is not the inverse of bit 0 (`S`).
    StartFlags,
    /// Node byte 1: the check bit `C` is 0.
    CheckBit,
    /// The stream ended inside a node or a response.
    Truncated,
}

impl core::error::Error for RplidarError {}

impl core::fmt::Display for RplidarError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RplidarError::StartFlags => "RPLIDAR: node start flags S and !S disagree",
            RplidarError::CheckBit => "RPLIDAR: node check bit is 0",
            RplidarError::Truncated => "RPLIDAR: truncated node or response",
        })
    }
}

/// A response descriptor.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Descriptor {
    /// Bytes per response (per node for a stream), 30 bits.
    pub len: u32,
    /// Send mode, 2 bits ([`MODE_SINGLE`], [`MODE_MULTIPLE`]; 2 and 3 are reserved).
    pub mode: u8,
    /// What follows ([`TYPE_SCAN`], [`TYPE_INFO`], …).
    pub data_type: u8,
}

impl Descriptor {
    /// Decodes 7 bytes; `None` unless they start with `A5 5A`.
    pub fn parse(b: &[u8; DESCRIPTOR_LEN]) -> Option<Descriptor> {
        let [s1, s2, l0, l1, l2, l3, data_type] = *b;
        if s1 != SYNC1 || s2 != SYNC2 {
            return None;
        }
        let word = u32::from_le_bytes([l0, l1, l2, l3]);
        Some(Descriptor {
            len: word & 0x3FFF_FFFF,
            mode: (word >> 30) as u8,
            data_type,
        })
    }

    /// The 7 wire bytes (`len` truncated to 30 bits, `mode` to 2).
    pub fn to_bytes(&self) -> [u8; DESCRIPTOR_LEN] {
        let word = (self.len & 0x3FFF_FFFF) | (u32::from(self.mode & 3) << 30);
        let [l0, l1, l2, l3] = word.to_le_bytes();
        [SYNC1, SYNC2, l0, l1, l2, l3, self.data_type]
    }

    /// What the parser does after it: the response it decodes, if any.
    fn follow(&self) -> Mode {
        match (self.data_type, self.len, self.mode) {
            (TYPE_SCAN, 5, _) => Mode::Locked,
            (TYPE_INFO, 20, MODE_SINGLE) => Mode::Response(Kind::Info),
            (TYPE_HEALTH, 3, MODE_SINGLE) => Mode::Response(Kind::Health),
            (TYPE_SAMPLERATE, 4, MODE_SINGLE) => Mode::Response(Kind::SampleRate),
            _ => Mode::Hunting,
        }
    }
}

/// One measurement of the standard scan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Node {
    /// `S`: the first node of a new 360° scan.
    pub start: bool,
    /// Return strength, 6 bits (0…63).
    pub quality: u8,
    /// Angle, 1/64 degree clockwise, 15 bits (nominally below [`TURN_Q6`]).
    pub angle_q6: u16,
    /// Distance, mm × 4; 0 = no return.
    pub distance_q2: u16,
}

/// Whether node byte 0 has `!S` = not `S`.
#[inline]
const fn flags_ok(b0: u8) -> bool {
    (b0 ^ (b0 >> 1)) & 1 == 1
}

#[inline]
fn node_angle(b1: u8, b2: u8) -> u16 {
    (u16::from(b2) << 7) | u16::from(b1 >> 1)
}

impl Node {
    /// Decodes and checks 5 bytes.
    pub fn parse(b: &[u8; NODE_LEN]) -> Result<Node, RplidarError> {
        let [b0, b1, b2, d0, d1] = *b;
        if !flags_ok(b0) {
            return Err(RplidarError::StartFlags);
        }
        if b1 & 1 == 0 {
            return Err(RplidarError::CheckBit);
        }
        Ok(Node {
            start: b0 & 1 == 1,
            quality: b0 >> 2,
            angle_q6: node_angle(b1, b2),
            distance_q2: u16::from_le_bytes([d0, d1]),
        })
    }

    /// The 5 wire bytes (`quality` truncated to 6 bits, `angle_q6` to 15).
    pub fn to_bytes(&self) -> [u8; NODE_LEN] {
        let s = u8::from(self.start);
        let a = self.angle_q6 & 0x7FFF;
        let [d0, d1] = self.distance_q2.to_le_bytes();
        [
            (self.quality << 2) | ((s ^ 1) << 1) | s,
            (((a & 0x7F) as u8) << 1) | 1,
            (a >> 7) as u8,
            d0,
            d1,
        ]
    }

    /// The node the encoder sends for `beam`: angle to the nearest q6 step, `Hit(mm)` as mm × 4
    /// with quality [`HIT_QUALITY`] (`Hit(0)` as 1 mm; beyond [`MAX_RANGE_MM`] as no return, since
    /// the sensor could not report it either), no return as distance 0, quality 0.
    pub fn from_beam(beam: &Beam, start: bool) -> Node {
        let (quality, distance_q2) = match beam.range {
            Range::Hit(mm) if mm <= MAX_RANGE_MM => (HIT_QUALITY, (mm.max(1) * 4) as u16),
            _ => (0, 0),
        };
        Node {
            start,
            quality,
            angle_q6: theta_q6(beam.angle),
            distance_q2,
        }
    }

    /// The distance in whole mm (rounded to nearest, at least 1), `None` for no return.
    pub fn distance_mm(&self) -> Option<u32> {
        match self.distance_q2 {
            0 => None,
            q2 => Some(((u32::from(q2) + 2) >> 2).max(1)),
        }
    }

    /// The node as a beam (ogm-core angle; no return for distance 0).
    pub fn beam(&self) -> Beam {
        Beam {
            angle: beam_angle(self.angle_q6),
            range: self.distance_mm().map_or(Range::NoReturn, Range::Hit),
        }
    }
}

/// The ogm-core beam angle (counter-clockwise) of an RPLIDAR angle (q6 clockwise; wrapped to one
/// turn, so 360° and more are accepted).
pub fn beam_angle(theta_q6: u16) -> Angle {
    let ccw = (TURN_Q6 - u32::from(theta_q6) % TURN_Q6) % TURN_Q6; // 0..23040
    Angle(((ccw * FULL_TURN + TURN_Q6 / 2) / TURN_Q6) as u16) // ≤ 65533: no wrap needed
}

/// The RPLIDAR angle (q6 clockwise, `0..23040`) nearest to a beam angle.
pub fn theta_q6(angle: Angle) -> u16 {
    let ccw = (u32::from(angle.0) * TURN_Q6 + FULL_TURN / 2) >> 16; // 0..=23040
    ((TURN_Q6 - ccw % TURN_Q6) % TURN_Q6) as u16
}

/// The `GET_INFO` response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceInfo {
    /// Model id (the high nibble is the series in the vendor SDK: 1 = A1, 2 = A2, 3 = A3).
    pub model: u8,
    /// Firmware version, minor.
    pub firmware_minor: u8,
    /// Firmware version, major.
    pub firmware_major: u8,
    /// Hardware revision.
    pub hardware: u8,
    /// Serial number (128 bits).
    pub serial: [u8; 16],
}

/// The health status byte of [`Health`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HealthStatus {
    /// 0: working.
    Good,
    /// 1: working, but something is off.
    Warning,
    /// 2: stopped (protection stop); send `RESET`.
    Error,
    /// Any other value.
    Unknown(u8),
}

/// The `GET_HEALTH` response.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Health {
    /// Status.
    pub status: HealthStatus,
    /// Vendor error code (u16 LE).
    pub error_code: u16,
}

/// The `GET_SAMPLERATE` response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SampleRate {
    /// Time per sample in standard scan mode, µs (≈ 500 for a 2 kHz A1).
    pub standard_us: u16,
    /// Time per sample in express scan mode, µs.
    pub express_us: u16,
}

/// What the parser delivers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A scan node.
    Node(Node),
    /// A response descriptor (a new response or node stream starts).
    Descriptor(Descriptor),
    /// A `GET_INFO` response.
    Info(DeviceInfo),
    /// A `GET_HEALTH` response.
    Health(Health),
    /// A `GET_SAMPLERATE` response.
    SampleRate(SampleRate),
}

/// What the parser saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RplidarCounters {
    /// Good nodes delivered.
    pub nodes: u32,
    /// Nodes rejected at a locked boundary (check bits wrong).
    pub bad_nodes: u32,
    /// Delivered nodes with `S = 1`: starts of a new 360° scan.
    pub scans: u32,
    /// Response descriptors recognised.
    pub descriptors: u32,
    /// Info, health and sample-rate responses decoded.
    pub responses: u32,
    /// Node boundaries found without a descriptor (start-up mid-stream, resynchronisation).
    pub locks: u32,
    /// Bytes dropped while hunting for a boundary (garbage, bad nodes, unfinished data at the end).
    pub skipped_bytes: u32,
    /// Nodes or responses cut short by the end of the stream.
    pub truncated: u32,
}

/// Which single response the parser is collecting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Info,
    Health,
    SampleRate,
}

impl Kind {
    const fn len(self) -> usize {
        match self {
            Kind::Info => INFO_LEN,
            Kind::Health => HEALTH_LEN,
            Kind::SampleRate => SAMPLERATE_LEN,
        }
    }
}

/// Parser state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// Looking for a descriptor or a node boundary.
    Hunting,
    /// At a node boundary: every 5 bytes are a node.
    Locked,
    /// Collecting a single response's payload.
    Response(Kind),
}

/// Verdict on the candidate at the start of the hunting buffer.
enum Candidate {
    NeedMore,
    Reject,
    Lock,
}

/// Buffer size: the largest of a lock-on window (15), a descriptor (7) and an info response (20).
const BUF_LEN: usize = INFO_LEN;
const _: () = assert!(BUF_LEN >= LOCK_NODES * NODE_LEN && BUF_LEN >= DESCRIPTOR_LEN);

/// The sans-IO RPLIDAR parser: feed it bytes as they arrive (any chunking), get events or errors
/// back in stream order. See the module docs for the synchronisation rules.
#[derive(Clone, Debug)]
pub struct RplidarParser {
    buf: [u8; BUF_LEN],
    len: usize,
    mode: Mode,
    counters: RplidarCounters,
}

impl Default for RplidarParser {
    fn default() -> Self {
        Self::new()
    }
}

impl RplidarParser {
    /// A parser looking for a descriptor or a node stream.
    pub const fn new() -> Self {
        RplidarParser {
            buf: [0; BUF_LEN],
            len: 0,
            mode: Mode::Hunting,
            counters: RplidarCounters {
                nodes: 0,
                bad_nodes: 0,
                scans: 0,
                descriptors: 0,
                responses: 0,
                locks: 0,
                skipped_bytes: 0,
                truncated: 0,
            },
        }
    }

    /// Counters so far.
    pub fn counters(&self) -> RplidarCounters {
        self.counters
    }

    /// Bytes held back (an unfinished node, response or lock-on window), always `< 20`.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Whether the parser is at a node boundary (after a scan descriptor or a lock-on).
    pub fn is_locked(&self) -> bool {
        self.mode == Mode::Locked
    }

    /// Feeds `data`, calling `f` for every event or error, in stream order.
    pub fn feed(&mut self, data: &[u8], mut f: impl FnMut(Result<Event, RplidarError>)) {
        for &b in data {
            self.push(b, &mut f);
        }
    }

    /// Feeds one byte, calling `f` for what it completes: usually nothing or one event; a
    /// completed lock-on delivers its [`LOCK_NODES`] nodes at once.
    pub fn push(&mut self, byte: u8, mut f: impl FnMut(Result<Event, RplidarError>)) {
        if self.len >= BUF_LEN {
            // Unreachable (every mode decides before the buffer fills), but a full buffer must
            // not stall the parser: drop the oldest byte.
            self.consume(1);
            self.skip(1);
        }
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
        // Each step consumes bytes or leaves `Locked`, so this ends well within the bound; the
        // bound only guards against a logic error turning into a hang.
        for _ in 0..2 * BUF_LEN + 2 {
            if !self.step(&mut f) {
                break;
            }
        }
    }

    /// End of stream: an unfinished node or response counts as truncated; whatever is held back is
    /// dropped (counted as skipped) and the parser starts hunting again.
    pub fn finish(&mut self) -> Option<RplidarError> {
        let truncated = match self.mode {
            Mode::Locked => self.len > 0,
            Mode::Response(_) => true,
            Mode::Hunting => false,
        };
        self.skip(self.len);
        self.len = 0;
        self.mode = Mode::Hunting;
        if truncated {
            self.counters.truncated = self.counters.truncated.saturating_add(1);
            Some(RplidarError::Truncated)
        } else {
            None
        }
    }

    fn held(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    fn consume(&mut self, n: usize) {
        // `len ≤ BUF_LEN` always; the bound makes `copy_within` provably in range (no panic
        // path, which also kept `core::fmt` in the firmware image).
        let len = self.len.min(self.buf.len());
        let n = n.min(len);
        self.buf.copy_within(n..len, 0);
        self.len = len - n;
    }

    fn skip(&mut self, n: usize) {
        let n = u32::try_from(n).unwrap_or(u32::MAX);
        self.counters.skipped_bytes = self.counters.skipped_bytes.saturating_add(n);
    }

    fn node_at(&self, at: usize) -> Option<Node> {
        let b = self.held().get(at..at + NODE_LEN)?;
        Node::parse(b.try_into().ok()?).ok()
    }

    fn deliver(&mut self, n: Node, f: &mut impl FnMut(Result<Event, RplidarError>)) {
        self.counters.nodes = self.counters.nodes.saturating_add(1);
        if n.start {
            self.counters.scans = self.counters.scans.saturating_add(1);
        }
        f(Ok(Event::Node(n)));
    }

    /// One step of the state machine; `false` when it needs more bytes.
    fn step(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        match self.mode {
            Mode::Locked => self.step_locked(f),
            Mode::Response(kind) => self.step_response(kind, f),
            Mode::Hunting => self.step_hunting(f),
        }
    }

    fn step_locked(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        if let [SYNC1, SYNC2, ..] = *self.held() {
            // Cannot be a node (`C` would be 0): a new descriptor, e.g. after STOP + SCAN.
            self.mode = Mode::Hunting;
            return true;
        }
        let Some(b) = self.held().get(..NODE_LEN) else {
            return false;
        };
        let parsed = <&[u8; NODE_LEN]>::try_from(b)
            .map_err(|_| RplidarError::Truncated)
            .and_then(Node::parse);
        match parsed {
            Ok(n) => {
                self.consume(NODE_LEN);
                self.deliver(n, f);
            }
            Err(e) => {
                // Not consumed: lock-on restarts at this node's first byte, so a valid
                // boundary inside the rejected bytes is still found.
                self.counters.bad_nodes = self.counters.bad_nodes.saturating_add(1);
                self.mode = Mode::Hunting;
                f(Err(e));
            }
        }
        true
    }

    fn step_response(
        &mut self,
        kind: Kind,
        f: &mut impl FnMut(Result<Event, RplidarError>),
    ) -> bool {
        let Some(p) = self.held().get(..kind.len()) else {
            return false;
        };
        let event = match (kind, p) {
            (Kind::Health, &[status, e0, e1]) => Event::Health(Health {
                status: match status {
                    0 => HealthStatus::Good,
                    1 => HealthStatus::Warning,
                    2 => HealthStatus::Error,
                    s => HealthStatus::Unknown(s),
                },
                error_code: u16::from_le_bytes([e0, e1]),
            }),
            (Kind::SampleRate, &[s0, s1, x0, x1]) => Event::SampleRate(SampleRate {
                standard_us: u16::from_le_bytes([s0, s1]),
                express_us: u16::from_le_bytes([x0, x1]),
            }),
            (Kind::Info, &[model, firmware_minor, firmware_major, hardware, ref serial @ ..]) => {
                Event::Info(DeviceInfo {
                    model,
                    firmware_minor,
                    firmware_major,
                    hardware,
                    serial: serial.try_into().unwrap_or_default(),
                })
            }
            // The payload length always matches the kind; never taken.
            _ => {
                self.mode = Mode::Hunting;
                return true;
            }
        };
        self.consume(kind.len());
        self.mode = Mode::Hunting;
        self.counters.responses = self.counters.responses.saturating_add(1);
        f(Ok(event));
        true
    }

    fn step_hunting(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        if let [SYNC1, SYNC2, ..] = *self.held() {
            let Some(Ok(d)) = self
                .held()
                .get(..DESCRIPTOR_LEN)
                .map(<&[u8; DESCRIPTOR_LEN]>::try_from)
            else {
                return false;
            };
            match Descriptor::parse(d) {
                Some(d) if d.mode <= MODE_MULTIPLE => {
                    self.consume(DESCRIPTOR_LEN);
                    self.counters.descriptors = self.counters.descriptors.saturating_add(1);
                    self.mode = d.follow();
                    f(Ok(Event::Descriptor(d)));
                }
                _ => {
                    // Reserved send mode: garbage that happens to start with `A5 5A`.
                    self.consume(1);
                    self.skip(1);
                }
            }
            return true;
        }
        match lock_candidate(self.held()) {
            Candidate::NeedMore => false,
            Candidate::Reject => {
                self.consume(1);
                self.skip(1);
                true
            }
            Candidate::Lock => {
                for i in 0..LOCK_NODES {
                    if let Some(n) = self.node_at(i * NODE_LEN) {
                        self.deliver(n, f);
                    }
                }
                self.consume(LOCK_NODES * NODE_LEN);
                self.counters.locks = self.counters.locks.saturating_add(1);
                self.mode = Mode::Locked;
                true
            }
        }
    }
}

/// Judges the lock-on window at the start of `b` as far as its bytes go (see the module docs):
/// rejects as soon as a rule fails, locks once [`LOCK_NODES`] nodes pass.
fn lock_candidate(b: &[u8]) -> Candidate {
    let mut prev: Option<u32> = None;
    for i in 0..LOCK_NODES {
        let from = i * NODE_LEN;
        let node = b.get(from..b.len().min(from + NODE_LEN)).unwrap_or(&[]);
        if node.is_empty() {
            return Candidate::NeedMore;
        }
        if let Some(&b0) = node.first() {
            if !flags_ok(b0) || (i > 0 && b0 & 1 == 1) {
                return Candidate::Reject;
            }
        }
        if let Some(&b1) = node.get(1) {
            if b1 & 1 == 0 {
                return Candidate::Reject;
            }
        }
        if let (Some(&b1), Some(&b2)) = (node.get(1), node.get(2)) {
            let a = u32::from(node_angle(b1, b2));
            if a >= TURN_Q6 {
                return Candidate::Reject;
            }
            if let Some(p) = prev {
                let step = (a + TURN_Q6 - p % TURN_Q6) % TURN_Q6;
                if step == 0 || step > MAX_LOCK_STEP_Q6 {
                    return Candidate::Reject;
                }
            }
            prev = Some(a);
        }
        if node.len() < NODE_LEN {
            return Candidate::NeedMore;
        }
    }
    Candidate::Lock
}

/// Nodes one byte can complete (a lock-on window): what may spill over into the next scan.
const CARRY: usize = LOCK_NODES + 1;

/// A blocking RPLIDAR driver over any [`embedded_io::Read`] (a UART on the robot, a byte slice or
/// a pipe on the host): implements [`RangeSensor`] by assembling one full 360° turn per scan. The
/// caller starts the stream by writing [`REQ_SCAN`] to the sensor (after [`REQ_STOP`] and a
/// 1 ms pause if it may already be scanning); the reader only reads.
///
/// A scan runs from one node with `S = 1` to the next (exclusive), like the vendor SDK's
/// `grabScanData`: unlike [`crate::lidar::ld06::Ld06Reader`], which returns the partial first turn, nodes
/// before the first start flag are dropped (counted in [`RplidarReader::discarded_nodes`]), as is
/// a turn interrupted by a new descriptor (the sensor restarted) or by an error returned from
/// `read_scan` (the next call starts at the next start flag). Nodes lost to corruption are
/// simply missing from their turn; bad bytes are counted by the parser
/// ([`RplidarReader::counters`]). Beams beyond the [`ScanBuf`]'s capacity are counted in its
/// overflow, never written.
pub struct RplidarReader<R> {
    rx: R,
    parser: RplidarParser,
    chunk: [u8; 64],
    chunk_len: usize,
    chunk_pos: usize,
    carry: [Beam; CARRY],
    n_carry: usize,
    scans: u32,
    discarded: u32,
}

impl<R: embedded_io::Read> RplidarReader<R> {
    /// A reader on `rx`.
    pub fn new(rx: R) -> Self {
        RplidarReader {
            rx,
            parser: RplidarParser::new(),
            chunk: [0; 64],
            chunk_len: 0,
            chunk_pos: 0,
            carry: [Beam {
                angle: Angle::ZERO,
                range: Range::NoReturn,
            }; CARRY],
            n_carry: 0,
            scans: 0,
            discarded: 0,
        }
    }

    /// Parser counters.
    pub fn counters(&self) -> RplidarCounters {
        self.parser.counters()
    }

    /// Complete turns returned.
    pub fn scans(&self) -> u32 {
        self.scans
    }

    /// Good nodes not returned in any scan: before the first start flag, or in a turn cut short
    /// by a new descriptor, a read error or the end of the stream.
    pub fn discarded_nodes(&self) -> u32 {
        self.discarded
    }

    /// The byte source back.
    pub fn into_inner(self) -> R {
        self.rx
    }

    fn next_byte(&mut self) -> Result<u8, ReadError<R::Error>> {
        if self.chunk_pos >= self.chunk_len {
            let n = self.rx.read(&mut self.chunk).map_err(ReadError::Io)?;
            if n == 0 {
                self.parser.finish();
                return Err(ReadError::Eof);
            }
            (self.chunk_len, self.chunk_pos) = (n.min(self.chunk.len()), 0);
        }
        let b = self.chunk.get(self.chunk_pos).copied().unwrap_or(0);
        self.chunk_pos += 1;
        Ok(b)
    }
}

impl<R: embedded_io::Read> RangeSensor for RplidarReader<R> {
    type Error = ReadError<R::Error>;

    fn read_scan<const N: usize>(&mut self, scan: &mut ScanBuf<N>) -> Result<(), Self::Error> {
        scan.clear();
        // A carry always starts with the start node that ended the previous scan.
        let mut in_scan = self.n_carry > 0;
        let mut nodes = 0u32; // in this turn, including beams the buffer dropped
        for b in self.carry.iter().take(self.n_carry) {
            scan.push(*b);
            nodes = nodes.saturating_add(1);
        }
        self.n_carry = 0;
        loop {
            let byte = match self.next_byte() {
                Ok(b) => b,
                Err(e) => {
                    // The turn in progress is abandoned; the next call starts at a start flag.
                    self.discarded = self.discarded.saturating_add(nodes);
                    return Err(e);
                }
            };
            let mut done = false;
            let (carry, n_carry, discarded) =
                (&mut self.carry, &mut self.n_carry, &mut self.discarded);
            self.parser.push(byte, |r| match r {
                Ok(Event::Node(n)) => {
                    if done || (n.start && in_scan) {
                        // The next turn has begun: keep its nodes for the next call.
                        done = true;
                        if let Some(slot) = carry.get_mut(*n_carry) {
                            *slot = n.beam();
                            *n_carry += 1;
                        }
                    } else if n.start || in_scan {
                        in_scan = true;
                        scan.push(n.beam());
                        nodes = nodes.saturating_add(1);
                    } else {
                        *discarded = discarded.saturating_add(1);
                    }
                }
                Ok(Event::Descriptor(_)) => {
                    // The sensor (re)started a response: the turn in progress will never be
                    // completed consistently.
                    if done {
                        *discarded = discarded.saturating_add(*n_carry as u32);
                        *n_carry = 0;
                    } else {
                        *discarded = discarded.saturating_add(nodes);
                        nodes = 0;
                        in_scan = false;
                        scan.clear();
                    }
                }
                _ => {}
            });
            if done {
                self.scans = self.scans.saturating_add(1);
                return Ok(());
            }
        }
    }
}

/// Why an encoder refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EncodeError {
    /// The output buffer needs this many bytes.
    BufferTooSmall {
        /// Bytes required.
        needed: usize,
    },
    /// A request payload longer than 255 bytes.
    PayloadTooLong,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::BufferTooSmall { needed } => {
                write!(
                    f,
                    "RPLIDAR: output buffer too small ({needed} bytes needed)"
                )
            }
            EncodeError::PayloadTooLong => f.write_str("RPLIDAR: request payload over 255 bytes"),
        }
    }
}

/// Bytes [`encode_scan`] writes for `beams` beams, with or without the descriptor (saturating).
pub const fn scan_len(beams: usize, descriptor: bool) -> usize {
    let d = if descriptor { DESCRIPTOR_LEN } else { 0 };
    beams.saturating_mul(NODE_LEN).saturating_add(d)
}

/// Writes one turn into `out`: [`SCAN_DESCRIPTOR`] if `descriptor`, then one node per beam in the
/// given order (which should be clockwise, i.e. increasing [`theta_q6`], as the sensor sends
/// them), the first with `S = 1` and the rest with `S = 0` ([`Node::from_beam`] gives the
/// quantisation). Returns the bytes written ([`scan_len`]); writes nothing if `out` is too short.
/// Concatenating turns (the descriptor on the first only) gives a sensor stream.
pub fn encode_scan(beams: &[Beam], descriptor: bool, out: &mut [u8]) -> Result<usize, EncodeError> {
    let needed = scan_len(beams.len(), descriptor);
    let Some(out) = out.get_mut(..needed) else {
        return Err(EncodeError::BufferTooSmall { needed });
    };
    let nodes = if descriptor {
        let (d, rest) = out.split_at_mut(DESCRIPTOR_LEN);
        d.copy_from_slice(&SCAN_DESCRIPTOR);
        rest
    } else {
        out
    };
    for (i, (dst, beam)) in nodes.chunks_exact_mut(NODE_LEN).zip(beams).enumerate() {
        dst.copy_from_slice(&Node::from_beam(beam, i == 0).to_bytes());
    }
    Ok(needed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(start: bool, angle_q6: u16, distance_q2: u16) -> Node {
        Node {
            start,
            quality: if distance_q2 == 0 { 0 } else { HIT_QUALITY },
            angle_q6,
            distance_q2,
        }
    }

    /// `n` nodes of a turn starting at `start_q6`, 1° apart, the first flagged `S`.
    fn turn(n: usize, start_q6: u16) -> Vec<u8> {
        let mut v = Vec::new();
        for i in 0..n {
            let a = ((u32::from(start_q6) + 64 * i as u32) % TURN_Q6) as u16;
            let d = if i % 7 == 3 { 0 } else { 4000 + 4 * i as u16 };
            v.extend_from_slice(&node(i == 0, a, d).to_bytes());
        }
        v
    }

    fn run(p: &mut RplidarParser, bytes: &[u8]) -> (Vec<Node>, Vec<Event>, Vec<RplidarError>) {
        let (mut nodes, mut other, mut errors) = (Vec::new(), Vec::new(), Vec::new());
        p.feed(bytes, |r| match r {
            Ok(Event::Node(n)) => nodes.push(n),
            Ok(e) => other.push(e),
            Err(e) => errors.push(e),
        });
        (nodes, other, errors)
    }

    #[test]
    fn requests_and_checksums_match_the_protocol_document() {
        assert_eq!(REQ_STOP, [0xA5, 0x25]);
        assert_eq!(REQ_RESET, [0xA5, 0x40]);
        assert_eq!(REQ_SCAN, [0xA5, 0x20]);
        assert_eq!(REQ_FORCE_SCAN, [0xA5, 0x21]);
        assert_eq!(REQ_GET_INFO, [0xA5, 0x50]);
        assert_eq!(REQ_GET_HEALTH, [0xA5, 0x52]);
        assert_eq!(REQ_GET_SAMPLERATE, [0xA5, 0x59]);
        assert_eq!(
            express_scan_request(0),
            [0xA5, 0x82, 0x05, 0, 0, 0, 0, 0, 0x22]
        );
        assert_eq!(
            set_motor_pwm_request(660),
            [0xA5, 0xF0, 0x02, 0x94, 0x02, 0xC1]
        );
        let mut out = [0u8; 9];
        assert_eq!(
            request_with_payload(CMD_EXPRESS_SCAN, &[0; 5], &mut out),
            Ok(9)
        );
        assert_eq!(out, express_scan_request(0));
        assert_eq!(
            checksum(&out),
            0,
            "XOR over a request including its checksum"
        );
        assert_eq!(
            request_with_payload(CMD_EXPRESS_SCAN, &[0; 5], &mut out[..8]),
            Err(EncodeError::BufferTooSmall { needed: 9 })
        );
        assert_eq!(
            request_with_payload(0x90, &[0; 256], &mut [0u8; 300]),
            Err(EncodeError::PayloadTooLong)
        );
    }

    #[test]
    fn descriptors_round_trip() {
        let d = Descriptor::parse(&SCAN_DESCRIPTOR).unwrap();
        assert_eq!(
            d,
            Descriptor {
                len: 5,
                mode: MODE_MULTIPLE,
                data_type: TYPE_SCAN
            }
        );
        assert_eq!(d.to_bytes(), SCAN_DESCRIPTOR);
        assert_eq!(Descriptor::parse(&[0xA5, 0x5B, 5, 0, 0, 0x40, 0x81]), None);
        let info = Descriptor {
            len: 20,
            mode: MODE_SINGLE,
            data_type: TYPE_INFO,
        };
        assert_eq!(info.to_bytes(), [0xA5, 0x5A, 0x14, 0, 0, 0, 0x04]);
    }

    #[test]
    fn node_bits_follow_the_table() {
        // Quality 47, S = 1, 90.5° (q6 5792), 1234.25 mm (q2 4937).
        let n = Node {
            start: true,
            quality: 47,
            angle_q6: 5792,
            distance_q2: 4937,
        };
        let b = n.to_bytes();
        assert_eq!(b[0], (47 << 2) | 0b01);
        assert_eq!(b[1], ((5792 & 0x7F) << 1 | 1) as u8);
        assert_eq!(b[2], (5792 >> 7) as u8);
        assert_eq!(u16::from_le_bytes([b[3], b[4]]), 4937);
        assert_eq!(Node::parse(&b), Ok(n));
        assert_eq!(n.distance_mm(), Some(1234));
        let s0 = Node { start: false, ..n }.to_bytes();
        assert_eq!(s0[0] & 3, 0b10);
        let mut bad = b;
        bad[0] |= 0b11;
        assert_eq!(Node::parse(&bad), Err(RplidarError::StartFlags));
        bad[0] &= !0b11;
        assert_eq!(Node::parse(&bad), Err(RplidarError::StartFlags));
        let mut bad = b;
        bad[1] &= !1;
        assert_eq!(Node::parse(&bad), Err(RplidarError::CheckBit));
        // Distance rounding and the no-return rule.
        assert_eq!(node(false, 0, 0).beam().range, Range::NoReturn);
        assert_eq!(node(false, 0, 1).distance_mm(), Some(1));
        assert_eq!(node(false, 0, 6).distance_mm(), Some(2));
        assert_eq!(node(false, 0, u16::MAX).distance_mm(), Some(16384));
    }

    #[test]
    fn angles_are_clockwise_and_round_trip() {
        // Clockwise 90° is counter-clockwise 270°.
        assert_eq!(beam_angle(90 * 64), Angle(49_152));
        assert_eq!(beam_angle(0), Angle(0));
        assert_eq!(beam_angle(TURN_Q6 as u16), Angle(0));
        assert_eq!(beam_angle(450 * 64), Angle(49_152), "wraps past 360°");
        assert_eq!(theta_q6(Angle(49_152)), 90 * 64);
        assert_eq!(theta_q6(Angle(0)), 0);
        assert_eq!(theta_q6(Angle(u16::MAX)), 0);
        for q in 0..TURN_Q6 as u16 {
            assert_eq!(theta_q6(beam_angle(q)), q, "q6 → beam → q6 is exact");
        }
        for a in 0..=u16::MAX {
            let back = beam_angle(theta_q6(Angle(a)));
            assert!(back.signed_diff(Angle(a)).abs() <= 1, "{a} -> {back:?}");
        }
    }

    #[test]
    fn beam_encoding_rules() {
        let b = |range| Beam {
            angle: Angle(1000),
            range,
        };
        assert_eq!(Node::from_beam(&b(Range::Hit(0)), false).distance_q2, 4);
        assert_eq!(
            Node::from_beam(&b(Range::Hit(MAX_RANGE_MM)), false)
                .beam()
                .range,
            Range::Hit(MAX_RANGE_MM)
        );
        let far = Node::from_beam(&b(Range::Hit(MAX_RANGE_MM + 1)), true);
        assert_eq!((far.distance_q2, far.quality, far.start), (0, 0, true));
        assert_eq!(Node::from_beam(&b(Range::NoReturn), false).quality, 0);
        assert_eq!(
            Node::from_beam(&b(Range::Hit(5)), false).quality,
            HIT_QUALITY
        );
    }

    #[test]
    fn descriptor_then_nodes() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(10, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert_eq!(nodes.len(), 10);
        assert!(nodes[0].start && nodes[1..].iter().all(|n| !n.start));
        assert_eq!(
            other,
            vec![Event::Descriptor(
                Descriptor::parse(&SCAN_DESCRIPTOR).unwrap()
            )]
        );
        assert!(errors.is_empty());
        let c = p.counters();
        assert_eq!((c.nodes, c.scans, c.descriptors, c.locks), (10, 1, 1, 0));
        assert_eq!((c.skipped_bytes, c.bad_nodes), (0, 0));
        assert!(p.is_locked());
    }

    #[test]
    fn locks_on_mid_stream_and_skips_the_partial_node() {
        let s = turn(20, 100);
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s[7..]); // starts inside node 1
        assert!(errors.is_empty());
        let want: Vec<Node> = s[10..]
            .chunks(5)
            .map(|c| Node::parse(c.try_into().unwrap()).unwrap())
            .collect();
        assert_eq!(nodes, want);
        let c = p.counters();
        assert_eq!((c.locks, c.skipped_bytes, c.descriptors), (1, 3, 0));
    }

    #[test]
    fn lock_on_needs_a_plausible_angle_sequence() {
        // Noise-free constant distances (q2 0x0102) and quality 15: seen from byte 3 of a node,
        // every window passes the check bits and has S = 0 (`02`, `01`, then `3E …`), and its
        // "angle" (`3E << 7`) never changes. Only the angle rule rejects that boundary.
        let nodes: Vec<Node> = (0..12u16)
            .map(|i| Node {
                start: false,
                quality: 15,
                angle_q6: 1000 + 70 * i,
                distance_q2: 0x0102,
            })
            .collect();
        let bytes: Vec<u8> = nodes.iter().flat_map(|n| n.to_bytes()).collect();
        let window = &bytes[3..3 + LOCK_NODES * NODE_LEN];
        for c in window.chunks(NODE_LEN) {
            let n = Node::parse(c.try_into().unwrap()).unwrap();
            assert!(!n.start && n.angle_q6 == 0x3E << 7);
        }
        assert!(matches!(lock_candidate(window), Candidate::Reject));
        let mut p = RplidarParser::new();
        let (got, _, errors) = run(&mut p, &bytes[3..]);
        assert!(errors.is_empty());
        assert_eq!(got, nodes[1..]);
        assert_eq!(p.counters().skipped_bytes, 2);
    }

    #[test]
    fn bad_check_bit_is_rejected_and_the_stream_resyncs() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(30, 0));
        let at = 7 + 5 * 12;
        s[at + 1] &= !1; // node 12: C = 0
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s);
        assert_eq!(errors, vec![RplidarError::CheckBit]);
        assert_eq!(nodes.len(), 29, "only the corrupted node is lost");
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks, c.skipped_bytes), (1, 1, 5));
        assert!(p.is_locked());
    }

    #[test]
    fn lost_byte_and_garbage_resync() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        let t = turn(40, 0);
        s.extend_from_slice(&t[..5 * 10 + 2]);
        s.extend_from_slice(&t[5 * 10 + 3..5 * 20]); // one byte of node 10 lost
        s.extend_from_slice(&[0x00, 0xFF, 0x33, 0xCC]); // garbage that cannot start a node
        s.extend_from_slice(&t[5 * 20..]);
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s);
        // The garbage is caught at once (its first byte fails `S`/`!S`), the lost byte only
        // when a misaligned node fails a check bit: node 10's remains and two misaligned nodes
        // pass (angles 0 and 26114), nodes 11 and 12 are eaten, and lock-on resumes at node 13.
        assert_eq!(errors, [RplidarError::CheckBit, RplidarError::StartFlags]);
        let angles: Vec<u16> = nodes.iter().map(|n| n.angle_q6).collect();
        let want = |r: core::ops::Range<u16>| r.map(|i| 64 * i).collect::<Vec<u16>>();
        assert_eq!(angles[..10], want(0..10));
        assert_eq!(angles[10..12], [0, 26114]);
        assert_eq!(angles[12..], want(13..40));
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks), (2, 2));
        assert!(p.is_locked());
    }

    #[test]
    fn info_health_and_samplerate_responses() {
        let mut s = vec![0x13, 0x37]; // garbage first
        s.extend_from_slice(&[0xA5, 0x5A, 0x14, 0, 0, 0, 0x04]);
        s.extend_from_slice(&[0x18, 29, 1, 7]);
        s.extend(1..=16u8);
        s.extend_from_slice(&[0xA5, 0x5A, 0x03, 0, 0, 0, 0x06, 0x02, 0x34, 0x12]);
        s.extend_from_slice(&[0xA5, 0x5A, 0x04, 0, 0, 0, 0x15, 0xF4, 0x01, 0xFA, 0x00]);
        s.extend_from_slice(&SCAN_DESCRIPTOR);
        s.extend(turn(3, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert!(errors.is_empty());
        assert_eq!(nodes.len(), 3);
        let mut serial = [0u8; 16];
        serial.iter_mut().zip(1..).for_each(|(s, i)| *s = i);
        assert_eq!(
            other[1],
            Event::Info(DeviceInfo {
                model: 0x18,
                firmware_minor: 29,
                firmware_major: 1,
                hardware: 7,
                serial
            })
        );
        assert_eq!(
            other[3],
            Event::Health(Health {
                status: HealthStatus::Error,
                error_code: 0x1234
            })
        );
        assert_eq!(
            other[5],
            Event::SampleRate(SampleRate {
                standard_us: 500,
                express_us: 250
            })
        );
        let c = p.counters();
        assert_eq!((c.descriptors, c.responses, c.skipped_bytes), (4, 3, 2));
    }

    #[test]
    fn truncation_is_counted() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend_from_slice(&turn(2, 0)[..7]);
        let mut p = RplidarParser::new();
        let (nodes, _, _) = run(&mut p, &s);
        assert_eq!(nodes.len(), 1);
        assert_eq!(p.pending(), 2);
        assert_eq!(p.finish(), Some(RplidarError::Truncated));
        assert_eq!(p.finish(), None);
        let c = p.counters();
        assert_eq!((c.truncated, c.skipped_bytes), (1, 2));
        // A health descriptor without its payload.
        let mut p = RplidarParser::new();
        p.feed(&[0xA5, 0x5A, 0x03, 0, 0, 0, 0x06, 0x00], |_| {});
        assert_eq!(p.finish(), Some(RplidarError::Truncated));
    }

    #[test]
    fn a_new_descriptor_is_recognised_while_locked() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(5, 0));
        s.extend_from_slice(&SCAN_DESCRIPTOR); // STOP + SCAN
        s.extend(turn(5, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert_eq!((nodes.len(), other.len(), errors.len()), (10, 2, 0));
        assert_eq!(p.counters().skipped_bytes, 0);
    }

    #[test]
    fn parser_never_panics_on_noise_and_accounts_for_every_byte() {
        let mut x = 0x9E37_79B9u32;
        let mut s = Vec::new();
        for k in 0..300 {
            for _ in 0..(k % 23) {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                s.push(if x % 7 == 0 { SYNC1 } else { x as u8 });
            }
            if k % 50 == 0 {
                s.extend_from_slice(&SCAN_DESCRIPTOR);
            }
            s.extend(turn(8, (k * 37 % 360) as u16 * 64));
        }
        let mut p = RplidarParser::new();
        let mut payload = 0usize;
        p.feed(&s, |r| {
            payload += match r {
                Ok(Event::Node(_)) => NODE_LEN,
                Ok(Event::Descriptor(_)) => DESCRIPTOR_LEN,
                Ok(Event::Info(_)) => INFO_LEN,
                Ok(Event::Health(_)) => HEALTH_LEN,
                Ok(Event::SampleRate(_)) => SAMPLERATE_LEN,
                Err(_) => 0,
            }
        });
        let pending = p.pending();
        let c = p.counters();
        assert_eq!(payload + c.skipped_bytes as usize + pending, s.len());
        assert!(c.nodes > 300 * 5, "most nodes recovered: {c:?}");
    }

    #[test]
    fn reader_assembles_full_turns() {
        let beams: Vec<Beam> = (0..36)
            .map(|i| Beam {
                angle: beam_angle((i * 10 * 64) as u16),
                range: if i % 5 == 0 {
                    Range::NoReturn
                } else {
                    Range::Hit(1000 + i)
                },
            })
            .collect();
        let mut bytes = vec![0u8; scan_len(36, true) + 3 * scan_len(36, false)];
        // Start-up mid-turn: the tail of a turn (no start flag) comes first.
        let mut at = encode_scan(&beams, false, &mut bytes).unwrap() - 20 * NODE_LEN;
        bytes.copy_within(20 * NODE_LEN..36 * NODE_LEN, 0);
        at += encode_scan(&beams, false, &mut bytes[at..]).unwrap();
        at += encode_scan(&beams, false, &mut bytes[at..]).unwrap();
        at += encode_scan(&beams[..10], false, &mut bytes[at..]).unwrap();
        bytes.truncate(at);
        let mut r = RplidarReader::new(&bytes[..]);
        let mut scan: ScanBuf<64> = ScanBuf::new();
        for _ in 0..2 {
            r.read_scan(&mut scan).unwrap();
            assert_eq!(scan.beams(), &beams[..]);
            assert_eq!(scan.overflow(), 0);
        }
        assert_eq!(r.read_scan(&mut scan), Err(ReadError::Eof));
        assert_eq!(r.scans(), 2);
        // The leading partial turn (16 nodes: lock-on confirms three of them and delivers
        // all) and the unfinished last one (10) are not returned.
        assert_eq!(r.discarded_nodes(), 16 + 10);
        // A small buffer: beams are dropped and counted, the turn boundary still holds.
        let mut r = RplidarReader::new(&bytes[..]);
        let mut small: ScanBuf<10> = ScanBuf::new();
        r.read_scan(&mut small).unwrap();
        assert_eq!((small.beams().len(), small.overflow()), (10, 26));
        assert_eq!(small.beams(), &beams[..10]);
    }

    #[test]
    fn encoder_checks_the_buffer() {
        let b = [Beam {
            angle: Angle::ZERO,
            range: Range::Hit(1),
        }; 3];
        let mut out = [0u8; 21];
        assert_eq!(
            encode_scan(&b, true, &mut out[..21]),
            Err(EncodeError::BufferTooSmall { needed: 22 })
        );
        assert_eq!(encode_scan(&b, false, &mut out), Ok(15));
        assert_eq!(scan_len(usize::MAX, true), usize::MAX);
    }
}
