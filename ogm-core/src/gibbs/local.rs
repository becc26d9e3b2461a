//! The rays of one tile visit, indexed by block.
//!
//! When the sampler starts a tile visit it copies the rays crossing the tile (plus the margin a
//! patch reaches) into the caller's `local` buffer, and splits the gathered box into 8×8 blocks:
//! for each block a bitset over the local rays (one row of ⌈capacity/32⌉ words in the caller's
//! `blocks` buffer) says which rays visit one of its cells. A 3×3 patch touches at most 3×3
//! blocks (2×2 for the default 16-cell tiles), so the rays that can cross it are the set bits of
//! the union of a few rows — no scan of the whole list, no duplicates.

use super::segment::Segment;
use crate::geometry::CellCoord;

/// Blocks per side of a gathered box.
const G: usize = 8;

/// A ray gathered for the current tile visit (24 bytes): everything the per-patch work needs,
/// precomputed once per visit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LocalRay {
    /// Index in the store's ray array (for the first-occupied cache).
    pub(crate) index: u32,
    /// The ray, start to far end.
    pub(crate) seg: Segment,
    /// Step length, Q12 cells.
    pub(crate) step_q12: u16,
    /// Measured range, 1/16 steps, or [`crate::ray_store::NONE`].
    pub(crate) z_q4: u16,
}

impl Default for LocalRay {
    fn default() -> Self {
        let o = CellCoord::default();
        LocalRay {
            index: 0,
            seg: Segment::new(o, o),
            step_q12: 4096,
            z_q4: 0,
        }
    }
}

/// Words of block bitsets needed for `local_capacity` local rays.
pub const fn block_words(local_capacity: usize) -> usize {
    G * G * local_capacity.div_ceil(32)
}

/// The 8×8 block partition of a gathered box. Column of x = ⌊(x − x0)·mx / 2¹⁶⌋ with
/// mx = ⌊8·2¹⁶ / width⌋: monotone, within 0..8, and computed with one multiply — the gather and
/// the per-patch queries use the same function, which is all the index needs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct BlockGrid {
    /// Gathered box (inclusive).
    pub(crate) x0: i32,
    pub(crate) y0: i32,
    pub(crate) x1: i32,
    pub(crate) y1: i32,
    mx: u32,
    my: u32,
}

impl BlockGrid {
    pub(crate) fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> BlockGrid {
        // Tiles are at most 2^12 + 2 cells wide, so (x − x0)·m < 2^13 · 2^19 fits a u32.
        let (w, h) = ((x1 - x0 + 1).max(1) as u32, (y1 - y0 + 1).max(1) as u32);
        let g = (G as u32) << 16;
        BlockGrid {
            x0,
            y0,
            x1,
            y1,
            mx: g / w,
            my: g / h,
        }
    }

    #[inline]
    fn col(&self, x: i32) -> u32 {
        (((x - self.x0).max(0) as u32).wrapping_mul(self.mx) >> 16).min(G as u32 - 1)
    }

    #[inline]
    fn row(&self, y: i32) -> u32 {
        (((y - self.y0).max(0) as u32).wrapping_mul(self.my) >> 16).min(G as u32 - 1)
    }

    /// The block of a cell inside the box.
    #[inline]
    pub(crate) fn block(&self, c: CellCoord) -> u32 {
        G as u32 * self.row(c.y) + self.col(c.x)
    }

    /// Blocks overlapping the box `[x0, x1] × [y0, y1]` (clamped to the gathered box).
    #[inline]
    pub(crate) fn blocks_of_box(&self, x0: i32, y0: i32, x1: i32, y1: i32) -> u64 {
        let (c0, c1) = (self.col(x0.max(self.x0)), self.col(x1.min(self.x1)));
        let (r0, r1) = (self.row(y0.max(self.y0)), self.row(y1.min(self.y1)));
        let cols = (1u64 << (c1 + 1)) - (1 << c0);
        (r0..=r1).fold(0, |m, r| m | cols << (G as u32 * r))
    }
}

/// Sets bit `j` in block row `b` (rows of `words` words).
#[inline]
pub(crate) fn set_bit(bits: &mut [u32], words: usize, b: u32, j: usize) {
    if let Some(w) = bits.get_mut(b as usize * words + j / 32) {
        *w |= 1 << (j % 32);
    }
}

/// Calls `f(j)` for every local ray `j` set in any block of `mask`, each once, in order.
#[inline]
pub(crate) fn for_each_ray(
    bits: &[u32],
    words: usize,
    n_local: usize,
    mask: u64,
    mut f: impl FnMut(usize),
) {
    let used = n_local.div_ceil(32).min(words);
    for w in 0..used {
        let mut union = 0u32;
        let mut m = mask;
        while m != 0 {
            let b = m.trailing_zeros() as usize;
            m &= m - 1;
            union |= bits.get(b * words + w).copied().unwrap_or(0);
        }
        while union != 0 {
            let j = w * 32 + union.trailing_zeros() as usize;
            union &= union - 1;
            f(j);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_partition_the_box() {
        let g = BlockGrid::new(10, 20, 27, 37); // 18×18
        let mut seen = [0u32; 64];
        for y in 20..=37 {
            for x in 10..=27 {
                let b = g.block(CellCoord { x, y });
                seen[b as usize] += 1;
                assert_ne!(g.blocks_of_box(x, y, x, y) & (1 << b), 0);
            }
        }
        assert!(seen.iter().all(|&n| n >= 1), "{seen:?}");
        assert_eq!(g.blocks_of_box(0, 0, 100, 100), u64::MAX);
        assert_eq!(g.blocks_of_box(10, 20, 10, 20), 1);
    }

    #[test]
    fn union_iteration_has_no_duplicates() {
        let words = 2;
        let mut bits = vec![0u32; 64 * words];
        for (b, j) in [(0, 3), (1, 3), (1, 40), (5, 7), (63, 63)] {
            set_bit(&mut bits, words, b, j);
        }
        let mut got = Vec::new();
        for_each_ray(&bits, words, 64, 0b11, |j| got.push(j));
        assert_eq!(got, vec![3, 40]);
        got.clear();
        for_each_ray(&bits, words, 64, u64::MAX, |j| got.push(j));
        assert_eq!(got, vec![3, 7, 40, 63]);
    }
}
