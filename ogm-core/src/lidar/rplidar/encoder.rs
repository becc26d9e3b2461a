//! The encoder (for the simulator and tests): beams to a sensor's byte stream.

use super::protocol::{Node, DESCRIPTOR_LEN, NODE_LEN, SCAN_DESCRIPTOR};
use crate::lidar::encode::EncodeError;
use crate::types::scan::Beam;

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
///
/// [`theta_q6`]: super::theta_q6
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
    use crate::types::angle::Angle;
    use crate::types::scan::Range;

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
