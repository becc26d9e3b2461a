//! Pass 3 of the beam model's insertion: the sweep over the scan's mark words that frees the
//! cells the rays crossed and no beam hit, bit by bit or, on a 64-bit host when nobody hears
//! about each cell, lane-wise.

use super::listener::{hears, Reports, UpdateListener};
use super::update::Update;
use crate::types::fixed::LogOdds;

/// Whether the sweep updates a word's 32 cells lane-wise ([`Update::free_lanes`]) when nobody
/// needs to hear about each cell: on 64-bit hosts, whose vector units do 32 lanes in a handful of
/// instructions; a 32-bit microcontroller has no such unit and visits the set bits one by one.
pub(super) const LANE_SWEEP: bool = cfg!(target_pointer_width = "64");

/// Frees the cells whose bits are set in `marks[first..=last]`, in increasing index order, and
/// clears those words; returns how many cells it freed, and tells `listener` (see [`Reports`]).
// Out of line on a 32-bit core, whose registers then hold the sweep's state instead of the
// whole insertion's; inlined on a 64-bit host, where it serves only listeners that hear about
// cells (the lane-wise sweep is `free_words_lanes`).
#[cfg_attr(target_pointer_width = "32", inline(never))]
#[cfg_attr(not(target_pointer_width = "32"), inline(always))]
pub(super) fn free_words<L: UpdateListener>(
    marks: &mut [u32],
    first: usize,
    last: usize,
    cells: &mut [LogOdds],
    update: Update,
    listener: &mut L,
) -> u32 {
    let mut freed = 0u32;
    let Some(words) = marks.get_mut(first..=last) else {
        return 0;
    };
    for (k, word) in words.iter_mut().enumerate() {
        if *word == 0 {
            continue;
        }
        let bits = core::mem::take(word);
        // The words of in-grid cells: base + 31 < 2^32 · 32, no overflow.
        let base = (first + k) * 32;
        // Marked cells are in the grid (marking sets no bit past its end), so all are freed:
        // counted per word on a 32-bit core (one register fewer in its loop), per cell on a
        // 64-bit host (which has no cheaper count without `popcnt`).
        if !LANE_SWEEP {
            freed += bits.count_ones();
        }
        // A whole word of cells (all but possibly the grid's last word): no bounds check per
        // cell.
        let lanes = cells
            .get_mut(base..base + 32)
            .and_then(|c| <&mut [LogOdds; 32]>::try_from(c).ok());
        let fresh = match lanes {
            Some(lanes) => free_bits(bits, base, update, listener, &mut freed, lanes),
            None => {
                let tail = cells.get_mut(base..).unwrap_or(&mut []);
                free_bits(bits, base, update, listener, &mut freed, tail)
            }
        };
        if fresh != 0 {
            listener.fresh_word(first + k, fresh, update.apply(LogOdds(0), update.free));
        }
    }
    freed
}

/// [`free_words`] lane-wise, for a host when nobody hears about each cell (see
/// [`LANE_SWEEP`]): empty words are skipped four at a time (most of a scan's box is empty),
/// each whole word's cells are freed by [`Update::free_lanes`], and the count is kept in
/// `count`'s vector lanes across the scan's rows. A range longer than [`LANE_BLOCK`] words (never
/// a row of the box: a grid is under 2^16 cells wide) takes the bit-by-bit sweep instead.
#[inline(always)]
pub(super) fn free_words_lanes(
    marks: &mut [u32],
    first: usize,
    last: usize,
    cells: &mut [LogOdds],
    update: Update,
    count: &mut LaneCount,
) {
    let Some(words) = marks.get_mut(first..=last) else {
        return;
    };
    if words.len() > LANE_BLOCK {
        count.total =
            count
                .total
                .saturating_add(free_words(marks, first, last, cells, update, &mut ()));
        return;
    }
    count.make_room(words.len());
    let done = words.len() / 4 * 4;
    let mut quads = words.chunks_exact_mut(4);
    for (q, quad) in quads.by_ref().enumerate() {
        if quad.iter().fold(0, |a, w| a | w) == 0 {
            continue;
        }
        for (j, word) in quad.iter_mut().enumerate() {
            if *word != 0 {
                free_word_lanes(word, (first + 4 * q + j) * 32, cells, update, count);
            }
        }
    }
    for (j, word) in quads.into_remainder().iter_mut().enumerate() {
        if *word != 0 {
            free_word_lanes(word, (first + done + j) * 32, cells, update, count);
        }
    }
}

/// The lane-wise sweep's count of freed cells over a scan: eight `u16` lanes, each gaining at
/// most 4 per word, summed into `total` before more than [`LANE_BLOCK`] words have gone into
/// them (so at most 2^14 per lane, no wrap).
#[derive(Default)]
pub(super) struct LaneCount {
    lanes: [u16; 8],
    /// Words counted into `lanes` since they were last summed.
    pending: usize,
    total: u32,
}

impl LaneCount {
    /// Makes room in the lanes for `words` more words (≤ [`LANE_BLOCK`]).
    #[inline(always)]
    fn make_room(&mut self, words: usize) {
        if self.pending + words > LANE_BLOCK {
            self.flush();
        }
        self.pending += words;
    }

    fn flush(&mut self) {
        let sum: u32 = self.lanes.iter().map(|&n| u32::from(n)).sum();
        self.total = self.total.saturating_add(sum);
        (self.lanes, self.pending) = ([0; 8], 0);
    }

    /// All the cells counted.
    pub(super) fn total(mut self) -> u32 {
        self.flush();
        self.total
    }
}

/// [`LaneCount`]'s block: a `u16` lane gains at most 4 per word, so at most 2^14 per block.
const LANE_BLOCK: usize = 1 << 12;

/// One nonzero word of [`free_words_lanes`], `base` being the index of its bit 0 (`base + 31 <
/// 2^32 · 32`: the words of in-grid cells): lane-wise if all its 32 cells exist, else (the
/// grid's last word) bit by bit, counted in `count.total`.
#[inline(always)]
fn free_word_lanes(
    word: &mut u32,
    base: usize,
    cells: &mut [LogOdds],
    update: Update,
    count: &mut LaneCount,
) {
    let bits = core::mem::take(word);
    match cells
        .get_mut(base..base + 32)
        .and_then(|c| <&mut [LogOdds; 32]>::try_from(c).ok())
    {
        Some(lanes) => update.free_lanes(lanes, bits, &mut count.lanes),
        None => {
            let tail = cells.get_mut(base..).unwrap_or(&mut []);
            free_bits(bits, base, update, &mut (), &mut count.total, tail);
        }
    }
}

/// The cells of one mark word, from its bit 0 on: a whole word's 32 (no bounds check per cell)
/// or the grid's last, shorter word's.
trait WordCells {
    /// The cell of bit `b` (< 32), if there is one.
    fn cell(&mut self, b: u32) -> Option<&mut LogOdds>;
}

impl WordCells for [LogOdds; 32] {
    #[inline(always)]
    fn cell(&mut self, b: u32) -> Option<&mut LogOdds> {
        // b % 32 < 32: the check folds away.
        self.get_mut(b as usize % 32)
    }
}

impl WordCells for [LogOdds] {
    #[inline(always)]
    fn cell(&mut self, b: u32) -> Option<&mut LogOdds> {
        self.get_mut(b as usize)
    }
}

/// [`free_words`]' loop over the set bits of one word, `base` being the index of its bit 0;
/// returns, with [`Reports::Notable`], the bits of the cells that were unobserved (told
/// afterwards as one word), else 0.
#[inline(always)]
fn free_bits<L: UpdateListener, W: WordCells + ?Sized>(
    mut bits: u32,
    base: usize,
    update: Update,
    listener: &mut L,
    freed: &mut u32,
    cells: &mut W,
) -> u32 {
    let mut fresh = 0u32;
    while bits != 0 {
        let b = bits.trailing_zeros();
        // Clears the lowest set bit.
        bits &= bits - 1;
        if let Some(cell) = cells.cell(b) {
            let before = *cell;
            let after = update.apply(before, update.free);
            *cell = after;
            *freed += u32::from(LANE_SWEEP);
            // One test in the common case: a cell that was unobserved (0) always makes a
            // notable change (it ends below 0).
            if hears_freed::<L>(before, after) {
                if L::REPORTS == Reports::Notable && before.0 == 0 {
                    fresh |= 1 << b;
                } else {
                    listener.changed(base + b as usize, before, after);
                }
            }
        }
    }
    fresh
}

/// [`hears`] for a freed cell, in fewer instructions: the free increment is negative and
/// `min < 0 < max` (both checked where models and clamps are made), so a freed cell's change is
/// notable iff `before ≥ 0` and `after ≤ 0` (from below 0 it stays below 0; from 0 or above it
/// flips or was unobserved iff it ends at or below 0).
#[inline(always)]
fn hears_freed<L: UpdateListener>(before: LogOdds, after: LogOdds) -> bool {
    let hear = match L::REPORTS {
        Reports::Nothing => false,
        Reports::Notable => (i32::from(before.0) | -i32::from(after.0)) >= 0,
        Reports::Every => true,
    };
    debug_assert_eq!(hear, hears::<L>(before, after), "{before:?} -> {after:?}");
    hear
}

#[cfg(test)]
mod tests {
    use super::super::marks_len;
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// The lane-wise sweep (mask table, empty words skipped four at a time, count kept in
        /// lanes) frees exactly the cells the bit-by-bit sweep frees, from any cell values
        /// (outside the clamp too), on any range of words including the grid's last, shorter
        /// one, and clears the same words.
        #[test]
        fn lane_sweep_matches_bit_sweep(cells in prop::collection::vec(any::<i16>(), 1..700),
                                        marks in prop::collection::vec(
                                            prop_oneof![Just(0u32), any::<u32>(), Just(u32::MAX)], 22),
                                        first in 0usize..22, len in 0usize..22,
                                        free in -3000i32..0, lo in -32768i32..0, hi in 1i32..32768) {
            let update = Update { occ: 1, free, min: lo, max: hi };
            let cells: Vec<LogOdds> = cells.into_iter().map(LogOdds).collect();
            // Marks only over the cells that exist, as marking leaves them.
            let mut marks = marks;
            marks.truncate(marks_len(cells.len()));
            if let Some(tail) = marks.last_mut().filter(|_| cells.len() % 32 != 0) {
                *tail &= (1u32 << (cells.len() % 32)) - 1;
            }
            let last = (first + len).min(marks.len().saturating_sub(1));
            let (mut lane_cells, mut lane_marks) = (cells.clone(), marks.clone());
            let mut count = LaneCount::default();
            free_words_lanes(&mut lane_marks, first, last, &mut lane_cells, update, &mut count);
            let lanes = count.total();
            let (mut bit_cells, mut bit_marks) = (cells, marks);
            let bits = free_words(&mut bit_marks, first, last, &mut bit_cells, update, &mut ());
            prop_assert_eq!(lanes, bits);
            prop_assert_eq!(lane_cells, bit_cells);
            prop_assert_eq!(lane_marks, bit_marks);
        }
    }

    /// The lane-wise count over many rows, all set, is the number of their cells: without the
    /// flushes, a `u16` lane's count (4 per word) would wrap after 2^14 words. A range longer
    /// than a block (the bit-by-bit fallback) is freed and counted in full too.
    #[test]
    fn lane_sweep_counts_past_a_block() {
        let (row, rows) = (2_000, 11);
        let update = Update {
            occ: 1,
            free: -5,
            min: -100,
            max: 100,
        };
        let mut cells = vec![LogOdds(7); row * rows * 32];
        let mut marks = vec![u32::MAX; row * rows];
        let mut count = LaneCount::default();
        for r in 0..rows {
            free_words_lanes(
                &mut marks,
                r * row,
                r * row + row - 1,
                &mut cells,
                update,
                &mut count,
            );
        }
        assert_eq!(count.total() as usize, row * rows * 32);
        assert!(cells.iter().all(|c| *c == LogOdds(2)));
        assert!(marks.iter().all(|&w| w == 0));
        let words = LANE_BLOCK + 3;
        let mut cells = vec![LogOdds(7); words * 32];
        let mut marks = vec![u32::MAX; words];
        let mut count = LaneCount::default();
        free_words_lanes(&mut marks, 0, words - 1, &mut cells, update, &mut count);
        assert_eq!(count.total() as usize, words * 32);
        assert!(cells.iter().all(|c| *c == LogOdds(2)));
        assert!(marks.iter().all(|&w| w == 0));
    }
}
