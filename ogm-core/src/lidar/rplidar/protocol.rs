//! The protocol's constants, requests and wire items: response descriptors, scan nodes (and
//! their angles), the info / health / sample-rate responses, and what can be wrong with them.

use crate::lidar::encode::EncodeError;
use crate::types::angle::{Angle, FULL_TURN};
use crate::types::scan::{Beam, Range};

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
pub(super) const fn flags_ok(b0: u8) -> bool {
    (b0 ^ (b0 >> 1)) & 1 == 1
}

#[inline]
pub(super) fn node_angle(b1: u8, b2: u8) -> u16 {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lidar::rplidar::tests::node;

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
}
