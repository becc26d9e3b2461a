//! The bounded, border-conditioned patch Gibbs sampler (Merali & Barfoot, Algorithm 1 / Eq. 1).
//!
//! The sampler keeps one binary map sample `m^r` (a bitset) and repeatedly resamples a random
//! patch `a_k` (3×3 for L = 9, one cell for L = 1) from
//!
//! ```text
//! p(a_k = w | z, x, m_¬a_k) = η · p(a_k = w | border) · Π_n p(z_n | f_n(w))        (Eq. 1)
//! ```
//!
//! where the product runs over the rays crossing the patch and `f_n(w)` is ray n's first occupied
//! cell if the patch takes configuration `w`. With probability `p_randPatch` (0.001) a uniformly
//! random configuration is set instead, which keeps the chain ergodic although most
//! configurations have zero prior.
//!
//! ## Where the time goes, and how it is bounded
//! * **Candidates** come from a [`PatchPrior`]: for the border prior usually exactly one, and then
//!   no likelihood is evaluated at all (the paper's key saving). At most
//!   [`SamplerConfig::max_candidates`] ≤ [`MAX_CANDIDATES`] are considered.
//! * **Rays** are found through *tile visits*: the sampler picks a random tile (2^`tile_shift`
//!   cells square), gathers the rays crossing it (plus a one-cell margin) into a bounded local
//!   list, and then resamples patches centred in that tile for a while. Every update is still an
//!   exact Gibbs step (all rays crossing the patch are in the list), so the posterior is invariant;
//!   only the order of updates differs from a uniform random scan. Rays that do not fit the local
//!   list are counted in [`SamplerStats::local_overflow`] (size it so this stays zero).
//! * **First occupied cells** are cached per ray ([`crate::ray_store::StoredRay`]); a ray whose
//!   first occupied cell lies before the patch is unaffected by it and skipped in O(1); otherwise
//!   the cells before the patch are known free, the patch's cells are taken in ray order, and the
//!   first occupied cell after the patch is found once per ray and shared by all candidates.
//! * [`Gibbs::step`] does at most `budget` patch updates (plus, when a new tile visit starts, one
//!   gather over the store), so it can run between lidar scans.
//!
//! ## Marginals
//! Per-cell occupancy counts are `u8`. Once burn-in is over, every patch update also accumulates
//! the next `L` cells of a cursor that walks the map once per sweep (K/L updates), so each sweep
//! adds one sample of every cell at bounded cost. When 255 samples have been accumulated the next
//! pass halves every count (and the sample total) as it goes: the estimate becomes an
//! exponentially-forgetting average with a horizon of ~128–255 sweeps and never overflows.

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro128PlusPlus;

use crate::error::{Error, Result};
use crate::fixed::LogOdds;
use crate::forward_model::{ForwardModel, LogLik};
use crate::geometry::{CellCoord, GridGeometry};
use crate::ray::Ray;
use crate::ray_store::{RayStore, StoredRay, StoredScan, NONE};

/// Upper bound on candidates per patch (the paper saw at most 13 per border).
pub const MAX_CANDIDATES: usize = 16;

/// A marginal counter cell: `u8` on the firmware (64 KB for 256×256), `u16`/`u32` on the host
/// when more samples should be averaged before the counts halve.
pub trait Count: Copy + Default {
    /// Largest count; the sample total halves when it reaches this.
    const MAX: u32;
    /// As `u32`.
    fn get(self) -> u32;
    /// From `u32` (the caller keeps it ≤ `MAX`).
    fn set(v: u32) -> Self;
}

macro_rules! impl_count {
    ($($t:ty),*) => {$(
        impl Count for $t {
            const MAX: u32 = <$t>::MAX as u32;
            #[inline]
            fn get(self) -> u32 {
                u32::from(self)
            }
            #[inline]
            fn set(v: u32) -> Self {
                v.min(<Self as Count>::MAX) as $t
            }
        }
    )*};
}
impl_count!(u8, u16, u32);

/// A candidate configuration with its log-prior (LSB units of [`crate::fixed::LSB_NATS`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PatchCandidate {
    /// Bit `size·r + c` = cell (column c, row r) of the patch, row 0 at the bottom.
    pub config: u16,
    /// log p(config | border) in LSB; only differences between candidates matter.
    pub log_prior: i32,
}

/// The patch prior p(a_k | border) of Eq. 1.
pub trait PatchPrior {
    /// Patch edge: 1 (L = 1) or 3 (L = 9).
    fn size(&self) -> u8;
    /// Cells around patch centres that must lie inside the map so the border can be read:
    /// 2 for a 3×3 patch with a 16-cell border, 1 for a cell with 8 neighbours, 0 if the prior
    /// ignores the border.
    fn margin(&self) -> u8;
    /// Writes candidates for `border` (the 16-cell border of a 3×3 patch, or the 8-neighbour byte
    /// of a cell, in [`crate::patch`]'s bit order) into `out`, most probable first, and returns
    /// how many were written: at least 1 whenever `out` is not empty.
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize;
}

/// L = 1 with a constant prior p(m_k) (merali-barfoot-mcmc-gibbs-ogm).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConstantCellPrior {
    log_free: i32,
    log_occ: i32,
}

impl ConstantCellPrior {
    /// A prior with p(occupied) = `p`, in (0, 1).
    pub fn new(p: f64) -> Result<Self> {
        if !(p > 0.0 && p < 1.0) {
            return Err(Error::InvalidProbability);
        }
        let l = |q: f64| {
            i32::from(
                LogOdds::from_nats(libm::log(q))
                    .map(|l| l.0)
                    .unwrap_or(i16::MIN),
            )
        };
        Ok(ConstantCellPrior {
            log_free: l(1.0 - p),
            log_occ: l(p),
        })
    }
}

impl PatchPrior for ConstantCellPrior {
    fn size(&self) -> u8 {
        1
    }
    fn margin(&self) -> u8 {
        0
    }
    fn candidates(&self, _border: u16, out: &mut [PatchCandidate]) -> usize {
        let c = [
            PatchCandidate {
                config: 0,
                log_prior: self.log_free,
            },
            PatchCandidate {
                config: 1,
                log_prior: self.log_occ,
            },
        ];
        let n = out.len().min(2);
        for (o, c) in out.iter_mut().zip(c) {
            *o = c;
        }
        n
    }
}

/// The data-driven L = 9 prior conditioned on the 16-cell border (the paper's "MCMC + border",
/// the default): [`crate::prior::candidates`], with its documented fallback for unseen borders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BorderPrior;

impl PatchPrior for BorderPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        2
    }
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize {
        copy_candidates(crate::prior::candidates(border, out.len()), out)
    }
}

/// The data-driven L = 9 prior without border (the paper's "MCMC, L = 9"): the most likely
/// unconditioned configurations, top-k by mass.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UnconditionedPrior;

impl PatchPrior for UnconditionedPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        1
    }
    fn candidates(&self, _border: u16, out: &mut [PatchCandidate]) -> usize {
        copy_candidates(crate::prior::unconditioned(out.len()), out)
    }
}

fn copy_candidates(c: crate::prior::Candidates, out: &mut [PatchCandidate]) -> usize {
    let mut n = 0;
    for (o, (config, lp)) in out.iter_mut().zip(c.configs().iter().zip(c.log_priors())) {
        *o = PatchCandidate {
            config: *config,
            log_prior: i32::from(*lp),
        };
        n += 1;
    }
    n
}

/// Sampler settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SamplerConfig {
    /// Probability of setting a random configuration (paper: 0.001).
    pub p_rand_patch: f32,
    /// Sweeps (K/L patch updates each) before marginals are accumulated.
    pub burn_in_sweeps: u32,
    /// Candidates considered per patch (top-k of the prior), 1 ..= [`MAX_CANDIDATES`].
    pub max_candidates: u8,
    /// Initial sample: a cell starts occupied iff its log-odds exceeds this.
    pub init_threshold: LogOdds,
    /// Tiles are 2^`tile_shift` cells square.
    pub tile_shift: u8,
    /// Length of a tile visit, in sweeps of the tile (tile cells / L updates each).
    pub visit_sweeps: u8,
    /// RNG seed.
    pub seed: u64,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig {
            p_rand_patch: 0.001,
            burn_in_sweeps: 10,
            max_candidates: MAX_CANDIDATES as u8,
            init_threshold: LogOdds::ZERO,
            tile_shift: 4,
            visit_sweeps: 2,
            seed: 1,
        }
    }
}

/// A ray gathered for the current tile visit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LocalRay {
    /// Index in the store's ray array (for the first-occupied cache).
    pub index: u32,
    /// Start cell.
    pub start: CellCoord,
    /// Far-end cell.
    pub end: CellCoord,
    /// Step length, Q12 cells.
    pub step_q12: u32,
    /// Measured range, 1/16 steps, or [`NONE`].
    pub z_q4: u16,
}

/// Counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SamplerStats {
    /// Patch updates done.
    pub updates: u64,
    /// Of which random configurations (`p_randPatch`).
    pub random_patches: u64,
    /// Updates that had a single candidate (no likelihood needed).
    pub single_candidate: u64,
    /// Updates that changed the patch.
    pub changed: u64,
    /// Ray evaluations (ray × patch) that needed the likelihood.
    pub rays_evaluated: u64,
    /// Tile visits started.
    pub tile_visits: u64,
    /// Rays that crossed a tile but did not fit the local list.
    pub local_overflow: u64,
    /// Completed sweeps.
    pub sweeps: u32,
}

/// The sampler, over caller storage: `sample` (⌈K/32⌉ words), `counts` (K counters) and `local`
/// (the tile's ray list).
#[derive(Clone, Debug)]
pub struct Gibbs<P, B, C, L, N = u8> {
    prior: P,
    forward: ForwardModel,
    config: SamplerConfig,
    geometry: GridGeometry,
    sample: B,
    counts: C,
    local: L,
    n_local: usize,
    rng: Xoshiro128PlusPlus,
    p_rand_u32: u32,
    // Patch-centre range and tiling.
    cx0: i32,
    cx1: i32,
    cy0: i32,
    cy1: i32,
    tile: (i32, i32, i32, i32),
    visit_left: u32,
    // Sweeps and marginals.
    sweep_len: u32,
    in_sweep: u32,
    cursor: usize,
    samples: u32,
    halving: bool,
    stats: SamplerStats,
    _count: core::marker::PhantomData<N>,
}

/// 2^(−i/512) in Q16 for i in 0..512: the weight of a log-odds difference of i LSB (because
/// one LSB is ln 2 / 512, `exp(−d·LSB) = 2^(−d/512)` exactly).
const EXP2_TABLE: [u32; 512] = build_exp2_table();

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_exp2_table() -> [u32; 512] {
    let mut t = [0u32; 512];
    let mut i = 0;
    while i < 512 {
        // 2^(-i/512) = exp(-i·ln2/512) by its Taylor series (x ≤ ln 2: 25 terms are plenty).
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
fn weight_q16(d: u32) -> u32 {
    let (q, r) = (d / 512, (d % 512) as usize);
    if q >= 17 {
        return 0;
    }
    EXP2_TABLE.get(r).copied().unwrap_or(0) >> q
}

/// Uniform integer in `0..n` from a 32-bit random number (Lemire's multiply-shift).
#[inline]
fn below(r: u32, n: u32) -> u32 {
    ((u64::from(r) * u64::from(n)) >> 32) as u32
}

impl<P, B, C, L, N> Gibbs<P, B, C, L, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
{
    /// A sampler over `geometry`. `sample` needs ⌈K/32⌉ words, `counts` K bytes, `local` at least
    /// one entry. Call [`Gibbs::reset`] before stepping.
    pub fn new(
        geometry: GridGeometry,
        prior: P,
        forward: ForwardModel,
        config: SamplerConfig,
        sample: B,
        counts: C,
        local: L,
    ) -> Result<Self> {
        let k = geometry.len();
        if sample.as_ref().len() < k.div_ceil(32) {
            return Err(Error::BufferSize {
                expected: k.div_ceil(32),
                actual: sample.as_ref().len(),
            });
        }
        if counts.as_ref().len() < k {
            return Err(Error::BufferSize {
                expected: k,
                actual: counts.as_ref().len(),
            });
        }
        if local.as_ref().is_empty() {
            return Err(Error::BufferSize {
                expected: 1,
                actual: 0,
            });
        }
        let size = i32::from(prior.size());
        if !(size == 1 || size == 3) || config.max_candidates == 0 || config.tile_shift > 12 {
            return Err(Error::InvalidModel);
        }
        let m = i32::from(prior.margin()).max(size / 2);
        let (w, h) = (i32::from(geometry.width()), i32::from(geometry.height()));
        if w <= 2 * m || h <= 2 * m {
            return Err(Error::InvalidGeometry);
        }
        let p = f64::from(config.p_rand_patch).clamp(0.0, 1.0);
        let cells_per_patch = (size * size) as u32;
        Ok(Gibbs {
            prior,
            forward,
            config,
            geometry,
            sample,
            counts,
            local,
            n_local: 0,
            rng: Xoshiro128PlusPlus::seed_from_u64(config.seed),
            p_rand_u32: (p * 4_294_967_295.0) as u32,
            cx0: m,
            cx1: w - 1 - m,
            cy0: m,
            cy1: h - 1 - m,
            tile: (0, 0, 0, 0),
            visit_left: 0,
            sweep_len: (k as u32).div_ceil(cells_per_patch).max(1),
            in_sweep: 0,
            cursor: 0,
            samples: 0,
            halving: false,
            stats: SamplerStats::default(),
            _count: core::marker::PhantomData,
        })
    }

    /// The grid geometry.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Counters.
    pub fn stats(&self) -> SamplerStats {
        self.stats
    }

    /// The settings.
    pub fn config(&self) -> &SamplerConfig {
        &self.config
    }

    /// The forward model.
    pub fn forward_model(&self) -> &ForwardModel {
        &self.forward
    }

    /// The prior.
    pub fn prior(&self) -> &P {
        &self.prior
    }

    /// Whether cell `index` is occupied in the current sample.
    #[inline]
    pub fn occupied(&self, index: usize) -> bool {
        self.sample
            .as_ref()
            .get(index / 32)
            .is_some_and(|w| w & (1 << (index % 32)) != 0)
    }

    #[inline]
    fn set_occupied(&mut self, index: usize, v: bool) {
        if let Some(w) = self.sample.as_mut().get_mut(index / 32) {
            if v {
                *w |= 1 << (index % 32);
            } else {
                *w &= !(1 << (index % 32));
            }
        }
    }

    #[inline]
    fn occupied_at(&self, c: CellCoord) -> bool {
        self.geometry.index(c).is_some_and(|i| self.occupied(i))
    }

    /// Samples accumulated into the marginal counts (≤ `Count::MAX`, halves when full).
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Occupancy count of cell `index` out of [`Gibbs::samples`].
    pub fn count(&self, index: usize) -> u32 {
        self.counts.as_ref().get(index).map_or(0, |c| c.get())
    }

    /// Marginal p(m_k = 1) estimate of cell `index`, or `None` before the first sample.
    pub fn marginal(&self, index: usize) -> Option<f32> {
        if self.samples == 0 || index >= self.geometry.len() {
            return None;
        }
        Some((self.count(index) as f32 / self.samples as f32).min(1.0))
    }

    /// Starts over from the thresholded log-odds map: resets the sample, the marginals, the
    /// sweep counters and every ray's first-occupied cache.
    pub fn reset<S, R>(&mut self, map: &[LogOdds], store: &mut RayStore<S, R>) -> Result<()>
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        if map.len() != self.geometry.len() {
            return Err(Error::BufferSize {
                expected: self.geometry.len(),
                actual: map.len(),
            });
        }
        if store.geometry() != &self.geometry {
            return Err(Error::InvalidGeometry);
        }
        self.sample.as_mut().fill(0);
        for (i, l) in map.iter().enumerate() {
            if *l > self.config.init_threshold {
                self.set_occupied(i, true);
            }
        }
        self.counts.as_mut().fill(N::default());
        (
            self.samples,
            self.halving,
            self.in_sweep,
            self.cursor,
            self.visit_left,
        ) = (0, false, 0, 0, 0);
        self.stats.sweeps = 0;
        self.refresh_rays(store, 0..usize::MAX);
        Ok(())
    }

    /// Recomputes the first-occupied cache of the rays in `range` (e.g. the rays a new scan just
    /// added) and ends the current tile visit so the next one sees them.
    pub fn refresh_rays<S, R>(&mut self, store: &mut RayStore<S, R>, range: core::ops::Range<usize>)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.visit_left = 0;
        let n_scans = store.scans().len();
        for s in 0..n_scans {
            let Some(scan) = store.scans().get(s).copied() else {
                break;
            };
            for k in 0..scan.len as usize {
                let idx = scan.first as usize + k;
                if idx < range.start || idx >= range.end {
                    continue;
                }
                let Some(stored) = store.rays().get(idx).copied() else {
                    continue;
                };
                let geom = store.ray_geometry(&scan.pose, stored.angle);
                let f = self.first_occupied_from(&geom.ray, 0);
                if let Some(r) = store.rays_mut().get_mut(idx) {
                    r.first_occupied = f;
                }
            }
        }
    }

    /// First occupied in-grid step of `ray` at or after step `from`, or [`NONE`].
    fn first_occupied_from(&self, ray: &Ray, from: u64) -> u16 {
        let g = &self.geometry;
        let Some(mut steps) = ray.clip(g.width(), g.height()) else {
            return NONE;
        };
        if steps.last < from {
            return NONE;
        }
        steps.first = steps.first.max(from);
        ray.find_step(steps, g.width(), |idx| self.occupied(idx))
            .map_or(NONE, |i| i.min(u64::from(NONE - 1)) as u16)
    }

    /// Does up to `budget` patch updates (Algorithm 1's inner loop); returns how many were done.
    pub fn step<S, R>(&mut self, store: &mut RayStore<S, R>, budget: u32) -> u32
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        for _ in 0..budget {
            if self.visit_left == 0 {
                self.start_visit(store);
            }
            self.visit_left = self.visit_left.saturating_sub(1);
            self.update_one(store);
            self.accumulate();
        }
        budget
    }

    /// Picks a random tile and gathers the rays crossing it (with a one-cell margin).
    fn start_visit<S, R>(&mut self, store: &RayStore<S, R>)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let t = 1i32 << self.config.tile_shift;
        let tiles_x = (self.cx1 - self.cx0) / t + 1;
        let tiles_y = (self.cy1 - self.cy0) / t + 1;
        let tx = below(self.rng.next_u32(), tiles_x as u32) as i32;
        let ty = below(self.rng.next_u32(), tiles_y as u32) as i32;
        let x0 = self.cx0 + tx * t;
        let y0 = self.cy0 + ty * t;
        let x1 = (x0 + t - 1).min(self.cx1);
        let y1 = (y0 + t - 1).min(self.cy1);
        self.tile = (x0, y0, x1, y1);
        let size = i32::from(self.prior.size());
        let cells = ((x1 - x0 + 1) * (y1 - y0 + 1)) as u32;
        self.visit_left =
            (cells / (size * size) as u32).max(1) * u32::from(self.config.visit_sweeps.max(1));
        self.stats.tile_visits += 1;
        let h = size / 2;
        self.gather(store, (x0 - h, y0 - h, x1 + h, y1 + h));
    }

    /// Collects the rays crossing the box `(x0, y0, x1, y1)` (inclusive) into the local list.
    fn gather<S, R>(&mut self, store: &RayStore<S, R>, (bx0, by0, bx1, by1): (i32, i32, i32, i32))
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let reach = i64::from(store_reach_cells(store)) + 2;
        self.n_local = 0;
        let cap = self.local.as_ref().len();
        for scan in store.scans() {
            let start = store.start_cell(&scan.pose);
            // Quick reject: the box is beyond the sensor's reach from this pose.
            let ddx = dist_to_interval(start.x, bx0, bx1);
            let ddy = dist_to_interval(start.y, by0, by1);
            if ddx * ddx + ddy * ddy > reach * reach {
                continue;
            }
            for k in 0..scan.len as usize {
                let idx = scan.first as usize + k;
                let Some(stored) = store.rays().get(idx) else {
                    continue;
                };
                let geom = store.ray_geometry(&scan.pose, stored.angle);
                if clip_box(&geom.ray, bx0, by0, bx1, by1).is_none() {
                    continue;
                }
                if self.n_local >= cap {
                    self.stats.local_overflow += 1;
                    continue;
                }
                if let Some(slot) = self.local.as_mut().get_mut(self.n_local) {
                    *slot = LocalRay {
                        index: idx as u32,
                        start,
                        end: geom.ray.cell_at(geom.ray.steps()),
                        step_q12: geom.step_q12,
                        z_q4: stored.z_q4,
                    };
                    self.n_local += 1;
                }
            }
        }
    }

    /// The conditional of Eq. 1 for the patch centred at `centre` as the sampler computes it
    /// (fixed point), normalised: writes (config, probability) into `out` and returns how many.
    /// Diagnostic and test API; it ends the current tile visit.
    pub fn conditional<S, R>(
        &mut self,
        store: &RayStore<S, R>,
        centre: CellCoord,
        out: &mut [(u16, f64)],
    ) -> usize
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let h = i32::from(self.prior.size()) / 2;
        self.gather(
            store,
            (centre.x - h, centre.y - h, centre.x + h, centre.y + h),
        );
        self.visit_left = 0;
        let (_, border) = self.config_and_border(centre);
        let mut cands = [PatchCandidate::default(); MAX_CANDIDATES];
        let k = usize::from(self.config.max_candidates)
            .min(MAX_CANDIDATES)
            .min(out.len());
        let n = self
            .prior
            .candidates(border, cands.get_mut(..k).unwrap_or(&mut []))
            .min(k);
        let cands = cands.get(..n).unwrap_or(&[]);
        let mut w = [0i32; MAX_CANDIDATES];
        self.log_weights(store, centre, cands, &mut w);
        let best = w.iter().take(n).copied().max().unwrap_or(0);
        let q: [u32; MAX_CANDIDATES] = core::array::from_fn(|j| {
            w.get(j)
                .filter(|_| j < n)
                .map_or(0, |wj| weight_q16(best.saturating_sub(*wj).unsigned_abs()))
        });
        let total: u64 = q.iter().map(|&x| u64::from(x)).sum();
        for ((o, c), qi) in out.iter_mut().zip(cands).zip(q) {
            *o = (c.config, qi as f64 / total.max(1) as f64);
        }
        n
    }

    /// Reads the (2·r+1)² window around `c` (r = 2: 25 bits in [`crate::patch`] order; r = 1: 9).
    fn window(&self, c: CellCoord, r: i32) -> u32 {
        let side = 2 * r + 1;
        let mut win = 0u32;
        for dy in 0..side {
            for dx in 0..side {
                if self.occupied_at(CellCoord {
                    x: c.x - r + dx,
                    y: c.y - r + dy,
                }) {
                    win |= 1 << (dy * side + dx);
                }
            }
        }
        win
    }

    /// The current configuration and border of the patch centred at `c`.
    fn config_and_border(&self, c: CellCoord) -> (u16, u16) {
        match (self.prior.size(), self.prior.margin()) {
            (3, _) => {
                let w = self.window(c, 2);
                (crate::patch::patch_of(w), crate::patch::border_of(w))
            }
            (_, 0) => (u16::from(self.occupied_at(c)), 0),
            _ => {
                let w = self.window(c, 1) as u16;
                (
                    u16::from(crate::patch::centre_of(w)),
                    u16::from(crate::patch::neighbours_of(w)),
                )
            }
        }
    }

    fn update_one<S, R>(&mut self, store: &mut RayStore<S, R>)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.stats.updates += 1;
        let (x0, y0, x1, y1) = self.tile;
        let cx = x0 + below(self.rng.next_u32(), (x1 - x0 + 1) as u32) as i32;
        let cy = y0 + below(self.rng.next_u32(), (y1 - y0 + 1) as u32) as i32;
        let centre = CellCoord { x: cx, y: cy };
        let size = i32::from(self.prior.size());
        let (current, border) = self.config_and_border(centre);
        let new = if self.rng.next_u32() < self.p_rand_u32 {
            self.stats.random_patches += 1;
            (self.rng.next_u32() & ((1u32 << (size * size)) - 1)) as u16
        } else {
            let mut cands = [PatchCandidate::default(); MAX_CANDIDATES];
            let k = usize::from(self.config.max_candidates).min(MAX_CANDIDATES);
            let n = self
                .prior
                .candidates(border, cands.get_mut(..k).unwrap_or(&mut []))
                .min(k);
            match n {
                0 => current,
                1 => {
                    self.stats.single_candidate += 1;
                    cands.first().map_or(current, |c| c.config)
                }
                _ => {
                    let cands = cands.get(..n).unwrap_or(&[]);
                    let mut w = [0i32; MAX_CANDIDATES];
                    self.log_weights(store, centre, cands, &mut w);
                    self.draw(cands, w.get(..n).unwrap_or(&[]))
                }
            }
        };
        if new != current {
            self.stats.changed += 1;
            self.apply(store, centre, new);
        }
    }

    /// Eq. 1 in the log domain: log-prior plus Σ over crossing rays of log p(z | f(config)).
    fn log_weights<S, R>(
        &mut self,
        store: &RayStore<S, R>,
        centre: CellCoord,
        cands: &[PatchCandidate],
        w: &mut [i32],
    ) where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        for (wi, c) in w.iter_mut().zip(cands) {
            *wi = c.log_prior;
        }
        for j in 0..self.n_local {
            let Some(lr) = self.local.as_ref().get(j).copied() else {
                break;
            };
            let Some(cross) = self.crossing(store, &lr, centre) else {
                continue;
            };
            self.stats.rays_evaluated += 1;
            for (wi, c) in w.iter_mut().zip(cands) {
                let f = cross.first_in_patch(c.config).unwrap_or(cross.f_after);
                *wi = wi.saturating_add(self.log_lik(&lr, f, cross.n));
            }
        }
    }

    /// How `lr` crosses the patch at `centre`, if the patch can change its first occupied cell.
    fn crossing<S, R>(
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
        let ray = Ray::new(lr.start, lr.end);
        let steps = clip_box(&ray, centre.x - h, centre.y - h, centre.x + h, centre.y + h)?;
        let f = store
            .rays()
            .get(lr.index as usize)
            .map_or(NONE, |r| r.first_occupied);
        if f != NONE && u64::from(f) < steps.first {
            return None; // occupied before the patch: the patch cannot matter
        }
        let f_after = if f != NONE && u64::from(f) > steps.last {
            f
        } else {
            self.first_occupied_from(&ray, steps.last + 1)
        };
        let size = h * 2 + 1;
        let mut cells = [(0u16, 0u16); 5];
        let mut n_cells = 0;
        for i in steps.first..=steps.last {
            let c = ray.cell_at(i);
            let bit = ((c.y - (centre.y - h)) * size + (c.x - (centre.x - h))) as u16;
            if let Some(slot) = cells.get_mut(n_cells) {
                *slot = (i.min(u64::from(NONE - 1)) as u16, bit);
                n_cells += 1;
            }
        }
        Some(Crossing {
            cells,
            n_cells,
            f_after,
            n: ray.steps().min(u64::from(NONE - 1)) as u16,
        })
    }

    /// log p(z | f) for a local ray; `n` is the far end's step (max range).
    #[inline]
    fn log_lik(&self, lr: &LocalRay, f: u16, n: u16) -> LogLik {
        let k = i64::from(lr.step_q12);
        if lr.z_q4 == NONE {
            if f == NONE {
                return self.forward.no_return_clear();
            }
            // (F − f) steps → 1/16 cells: × step (Q12) × 16.
            let q = ((i64::from(n) - i64::from(f)) * k + 128) >> 8;
            return self
                .forward
                .no_return(q.clamp(0, i64::from(i32::MAX)) as i32);
        }
        if f == NONE {
            return self.forward.hit_clear();
        }
        // (z − f) in 1/16 steps → 1/16 cells: × step (Q12) / 4096.
        let d = i64::from(lr.z_q4) - 16 * i64::from(f);
        let q = (d * k + if d >= 0 { 2048 } else { -2048 }) / 4096;
        self.forward
            .hit(q.clamp(-i64::from(i32::MAX), i64::from(i32::MAX)) as i32)
    }

    /// Draws a candidate with probability ∝ exp(w).
    fn draw(&mut self, cands: &[PatchCandidate], w: &[i32]) -> u16 {
        let best = w.iter().copied().max().unwrap_or(0);
        let mut q = [0u32; MAX_CANDIDATES];
        let mut total = 0u32;
        for (qi, wi) in q.iter_mut().zip(w) {
            *qi = weight_q16(best.saturating_sub(*wi).unsigned_abs());
            total = total.saturating_add(*qi);
        }
        let mut r = below(self.rng.next_u32(), total.max(1));
        for (c, qi) in cands.iter().zip(q) {
            if r < qi {
                return c.config;
            }
            r -= qi;
        }
        cands.first().map_or(0, |c| c.config)
    }

    /// Writes `config` into the patch at `centre` and updates the caches of the rays crossing it.
    fn apply<S, R>(&mut self, store: &mut RayStore<S, R>, centre: CellCoord, config: u16)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        // First the rays (their crossing is computed against the old sample)…
        for j in 0..self.n_local {
            let Some(lr) = self.local.as_ref().get(j).copied() else {
                break;
            };
            let Some(cross) = self.crossing(store, &lr, centre) else {
                continue;
            };
            let f = cross.first_in_patch(config).unwrap_or(cross.f_after);
            if let Some(r) = store.rays_mut().get_mut(lr.index as usize) {
                r.first_occupied = f;
            }
        }
        // …then the cells.
        let size = i32::from(self.prior.size());
        let h = size / 2;
        for py in 0..size {
            for px in 0..size {
                let c = CellCoord {
                    x: centre.x - h + px,
                    y: centre.y - h + py,
                };
                if let Some(i) = self.geometry.index(c) {
                    self.set_occupied(i, config & (1 << (py * size + px)) != 0);
                }
            }
        }
    }

    /// Advances the marginal-accumulation cursor by L cells; counts sweeps.
    fn accumulate(&mut self) {
        let size = usize::from(self.prior.size());
        let k = self.geometry.len();
        let counting = self.stats.sweeps >= self.config.burn_in_sweeps;
        if counting && self.cursor == 0 {
            self.halving = self.samples >= N::MAX;
        }
        for _ in 0..size * size {
            if self.cursor >= k {
                break;
            }
            if counting {
                let bit = u32::from(self.occupied(self.cursor));
                let halving = self.halving;
                if let Some(c) = self.counts.as_mut().get_mut(self.cursor) {
                    *c = N::set(if halving {
                        c.get() / 2 + bit
                    } else {
                        c.get().saturating_add(bit)
                    });
                }
            }
            self.cursor += 1;
        }
        self.in_sweep += 1;
        if self.in_sweep >= self.sweep_len {
            if counting {
                self.samples = if self.halving {
                    self.samples / 2 + 1
                } else {
                    (self.samples + 1).min(N::MAX)
                };
                self.halving = false;
            }
            self.in_sweep = 0;
            self.cursor = 0;
            self.stats.sweeps = self.stats.sweeps.saturating_add(1);
        }
    }
}

/// How a ray crosses a patch.
#[derive(Clone, Copy, Debug)]
struct Crossing {
    /// (step, patch bit) of the patch cells on the ray, in ray order.
    cells: [(u16, u16); 5],
    n_cells: usize,
    /// First occupied step after the patch (or the cached one if it lies after), or NONE.
    f_after: u16,
    /// The ray's last step (max range).
    n: u16,
}

impl Crossing {
    /// First step inside the patch occupied under `config`.
    #[inline]
    fn first_in_patch(&self, config: u16) -> Option<u16> {
        self.cells
            .iter()
            .take(self.n_cells)
            .find(|(_, bit)| config & (1 << bit) != 0)
            .map(|(s, _)| *s)
    }
}

/// The steps of `ray` inside the box [x0, x1] × [y0, y1] (inclusive).
fn clip_box(ray: &Ray, x0: i32, y0: i32, x1: i32, y1: i32) -> Option<crate::ray::Steps> {
    let s = ray.start();
    let e = ray.cell_at(ray.steps());
    let shifted = Ray::new(
        CellCoord {
            x: s.x - x0,
            y: s.y - y0,
        },
        CellCoord {
            x: e.x - x0,
            y: e.y - y0,
        },
    );
    let (w, h) = (
        u16::try_from(x1 - x0 + 1).ok()?,
        u16::try_from(y1 - y0 + 1).ok()?,
    );
    shifted.clip(w, h)
}

fn dist_to_interval(v: i32, lo: i32, hi: i32) -> i64 {
    if v < lo {
        i64::from(lo - v)
    } else if v > hi {
        i64::from(v - hi)
    } else {
        0
    }
}

/// The store's maximum range in cells (rounded up).
fn store_reach_cells<S, R>(store: &RayStore<S, R>) -> u32
where
    S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
    R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
{
    store.max_range_mm().div_ceil(store.geometry().cell_mm())
}
