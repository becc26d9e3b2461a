//! A scan's ranges for a live view: [`ScanRanges`] and its codec.

use serde::{Deserialize, Serialize};

use super::error::WireError;
use crate::types::angle::Angle;

/// A scan's ranges as the robot streams them for a live view (sent right after the scan's
/// [`ScanReport`], same `seq`, in the robot's frame at the report's pose): the closest hit of
/// each of [`SCAN_BINS`] angular bins, millimetres, [`RANGE_NONE`] or [`RANGE_NO_RETURN`]
/// otherwise. A 450-beam LD06 turn is 360 bytes instead of ~1.8 KB; the map itself never
/// depends on it. [`encode_ranges`] and [`ScanRanges::bins`] are its one codec.
///
/// [`ScanReport`]: super::ScanReport
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanRanges<'a> {
    /// The scan's number ([`ScanReport::seq`]).
    ///
    /// [`ScanReport::seq`]: super::ScanReport::seq
    pub seq: u32,
    /// [`SCAN_RANGES_LEN`] bytes.
    pub data: &'a [u8],
}

/// Angular bins of a streamed scan ([`ScanRanges`]): 2° each, counter-clockwise from the
/// robot's heading, bin `i` covering `[i·2°, (i+1)·2°)`.
pub const SCAN_BINS: usize = 180;
/// Bytes of [`ScanRanges::data`]: one little-endian `u16` per bin.
pub const SCAN_RANGES_LEN: usize = 2 * SCAN_BINS;
/// [`ScanRanges`] bin value: no beam fell in the bin.
pub const RANGE_NONE: u16 = 0;
/// [`ScanRanges`] bin value: the bin's beams returned nothing within range.
pub const RANGE_NO_RETURN: u16 = u16::MAX;

/// The bin of a beam direction.
fn range_bin(angle: Angle) -> usize {
    // < SCAN_BINS: angle < 2^16.
    ((u32::from(angle.0) * SCAN_BINS as u32) >> 16) as usize
}

/// Bins `beams` into `out` ([`ScanRanges::data`]): per bin the closest hit (clamped to
/// 1 ..= 65 534 mm), else [`RANGE_NO_RETURN`] if a beam returned nothing, else [`RANGE_NONE`].
pub fn encode_ranges(beams: &[crate::types::scan::Beam], out: &mut [u8; SCAN_RANGES_LEN]) {
    out.fill(0);
    for b in beams {
        let v = match b.range {
            crate::types::scan::Range::Hit(mm) => {
                mm.clamp(1, u32::from(RANGE_NO_RETURN - 1)) as u16
            }
            crate::types::scan::Range::NoReturn => RANGE_NO_RETURN,
        };
        let i = 2 * range_bin(b.angle);
        if let Some([lo, hi]) = out.get_mut(i..i + 2) {
            let old = u16::from_le_bytes([*lo, *hi]);
            if old == RANGE_NONE || v < old {
                [*lo, *hi] = v.to_le_bytes();
            }
        }
    }
}

impl ScanRanges<'_> {
    /// The bins that hold a reading: each bin's centre direction (robot frame) and its
    /// reading; [`WireError::Ranges`] if `data` is not [`SCAN_RANGES_LEN`] bytes.
    pub fn bins(
        &self,
    ) -> Result<impl Iterator<Item = (Angle, crate::types::scan::Range)> + '_, WireError> {
        if self.data.len() != SCAN_RANGES_LEN {
            return Err(WireError::Ranges);
        }
        Ok(self.data.chunks_exact(2).enumerate().filter_map(|(i, b)| {
            let v = match *b {
                [lo, hi] => u16::from_le_bytes([lo, hi]),
                _ => RANGE_NONE,
            };
            // The bin's centre: (i + ½) · 2^16 / SCAN_BINS.
            let angle = Angle((((2 * i + 1) << 16) / (2 * SCAN_BINS)) as u16);
            match v {
                RANGE_NONE => None,
                RANGE_NO_RETURN => Some((angle, crate::types::scan::Range::NoReturn)),
                mm => Some((angle, crate::types::scan::Range::Hit(u32::from(mm)))),
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{decode, encode, DeviceMsg};

    /// The reference of [`encode_ranges`]: per bin (by the angle in degrees, f64), the
    /// closest hit, else no return, else nothing.
    fn ranges_reference(
        beams: &[crate::types::scan::Beam],
    ) -> Vec<Option<crate::types::scan::Range>> {
        use crate::types::scan::Range;
        let mut bins = vec![None; SCAN_BINS];
        for b in beams {
            let deg = f64::from(b.angle.0) * 360.0 / 65_536.0;
            let i = (deg / 2.0).floor() as usize;
            let r = match b.range {
                Range::Hit(mm) => Range::Hit(mm.clamp(1, 65_534)),
                r => r,
            };
            bins[i] = match (bins[i], r) {
                (None, r) | (Some(Range::NoReturn), r) => Some(r),
                (Some(Range::Hit(a)), Range::Hit(b)) => Some(Range::Hit(a.min(b))),
                (old, Range::NoReturn) => old,
            };
        }
        bins
    }

    proptest::proptest! {
        #[test]
        fn scan_ranges_bin_the_closest_hit_and_survive_the_link(
            raw in proptest::collection::vec((0u16.., proptest::option::of(0u32..100_000)), 0..600)
        ) {
            use crate::types::scan::{Beam, Range};
            let beams: Vec<Beam> = raw
                .iter()
                .map(|&(a, r)| Beam { angle: Angle(a), range: r.map_or(Range::NoReturn, Range::Hit) })
                .collect();
            let mut data = [0u8; SCAN_RANGES_LEN];
            encode_ranges(&beams, &mut data);
            let mut buf = [0u8; 512];
            let mut frame = encode(&DeviceMsg::Ranges(ScanRanges { seq: 9, data: &data }), &mut buf)
                .unwrap()
                .to_vec();
            let n = frame.len() - 1;
            let got = match decode::<DeviceMsg>(&mut frame[..n]).unwrap() {
                DeviceMsg::Ranges(r) => {
                    proptest::prop_assert_eq!(r.seq, 9);
                    r.bins().unwrap().collect::<Vec<_>>()
                }
                m => panic!("{m:?}"),
            };
            let want: Vec<(Angle, Range)> = ranges_reference(&beams)
                .into_iter()
                .enumerate()
                .filter_map(|(i, r)| r.map(|r| (i, r)))
                .map(|(i, r)| (Angle::from_degrees(2.0 * i as f64 + 1.0), r))
                .collect();
            proptest::prop_assert_eq!(got.len(), want.len());
            for ((ga, gr), (wa, wr)) in got.iter().zip(&want) {
                proptest::prop_assert_eq!(gr, wr);
                proptest::prop_assert!(ga.signed_diff(*wa).abs() <= 1, "{:?} {:?}", ga, wa);
            }
        }
    }

    #[test]
    fn scan_ranges_of_the_wrong_length_are_refused() {
        let data = [1u8; SCAN_RANGES_LEN - 2];
        assert!(ScanRanges {
            seq: 0,
            data: &data
        }
        .bins()
        .is_err());
        let data = [0u8; SCAN_RANGES_LEN];
        assert_eq!(
            ScanRanges {
                seq: 0,
                data: &data
            }
            .bins()
            .unwrap()
            .count(),
            0
        );
    }
}
