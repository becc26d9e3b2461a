//! Change-driven tile scheduling: tiles whose evidence changed are visited first.
//!
//! A scan changes the log-odds of a few thousand cells, all near the robot; a uniform choice of
//! tiles spends most visits where nothing changed. [`HotTiles`] is a bitset of tiles (or, on
//! maps with more than [`MAX_GROUPS`] tiles, of square groups of tiles) marked when a cell in
//! them changes and cleared when a visit picks them; a share of the visits
//! ([`super::SamplerConfig::hot_share`]) goes round-robin over the marked ones, the rest stay
//! uniform so the chain keeps visiting every tile (ergodicity is unaffected: every update is
//! still an exact Gibbs step, only the order differs). Fixed memory: 128 bytes.

use rand_core::Rng;

use super::local::BlockGrid;
use super::update::below;
use super::{AverageShift, Count, Gibbs, LocalRay, PatchPrior};
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};

/// Most tile groups tracked.
pub(crate) const MAX_GROUPS: usize = 1024;

/// The marked tile groups.
#[derive(Clone, Debug)]
pub(crate) struct HotTiles {
    bits: [u32; MAX_GROUPS / 32],
    /// Visits since the group was last marked, saturating.
    ages: [u8; MAX_GROUPS],
    /// Tiles per group side, log2.
    group_shift: u32,
    groups_x: u32,
    groups: u32,
    cursor: u32,
    marked: u32,
}

impl HotTiles {
    /// For a `tiles_x × tiles_y` tiling.
    pub(crate) fn new(tiles_x: u32, tiles_y: u32) -> HotTiles {
        let mut group_shift = 0;
        while (tiles_x.div_ceil(1 << group_shift) * tiles_y.div_ceil(1 << group_shift)) as usize
            > MAX_GROUPS
        {
            group_shift += 1;
        }
        let groups_x = tiles_x.div_ceil(1 << group_shift);
        HotTiles {
            bits: [0; MAX_GROUPS / 32],
            ages: [0; MAX_GROUPS],
            group_shift,
            groups_x,
            groups: groups_x * tiles_y.div_ceil(1 << group_shift),
            cursor: 0,
            marked: 0,
        }
    }

    /// Marks tile `(tx, ty)` and restarts its group's age.
    #[inline]
    pub(crate) fn mark(&mut self, tx: u32, ty: u32) {
        let g = self.group(tx, ty);
        if g < self.groups {
            if let Some(a) = self.ages.get_mut(g as usize) {
                *a = 0;
            }
            if let Some(w) = self.bits.get_mut((g / 32) as usize) {
                let bit = 1 << (g % 32);
                if *w & bit == 0 {
                    *w |= bit;
                    self.marked += 1;
                }
            }
        }
    }

    /// Tile `(tx, ty)`'s group index (`≥ groups` when out of range).
    #[inline]
    fn group(&self, tx: u32, ty: u32) -> u32 {
        (ty >> self.group_shift) * self.groups_x + (tx >> self.group_shift)
    }

    /// Tile `(tx, ty)`'s group age — visits since it was last marked — before this visit,
    /// which it counts (0 out of range).
    #[inline]
    pub(crate) fn visit_age(&mut self, tx: u32, ty: u32) -> u8 {
        let g = self.group(tx, ty);
        match self.ages.get_mut(g as usize) {
            Some(a) if g < self.groups => {
                let age = *a;
                *a = age.saturating_add(1);
                age
            }
            _ => 0,
        }
    }

    /// Whether tile `(tx, ty)`'s group is marked.
    #[cfg(any(test, debug_assertions))]
    pub(crate) fn is_marked(&self, tx: u32, ty: u32) -> bool {
        let g = self.group(tx, ty);
        g < self.groups
            && self
                .bits
                .get((g / 32) as usize)
                .is_some_and(|w| w >> (g % 32) & 1 != 0)
    }

    /// Clears every mark and age.
    pub(crate) fn clear(&mut self) {
        self.bits = [0; MAX_GROUPS / 32];
        self.ages = [0; MAX_GROUPS];
        self.marked = 0;
    }

    /// Moves the marks and ages with a map shifted by `(dtx, dty)` whole tiles: group `g` takes
    /// what group `g + d` had; groups entering are unmarked and new (age 0). A shift that is
    /// not a whole number of groups clears everything.
    pub(crate) fn shift(&mut self, dtx: i32, dty: i32) {
        let gs = 1i32 << self.group_shift;
        if dtx % gs != 0 || dty % gs != 0 {
            self.clear();
            return;
        }
        let (dgx, dgy) = (i64::from(dtx / gs), i64::from(dty / gs));
        let gx_n = i64::from(self.groups_x.max(1));
        let gy_n = i64::from(self.groups.div_ceil(self.groups_x.max(1)));
        let (bits, ages) = (self.bits, self.ages);
        self.clear();
        let mut marked = 0;
        for gy in 0..gy_n {
            for gx in 0..gx_n {
                let (sx, sy) = (gx + dgx, gy + dgy);
                if !(0..gx_n).contains(&sx) || !(0..gy_n).contains(&sy) {
                    continue;
                }
                let (src, dst) = ((sy * gx_n + sx) as usize, (gy * gx_n + gx) as usize);
                if let (Some(&a), Some(d)) = (ages.get(src), self.ages.get_mut(dst)) {
                    *d = a;
                }
                let set = bits.get(src / 32).is_some_and(|w| w >> (src % 32) & 1 != 0);
                if set {
                    if let Some(w) = self.bits.get_mut(dst / 32) {
                        *w |= 1 << (dst % 32);
                        marked += 1;
                    }
                }
            }
        }
        self.marked = marked;
    }

    /// Marked groups.
    #[cfg(test)]
    pub(crate) fn marked(&self) -> u32 {
        self.marked
    }

    /// Takes the next marked group after the cursor (round robin) and returns the first tile of
    /// it and the group's edge in tiles.
    pub(crate) fn take(&mut self) -> Option<(u32, u32, u32)> {
        if self.marked == 0 {
            return None;
        }
        let words = self.groups.div_ceil(32);
        for k in 0..=words {
            let w = (self.cursor / 32 + k) % words.max(1);
            let Some(word) = self.bits.get_mut(w as usize) else {
                continue;
            };
            // On the cursor's own word (first pass), only bits at or after it.
            let mask = if k == 0 {
                !0u32 << (self.cursor % 32)
            } else {
                !0
            };
            let cand = *word & mask;
            if cand != 0 {
                let b = cand.trailing_zeros();
                *word &= !(1 << b);
                self.marked = self.marked.saturating_sub(1);
                let g = w * 32 + b;
                self.cursor = (g + 1) % self.groups.max(1);
                // A set bit means groups_x ≥ 1 (`mark` sets none otherwise); `max` keeps the
                // division free of a panic path.
                let gx_n = self.groups_x.max(1);
                let (gx, gy) = (g % gx_n, g / gx_n);
                return Some((
                    gx << self.group_shift,
                    gy << self.group_shift,
                    1 << self.group_shift,
                ));
            }
        }
        None
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
    /// Picks a tile — a changed one for [`SamplerConfig::hot_share`] of the visits, else a
    /// uniformly random one — and gathers the rays its patches can meet.
    ///
    /// [`SamplerConfig::hot_share`]: super::SamplerConfig::hot_share
    pub(super) fn start_visit<S, R>(&mut self, store: &mut RayStore<S, R>)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let t = 1i32 << self.config.tile_shift;
        let r = self.rng.next_u32();
        // A visit takes a mark or ages a tile: either way the span's promise ends.
        self.hot_span = (1, 0);
        self.marked_cols = (u32::MAX, 0);
        let hot = if (r & 0xff) < u32::from(self.config.hot_share) {
            self.hot.take()
        } else {
            None
        };
        let (tx, ty) = match hot {
            Some((gx, gy, edge)) => {
                // A group of tiles on large maps: one of its tiles at random.
                let (dx, dy) = if edge > 1 {
                    (below(r >> 8 & 0xfff, edge), below(r >> 20, edge))
                } else {
                    (0, 0)
                };
                (
                    ((gx + dx).min(self.tiles_x - 1)) as i32,
                    ((gy + dy).min(self.tiles_y - 1)) as i32,
                )
            }
            None => (
                below(self.rng.next_u32(), self.tiles_x) as i32,
                below(self.rng.next_u32(), self.tiles_y) as i32,
            ),
        };
        self.visit_shift = AverageShift::new(
            self.config
                .estimator
                .shift_at(self.hot.visit_age(tx as u32, ty as u32)),
        );
        let x0 = self.cx0 + tx * t;
        let y0 = self.cy0 + ty * t;
        let (x1, y1) = ((x0 + t - 1).min(self.cx1), (y0 + t - 1).min(self.cy1));
        self.tile = (x0, y0, x1, y1);
        let size = i32::from(self.prior.size());
        let cells = ((x1 - x0 + 1) * (y1 - y0 + 1)) as u32;
        self.visit_left =
            (cells / (size * size) as u32).max(1) * u32::from(self.config.visit_sweeps.max(1));
        self.stats.tile_visits += 1;
        if self.config.data.uses_rays() {
            let h = size / 2;
            self.gather(
                store,
                BlockGrid::new(x0 - h, y0 - h, x1 + h, y1 + h, self.config.block_grid),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_are_taken_round_robin_once_each() {
        let mut h = HotTiles::new(16, 16);
        for (x, y) in [(3, 0), (15, 15), (0, 1), (3, 0)] {
            h.mark(x, y);
        }
        assert_eq!(h.marked(), 3);
        let got: Vec<_> = std::iter::from_fn(|| h.take()).collect();
        assert_eq!(got, vec![(3, 0, 1), (0, 1, 1), (15, 15, 1)]);
        assert_eq!(h.marked(), 0);
        // The cursor continues after the last group taken.
        h.mark(0, 0);
        h.mark(15, 15);
        assert_eq!(h.take(), Some((0, 0, 1)));
    }

    #[test]
    fn ages_count_visits_since_the_last_mark() {
        let mut h = HotTiles::new(16, 16);
        assert_eq!((h.visit_age(2, 3), h.visit_age(2, 3)), (0, 1));
        assert_eq!(h.visit_age(4, 3), 0, "ages are per tile");
        h.mark(2, 3);
        assert_eq!(h.visit_age(2, 3), 0, "a mark restarts the age");
        for _ in 0..300 {
            h.visit_age(5, 5);
        }
        assert_eq!(h.visit_age(5, 5), 255, "saturates");
        assert_eq!(h.visit_age(99, 99), 0, "out of range");
        h.clear();
        assert_eq!(h.visit_age(5, 5), 0);
    }

    #[test]
    fn marks_and_ages_move_with_a_shift() {
        let mut h = HotTiles::new(8, 8);
        h.mark(3, 4);
        h.mark(0, 0);
        for _ in 0..5 {
            h.visit_age(5, 5);
        }
        h.shift(2, -1);
        // Group (3, 4) is now (1, 5); (0, 0) left; (5, 5)'s age is at (3, 6).
        assert_eq!(h.marked(), 1);
        assert!(h.is_marked(1, 5));
        assert_eq!(h.visit_age(3, 6), 5);
        assert_eq!(h.visit_age(7, 0), 0, "entering groups are new");
        h.shift(100, 0);
        assert_eq!(h.marked(), 0);
        let mut g = HotTiles::new(100, 70);
        g.mark(8, 8);
        g.shift(1, 0);
        assert_eq!(g.marked(), 0, "not a whole group: cleared");
    }

    #[test]
    fn large_tilings_group_tiles() {
        let mut h = HotTiles::new(100, 70);
        assert!(h.groups as usize <= MAX_GROUPS);
        assert_eq!(h.group_shift, 2);
        h.mark(99, 69);
        assert_eq!(h.take(), Some((96, 68, 4)));
        // Out-of-range marks are ignored.
        h.mark(1000, 1000);
        assert_eq!(h.marked(), 0);
    }
}
