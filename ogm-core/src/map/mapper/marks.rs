//! The per-scan mark bits: one bit per cell, set where a scan's rays pass, cleared over the
//! words the scan touched only; and the marking of a ray's cells.

use crate::map::ray::IndexWalk;
use crate::types::geometry::CellCoord;

/// Words of scan-mark bitset needed for `cells` cells.
pub const fn marks_len(cells: usize) -> usize {
    cells.div_ceil(32)
}

/// One bit per cell, with the range of words touched this scan, so clearing is proportional to
/// the scan rather than to the grid.
///
/// The range is not tracked per cell (that kept two more live values in the hot loop, which a
/// Cortex-M4 spilled to the stack) but per ray: a ray's cells lie in the rows between its end
/// cells, so the words of those rows are covered.
pub(super) struct Marks<'a> {
    pub(super) words: &'a mut [u32],
    lo: usize,
    hi: usize,
}

impl<'a> Marks<'a> {
    pub(super) fn new(words: &'a mut [u32]) -> Self {
        Marks {
            words,
            lo: usize::MAX,
            hi: 0,
        }
    }

    /// Sets the bit; returns `true` if it was clear (first touch in this scan). The caller
    /// records the word range with [`Marks::cover`].
    #[inline(always)]
    pub(super) fn first_touch(words: &mut [u32], index: usize) -> bool {
        let (w, bit) = (index / 32, 1u32 << (index % 32));
        match words.get_mut(w) {
            Some(word) if *word & bit == 0 => {
                *word |= bit;
                true
            }
            _ => false,
        }
    }

    /// Records that cells with indices in `lo..=hi` may have been marked.
    #[inline]
    pub(super) fn cover(&mut self, lo: usize, hi: usize) {
        self.lo = self.lo.min(lo / 32);
        self.hi = self.hi.max(hi / 32);
    }

    /// Records that a ray between cells `a` and `b` may have marked cells: its cells lie in the
    /// rows between its end cells, and in the grid.
    #[inline]
    pub(super) fn cover_rows(&mut self, a: CellCoord, b: CellCoord, width: u16, height: u16) {
        let w = usize::from(width);
        let (y0, y1) = (a.y.min(b.y).max(0), a.y.max(b.y).min(i32::from(height) - 1));
        if y0 <= y1 {
            // 0 ≤ y0 ≤ y1 < height.
            self.cover(y0 as usize * w, y1 as usize * w + (w - 1));
        }
    }
}

impl Drop for Marks<'_> {
    fn drop(&mut self) {
        if self.lo <= self.hi {
            let hi = self.hi.min(self.words.len().saturating_sub(1));
            if let Some(ws) = self.words.get_mut(self.lo..=hi) {
                ws.fill(0);
            }
        }
    }
}

/// Cells a ray is marked in at a time before their updates are applied.
pub(super) const CHUNK: usize = 128;

/// Whether [`mark_chunk`] marks without a data-dependent branch. Whether a cell was touched
/// before in this scan is hard to predict (rays overlap near the robot and part ways further out),
/// which costs a deeply pipelined host core more than the extra work of always storing; an
/// in-order microcontroller core has no such penalty to avoid and runs fewer instructions with
/// the branch (Cortex-M4 under QEMU: 53 vs 62 instructions per updated cell). 64-bit targets
/// stand for the former, 32-bit ones for the latter; both variants give identical results.
pub(super) const BRANCH_FREE_MARKING: bool = cfg!(target_pointer_width = "64");

/// Marks up to [`CHUNK`] cells of `walk` and writes the indices of those it touched first this
/// scan to `out`; returns how many. Not inlined, so that its loop gets the registers to itself.
#[inline(never)]
pub(super) fn mark_chunk<const BRANCH_FREE: bool>(
    walk: &mut IndexWalk,
    words: &mut [u32],
    out: &mut [u32; CHUNK],
) -> usize {
    let mut wk = *walk;
    let m = wk.take(CHUNK as u32);
    let mut n = 0usize;
    for _ in 0..m {
        let i = wk.index();
        let (w, bit) = (i / 32, 1u32 << (i % 32));
        if let Some(word) = words.get_mut(w) {
            let old = *word;
            if BRANCH_FREE {
                // Always set the bit and store the index; only a first touch advances `n`.
                *word = old | bit;
                // n ≤ cells visited so far < m ≤ CHUNK, a power of two: the mask changes
                // nothing, it only lets the compiler drop the bounds check. Grid indices are
                // < 2^32.
                if let Some(slot) = out.get_mut(n & (CHUNK - 1)) {
                    *slot = i as u32;
                }
                n += usize::from(old & bit == 0);
            } else if old & bit == 0 {
                *word = old | bit;
                if let Some(slot) = out.get_mut(n & (CHUNK - 1)) {
                    *slot = i as u32;
                }
                n += 1;
            }
        }
        wk.advance();
    }
    *walk = wk;
    n
}

/// The cells a scan's rays can have marked: the bounding box, clipped to the grid, of the end
/// cells of the rays that cross the grid (a ray's cells lie between its end cells).
pub(super) struct ScanBox {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl ScanBox {
    pub(super) fn empty() -> Self {
        ScanBox {
            x0: i32::MAX,
            y0: i32::MAX,
            x1: i32::MIN,
            y1: i32::MIN,
        }
    }

    #[inline]
    pub(super) fn cover(&mut self, a: CellCoord, b: CellCoord) {
        self.x0 = self.x0.min(a.x.min(b.x));
        self.x1 = self.x1.max(a.x.max(b.x));
        self.y0 = self.y0.min(a.y.min(b.y));
        self.y1 = self.y1.max(a.y.max(b.y));
    }
}

/// Calls `f(first, last)` for each row of `area` (clipped to the grid), with the range of mark
/// words that hold the row's part of the box, less any word the previous row's range ended in:
/// each word of the box once, in increasing order.
#[inline(always)]
pub(super) fn box_words(area: &ScanBox, width: u16, height: u16, mut f: impl FnMut(usize, usize)) {
    let max_x = i32::from(width) - 1;
    let max_y = i32::from(height) - 1;
    let (x0, x1) = (area.x0.max(0), area.x1.min(max_x));
    let (y0, y1) = (area.y0.max(0), area.y1.min(max_y));
    if x0 > x1 || y0 > y1 {
        return;
    }
    // All four lie in the grid now, so these are in-grid cell indices.
    let w = usize::from(width);
    let (x0, x1) = (x0 as usize, x1 as usize);
    let mut next = 0usize;
    for y in y0 as usize..=y1 as usize {
        let first = ((y * w + x0) / 32).max(next);
        let last = (y * w + x1) / 32;
        if first > last {
            continue;
        }
        f(first, last);
        next = last + 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::ray::Ray;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// Marking a walk run by run sets exactly the bits of its cells.
        #[test]
        // Widths of whole words too (32, 64: the strided runs' one-bit path), and heights that
        // give long y-major runs.
        fn run_marking_sets_the_walked_cells(x0 in -20i32..80, y0 in -20i32..80, x1 in -20i32..80, y1 in -20i32..80,
                                             w in prop_oneof![1u16..70, Just(32u16), Just(64u16)],
                                             h in prop_oneof![1u16..9, 9u16..90]) {
            let r = Ray::new(CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let Some(steps) = r.clip(w, h) else { return Ok(()); };
            let Some(walk) = r.index_walk(steps, w) else { return Ok(()); };
            let mut want = vec![0u32; marks_len(usize::from(w) * usize::from(h))];
            r.for_each_index(steps, w, |_, i| want[i / 32] |= 1 << (i % 32));
            let mut got = vec![0u32; want.len()];
            walk.mark_all(&mut got);
            prop_assert_eq!(got, want);
        }

        /// Both marking loops (branch-free for hosts, branchy for microcontrollers) mark the
        /// same bits and report the same first touches.
        #[test]
        fn marking_variants_agree(x0 in -20i32..80, y0 in -20i32..80, x1 in -20i32..80, y1 in -20i32..80,
                                  premarked in prop::collection::vec(any::<u32>(), 7)) {
            let (w, h) = (50u16, 4u16);
            let r = Ray::new(CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let Some(steps) = r.clip(w, h) else { return Ok(()); };
            let Some(walk) = r.index_walk(steps, w) else { return Ok(()); };
            let run = |branch_free: bool| {
                let (mut words, mut wk, mut out) = (premarked.clone(), walk, Vec::new());
                let mut chunk = [0u32; CHUNK];
                while wk.left() > 0 {
                    let n = if branch_free {
                        mark_chunk::<true>(&mut wk, &mut words, &mut chunk)
                    } else {
                        mark_chunk::<false>(&mut wk, &mut words, &mut chunk)
                    };
                    out.extend_from_slice(&chunk[..n]);
                }
                (words, out)
            };
            prop_assert_eq!(run(true), run(false));
        }
    }
}
