//! Who hears about a scan's updates ([`UpdateListener`]), and which of them ([`Reports`]).

use crate::types::fixed::LogOdds;

/// Who hears about a scan's updates ([`Mapper::insert_scan_into`]). Each cell changes at most
/// once per scan: with the beam model first the hit cells in beam order (with the face band,
/// each beam's band cells in turn, a band's from either end), then the freed cells in increasing
/// index order; with the cone model in [`classify_scan`]'s order.
///
/// Why not a closure per cell: the online sampler needs every changed cell's *tile* but the
/// values of only a few cells; with [`Reports::Notable`] it learns the tiles from the scan's mark
/// words (a few tiles per word) and the values of the notable cells: on the Cortex-M4 its share
/// of the per-scan step fell from ~83 to ~18 instructions per updated cell (docs/performance.md).
///
/// [`Mapper::insert_scan_into`]: super::Mapper::insert_scan_into
/// [`classify_scan`]: super::classify_scan
pub trait UpdateListener {
    /// Which changes [`UpdateListener::changed`] hears.
    const REPORTS: Reports;
    /// Cell `index` changed from `before` to `after` (which cells: [`UpdateListener::REPORTS`]).
    fn changed(&mut self, index: usize, before: LogOdds, after: LogOdds);
    /// With [`Reports::Notable`], after marking and before any update, once per row of the
    /// scan's box with the row's mark words (some may be 0), `first` being the first one's
    /// index: the cells `32·(first + k) + b`, for each bit `b` set in `words[k]`, are the ones
    /// this scan changes (together with the other rows' cells). Each word is passed once.
    fn marked_words(&mut self, first: usize, words: &[u32]);
    /// With [`Reports::Notable`], instead of [`UpdateListener::changed`] for each: the sweep
    /// freed the cells `32·word + b`, for each bit `b` set in `bits`, which were unobserved
    /// (log-odds 0) and are now all `after`. Most of a scan's notable cells are such newly
    /// seen free space, and a word of them costs the listener about a cell's worth.
    fn fresh_word(&mut self, word: usize, bits: u32, after: LogOdds);
}

/// Which changes an [`UpdateListener`] hears through [`UpdateListener::changed`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reports {
    /// None (the mapper alone: a 64-bit host may then free a word's cells lane-wise).
    Nothing,
    /// Only the notable ones ([`notable`]); the cells that change at all arrive beforehand as
    /// mark words ([`UpdateListener::marked_words`]).
    Notable,
    /// Every one.
    Every,
}

/// Whether a change of a cell from `before` to `after` is notable: the cell was unobserved
/// (`before` = 0) or the sign of its evidence flipped. The online sampler seeds such cells and
/// restarts their estimates; every other change only marks its tile.
#[inline(always)]
pub fn notable(before: LogOdds, after: LogOdds) -> bool {
    // v > 0 iff v − 1 ≥ 0 (in i32, no overflow): the signs differ iff the xor is negative.
    before.0 == 0 || ((i32::from(before.0) - 1) ^ (i32::from(after.0) - 1)) < 0
}

/// The mapper alone: nobody listens.
impl UpdateListener for () {
    const REPORTS: Reports = Reports::Nothing;
    #[inline(always)]
    fn changed(&mut self, _: usize, _: LogOdds, _: LogOdds) {}
    #[inline(always)]
    fn marked_words(&mut self, _: usize, _: &[u32]) {}
    #[inline(always)]
    fn fresh_word(&mut self, _: usize, _: u32, _: LogOdds) {}
}

/// A closure that hears every changed cell ([`Mapper::insert_scan_with`]).
///
/// [`Mapper::insert_scan_with`]: super::Mapper::insert_scan_with
pub(super) struct EachCell<F>(pub(super) F);

impl<F: FnMut(usize, LogOdds, LogOdds)> UpdateListener for EachCell<F> {
    const REPORTS: Reports = Reports::Every;
    #[inline(always)]
    fn changed(&mut self, index: usize, before: LogOdds, after: LogOdds) {
        (self.0)(index, before, after)
    }
    #[inline(always)]
    fn marked_words(&mut self, _: usize, _: &[u32]) {}
    #[inline(always)]
    fn fresh_word(&mut self, _: usize, _: u32, _: LogOdds) {}
}

/// Whether `listener` hears the change of a cell from `before` to `after`.
#[inline(always)]
pub(super) fn hears<L: UpdateListener>(before: LogOdds, after: LogOdds) -> bool {
    match L::REPORTS {
        Reports::Nothing => false,
        Reports::Notable => notable(before, after),
        Reports::Every => true,
    }
}
