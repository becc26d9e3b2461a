//! One patch update, Eq. 1 over the candidates: their weights, the draw, the random patch
//! (`p_randPatch`) and writing the new configuration (with the caches of the rays that cross
//! it). The general path, for every data term; [`super::sweep`] is the evidence term's fast
//! path through the same steps.

use rand_core::Rng;
use rand_xoshiro::Xoshiro128PlusPlus;

use super::evidence::{self, patch_evidence};
use super::local::{for_each_ray, BlockGrid};
use super::rays::CrossingCache;
use super::{Count, Gibbs, LocalRay, PatchCandidate, PatchPrior, MAX_CANDIDATES};
use crate::config::DataTerm;
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use crate::types::fixed::LogOdds;
use crate::types::geometry::CellCoord;
use crate::wire::StoreReport;

/// 2^(−i/512) in Q16 for i in 0..512: the weight of a log-odds difference of i LSB (one LSB is
/// ln 2 / 512, so `exp(−d·LSB) = 2^(−d/512)` exactly). A `static`, like every lookup table in
/// this crate: a `const` array is copied into each codegen unit that indexes it (this one was in
/// the firmware twice, 2 KiB of flash).
static EXP2_TABLE: [u32; 512] = build_exp2_table();

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_exp2_table() -> [u32; 512] {
    let mut t = [0u32; 512];
    let mut i = 0;
    while i < 512 {
        // 2^(-i/512) = exp(-i·ln2/512) by its Taylor series (|x| ≤ ln 2: 25 terms are plenty).
        let x = -(i as f64) * core::f64::consts::LN_2 / 512.0;
        let mut term = 1.0;
        let mut sum = 1.0;
        let mut k = 1;
        while k < 25 {
            term = term * x / (k as f64);
            sum += term;
            k += 1;
        }
        t[i] = (sum * 65536.0 + 0.5) as u32;
        i += 1;
    }
    t
}

/// Weight (Q16) of a candidate `d` LSB below the best one.
#[inline]
pub(super) fn weight_q16(d: u32) -> u32 {
    let (q, r) = (d / 512, (d % 512) as usize);
    if q >= 17 {
        return 0;
    }
    EXP2_TABLE.get(r).copied().unwrap_or(0) >> q
}

/// One update's step of the random-patch countdown (`p_randPatch`): random patches come every
/// `1 + below(period)` updates (`period` 0: never). Whether this update is one; then the next
/// `gap` is drawn from `rng` ([`next_gap`]; the raster run counts down in centres instead).
#[inline]
fn random_patch_step(period: u32, gap: &mut u32, rng: &mut Xoshiro128PlusPlus) -> bool {
    if period == 0 {
        return false;
    }
    // Invariant: the gap is ≥ 1 while random patches are on.
    *gap = gap.saturating_sub(1);
    if *gap > 0 {
        return false;
    }
    *gap = next_gap(period, rng);
    true
}

/// The gap to the next random patch, drawn at a random patch (`period` > 0).
#[inline]
pub(super) fn next_gap(period: u32, rng: &mut Xoshiro128PlusPlus) -> u32 {
    1 + below(rng.next_u32(), period)
}

/// Uniform integer in `0..n` from a 32-bit random number (Lemire's multiply-shift).
#[inline]
pub(super) fn below(r: u32, n: u32) -> u32 {
    ((u64::from(r) * u64::from(n)) >> 32) as u32
}

/// The unnormalised weights (Q16, the best candidate 2^16) of log-weights `w` into `q`; returns
/// their sum (at most 17 × 2^16: no overflow). The evidence update (the robot's hot path) has
/// the same loop fused with its log-weights: as a shared helper it cost 2–4 instructions per
/// patch on the M4.
fn weights_q16(w: &[i32], q: &mut [u32]) -> u32 {
    let best = w.iter().copied().max().unwrap_or(0);
    let mut total = 0u32;
    for (qi, wi) in q.iter_mut().zip(w) {
        *qi = weight_q16(best.saturating_sub(*wi).unsigned_abs());
        total = total.saturating_add(*qi);
    }
    total
}

/// [`DataTerm::Hybrid`]'s evidence gain: `gain_q8` times the share of the beams offered to the
/// store that it no longer holds (decimated on arrival or thinned since).
fn hybrid_gain(gain_q8: u16, s: &StoreReport) -> i32 {
    let dropped = u64::from(s.rays_decimated) + u64::from(s.rays_thinned);
    let offered = u64::from(s.rays_added) + u64::from(s.rays_decimated);
    if offered == 0 {
        return 0;
    }
    (u64::from(gain_q8) * dropped.min(offered) / offered) as i32
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
    /// The evidence gains in effect: the configured ones, scaled by the dropped share of the
    /// beams for [`DataTerm::Hybrid`], none for [`DataTerm::Rays`].
    pub(super) fn set_gains(&mut self, store: &StoreReport) {
        let g = i32::from(self.config.evidence_gain_q8);
        self.ev_gain = match self.config.data {
            DataTerm::Evidence => g,
            DataTerm::Hybrid => hybrid_gain(self.config.evidence_gain_q8, store),
            DataTerm::Rays => 0,
        };
        // ≤ 2^12 · 2^12 before the shift.
        self.ev_free_gain = (self.ev_gain * i32::from(self.config.evidence_free_q8)) >> 8;
    }

    /// The conditional of Eq. 1 for the patch centred at `centre` as the sampler computes it
    /// (fixed point), normalised: writes (config, probability) into `out` and returns how many.
    /// Diagnostic and test API; it ends the current tile visit.
    pub fn conditional<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        map: &[LogOdds],
        centre: CellCoord,
        out: &mut [(u16, f64)],
    ) -> usize
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.set_gains(&store.stats());
        let h = i32::from(self.prior.size()) / 2;
        if self.config.data.uses_rays() {
            self.gather(
                store,
                BlockGrid::new(
                    centre.x - h,
                    centre.y - h,
                    centre.x + h,
                    centre.y + h,
                    self.config.block_grid,
                ),
            );
        }
        self.visit_left = 0;
        let (current, border) = self.config_and_border(centre);
        let mut cands = [PatchCandidate::default(); MAX_CANDIDATES + 1];
        let mut w = [0i32; MAX_CANDIDATES + 1];
        let n = self
            .candidates(map, centre, current, border, &mut cands, &mut w)
            .min(out.len());
        let cands = cands.get(..n).unwrap_or(&[]);
        if self.config.data.uses_rays() {
            self.log_weights(store, centre, cands, &mut w, &mut CrossingCache::new());
        }
        let mut q = [0u32; MAX_CANDIDATES + 1];
        let total = weights_q16(w.get(..n).unwrap_or(&[]), &mut q);
        for ((o, c), qi) in out.iter_mut().zip(cands).zip(q) {
            *o = (c.config, f64::from(qi) / f64::from(total.max(1)));
        }
        n
    }

    /// The current configuration and border of the patch centred at `c`.
    pub(super) fn config_and_border(&self, c: CellCoord) -> (u16, u16) {
        let width = self.geometry.width() as usize;
        // Patch centres keep the prior's margin from the map edge, so the window is in the map.
        let row = |dy: i32, r: i32| {
            let y = (c.y + dy) as usize;
            self.bits(y * width + (c.x - r) as usize, (2 * r + 1) as u32)
        };
        match (self.prior.size(), self.prior.margin()) {
            (3, 2) => {
                let w = (0..5).fold(0u32, |w, r| w | row(r - 2, 2) << (5 * r));
                (
                    crate::sampler::patch::patch_of(w),
                    crate::sampler::patch::border_of(w),
                )
            }
            (3, _) => {
                let w = (0..3).fold(0u32, |w, r| w | row(r - 1, 1) << (3 * r)) as u16;
                (w, 0)
            }
            (_, 0) => (u16::from(self.occupied_at(c)), 0),
            _ => {
                let w = (0..3).fold(0u32, |w, r| w | row(r - 1, 1) << (3 * r)) as u16;
                (
                    u16::from(crate::sampler::patch::centre_of(w)),
                    u16::from(crate::sampler::patch::neighbours_of(w)),
                )
            }
        }
    }

    pub(super) fn update_one<S, R>(&mut self, store: &mut RayStore<S, R>, map: &[LogOdds])
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.stats.updates += 1;
        let (x0, y0, x1, y1) = self.tile;
        // One random number places the patch (16 bits per axis: tiles are at most 2^12 wide, so
        // the bias of the multiply-shift is below 2^-4 of a cell's share).
        let r = self.rng.next_u32();
        let cx = x0 + below(r << 16, (x1 - x0 + 1) as u32) as i32;
        let cy = y0 + below(r & 0xffff_0000, (y1 - y0 + 1) as u32) as i32;
        let centre = CellCoord { x: cx, y: cy };
        let (current, border) = self.config_and_border(centre);
        if self.random_patch_due() {
            self.random_patch(store, centre, current);
            return;
        }
        self.update_at(store, map, centre, current, border);
    }

    /// Counts down to the next random patch (`p_randPatch`): whether this update is one.
    #[inline]
    fn random_patch_due(&mut self) -> bool {
        random_patch_step(self.rand_period, &mut self.rand_gap, &mut self.rng)
    }

    /// Sets a uniformly random configuration at `centre` (Algorithm 1's `p_randPatch` move);
    /// returns it.
    pub(super) fn random_patch<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        centre: CellCoord,
        current: u16,
    ) -> u16
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.stats.random_patches += 1;
        let size = i32::from(self.prior.size());
        let new = (self.rng.next_u32() & ((1u32 << (size * size)) - 1)) as u16;
        if new != current {
            self.stats.changed += 1;
            self.apply(store, centre, new, None);
        }
        new
    }

    /// One Gibbs update of the patch at `centre` whose configuration and border are `current`
    /// and `border`: Eq. 1 over the candidates, the estimates, the new configuration written.
    /// Returns it.
    pub(super) fn update_at<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        map: &[LogOdds],
        centre: CellCoord,
        current: u16,
        border: u16,
    ) -> u16
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let mut cands = [PatchCandidate::default(); MAX_CANDIDATES + 1];
        let mut w = [0i32; MAX_CANDIDATES + 1];
        let n = self.candidates(map, centre, current, border, &mut cands, &mut w);
        if n <= 1 {
            self.stats.single_candidate += 1;
            let new = cands.first().map_or(current, |c| c.config);
            self.average_config(centre, new);
            if new != current {
                self.stats.changed += 1;
                self.apply(store, centre, new, None);
            }
            return new;
        }
        let cands = cands.get(..n).unwrap_or(&[]);
        // Crossings computed for the likelihood are reused to update the ray caches if the patch
        // changes.
        let crossings = if self.config.data.uses_rays() {
            let mut c = CrossingCache::new();
            self.log_weights(store, centre, cands, &mut w, &mut c);
            Some(c)
        } else {
            None
        };
        let mut q = [0u32; MAX_CANDIDATES + 1];
        let total = weights_q16(w.get(..n).unwrap_or(&[]), &mut q);
        let new = self.draw(cands, &q, total);
        self.rao_blackwell(centre, cands, q.get(..n).unwrap_or(&[]), total, new);
        if new != current {
            self.stats.changed += 1;
            self.apply(store, centre, new, crossings.as_ref());
        }
        new
    }

    /// The candidates of the patch at `centre` (the prior's top-k, plus the evidence's own
    /// configuration with [`SamplerConfig::data_candidate`]) into `cands`, and in `w` their
    /// log-prior plus the evidence term; returns how many.
    ///
    /// [`SamplerConfig::data_candidate`]: super::SamplerConfig::data_candidate
    fn candidates(
        &mut self,
        map: &[LogOdds],
        centre: CellCoord,
        current: u16,
        border: u16,
        cands: &mut [PatchCandidate; MAX_CANDIDATES + 1],
        w: &mut [i32; MAX_CANDIDATES + 1],
    ) -> usize {
        let k = usize::from(self.config.max_candidates).min(MAX_CANDIDATES);
        let mut n = self
            .prior
            .candidates_cached(border, cands.get_mut(..k).unwrap_or(&mut []))
            .min(k);
        let use_ev = self.ev_gain != 0;
        if !use_ev && !self.config.data_candidate {
            for (wi, c) in w.iter_mut().zip(cands.iter()).take(n) {
                *wi = c.log_prior;
            }
            return n;
        }
        let ev = patch_evidence(
            map,
            usize::from(self.geometry.width()),
            centre,
            i32::from(self.prior.size()),
        );
        if self.config.data_candidate {
            let d = ev.data_config(current);
            if !cands.iter().take(n).any(|c| c.config == d) {
                if let Some(slot) = cands.get_mut(n) {
                    *slot = PatchCandidate {
                        config: d,
                        log_prior: i32::from(self.config.floor_log_prior),
                    };
                    n += 1;
                }
            }
        }
        if n <= 1 {
            // One candidate: no weights needed.
            return n;
        }
        let (occ, free) = (self.ev_gain, self.ev_free_gain);
        if use_ev && self.prior.size() == 3 {
            // Subset-sum tables: O(1) per candidate.
            let width = usize::from(self.geometry.width());
            let t = evidence::PatchTerms::new(map, width, centre, occ, free);
            for (wi, c) in w.iter_mut().zip(cands.iter()).take(n) {
                *wi = c.log_prior.saturating_add(t.of(c.config));
            }
            return n;
        }
        for (wi, c) in w.iter_mut().zip(cands.iter()).take(n) {
            *wi = if use_ev {
                c.log_prior.saturating_add(ev.of(c.config, occ, free))
            } else {
                c.log_prior
            };
        }
        n
    }

    /// Draws a candidate with probability `q / total` (see [`weights_q16`]).
    fn draw(&mut self, cands: &[PatchCandidate], q: &[u32], total: u32) -> u16 {
        let mut r = below(self.rng.next_u32(), total.max(1));
        for (c, &qi) in cands.iter().zip(q) {
            if r < qi {
                return c.config;
            }
            r -= qi;
        }
        cands.first().map_or(0, |c| c.config)
    }

    /// Writes `config` into the patch at `centre` and updates the caches of the rays crossing it
    /// (from `cache` when the likelihood already computed every crossing). Not inlined: one copy
    /// for its three callers.
    #[inline(never)]
    pub(super) fn apply<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        centre: CellCoord,
        config: u16,
        cache: Option<&CrossingCache>,
    ) where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        // First the rays (their crossings are computed against the old sample; a ray's update
        // only touches its own cache)…
        let h = i32::from(self.prior.size()) / 2;
        if !self.config.data.uses_rays() {
            // No rays are read: their caches are not kept.
        } else if let Some(cached) = cache.and_then(CrossingCache::get) {
            let rays = store.rays_mut();
            for (index, cross) in cached {
                let f = cross.first_in_patch(config).unwrap_or(cross.f_after);
                if let Some(r) = rays.get_mut(*index as usize) {
                    r.first_occupied = f;
                }
            }
        } else {
            let blocks =
                self.grid
                    .blocks_of_box(centre.x - h, centre.y - h, centre.x + h, centre.y + h);
            let local = self.buf.local.as_ref();
            for_each_ray(
                self.buf.blocks.as_ref(),
                self.block_row_words,
                self.n_local,
                blocks,
                |j| {
                    let Some(lr) = local.get(j) else { return };
                    let Some(cross) = self.crossing(store, lr, centre) else {
                        return;
                    };
                    let f = cross.first_in_patch(config).unwrap_or(cross.f_after);
                    if let Some(r) = store.rays_mut().get_mut(lr.index as usize) {
                        r.first_occupied = f;
                    }
                },
            );
        }
        // …then the cells, a row of the patch at a time (patch centres keep the prior's margin
        // from the edge, so every row is in the map).
        let size = 2 * h + 1;
        let width = usize::from(self.geometry.width());
        for py in 0..size {
            let y = centre.y - h + py;
            let x = centre.x - h;
            if y < 0 || x < 0 || x + size > i32::from(self.geometry.width()) {
                continue;
            }
            let bits = (u32::from(config) >> (py * size)) & ((1 << size) - 1);
            self.set_bits(y as usize * width + x as usize, size as u32, bits);
        }
    }
}
