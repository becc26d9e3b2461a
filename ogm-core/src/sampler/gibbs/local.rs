//! The rays of one tile visit, indexed by block.
//!
//! When the sampler starts a tile visit it copies the rays crossing the tile (plus the margin a
//! patch reaches) into the caller's `local` buffer, and splits the gathered box into G×G blocks
//! (G = 1 ..= 16, [`super::SamplerConfig::block_grid`]): for each block a bitset over the local
//! rays (one row of ⌈capacity/32⌉ words in the caller's `blocks` buffer) says which rays visit
//! one of its cells. The rays that can cross a patch are the set bits of the union of the rows of
//! the few blocks it touches — no scan of the whole list, no duplicates. G = 16 on the default
//! 18-cell box is nearly one block per cell (fewest false candidates, 256 rows of memory); G = 8
//! needs a quarter of that.

use super::segment::Segment;
use crate::types::geometry::CellCoord;

/// Largest number of blocks per side.
pub const MAX_BLOCK_GRID: u8 = 16;

/// The block grid a robot's sampler uses (8 × 8 blocks of a 16 × 16-cell tile: 2 × 2 cells
/// each), which sizes its block bitsets ([`block_words`]).
pub const DEFAULT_BLOCK_GRID: u8 = 8;

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
    /// Measured range, 1/16 steps, or [`crate::sampler::ray_store::NONE`].
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

/// Words of block bitsets needed for `local_capacity` local rays with `grid` blocks per side.
pub const fn block_words(local_capacity: usize, grid: u8) -> usize {
    grid as usize * grid as usize * local_capacity.div_ceil(32)
}

/// The G×G block partition of a gathered box. Column of x = ⌊(x − x0)·mx / 2¹⁶⌋ with
/// mx = ⌊G·2¹⁶ / width⌋: monotone, within 0..G, and computed with one multiply — the gather and
/// the per-patch queries use the same function, which is all the index needs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct BlockGrid {
    /// Gathered box (inclusive).
    pub(crate) x0: i32,
    pub(crate) y0: i32,
    pub(crate) x1: i32,
    pub(crate) y1: i32,
    g: u32,
    mx: u32,
    my: u32,
}

impl BlockGrid {
    /// `g` blocks per side (1 ..= 16) over the box `[x0, x1] × [y0, y1]`.
    pub(crate) fn new(x0: i32, y0: i32, x1: i32, y1: i32, g: u8) -> BlockGrid {
        // Tiles are at most 2^12 + 2 cells wide, so (x − x0)·m < 2^13 · 2^20 fits a u32.
        let (w, h) = ((x1 - x0 + 1).max(1) as u32, (y1 - y0 + 1).max(1) as u32);
        let g = u32::from(g.clamp(1, MAX_BLOCK_GRID));
        BlockGrid {
            x0,
            y0,
            x1,
            y1,
            g,
            mx: (g << 16) / w,
            my: (g << 16) / h,
        }
    }

    #[inline]
    fn col(&self, x: i32) -> u32 {
        (((x - self.x0).max(0) as u32).wrapping_mul(self.mx) >> 16).min(self.g - 1)
    }

    #[inline]
    fn row(&self, y: i32) -> u32 {
        (((y - self.y0).max(0) as u32).wrapping_mul(self.my) >> 16).min(self.g - 1)
    }

    /// The block of a cell inside the box.
    #[inline]
    pub(crate) fn block(&self, c: CellCoord) -> u32 {
        self.g * self.row(c.y) + self.col(c.x)
    }

    /// Blocks overlapping the box `[x0, x1] × [y0, y1]` (clamped to the gathered box).
    #[inline]
    pub(crate) fn blocks_of_box(&self, x0: i32, y0: i32, x1: i32, y1: i32) -> Blocks {
        Blocks {
            g: self.g,
            c0: self.col(x0.max(self.x0)),
            c1: self.col(x1.min(self.x1)),
            r0: self.row(y0.max(self.y0)),
            r1: self.row(y1.min(self.y1)),
        }
    }
}

/// A rectangle of blocks `[c0, c1] × [r0, r1]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Blocks {
    g: u32,
    c0: u32,
    c1: u32,
    r0: u32,
    r1: u32,
}

/// Sets bit `j` in block row `b` (rows of `words` words).
#[inline]
pub(crate) fn set_bit(bits: &mut [u32], words: usize, b: u32, j: usize) {
    if let Some(w) = bits.get_mut(b as usize * words + j / 32) {
        *w |= 1 << (j % 32);
    }
}

/// Calls `f(j)` for every local ray `j` set in any block of `blocks`, each once, in order.
#[inline]
pub(crate) fn for_each_ray(
    bits: &[u32],
    words: usize,
    n_local: usize,
    blocks: Blocks,
    mut f: impl FnMut(usize),
) {
    let used = n_local.div_ceil(32).min(words);
    for w in 0..used {
        let mut union = 0u32;
        for r in blocks.r0..=blocks.r1 {
            for c in blocks.c0..=blocks.c1 {
                let b = (r * blocks.g + c) as usize;
                union |= bits.get(b * words + w).copied().unwrap_or(0);
            }
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
        for grid in [1u8, 4, 8, 16] {
            let g = BlockGrid::new(10, 20, 27, 37, grid); // 18×18
            let mut seen = vec![0u32; usize::from(grid) * usize::from(grid)];
            for y in 20..=37 {
                for x in 10..=27 {
                    let b = g.block(CellCoord { x, y });
                    seen[b as usize] += 1;
                    let one = g.blocks_of_box(x, y, x, y);
                    assert_eq!(one.r0 * one.g + one.c0, b);
                    assert_eq!((one.r0, one.c0), (one.r1, one.c1));
                }
            }
            assert!(seen.iter().all(|&n| n >= 1), "{grid}: {seen:?}");
            let all = g.blocks_of_box(0, 0, 100, 100);
            let last = u32::from(grid) - 1;
            assert_eq!((all.c0, all.r0, all.c1, all.r1), (0, 0, last, last));
        }
    }

    #[test]
    fn union_iteration_has_no_duplicates() {
        let words = 2;
        let mut bits = vec![0u32; 64 * words];
        for (b, j) in [(0, 3), (1, 3), (1, 40), (5, 7), (63, 63)] {
            set_bit(&mut bits, words, b, j);
        }
        let first_two = Blocks {
            g: 8,
            c0: 0,
            c1: 1,
            r0: 0,
            r1: 0,
        };
        let mut got = Vec::new();
        for_each_ray(&bits, words, 64, first_two, |j| got.push(j));
        assert_eq!(got, vec![3, 40]);
        got.clear();
        let all = Blocks {
            g: 8,
            c0: 0,
            c1: 7,
            r0: 0,
            r1: 7,
        };
        for_each_ray(&bits, words, 64, all, |j| got.push(j));
        assert_eq!(got, vec![3, 7, 40, 63]);
    }
}
