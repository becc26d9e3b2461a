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
//!   cells square), gathers the rays crossing it (plus the margin a patch reaches) into a bounded
//!   local list indexed by 4×4 blocks (module `local`), and then resamples patches centred in that
//!   tile for a while. Every update is still an exact Gibbs step (all rays crossing the patch are
//!   in the list), so the posterior is invariant; only the order of updates differs from a
//!   uniform random scan. Rays that do not fit the local list are counted in
//!   [`SamplerReport::local_overflow`] (size the buffer so this stays zero).
//! * **First occupied cells** are cached per ray ([`crate::sampler::ray_store::StoredRay`]); a ray whose
//!   first occupied cell lies before the patch is unaffected by it and skipped in O(1); otherwise
//!   the cells before the patch are known free, the patch's cells are taken in ray order, and the
//!   first occupied cell after the patch is found once per ray and shared by all candidates.
//! * [`Gibbs::step`] does at most `budget` patch updates (plus, when a new tile visit starts, one
//!   gather over the store), so it can run between lidar scans.
//!
//! ## Marginals
//! Per-cell occupancy counts are a [`Count`] (`u8` on the firmware). Once burn-in is over, every
//! patch update also accumulates the next `L` cells of a cursor that walks the map once per sweep
//! (K/L updates), so each sweep adds one sample of every cell at bounded cost. When `Count::MAX`
//! samples (255 for `u8`) have been accumulated the next pass halves every count (and the sample
//! total) as it goes: the estimate becomes an exponentially-forgetting average over the last
//! ½–1 × `MAX` sweeps and never overflows.
//!
//! ## Where the code is
//! This file: [`Gibbs`], its settings and its public API. One `impl` per concern in the
//! submodules: `update` (one patch update, Eq. 1), `evidence` (the per-cell evidence term),
//! `sweep` (that term's raster sweep, the robot's hot path), `rays` and `local` (the ray
//! term), `schedule` (tile visits), `notes` (following the mapper online), `estimate` and
//! `count` (the marginals), `priors` ([`PatchPrior`]) and `segment` (short Bresenham rays).

mod count;
mod estimate;
mod evidence;
mod local;
mod notes;
mod priors;
mod rays;
mod schedule;
mod segment;
mod sweep;
mod update;

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro128PlusPlus;

use crate::config::{DataTerm, Estimator};
use crate::error::{Error, Result};
use crate::sampler::forward_model::ForwardModel;
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use crate::types::fixed::LogOdds;
use crate::types::geometry::{CellCoord, GridGeometry};
use crate::wire::SamplerReport;
pub use count::{average_byte, AverageShift, Count};
use local::BlockGrid;
pub use local::{block_words, LocalRay, DEFAULT_BLOCK_GRID, MAX_BLOCK_GRID};
use notes::RESTARTS;
pub use priors::{
    BorderPrior, ConstantCellPrior, NeighbourPrior, PatchCandidate, PatchPrior, UnconditionedPrior,
};
use schedule::HotTiles;
pub use segment::Segment;
use update::below;

/// Upper bound on candidates per patch (the paper saw at most 13 per border).
pub const MAX_CANDIDATES: usize = 16;

/// The sampler, over caller storage (see [`Buffers`]).
#[derive(Clone, Debug)]
pub struct Gibbs<P, B, C, L, K, N = u8> {
    prior: P,
    forward: ForwardModel,
    config: SamplerConfig,
    geometry: GridGeometry,
    buf: Buffers<B, C, L, K>,
    n_local: usize,
    block_row_words: usize,
    grid: BlockGrid,
    rng: Xoshiro128PlusPlus,
    /// The estimates' rounding dither (xorshift32, never 0): a generator of its own, so the
    /// chain draws the same numbers whatever the estimator.
    dither: u32,
    /// Random patches come every `1 + below(rand_period)` updates (mean 1/p_randPatch; 0 =
    /// never): one random number per random patch instead of one per update.
    rand_period: u32,
    rand_gap: u32,
    // Patch-centre range, current tile.
    cx0: i32,
    cx1: i32,
    cy0: i32,
    cy1: i32,
    tile: (i32, i32, i32, i32),
    visit_left: u32,
    raster: sweep::Raster,
    // Sweeps and marginals.
    sweep_len: u32,
    in_sweep: u32,
    cursor: usize,
    samples: u32,
    halving: bool,
    /// The counters the wire reports (`samples` and `store` stay zero, see [`Gibbs::stats`]).
    stats: SamplerReport,
    /// Local rays examined for a patch (the block index's candidates), over all updates.
    rays_examined: u64,
    /// Rays gathered into local lists, over all visits.
    rays_gathered: u64,
    // Tiling of the patch-centre range, and the tiles whose evidence changed.
    tiles_x: u32,
    tiles_y: u32,
    hot: HotTiles,
    /// Cell indices `lo ..= hi` (part of one row) whose tile is marked in `hot`: consecutive
    /// changed cells mostly share a tile, and this spares them the division and the bitset
    /// (empty when `lo > hi`; emptied whenever a visit takes a mark).
    hot_span: (usize, usize),
    /// [`Gibbs::note_marked_words`]'s row: the first and last index of the row of the last cell
    /// it looked at, and the row's tile row (geometry only, never stale).
    mark_row: (usize, usize, u32),
    /// Tile row and the tile columns (below 32) of it that [`Gibbs::note_marked_words`] marked
    /// since the last visit: the rows of a tile row mark the same tiles again and again, and
    /// marking is idempotent until a visit takes a mark or ages a tile (then it is emptied,
    /// with `hot_span`).
    marked_cols: (u32, u32),
    /// Recent estimate restarts ([`Gibbs::note_estimate`]): log-odds and the estimate each
    /// gives, entry `v mod RESTARTS` for the value `v`. A scan restarts most cells at a few
    /// values (its first-observed free cells at the free update, its face band's at one value
    /// per band slot), so this spares most restarts the probability lookup.
    restart: [(LogOdds, N); RESTARTS],
    /// The estimate's averaging shift on this tile visit ([`Estimator::shift_at`]).
    visit_shift: AverageShift,
    /// The evidence update's candidate weights (only the entries an update wrote are read).
    scratch: [u32; MAX_CANDIDATES + 1],
    /// Evidence gains in effect (Q8), occupied and free: the configured ones, scaled for the
    /// hybrid term.
    ev_gain: i32,
    ev_free_gain: i32,
    /// Candidates an evidence update considers: [`SamplerConfig::max_candidates`], at most
    /// [`MAX_CANDIDATES`] (clamped once here, not on every update).
    ev_k: u8,
    _count: core::marker::PhantomData<N>,
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
    /// A sampler over `geometry`. Call [`Gibbs::reset`] before stepping.
    pub fn new(
        geometry: GridGeometry,
        prior: P,
        forward: ForwardModel,
        config: SamplerConfig,
        buf: Buffers<B, C, L, K>,
    ) -> Result<Self> {
        let k = geometry.len();
        let need = |expected: usize, actual: usize| {
            if actual < expected {
                Err(Error::BufferSize { expected, actual })
            } else {
                Ok(())
            }
        };
        need(k.div_ceil(32), buf.sample.as_ref().len())?;
        need(k, buf.counts.as_ref().len())?;
        need(1, buf.local.as_ref().len())?;
        need(
            block_words(buf.local.as_ref().len(), config.block_grid),
            buf.blocks.as_ref().len(),
        )?;
        let size = i32::from(prior.size());
        let valid = (size == 1 || size == 3)
            && config.max_candidates > 0
            && (2..=12).contains(&config.tile_shift)
            && (1..=MAX_BLOCK_GRID).contains(&config.block_grid)
            && config.p_rand_patch.is_finite()
            && config.data.available()
            && config.estimator.available()
            && config.floor_log_prior <= 0
            && config.evidence_gain_q8 <= crate::config::noise::MAX_GAIN_Q8
            && config.evidence_free_q8 <= crate::config::noise::MAX_GAIN_Q8
            && match config.estimator {
                Estimator::Counts => true,
                Estimator::Average {
                    shift, max_shift, ..
                } => (1..=15).contains(&shift) && (shift..=15).contains(&max_shift),
            };
        if !valid {
            return Err(Error::InvalidModel);
        }
        let m = i32::from(prior.margin()).max(size / 2);
        let (w, h) = (i32::from(geometry.width()), i32::from(geometry.height()));
        if w <= 2 * m || h <= 2 * m {
            return Err(Error::InvalidGeometry);
        }
        // f32, like the setting: hardware arithmetic on the Cortex-M4F, no f64 code in flash.
        let p = config.p_rand_patch.clamp(0.0, 1.0);
        let cells_per_patch = (size * size) as u32;
        let block_row_words = buf.local.as_ref().len().div_ceil(32);
        let t = 1i32 << config.tile_shift;
        let (cx0, cx1, cy0, cy1) = (m, w - 1 - m, m, h - 1 - m);
        let (tiles_x, tiles_y) = (((cx1 - cx0) / t + 1) as u32, ((cy1 - cy0) / t + 1) as u32);
        let mut rng = Xoshiro128PlusPlus::seed_from_u64(config.seed);
        let rand_period = if p > 0.0 {
            // Uniform gaps on 1 ..= period have mean (period + 1) / 2 = 1/p.
            // `as` saturates at u32::MAX (and 2/p ≥ 2 keeps it ≥ 1).
            (libm::roundf(2.0 / p - 1.0) as u32).max(1)
        } else {
            0
        };
        let rand_gap = if rand_period > 0 {
            1 + below(rng.next_u32(), rand_period)
        } else {
            0
        };
        Ok(Gibbs {
            prior,
            forward,
            config,
            geometry,
            buf,
            n_local: 0,
            block_row_words,
            grid: BlockGrid::default(),
            rng,
            // Odd, so never the generator's fixed point 0.
            dither: (config.seed as u32 ^ (config.seed >> 32) as u32 ^ 0x9E37_79B9) | 1,
            rand_period,
            rand_gap,
            cx0,
            cx1,
            cy0,
            cy1,
            tile: (0, 0, 0, 0),
            visit_left: 0,
            raster: sweep::Raster::default(),
            sweep_len: (k as u32).div_ceil(cells_per_patch).max(1),
            in_sweep: 0,
            cursor: 0,
            samples: 0,
            halving: false,
            stats: SamplerReport::default(),
            rays_examined: 0,
            rays_gathered: 0,
            tiles_x,
            tiles_y,
            hot: HotTiles::new(tiles_x, tiles_y),
            hot_span: (1, 0),
            mark_row: (1, 0, 0),
            marked_cols: (u32::MAX, 0),
            // Entry k holds value k: each entry's value maps to its own slot.
            restart: core::array::from_fn(|k| {
                let v = LogOdds(k as i16);
                (v, N::from_probability_q16(estimate::probability_q16(v)))
            }),
            visit_shift: AverageShift::new(config.estimator.shift_at(0)),
            scratch: [0; MAX_CANDIDATES + 1],
            ev_gain: 0,
            ev_free_gain: 0,
            ev_k: config.max_candidates.min(MAX_CANDIDATES as u8),
            _count: core::marker::PhantomData,
        })
    }

    /// The grid geometry.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// The counters of what the updates did, as the wire reports them. `samples` and `store`
    /// stay zero: [`crate::Session::sampler_report`] fills them in from [`Gibbs::samples`] and
    /// [`RayStore::stats`].
    pub fn stats(&self) -> SamplerReport {
        self.stats
    }

    /// Local rays examined for a patch (the block index's candidates), over all updates: a
    /// diagnostic the wire does not carry.
    pub fn rays_examined(&self) -> u64 {
        self.rays_examined
    }

    /// Rays gathered into local lists, over all tile visits: a diagnostic the wire does not
    /// carry.
    pub fn rays_gathered(&self) -> u64 {
        self.rays_gathered
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

    /// Gives the buffers back.
    pub fn into_buffers(self) -> Buffers<B, C, L, K> {
        self.buf
    }

    /// Whether cell `index` is occupied in the current sample.
    #[inline]
    pub fn occupied(&self, index: usize) -> bool {
        self.buf
            .sample
            .as_ref()
            .get(index / 32)
            .is_some_and(|w| w & (1 << (index % 32)) != 0)
    }

    #[inline]
    pub(super) fn set_occupied(&mut self, index: usize, v: bool) {
        if let Some(w) = self.buf.sample.as_mut().get_mut(index / 32) {
            if v {
                *w |= 1 << (index % 32);
            } else {
                *w &= !(1 << (index % 32));
            }
        }
    }

    #[inline]
    pub(super) fn occupied_at(&self, c: CellCoord) -> bool {
        self.geometry.index(c).is_some_and(|i| self.occupied(i))
    }

    /// `n` ≤ 25 consecutive sample bits starting at cell `index` (row-major), bit 0 first.
    #[inline]
    pub(super) fn bits(&self, index: usize, n: u32) -> u32 {
        let words = self.buf.sample.as_ref();
        let (w, off) = (index / 32, (index % 32) as u32);
        let lo = words.get(w).copied().unwrap_or(0) >> off;
        // 32-bit only (a 64-bit shift is several instructions on a 32-bit core).
        let v = if off + n <= 32 {
            lo
        } else {
            lo | words.get(w + 1).copied().unwrap_or(0) << (32 - off)
        };
        v & ((1 << n) - 1)
    }

    /// Writes the `n` ≤ 31 bits `v` into the sample at cells `index..index + n`. Not inlined:
    /// its callers (a changed patch's rows, a raster run's rows) are not the hot path.
    #[inline(never)]
    pub(super) fn set_bits(&mut self, index: usize, n: u32, v: u32) {
        let words = self.buf.sample.as_mut();
        let (w, off) = (index / 32, (index % 32) as u32);
        let mask = (1u32 << n) - 1;
        if let Some(lo) = words.get_mut(w) {
            *lo = (*lo & !(mask << off)) | (v & mask) << off;
        }
        if off + n > 32 {
            // The rest spills into the next word.
            let s = 32 - off;
            if let Some(hi) = words.get_mut(w + 1) {
                *hi = (*hi & !(mask >> s)) | (v & mask) >> s;
            }
        }
    }

    /// The denominator of [`Gibbs::count`]: samples accumulated into the marginal counts
    /// (≤ `Count::MAX`, halves when full) with [`Estimator::Counts`]; `Count::MAX` with
    /// [`Estimator::Average`], whose counts are probabilities scaled to `Count::MAX`.
    pub fn samples(&self) -> u32 {
        match self.config.estimator {
            Estimator::Counts => self.samples,
            Estimator::Average { .. } => N::MAX,
        }
    }

    /// Marginal count of cell `index` out of [`Gibbs::samples`].
    pub fn count(&self, index: usize) -> u32 {
        self.buf.counts.as_ref().get(index).map_or(0, |c| c.get())
    }

    /// Marginal p(m_k = 1) estimate of cell `index`, or `None` before the first sample.
    pub fn marginal(&self, index: usize) -> Option<f32> {
        let n = self.samples();
        if n == 0 || index >= self.geometry.len() {
            return None;
        }
        Some((self.count(index) as f32 / n as f32).min(1.0))
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
        self.buf.sample.as_mut().fill(0);
        for (i, l) in map.iter().enumerate() {
            if *l > self.config.init_threshold {
                self.set_occupied(i, true);
            }
        }
        match self.config.estimator {
            Estimator::Counts => self.buf.counts.as_mut().fill(N::default()),
            // Estimates start at the log-odds map's probabilities.
            Estimator::Average { .. } => {
                for (c, l) in self.buf.counts.as_mut().iter_mut().zip(map) {
                    *c = N::default().ema(estimate::probability_q16(*l), 0);
                }
            }
        }
        self.hot.clear();
        self.hot_span = (1, 0);
        self.marked_cols = (u32::MAX, 0);
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

    /// Does up to `budget` patch updates (Algorithm 1's inner loop) on the rays in `store` and
    /// the evidence in `map` (the online log-odds map, row-major over the sampler's geometry;
    /// read only by [`DataTerm::Evidence`] / [`DataTerm::Hybrid`] and
    /// [`SamplerConfig::data_candidate`]); returns how many were done.
    pub fn step<S, R>(&mut self, store: &mut RayStore<S, R>, map: &[LogOdds], budget: u32) -> u32
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        self.set_gains(&store.stats());
        if self.config.data == DataTerm::Evidence && self.prior.size() == 3 {
            return self.step_raster(store, map, budget);
        }
        for _ in 0..budget {
            if self.visit_left == 0 {
                self.start_visit(store);
            }
            self.visit_left -= 1;
            self.update_one(store, map);
            self.accumulate();
        }
        budget
    }
}

/// The caller-provided memory of a sampler.
#[derive(Clone, Debug)]
pub struct Buffers<B, C, L, K> {
    /// The current sample, one bit per cell: ⌈K/32⌉ words.
    pub sample: B,
    /// Marginal counts, one per cell.
    pub counts: C,
    /// The tile visit's rays (its length is the local capacity).
    pub local: L,
    /// Block bitsets over the local rays: [`block_words`]`(local.len())` words.
    pub blocks: K,
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
    /// Initial sample: a cell starts occupied iff its log-odds exceeds this. The default, −1 LSB,
    /// starts never-observed cells (l = 0) occupied: unobserved space in a mapped building is
    /// mostly the inside of walls and furniture, and the sampler carves free space wherever rays
    /// pass (on the default world this gives max F1 0.86 instead of 0.79 when unknown starts free).
    pub init_threshold: LogOdds,
    /// Tiles are 2^`tile_shift` cells square (2 ..= 12).
    pub tile_shift: u8,
    /// Length of a tile visit, in sweeps of the tile (tile cells / L updates each; 0 counts as 1).
    pub visit_sweeps: u8,
    /// Blocks per side of the tile visit's ray index (1 ..= [`MAX_BLOCK_GRID`]); the `blocks`
    /// buffer needs [`block_words`]`(local capacity, block_grid)` words. Finer is faster and
    /// larger (see module `local`).
    pub block_grid: u8,
    /// RNG seed.
    pub seed: u64,
    /// The measurement term of Eq. 1 (rays, per-cell evidence, or both).
    pub data: DataTerm,
    /// Scale of the per-cell evidence (the log-odds map), Q8: 256 = the log-odds as they are.
    pub evidence_gain_q8: u16,
    /// Relative scale of *free* evidence (negative log-odds), Q8: the inverse model frees every
    /// cell before a noisy hit, so the cells at a wall's face read free about as often as the
    /// wall is hit; a smaller weight on free evidence keeps them from outvoting the hits.
    pub evidence_free_q8: u16,
    /// Also offer the configuration the evidence alone prefers ([`DataTerm::Evidence`]'s
    /// thresholded log-odds; unobserved cells as they are) as a candidate whenever the prior's
    /// top-k lacks it, with log-prior [`SamplerConfig::floor_log_prior`] — a floor under the
    /// pruned prior, so that where the evidence is strong the data wins (thin walls the corpus
    /// rarely shows, furniture the prior would square off).
    pub data_candidate: bool,
    /// Log-prior (LSB, ≤ 0) of a configuration the prior's table does not list.
    pub floor_log_prior: i16,
    /// How the marginals are estimated.
    pub estimator: Estimator,
    /// Of every 256 tile visits, how many go to tiles whose evidence changed since they were
    /// last visited (the rest are uniform, so every tile keeps being visited): see
    /// [`Gibbs::note_changed`]. 0 = uniform only.
    pub hot_share: u8,
}

impl Default for SamplerConfig {
    /// The paper's sampler: rays, sample counts, uniform tiles.
    fn default() -> Self {
        SamplerConfig {
            p_rand_patch: 0.001,
            burn_in_sweeps: 10,
            max_candidates: MAX_CANDIDATES as u8,
            init_threshold: LogOdds(-1),
            tile_shift: 4,
            visit_sweeps: 8,
            block_grid: 8,
            seed: 1,
            data: DataTerm::Rays,
            evidence_gain_q8: 256,
            evidence_free_q8: 256,
            data_candidate: false,
            floor_log_prior: FLOOR_LOG_PRIOR,
            estimator: Estimator::Counts,
            hot_share: 0,
        }
    }
}

/// Default [`SamplerConfig::floor_log_prior`]: ln(10⁻³) in LSB (one LSB is ln 2 / 512), a
/// tenth of the prior table's 1 % pruning threshold. One cell's clamped evidence (5 ln 4 =
/// 6.9 nats) outweighs it; one observation (ln 4) does not.
pub const FLOOR_LOG_PRIOR: i16 = -5102;
