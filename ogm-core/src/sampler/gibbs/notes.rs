//! What the mapper tells a sampler that runs online (see
//! [`crate::session::Session::insert`]): the cells it observed for the first time,
//! seeded into the sample, and the cells whose log-odds changed, which mark their tiles for a
//! visit ([`super::schedule`]) and may restart their estimates.

use super::schedule::HotTiles;
use super::{estimate, Count, Gibbs, LocalRay, PatchPrior};
use crate::types::fixed::LogOdds;

/// Entries of [`Gibbs`]'s estimate-restart memo (a power of two: the slot is the value's low
/// bits).
pub(super) const RESTARTS: usize = 64;

/// Marks tile `(tx, ty)` unless `cols`, the tile columns (below 32) of tile row `ty` marked
/// since the last visit, says it is already ([`Gibbs::note_marked_words`]).
#[inline(always)]
fn mark_once(hot: &mut HotTiles, cols: &mut u32, tx: u32, ty: u32) {
    let col = if tx < 32 { 1u32 << tx } else { 0 };
    if *cols & col == 0 {
        hot.mark(tx, ty);
        *cols |= col;
    }
}

impl<P, B, C, L, K, N> Gibbs<P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    /// Sets cell `index` of the current sample — for seeding cells the moment the mapper first
    /// observes them while the sampler runs online (see
    /// [`crate::session::Session::insert`]). The first-occupied caches of rays crossing the cell
    /// are stale afterwards: call [`Gibbs::refresh_rays`] (once per scan is enough).
    pub fn seed(&mut self, index: usize, occupied: bool) {
        self.set_occupied(index, occupied);
    }

    /// [`Gibbs::seed`] for the cells `32·word + b` of each bit `b` set in `bits`, all with the
    /// same state: a word at a time.
    pub fn seed_word(&mut self, word: usize, bits: u32, occupied: bool) {
        if let Some(w) = self.buf.sample.as_mut().get_mut(word) {
            if occupied {
                *w |= bits;
            } else {
                *w &= !bits;
            }
        }
    }

    /// Tells the sampler that a scan changed cell `index`'s log-odds from `before` to `now`
    /// (what [`crate::session::Session::insert`] does for every cell it updates): marks its
    /// tile for a visit ([`SamplerConfig::hot_share`]) and, with [`Estimator::Average`]'s
    /// `reset_on_change`, restarts its estimate at `now`'s probability if the cell was
    /// unobserved (`before` = 0) or the sign of its evidence flipped. Evidence that only grew
    /// stronger keeps the estimate: on the simulated runs that is +0.002 to +0.007 of online
    /// max F1 at the same update count, and fewer instructions per scan (docs/results.md).
    ///
    /// [`SamplerConfig::hot_share`]: super::SamplerConfig::hot_share
    /// [`Estimator::Average`]: crate::config::Estimator::Average
    #[inline]
    pub fn note_changed(&mut self, index: usize, before: LogOdds, now: LogOdds) {
        let (lo, hi) = self.hot_span;
        if self.marks_tiles() && !(lo <= index && index <= hi) {
            let (first, last, _) = self.mark_tile_of(index);
            self.hot_span = (first, last);
        }
        // The span's promise: this cell's tile is marked.
        #[cfg(debug_assertions)]
        if self.marks_tiles() {
            let (tx, ty, _) = self.tile_of(index);
            debug_assert!(
                self.hot.is_marked(tx, ty),
                "cell {index}: tile ({tx}, {ty})"
            );
        }
        self.note_estimate(index, before, now);
    }

    /// The tile part of [`Gibbs::note_changed`] for the cells `32·(first + k) + b` of each bit
    /// `b` set in each `words[k]` (a row of a scan's mark words,
    /// [`crate::map::mapper::UpdateListener::marked_words`]): marks their tiles, one tile row segment
    /// at a time (a mark word holds at most a few), skipping the tiles it marked since the last
    /// visit. Their estimates are [`Gibbs::note_estimate`]'s, which only the notable changes
    /// need ([`crate::map::mapper::notable`]).
    // Out of line: its loop needs its own registers (inlined into the mapper it spilled most).
    #[inline(never)]
    pub fn note_marked_words(&mut self, first: usize, words: &[u32]) {
        let len = self.geometry.len();
        if !self.marks_tiles() {
            return;
        }
        let w = usize::from(self.geometry.width()).max(1);
        let s = u32::from(self.config.tile_shift);
        let cx0 = self.cx0 as u32;
        let last_tx = self.tiles_x - 1;
        let (mut cols_ty, mut cols) = self.marked_cols;
        if w % 32 == 0 && s <= 5 {
            // Rows that start on a word boundary (the mapper then passes one row's words) and
            // tiles no wider than a word (the firmware's grid): a tile's cells in a word are the
            // bits below where the next tile starts, so a word costs a few instructions per tile
            // it holds rather than a tile search per run of set bits.
            let Some(start) = first.checked_mul(32).filter(|&i| i < len) else {
                return;
            };
            let y = start / w;
            let ty = self.tile_row(y as u32);
            if cols_ty != ty {
                (cols_ty, cols) = (ty, 0);
            }
            // Column of the first word's bit 0 (< w ≤ 65535), and of each next word's.
            let mut x = (start - y * w) as u32;
            for &word in words {
                if x as usize >= w {
                    break;
                }
                if word == 0 {
                    x += 32;
                    continue;
                }
                let (mut bits, mut tx) = (word, self.tile_col(x));
                // Most words lie in tiles this tile row has marked already (a tile row spans
                // 2^tile_shift grid rows, more at the margins, and the mapper passes each grid
                // row's words in a call of its own): skip those whole.
                let hi = self.tile_col(x.saturating_add(31));
                if hi < 32 {
                    // Bits tx ..= hi (tx ≤ hi < 32).
                    let span = (u32::MAX >> (31 - hi)) & (u32::MAX << tx);
                    if cols & span == span {
                        bits = 0;
                    }
                }
                while bits != 0 {
                    // Tile tx's bits: those below the column where tile tx + 1 starts, which
                    // lies past x (the last tile column takes the rest of the row).
                    let below = if tx >= last_tx {
                        u32::MAX
                    } else {
                        let next = (cx0 + ((tx + 1) << s)).saturating_sub(x);
                        if next >= 32 {
                            u32::MAX
                        } else {
                            (1 << next) - 1
                        }
                    };
                    if bits & below != 0 {
                        mark_once(&mut self.hot, &mut cols, tx, ty);
                    }
                    bits &= !below;
                    tx += 1;
                }
                x += 32;
            }
            self.marked_cols = (cols_ty, cols);
            return;
        }
        let (mut lo, mut hi, mut ty) = self.mark_row;
        for (k, &word) in words.iter().enumerate() {
            let mut bits = word;
            // Indices ≤ len + 31 < 2^32 (a grid has at most 65535² cells) below `len`.
            let Some(base) = first.checked_add(k).and_then(|i| i.checked_mul(32)) else {
                break;
            };
            while bits != 0 {
                let index = base + bits.trailing_zeros() as usize;
                if index >= len {
                    break;
                }
                if !(lo <= index && index <= hi) {
                    // A new row: one division, then none for the rest of the row.
                    let y = index / w;
                    (lo, hi) = (y * w, y * w + w - 1);
                    ty = self.tile_row(y as u32);
                }
                // index − lo < w ≤ 65535.
                let tx = self.tile_col((index - lo) as u32);
                if cols_ty != ty {
                    (cols_ty, cols) = (ty, 0);
                }
                mark_once(&mut self.hot, &mut cols, tx, ty);
                // Clear the bits of the cells up to the tile's last in this row (≥ index).
                let n = lo + self.tile_x_hi(tx) as usize - base + 1;
                if n >= 32 {
                    break;
                }
                bits &= u32::MAX << n;
            }
        }
        self.mark_row = (lo, hi, ty);
        self.marked_cols = (cols_ty, cols);
    }

    /// The estimate part of [`Gibbs::note_changed`]: with [`Estimator::Average`]'s
    /// `reset_on_change`, restarts cell `index`'s estimate at `now`'s probability if the change
    /// is notable ([`crate::map::mapper::notable`]).
    ///
    /// [`Estimator::Average`]: crate::config::Estimator::Average
    #[inline]
    pub fn note_estimate(&mut self, index: usize, before: LogOdds, now: LogOdds) {
        if self.config.estimator.resets() && crate::map::mapper::notable(before, now) {
            let c = self.restart_at(now);
            if let Some(e) = self.buf.counts.as_mut().get_mut(index) {
                *e = c;
            }
        }
    }

    /// The estimate a restart at `now` sets, through the memo `restart`.
    #[inline]
    fn restart_at(&mut self, now: LogOdds) -> N {
        let slot = usize::from(now.0 as u16) % RESTARTS;
        match self.restart.get_mut(slot) {
            Some(&mut (v, c)) if v == now => c,
            entry => {
                let c = N::from_probability_q16(estimate::probability_q16(now));
                if let Some(e) = entry {
                    *e = (now, c);
                }
                c
            }
        }
    }

    /// [`Gibbs::note_estimate`] for the cells `32·word + b` of each bit `b` set in `bits`, all
    /// changed from `before` to `now` by the same scan.
    pub fn note_estimate_word(
        &mut self,
        word: usize,
        mut bits: u32,
        before: LogOdds,
        now: LogOdds,
    ) {
        if !(self.config.estimator.resets() && crate::map::mapper::notable(before, now)) {
            return;
        }
        let c = self.restart_at(now);
        let Some(base) = word.checked_mul(32) else {
            return;
        };
        let counts = self.buf.counts.as_mut();
        while bits != 0 {
            let i = base.saturating_add(bits.trailing_zeros() as usize);
            bits &= bits - 1;
            if let Some(e) = counts.get_mut(i) {
                *e = c;
            }
        }
    }

    /// Whether changed cells mark their tiles: for change-driven visits, and because marks also
    /// restart the tile's age, which lengthening estimates read.
    #[inline]
    fn marks_tiles(&self) -> bool {
        self.config.hot_share > 0 || self.config.estimator.lengthens()
    }

    /// The last column of tile column `tx` (the last tile column also takes the margin).
    #[inline]
    fn tile_x_hi(&self, tx: u32) -> u32 {
        let w = u32::from(self.geometry.width());
        if tx + 1 >= self.tiles_x {
            w.saturating_sub(1)
        } else {
            (self.cx0 as u32)
                .saturating_add((tx + 1) << self.config.tile_shift)
                .saturating_sub(1)
                .min(w.saturating_sub(1))
        }
    }

    /// Marks the tile of cell `index` and returns the indices of the first and last cells of the
    /// tile's part of that cell's row (the first and last tile columns also take the margins
    /// outside the sampled area), and whether `index` lies in the grid.
    fn mark_tile_of(&mut self, index: usize) -> (usize, usize, bool) {
        if index >= self.geometry.len() {
            return (index, index, false);
        }
        let (tx, ty, (x, y)) = self.tile_of(index);
        self.hot.mark(tx, ty);
        let (w, s) = (
            u32::from(self.geometry.width()),
            u32::from(self.config.tile_shift),
        );
        let x_lo = if tx == 0 {
            0
        } else {
            (self.cx0 as u32).saturating_add(tx << s)
        };
        let x_hi = self.tile_x_hi(tx);
        debug_assert!(
            x_lo <= x && x <= x_hi,
            "cell {index}: {x} not in {x_lo}..={x_hi}"
        );
        // In the grid: y·w + x_hi < len.
        let row = (y * w) as usize;
        (row + x_lo as usize, row + x_hi as usize, true)
    }

    /// The sampler tile `(tx, ty)` that cell `index` belongs to (cells in the margin outside the
    /// sampled area go to the nearest tile), and the cell `(x, y)`: one hardware division
    /// (widths are at least 1).
    #[inline]
    fn tile_of(&self, index: usize) -> (u32, u32, (u32, u32)) {
        let w = u32::from(self.geometry.width());
        let i = index as u32;
        let y = i / w.max(1);
        let x = i - y * w;
        (self.tile_col(x), self.tile_row(y), (x, y))
    }

    /// The tile column of grid column `x` (columns in the margin go to the nearest tile).
    #[inline(always)]
    fn tile_col(&self, x: u32) -> u32 {
        (x.saturating_sub(self.cx0 as u32) >> self.config.tile_shift).min(self.tiles_x - 1)
    }

    /// The tile row of grid row `y` (rows in the margin go to the nearest tile).
    #[inline(always)]
    fn tile_row(&self, y: u32) -> u32 {
        (y.saturating_sub(self.cy0 as u32) >> self.config.tile_shift).min(self.tiles_y - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{
        block_words, estimate, BorderPrior, Buffers, Gibbs, LocalRay, SamplerConfig,
    };
    use super::Count;
    use crate::config::noise::free_evidence_q8;
    use crate::config::{DataTerm, Estimator};
    use crate::sampler::forward_model::ForwardModel;
    use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
    use crate::types::fixed::LogOdds;
    use crate::types::geometry::GridGeometry;
    use proptest::prelude::*;

    type Sampler = Gibbs<BorderPrior, Vec<u32>, Vec<u8>, Vec<LocalRay>, Vec<u32>, u8>;
    type Store = RayStore<Vec<StoredScan>, Vec<StoredRay>>;

    fn sampler(g: GridGeometry, tile_shift: u8) -> (Sampler, Store, Vec<LogOdds>) {
        let cfg = SamplerConfig {
            tile_shift,
            hot_share: 192,
            data: DataTerm::Evidence,
            evidence_gain_q8: 512,
            evidence_free_q8: free_evidence_q8(3.0),
            ..SamplerConfig::default()
        };
        let buf = Buffers {
            sample: vec![0; g.len().div_ceil(32)],
            counts: vec![0; g.len()],
            local: vec![LocalRay::default(); 1],
            blocks: vec![0; block_words(1, cfg.block_grid)],
        };
        let mut s = Gibbs::new(g, BorderPrior::default(), ForwardModel::pcsm(), cfg, buf).unwrap();
        let mut st = RayStore::new(
            g,
            1000,
            0,
            vec![StoredScan::default(); 1],
            vec![StoredRay::default(); 1],
        )
        .unwrap();
        let map: Vec<LogOdds> = (0..g.len())
            .map(|i| LogOdds((i % 7) as i16 * 300 - 900))
            .collect();
        s.reset(&map, &mut st).unwrap();
        (s, st, map)
    }

    proptest! {
        /// Seeding and restarting a word of cells equals doing it cell by cell.
        #[test]
        fn word_seeding_matches_cells(words in proptest::collection::vec(
                (0usize..60, any::<u32>(), -3000i16..3000, any::<bool>()), 1..8)) {
            let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
            let (mut by_word, _, _) = sampler(g, 4);
            let (mut by_cell, _, _) = sampler(g, 4);
            // Restarts need an estimator that resets.
            for s in [&mut by_word, &mut by_cell] {
                s.config.estimator = Estimator::Average {
                    shift: 3,
                    max_shift: 3,
                    reset_on_change: true,
                    rao_blackwell: false,
                };
            }
            for &(word, bits, now, occupied) in &words {
                by_word.seed_word(word, bits, occupied);
                by_word.note_estimate_word(word, bits, LogOdds(0), LogOdds(now));
                for i in (0..32).filter(|b| bits & (1 << b) != 0).map(|b| 32 * word + b) {
                    if i < g.len() {
                        by_cell.seed(i, occupied);
                        by_cell.note_estimate(i, LogOdds(0), LogOdds(now));
                    }
                }
            }
            prop_assert_eq!(by_word.buf.sample.as_slice(), by_cell.buf.sample.as_slice());
            prop_assert_eq!(by_word.buf.counts.as_slice(), by_cell.buf.counts.as_slice());
        }

        /// The estimate-restart memo gives the probability lookup's estimate, whatever the
        /// order of the values (repeats, collisions in a slot, negative values).
        #[test]
        fn restart_memo_matches_lookup(values in proptest::collection::vec(
                prop_oneof![-300i16..300, any::<i16>()], 1..200)) {
            let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
            let (mut s, _, _) = sampler(g, 3);
            for v in values.iter().chain(values.iter().rev()) {
                let want = u8::from_probability_q16(estimate::probability_q16(LogOdds(*v)));
                prop_assert_eq!(s.restart_at(LogOdds(*v)), want, "{}", v);
            }
        }

        /// A mark word's tiles are exactly those its cells would mark one by one, also after
        /// visits took or aged marks in between (rounds of words, then sampler steps).
        #[test]
        fn marked_words_mark_the_tiles_of_their_cells(
                w in prop_oneof![12u16..80, (1u16..4).prop_map(|k| 32 * k)], h in 12u16..40,
                tile_shift in 2u8..7,
                rounds in proptest::collection::vec(
                    proptest::collection::vec((0usize..120, proptest::collection::vec(any::<u32>(), 1..4)), 1..6), 1..4)) {
            let g = GridGeometry::new(w, h, 50, 0, 0).unwrap();
            let (mut by_word, mut st_w, map) = sampler(g, tile_shift);
            let (mut by_cell, mut st_c, _) = sampler(g, tile_shift);
            let row_words = usize::from(w) / 32;
            for words in &rounds {
                for (word, bits) in words {
                    // As the mapper passes them: the words of one row (rows that start on a word
                    // boundary), or any run of words.
                    let mut word = *word;
                    let mut bits = bits.as_slice();
                    if w % 32 == 0 {
                        word %= row_words * usize::from(h);
                        bits = &bits[..bits.len().min(row_words - word % row_words)];
                    }
                    by_word.note_marked_words(word, bits);
                    for (k, &bits) in bits.iter().enumerate() {
                        for i in (0..32).filter(|b| bits & (1 << b) != 0).map(|b| 32 * (word + k) + b) {
                            if i < g.len() {
                                by_cell.note_changed(i, LogOdds(5), LogOdds(3));
                            }
                        }
                    }
                }
                for ty in 0..by_cell.tiles_y {
                    for tx in 0..by_cell.tiles_x {
                        prop_assert_eq!(by_word.hot.is_marked(tx, ty), by_cell.hot.is_marked(tx, ty),
                            "tile ({}, {})", tx, ty);
                    }
                }
                by_word.step(&mut st_w, &map, 300);
                by_cell.step(&mut st_c, &map, 300);
                prop_assert_eq!(by_word.stats(), by_cell.stats());
                prop_assert_eq!(
                    (by_word.rays_examined(), by_word.rays_gathered()),
                    (by_cell.rays_examined(), by_cell.rays_gathered())
                );
            }
        }
    }
}
