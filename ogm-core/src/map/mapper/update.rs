//! The cell update the mapper applies: its increments and clamp in `i32`, one cell at a time or,
//! for the sweep on a 64-bit host, a word's 32 cells lane-wise.

use super::MapperConfig;
use crate::types::fixed::LogOdds;

/// A cell update with the mapper's increments and clamp, in `i32`: the bounds lie inside the
/// `i16` range, so clamping the exact sum equals [`Clamp::apply`]'s clamp of the saturated one,
/// and all four values stay in registers.
///
/// [`Clamp::apply`]: crate::types::fixed::Clamp::apply
#[derive(Clone, Copy)]
pub(super) struct Update {
    pub(super) occ: i32,
    pub(super) free: i32,
    pub(super) min: i32,
    pub(super) max: i32,
}

impl Update {
    pub(super) fn new(config: &MapperConfig) -> Self {
        Update {
            occ: i32::from(config.model.occ_increment().0),
            free: i32::from(config.model.free_increment().0),
            min: i32::from(config.clamp.min().0),
            max: i32::from(config.clamp.max().0),
        }
    }

    /// `value + delta` clamped to the bounds (`|value|, |delta| ≤ 2^15`, so the sum fits an
    /// `i32`; `min < max`, so the result lies in `[min, max]` ⊂ `i16`).
    #[inline(always)]
    pub(super) fn apply(&self, value: LogOdds, delta: i32) -> LogOdds {
        // The bounds came from `i16`s: saying so lets the compiler see that the result fits
        // one (no sign extension before a notable test).
        let (lo, hi) = (i32::from(self.min as i16), i32::from(self.max as i16));
        LogOdds((i32::from(value.0) + delta).max(lo).min(hi) as i16)
    }

    /// [`Update::apply`] of the free increment to each of the 32 cells whose bit is set in
    /// `bits`, without a data-dependent branch: every lane is computed and the set ones kept,
    /// which a host compiles to a few vector instructions per word instead of a loop over its
    /// bits. In `i16` with a saturating add, which equals the `i32` sum clamped, since the
    /// bounds lie inside the `i16` range. Each byte of `bits` selects its eight lanes through
    /// [`LANE_MASKS`] (a load per eight lanes instead of testing each bit), and lane `i` of
    /// `count` gains the number of bits `i`, `i + 8`, `i + 16`, `i + 24` set (≤ 4 per word).
    #[inline(always)]
    pub(super) fn free_lanes(&self, cells: &mut [LogOdds; 32], bits: u32, count: &mut [u16; 8]) {
        // All three came from `i16` values.
        let (d, lo, hi) = (self.free as i16, self.min as i16, self.max as i16);
        for (j, eight) in cells.chunks_exact_mut(8).enumerate() {
            // `& 0xff` < 256: always found, the check folds away.
            let masks = LANE_MASKS
                .get(((bits >> (8 * j)) & 0xff) as usize)
                .copied()
                .unwrap_or_default();
            for ((cell, m), n) in eight.iter_mut().zip(masks).zip(count.iter_mut()) {
                let v = cell.0.saturating_add(d).max(lo).min(hi);
                // m is 0 or −1: keeps the cell, or takes v.
                cell.0 ^= (cell.0 ^ v) & m;
                *n = n.wrapping_sub(m as u16);
            }
        }
    }
}

/// For each value of a byte, its eight bits as `i16` lane masks (−1 where the bit is set):
/// [`Update::free_lanes`]'s selection, 4 KiB, used on 64-bit hosts only.
// Indexing in a constant: out of bounds would fail the build, not panic at run time.
#[allow(clippy::indexing_slicing)]
const LANE_MASKS: [[i16; 8]; 256] = {
    let mut t = [[0i16; 8]; 256];
    let mut v = 0;
    while v < 256 {
        let mut b = 0;
        while b < 8 {
            if (v >> b) & 1 != 0 {
                t[v][b] = -1;
            }
            b += 1;
        }
        v += 1;
    }
    t
};
