//! Following a rolling window ([`crate::session::Session::apply_shift`]): the sample bits and
//! the estimates move with the map, the change-driven schedule's tiles move with them, and the
//! visit in progress and every cache of the old placement are dropped.

use super::{estimate, sweep, Count, Gibbs, LocalRay, PatchPrior};
use crate::config::Estimator;
use crate::map::shift::{shift_bits, shift_cells};
use crate::types::fixed::LogOdds;

impl<P, B, C, L, K, N> Gibbs<P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    /// Moves the sampler with its map by `(dx, dy)` whole cells: cell `(x, y)` takes the sample
    /// bit and estimate of cell `(x + dx, y + dy)`; entering cells start as [`Gibbs::reset`]
    /// starts an unknown cell (the sample from log-odds 0, the estimate at p = ½ or no count).
    /// The tiles of the change-driven schedule move by whole tiles when the shift is a multiple
    /// of the tile (and of the schedule's tile groups), else the schedule starts afresh. The
    /// visit in progress ends. Returns `false`, changing nothing, if the new origin leaves the
    /// `i32` mm range. The caller moves the ray store (its rays are of the old placement).
    pub fn shift(&mut self, dx: i32, dy: i32) -> bool {
        let Some(g) = self.geometry.shifted(dx, dy) else {
            return false;
        };
        let (w, h) = (usize::from(g.width()), usize::from(g.height()));
        let unknown_occupied = LogOdds::ZERO > self.config.init_threshold;
        shift_bits(self.buf.sample.as_mut(), w, h, dx, dy, unknown_occupied);
        let fill = match self.config.estimator {
            Estimator::Counts => N::default(),
            Estimator::Average { .. } => {
                N::default().ema(estimate::probability_q16(LogOdds::ZERO), 0)
            }
        };
        shift_cells(self.buf.counts.as_mut(), w, h, dx, dy, fill);
        let t = 1i32 << self.config.tile_shift;
        if dx % t == 0 && dy % t == 0 {
            self.hot.shift(dx / t, dy / t);
        } else {
            self.hot.clear();
        }
        self.visit_left = 0;
        self.n_local = 0;
        self.raster = sweep::Raster::default();
        self.hot_span = (1, 0);
        self.mark_row = (1, 0, 0);
        self.marked_cols = (u32::MAX, 0);
        self.geometry = g;
        true
    }

    /// Cell `index` restored from a stored tile as the window moved back over it
    /// ([`crate::session::Session::restore_tile`]): its log-odds are `l` again (seeded like a
    /// first observation, its tile marked for a visit) and its estimate is `estimate`, a byte
    /// in 1/255 as the wire's `Counts` layer carries it, or (`None`) `l`'s probability.
    pub fn restore_cell(&mut self, index: usize, l: LogOdds, estimate: Option<u8>) {
        if index >= self.geometry.len() {
            return;
        }
        self.seed(index, l > self.config.init_threshold);
        self.note_changed(index, LogOdds::ZERO, l);
        let value = match estimate {
            // The byte is p in 1/255, scaled to the counter's range.
            Some(b) => {
                N::set(u32::try_from(u64::from(b) * u64::from(N::MAX) / 255).unwrap_or(N::MAX))
            }
            None => N::default().ema(estimate::probability_q16(l), 0),
        };
        if let Some(c) = self.buf.counts.as_mut().get_mut(index) {
            *c = value;
        }
    }
}
