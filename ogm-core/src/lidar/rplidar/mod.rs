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
//! reported and the parser keeps hunting. While hunting, `A5 5A` may also be node data (angle or
//! distance bytes), so such a descriptor is taken only if no lock-on window starts inside it
//! (the window's check bits and angles pass); otherwise its `A5` is skipped and the nodes come
//! back. It counts nodes, bad nodes, scan starts, descriptors, responses, lock-ons, skipped bytes
//! and truncated responses ([`RplidarCounters`]).
//!
//! [`Angle`]: crate::types::angle::Angle

// One file per part; everything is re-exported here, so users write `rplidar::RplidarParser`.
mod encoder;
mod parser;
mod protocol;
mod reader;

pub use encoder::{encode_scan, scan_len};
pub use parser::{Event, RplidarCounters, RplidarParser, LOCK_NODES, MAX_LOCK_STEP_Q6};
pub use protocol::{
    beam_angle, checksum, express_scan_request, request, request_with_payload,
    set_motor_pwm_request, theta_q6, Descriptor, DeviceInfo, Health, HealthStatus, Node,
    RplidarError, SampleRate, CMD_EXPRESS_SCAN, CMD_FORCE_SCAN, CMD_GET_HEALTH, CMD_GET_INFO,
    CMD_GET_SAMPLERATE, CMD_RESET, CMD_SCAN, CMD_SET_MOTOR_PWM, CMD_STOP, DESCRIPTOR_LEN,
    HEALTH_LEN, HIT_QUALITY, INFO_LEN, MAX_RANGE_MM, MODE_MULTIPLE, MODE_SINGLE, NODE_LEN,
    REQ_FORCE_SCAN, REQ_GET_HEALTH, REQ_GET_INFO, REQ_GET_SAMPLERATE, REQ_RESET, REQ_SCAN,
    REQ_STOP, SAMPLERATE_LEN, SCAN_DESCRIPTOR, SYNC1, SYNC2, TURN_Q6, TYPE_EXPRESS_SCAN,
    TYPE_HEALTH, TYPE_INFO, TYPE_SAMPLERATE, TYPE_SCAN,
};
pub use reader::RplidarReader;

/// Fixtures shared by the submodules' tests.
#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn node(start: bool, angle_q6: u16, distance_q2: u16) -> Node {
        Node {
            start,
            quality: if distance_q2 == 0 { 0 } else { HIT_QUALITY },
            angle_q6,
            distance_q2,
        }
    }

    /// `n` nodes of a turn starting at `start_q6`, 1° apart, the first flagged `S`.
    pub(super) fn turn(n: usize, start_q6: u16) -> Vec<u8> {
        let mut v = Vec::new();
        for i in 0..n {
            let a = ((u32::from(start_q6) + 64 * i as u32) % TURN_Q6) as u16;
            let d = if i % 7 == 3 { 0 } else { 4000 + 4 * i as u16 };
            v.extend_from_slice(&node(i == 0, a, d).to_bytes());
        }
        v
    }
}
