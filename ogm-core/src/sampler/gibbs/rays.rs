//! The sampler's ray term ([`DataTerm::Rays`], [`DataTerm::Hybrid`]): the stored rays'
//! first-occupied caches, the gather of a tile visit's rays into the local list, and how a ray
//! crosses a patch (the likelihood factors of Eq. 1). The likelihood and the gather run only
//! when the data term uses rays ([`DataTerm::uses_rays`], never without the `rays` feature).
//!
//! [`DataTerm::Rays`]: crate::config::DataTerm::Rays
//! [`DataTerm::Hybrid`]: crate::config::DataTerm::Hybrid
//! [`DataTerm::uses_rays`]: crate::config::DataTerm::uses_rays

use super::local::{for_each_ray, set_bit, BlockGrid};
use super::{Count, Gibbs, LocalRay, PatchCandidate, PatchPrior, Segment};
use crate::sampler::forward_model::LogLik;
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan, NONE, STALE};
use crate::types::geometry::CellCoord;
use crate::Angle;

impl<P, B, C, L, K, N> Gibbs<P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    /// Recomputes the first-occupied cache of the rays in `range` (e.g. the rays a new scan just
    /// added) and ends the current tile visit so the next one sees them.
    pub fn refresh_rays<S, R>(&mut self, store: &mut RayStore<S, R>, range: core::ops::Range<usize>)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.visit_left = 0;
        for s in 0..store.scans().len() {
            let Some(scan) = store.scans().get(s).copied() else {
                break;
            };
            let start = store.start_cell(&scan.pose);
            for k in 0..scan.len as usize {
                let idx = scan.first as usize + k;
                if !range.contains(&idx) {
                    continue;
                }
                let Some(stored) = store.rays().get(idx).copied() else {
                    continue;
                };
                let seg = Segment::new(start, store.far_end(&scan.pose, stored.angle));
                let f = self.first_occupied_from(&seg, 0);
                if let Some(r) = store.rays_mut().get_mut(idx) {
                    r.first_occupied = f;
                }
            }
        }
    }

    /// Marks the first-occupied caches of the rays in `range` stale, to be recomputed from the
    /// current sample when a tile visit next gathers them, and ends the current visit. O(rays)
    /// writes and no ray walks: what [`crate::session::Session::insert`] does after seeding, so
    /// a scan's ingest stays cheap and the walks happen inside the sampler's bounded steps.
    pub fn invalidate_rays<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        range: core::ops::Range<usize>,
    ) where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.visit_left = 0;
        let rays = store.rays_mut();
        let (a, b) = (range.start.min(rays.len()), range.end.min(rays.len()));
        if let Some(rs) = rays.get_mut(a..b) {
            for r in rs {
                r.first_occupied = STALE;
            }
        }
    }

    /// First occupied in-grid step of `seg` at or after step `from`, or [`NONE`].
    fn first_occupied_from(&self, seg: &Segment, from: u32) -> u16 {
        let (w, h) = (
            i32::from(self.geometry.width()),
            i32::from(self.geometry.height()),
        );
        let Some((first, _)) = seg.clip(0, 0, w - 1, h - 1) else {
            return NONE;
        };
        self.first_occupied_in_map(seg, first.max(from))
    }

    /// First occupied step of `seg` from step `from` (which must be in the map, or past its
    /// last in-map step) until the ray leaves the map — a ray meets a rectangle once.
    fn first_occupied_in_map(&self, seg: &Segment, from: u32) -> u16 {
        let (w, h) = (
            i32::from(self.geometry.width()),
            i32::from(self.geometry.height()),
        );
        let mut found = NONE;
        seg.walk(from, seg.n(), |i, c| {
            if c.x < 0 || c.y < 0 || c.x >= w || c.y >= h {
                return false;
            }
            if self.occupied(c.y as usize * w as usize + c.x as usize) {
                found = i.min(u32::from(NONE - 1)) as u16;
                return false;
            }
            true
        });
        found
    }

    /// Collects the rays visiting the box of `grid` into the local list and block bitsets.
    pub(super) fn gather<S, R>(&mut self, store: &mut RayStore<S, R>, grid: BlockGrid)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let (bx0, by0, bx1, by1) = (grid.x0, grid.y0, grid.x1, grid.y1);
        self.grid = grid;
        let words = self.block_row_words;
        let used = self.n_local.div_ceil(32);
        for row in self.buf.blocks.as_mut().chunks_mut(words.max(1)) {
            if let Some(w) = row.get_mut(..used.min(words)) {
                w.fill(0);
            }
        }
        self.n_local = 0;
        let reach = i64::from(store.max_range_mm().div_ceil(store.geometry().cell_mm())) + 2;
        let cap = self.buf.local.as_ref().len();
        for scan in store.scans() {
            let start = store.start_cell(&scan.pose);
            // Quick reject: the box is beyond the sensor's reach from this pose.
            let (ddx, ddy) = (
                dist_to_interval(start.x, bx0, bx1),
                dist_to_interval(start.y, by0, by1),
            );
            if ddx * ddx + ddy * ddy > reach * reach {
                continue;
            }
            let rays = store
                .rays()
                .get(scan.first as usize..(scan.first + scan.len) as usize)
                .unwrap_or(&[]);
            // Only beams pointing into the box can cross it; rays are sorted by angle.
            let (lo, hi) = match angular_window(start, (bx0, by0, bx1, by1)) {
                Some((a, b)) => (
                    a.wrapping_sub(scan.pose.heading).0,
                    b.wrapping_sub(scan.pose.heading).0,
                ),
                None => (0, u16::MAX),
            };
            let (first, split) = (
                rays.partition_point(|r| r.angle.0 < lo),
                rays.partition_point(|r| r.angle.0 <= hi),
            );
            let ranges = if lo <= hi {
                [(first, split), (0, 0)]
            } else {
                [(first, rays.len()), (0, split)]
            };
            for (a, b) in ranges {
                for (k, stored) in rays.iter().enumerate().take(b).skip(a) {
                    let end = store.far_end(&scan.pose, stored.angle);
                    let seg = Segment::new(start, end);
                    let Some((s0, s1)) = seg.clip(bx0, by0, bx1, by1) else {
                        continue;
                    };
                    if self.n_local >= cap {
                        self.stats.local_overflow += 1;
                        continue;
                    }
                    let j = self.n_local;
                    let blocks = self.buf.blocks.as_mut();
                    let mut last_block = u32::MAX;
                    seg.walk(s0, s1, |_, c| {
                        let b = grid.block(c);
                        if b != last_block {
                            set_bit(blocks, words, b, j);
                            last_block = b;
                        }
                        true
                    });
                    if let Some(slot) = self.buf.local.as_mut().get_mut(j) {
                        *slot = LocalRay {
                            index: scan.first + k as u32,
                            seg,
                            step_q12: seg.step_q12(),
                            z_q4: stored.z_q4,
                        };
                        self.n_local += 1;
                    }
                }
            }
        }
        self.rays_gathered += self.n_local as u64;
        // Rays added or invalidated since they were last used get their first occupied cell
        // now, from the current sample (see `invalidate_rays`).
        let local = self.buf.local.as_ref();
        for lr in local.iter().take(self.n_local) {
            if store
                .rays()
                .get(lr.index as usize)
                .map(|r| r.first_occupied)
                == Some(STALE)
            {
                let f = self.first_occupied_from(&lr.seg, 0);
                if let Some(r) = store.rays_mut().get_mut(lr.index as usize) {
                    r.first_occupied = f;
                }
            }
        }
    }

    /// Calls `f(local ray, crossing)` for every local ray whose first occupied cell the patch at
    /// `centre` can change.
    fn for_each_crossing<S, R>(
        &self,
        store: &RayStore<S, R>,
        centre: CellCoord,
        mut f: impl FnMut(&LocalRay, &Crossing),
    ) -> u64
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let h = i32::from(self.prior.size()) / 2;
        let mask = self
            .grid
            .blocks_of_box(centre.x - h, centre.y - h, centre.x + h, centre.y + h);
        let local = self.buf.local.as_ref();
        let mut examined = 0;
        for_each_ray(
            self.buf.blocks.as_ref(),
            self.block_row_words,
            self.n_local,
            mask,
            |j| {
                examined += 1;
                if let Some(lr) = local.get(j) {
                    if let Some(cross) = self.crossing(store, lr, centre) {
                        f(lr, &cross);
                    }
                }
            },
        );
        examined
    }

    /// Eq. 1 in the log domain: adds to `w` (the log-priors, plus any evidence term) the Σ over
    /// crossing rays of log p(z | f(config)).
    pub(super) fn log_weights<S, R>(
        &mut self,
        store: &RayStore<S, R>,
        centre: CellCoord,
        cands: &[PatchCandidate],
        w: &mut [i32],
        cache: &mut CrossingCache,
    ) where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let mut evaluated = 0u64;
        cache.valid = true;
        let examined = self.for_each_crossing(store, centre, |lr, cross| {
            evaluated += 1;
            cache.push(lr.index, cross);
            for (wi, c) in w.iter_mut().zip(cands) {
                let f = cross.first_in_patch(c.config).unwrap_or(cross.f_after);
                *wi = wi.saturating_add(self.log_lik(lr, f, cross.n));
            }
        });
        self.stats.rays_evaluated += evaluated;
        self.rays_examined += examined;
    }

    /// How `lr` crosses the patch at `centre`, if the patch can change its first occupied cell.
    pub(super) fn crossing<S, R>(
        &self,
        store: &RayStore<S, R>,
        lr: &LocalRay,
        centre: CellCoord,
    ) -> Option<Crossing>
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let h = i32::from(self.prior.size()) / 2;
        let seg = &lr.seg;
        let (first, last) = seg.major_range(centre, h)?;
        // A ray already blocked before the patch's first possible step cannot see the patch.
        let f = store
            .rays()
            .get(lr.index as usize)
            .map_or(NONE, |r| r.first_occupied);
        if f != NONE && u32::from(f) < first {
            return None;
        }
        let size = 2 * h + 1;
        let mut cells = [(0u16, 0u16); 3];
        let mut n_cells = 0;
        seg.walk(first, last, |i, c| {
            if (c.x - centre.x).abs() <= h && (c.y - centre.y).abs() <= h {
                let bit = ((c.y - centre.y + h) * size + (c.x - centre.x + h)) as u16;
                if let Some(slot) = cells.get_mut(n_cells) {
                    *slot = (i as u16, bit);
                    n_cells += 1;
                }
            }
            true
        });
        let a = cells.first().filter(|_| n_cells > 0)?.0;
        let b = cells.get(n_cells.checked_sub(1)?)?.0;
        if f != NONE && f < a {
            return None; // occupied before the patch: the patch cannot matter
        }
        // Cells after the patch are the same for every candidate; the cache covers the whole ray,
        // so only an occupied cell inside the patch hides what lies behind it.
        let f_after = if f == NONE || f > b {
            f
        } else {
            self.first_occupied_in_map(seg, u32::from(b) + 1)
        };
        Some(Crossing {
            cells,
            n_cells,
            f_after,
            n: seg.n().min(u32::from(NONE - 1)) as u16,
        })
    }

    /// log p(z | f) for a local ray; `n` is the far end's step (max range).
    #[inline]
    fn log_lik(&self, lr: &LocalRay, f: u16, n: u16) -> LogLik {
        self.forward.ray(lr.z_q4, lr.step_q12, n, f)
    }
}

/// Crossings the likelihood computed for one patch, reused by the cache update.
pub(super) struct CrossingCache {
    items: [(u32, Crossing); CrossingCache::CAP],
    n: usize,
    /// Every crossing of the patch is in `items`.
    valid: bool,
}

impl CrossingCache {
    /// Enough for a well-observed patch; more crossings fall back to recomputation.
    const CAP: usize = 48;

    pub(super) fn new() -> Self {
        let none = Crossing {
            cells: [(0, 0); 3],
            n_cells: 0,
            f_after: NONE,
            n: 0,
        };
        CrossingCache {
            items: [(0, none); Self::CAP],
            n: 0,
            valid: false,
        }
    }

    fn push(&mut self, index: u32, cross: &Crossing) {
        match self.items.get_mut(self.n) {
            Some(slot) => {
                *slot = (index, *cross);
                self.n += 1;
            }
            None => self.valid = false,
        }
    }

    pub(super) fn get(&self) -> Option<&[(u32, Crossing)]> {
        if self.valid {
            self.items.get(..self.n)
        } else {
            None
        }
    }
}

/// How a ray crosses a patch.
#[derive(Clone, Copy, Debug)]
pub(super) struct Crossing {
    /// (step, patch bit) of the patch cells on the ray, in ray order (a Bresenham ray visits at
    /// most 3 cells of a 3×3 box: one per major coordinate).
    cells: [(u16, u16); 3],
    n_cells: usize,
    /// First occupied step after the patch (or the cached one if it lies after), or NONE.
    pub(super) f_after: u16,
    /// The ray's last step (max range).
    n: u16,
}

impl Crossing {
    /// First step inside the patch occupied under `config`.
    #[inline]
    pub(super) fn first_in_patch(&self, config: u16) -> Option<u16> {
        self.cells
            .iter()
            .take(self.n_cells)
            .find(|(_, bit)| config & (1 << bit) != 0)
            .map(|(s, _)| *s)
    }
}

/// The world directions (from the centre of cell `from`) spanned by the box of cells
/// `(x0, y0, x1, y1)` grown by two cells, as a counter-clockwise interval `(lo, hi)`; `None` if
/// `from` lies inside the grown box (every direction). The two-cell margin covers Bresenham's
/// ½-cell deviation from the ideal line and the rounding of the far end.
fn angular_window(
    from: CellCoord,
    (x0, y0, x1, y1): (i32, i32, i32, i32),
) -> Option<(Angle, Angle)> {
    // Box edges relative to the centre of `from`, in half cells.
    let (ex0, ey0) = (
        2 * i64::from(x0 - 2 - from.x) - 1,
        2 * i64::from(y0 - 2 - from.y) - 1,
    );
    let (ex1, ey1) = (
        2 * i64::from(x1 + 2 - from.x) + 1,
        2 * i64::from(y1 + 2 - from.y) + 1,
    );
    if ex0 <= 0 && 0 <= ex1 && ey0 <= 0 && 0 <= ey1 {
        return None;
    }
    let centre = Angle::atan2(ey0 + ey1, ex0 + ex1);
    let (mut lo, mut hi) = (0i32, 0i32);
    for (x, y) in [(ex0, ey0), (ex1, ey0), (ex0, ey1), (ex1, ey1)] {
        let d = i32::from(Angle::atan2(y, x).signed_diff(centre));
        lo = lo.min(d);
        hi = hi.max(d);
    }
    // Seen from outside a convex box the corners span less than a half turn; pad for atan2.
    let lo = centre.wrapping_add(Angle((lo - 8) as i16 as u16));
    let hi = centre.wrapping_add(Angle((hi + 8) as i16 as u16));
    Some((lo, hi))
}

fn dist_to_interval(v: i32, lo: i32, hi: i32) -> i64 {
    if v < lo {
        i64::from(lo) - i64::from(v)
    } else if v > hi {
        i64::from(v) - i64::from(hi)
    } else {
        0
    }
}
