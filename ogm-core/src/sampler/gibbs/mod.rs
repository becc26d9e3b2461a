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
//!   local list indexed by 4×4 blocks ([`local`]), and then resamples patches centred in that
//!   tile for a while. Every update is still an exact Gibbs step (all rays crossing the patch are
//!   in the list), so the posterior is invariant; only the order of updates differs from a
//!   uniform random scan. Rays that do not fit the local list are counted in
//!   [`SamplerStats::local_overflow`] (size the buffer so this stays zero).
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

mod estimate;
mod evidence;
mod local;
mod priors;
mod schedule;
mod segment;
mod sweep;

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro128PlusPlus;

use crate::config::{DataTerm, Estimator};
use crate::error::{Error, Result};
use crate::sampler::forward_model::{ForwardModel, LogLik};
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan, NONE, STALE};
use crate::types::fixed::LogOdds;
use crate::types::geometry::{CellCoord, GridGeometry};
use crate::Angle;
use evidence::patch_evidence;
pub use local::{block_words, LocalRay, DEFAULT_BLOCK_GRID, MAX_BLOCK_GRID};
use local::{for_each_ray, set_bit, BlockGrid};
pub use priors::{BorderPrior, ConstantCellPrior, NeighbourPrior, UnconditionedPrior};
use schedule::HotTiles;
pub use segment::Segment;


/// Upper bound on candidates per patch (the paper saw at most 13 per border).
pub const MAX_CANDIDATES: usize = 16;

/// A marginal counter cell: `u8` on the firmware (64 KB for 256×256), `u16`/`u32` on the host
/// when more samples should be averaged before the counts halve.
pub trait Count: Copy + Default {
    /// Largest count; the sample total halves when it reaches this.
    const MAX: u32;
    /// As `u32`.
    fn get(self) -> u32;
    /// From `u32` (saturating at `MAX`).
    fn set(v: u32) -> Self;
    /// Moves the value, read as a probability `self / MAX`, by `2^-shift` of the way towards
    /// `target_q16 / 2^16` (rounded to nearest): the Rao-Blackwellised estimator's update.
    #[inline]
    fn ema(self, target_q16: u32, shift: u8) -> Self {
        let t = Self::from_probability_q16(target_q16).get();
        Self::set(ema_u32(self.get(), t, shift))
    }
    /// [`Count::ema`] towards 0 or 1.
    #[inline]
    fn ema_bit(self, occupied: bool, shift: u8) -> Self {
        Self::set(ema_u32(
            self.get(),
            if occupied { Self::MAX } else { 0 },
            shift,
        ))
    }
    /// [`Count::ema_bit`] of the `n` cells `counts[start..start + n]` towards bit `k` of `bits`
    /// for cell `k` (cells out of range are skipped): what every patch update does per row.
    /// `dither` is a uniformly random word: `u8` estimates round stochastically with its byte
    /// `k` for cell `k` (see the `u8` implementation); wider counts round to nearest and
    /// ignore it.
    #[inline]
    fn average_row(counts: &mut [Self], start: usize, n: usize, bits: u32, shift: u8, dither: u32) {
        let _ = dither;
        if let Some(row) = counts.get_mut(start..start + n) {
            for (k, c) in row.iter_mut().enumerate() {
                *c = c.ema_bit(bits >> k & 1 != 0, shift);
            }
        }
    }
    /// [`Count::average_row`] of the three rows of a 3 × 3 patch, row r starting at
    /// `start + r · width` with bits `3r ..= 3r + 2` of `config` and dither
    /// `dither.rotate_right(8 r)`.
    #[inline]
    fn average_patch3(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: u8,
        dither: u32,
    ) {
        average_rows(counts, start, width, config, shift, dither);
    }
    /// [`Count::average_patch3`] with the shift's derived masks ([`AverageShift`], computed
    /// once per tile visit instead of once per update).
    #[inline]
    fn average_patch3_at(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: &AverageShift,
        dither: u32,
    ) {
        Self::average_patch3(counts, start, width, config, shift.shift, dither);
    }
    /// The value of probability `p_q16 / 2^16` (clamped to 1), rounded to nearest.
    #[inline]
    fn from_probability_q16(p_q16: u32) -> Self {
        let p = p_q16.min(1 << 16);
        Self::set(if Self::MAX <= 0xFFFF {
            // < 2^16 · 2^16: fits (32-bit arithmetic for u8/u16 counts).
            (p * Self::MAX + (1 << 15)) >> 16
        } else {
            ((u64::from(p) * u64::from(Self::MAX) + (1 << 15)) >> 16) as u32
        })
    }
}

/// `m + round((t − m) / 2^shift)`, within `[min(m, t), max(m, t)]`, for any `u32` (the
/// estimate settles within half a step of its target); shift 0 → `t`. Branch-free 32-bit
/// arithmetic when both fit 16 bits (`u8`/`u16` counts), 64-bit otherwise.
#[inline]
fn ema_u32(m: u32, t: u32, shift: u8) -> u32 {
    let s = u32::from(shift.min(31));
    if s == 0 {
        return t;
    }
    let half = 1i64 << (s - 1);
    if m <= 0xFFFF && t <= 0xFFFF {
        // |t − m| < 2^16: no overflow; the arithmetic shift rounds half-steps up.
        let (m, t) = (m as i32, t as i32);
        return (m + ((t - m + half as i32) >> s)) as u32;
    }
    let (m, t) = (i64::from(m), i64::from(t));
    (m + ((t - m + half) >> s)) as u32
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
impl_count!(u16, u32);

impl Count for u8 {
    const MAX: u32 = 255;
    #[inline]
    fn get(self) -> u32 {
        u32::from(self)
    }
    #[inline]
    fn set(v: u32) -> Self {
        v.min(255) as u8
    }
    /// Three cells at once in one 32-bit word (SIMD within a register; the firmware's hot path),
    /// with stochastic rounding so that long averages stay unbiased in 8 bits: cell `k` moves
    /// `⌊(d + u_k mod 2^s) / 2^s⌋` towards its target, `d` its distance to the target (`m` or
    /// `255 − m`), `s = min(shift, 7)` and `u_k` byte `k` of `dither`. The expected move is
    /// exactly `d / 2^s`, where truncation (what an 8-bit average of fixed rounding does) would
    /// lose up to one LSB a step and stop a rarely occupied cell from ever registering at
    /// `s` ≥ 5. A fourth byte rides along unchanged.
    #[inline]
    fn average_row(counts: &mut [Self], start: usize, n: usize, bits: u32, shift: u8, dither: u32) {
        let Some(w4) = counts.get_mut(start..start + 4).filter(|_| n == 3) else {
            // Not a 3-cell row with a byte after it: one cell at a time, the same rule.
            if let Some(row) = counts.get_mut(start..start + n) {
                for (k, c) in row.iter_mut().enumerate() {
                    *c = average_byte(
                        *c,
                        bits >> k & 1 != 0,
                        shift,
                        (dither >> (8 * (k & 3))) as u8,
                    );
                }
            }
            return;
        };
        let mut bytes = [0u8; 4];
        bytes.copy_from_slice(w4);
        let m = u32::from_le_bytes(bytes);
        w4.copy_from_slice(&average_word(m, bits, &AverageShift::new(shift), dither).to_le_bytes());
    }
    #[inline]
    fn average_patch3(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: u8,
        dither: u32,
    ) {
        Self::average_patch3_at(
            counts,
            start,
            width,
            config,
            &AverageShift::new(shift),
            dither,
        );
    }
    /// The robot's hot path: one bounds check for the patch, three unaligned word updates.
    #[inline]
    fn average_patch3_at(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: &AverageShift,
        dither: u32,
    ) {
        let Some(area) = counts.get_mut(start..start + 2 * width + 4) else {
            // At the map's last cell there is no byte after the patch: the general path.
            average_rows_u8(counts, start, width, config, shift.shift, dither);
            return;
        };
        for r in 0..3 {
            let Some(w4) = area
                .get_mut(r * width..r * width + 4)
                .and_then(|w| <&mut [u8; 4]>::try_from(w).ok())
            else {
                continue;
            };
            let d = row_dither(dither, r);
            *w4 = average_word(u32::from_le_bytes(*w4), config >> (3 * r), shift, d).to_le_bytes();
        }
    }
}

/// [`Count::average_patch3`] for `u8` a row at a time: where the patch has no byte after it.
/// Out of line and cold, so that the hot path's registers are not planned around it.
#[cold]
#[inline(never)]
fn average_rows_u8(
    counts: &mut [u8],
    start: usize,
    width: usize,
    config: u32,
    shift: u8,
    dither: u32,
) {
    average_rows(counts, start, width, config, shift, dither);
}

/// The body of [`Count::average_patch3`]'s default: [`Count::average_row`] of each of the
/// patch's three rows. One copy for the default and [`average_rows_u8`] (which `u8`'s override
/// cannot reach through the trait method: it would call itself).
#[inline(always)]
fn average_rows<N: Count>(
    counts: &mut [N],
    start: usize,
    width: usize,
    config: u32,
    shift: u8,
    dither: u32,
) {
    for r in 0..3 {
        N::average_row(
            counts,
            start + r * width,
            3,
            config >> (3 * r),
            shift,
            row_dither(dither, r),
        );
    }
}

/// The dither of row `r` of a patch: the patch's word rotated by `8 r` bits, so the three cells
/// of a column take different bytes. Every averaging path takes its rows' dither from here.
#[inline]
fn row_dither(dither: u32, r: usize) -> u32 {
    dither.rotate_right(8 * r as u32)
}

/// The `u8` rule of [`Count::average_row`] for one cell: moves `m` towards 255 (`occupied`) or
/// 0 by `⌊(d + u mod 2^s) / 2^s⌋`, `d` the distance, `s = min(shift, 7)`.
#[inline]
pub fn average_byte(m: u8, occupied: bool, shift: u8, u: u8) -> u8 {
    let s = u32::from(shift.min(7));
    let d = if occupied {
        255 - u32::from(m)
    } else {
        u32::from(m)
    };
    // ≤ 255 + 127 before the shift; the step is ≤ d.
    let step = ((d + (u32::from(u) & ((1 << s) - 1))) >> s) as u8;
    if occupied {
        m.saturating_add(step)
    } else {
        m.saturating_sub(step)
    }
}

/// An averaging shift and what [`average_word`] derives from it: `s = min(shift, 7)`, the
/// remainder mask `2^s − 1` and the quotient mask `0xFF >> s` in bytes 0..3.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AverageShift {
    shift: u8,
    s: u32,
    low: u32,
    quotient: u32,
}

impl AverageShift {
    /// The masks of `shift`. Not inlined: once per tile visit.
    #[inline(never)]
    pub fn new(shift: u8) -> Self {
        const LANES: u32 = 0x0001_0101;
        let s = u32::from(shift.min(7));
        AverageShift {
            shift,
            s,
            low: ((1 << s) - 1) * LANES,
            quotient: (0xFF >> s) * LANES,
        }
    }

    /// The shift.
    #[inline]
    pub fn shift(&self) -> u8 {
        self.shift
    }
}

/// [`average_word`]'s byte masks: byte k of entry t is 0xFF iff bit k of t is set.
static FLIP: [u32; 8] = build_flip();

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_flip() -> [u32; 8] {
    let mut f = [0u32; 8];
    let mut t = 0;
    while t < 8 {
        f[t] = ((t as u32 & 1) | (t as u32 & 2) << 7 | (t as u32 & 4) << 14) * 0xFF;
        t += 1;
    }
    f
}

/// [`average_byte`] of three `u8` cells packed in bytes 0..3 of `m`, towards bits 0..3 of
/// `bits`, with byte `k` of `dither` for cell `k`; byte 3 is unchanged. Branch-free: the bytes
/// whose target is 255 are complemented so that every target is 0, the distance's quotient and
/// the dithered remainder's carry are taken bytewise (neither crosses a byte: the remainder
/// and the dither are < 2^s ≤ 128 each), subtracted, and complemented back.
#[inline]
fn average_word(m: u32, bits: u32, shift: &AverageShift, dither: u32) -> u32 {
    let (s, low) = (shift.s, shift.low);
    // Bytes 0..3 = 0xFF where bit k of bits is set: one load (the bit spreading was six
    // instructions a row on the M4).
    let flip = FLIP.get((bits & 7) as usize).copied().unwrap_or(0);
    let d = m ^ flip;
    let quotient = (d >> s) & shift.quotient;
    // The sum is < 2^(s+1) per byte: its bit s is the carry. Masked with `!low` before the
    // shift, not with LANES after it, so the averaging needs one constant less in a register.
    let carry = (((d & low) + (dither & low)) & !low) >> s;
    // Per byte the step is ≤ d: no borrow between bytes.
    (d - (quotient + carry)) ^ flip
}

/// A candidate configuration with its log-prior (LSB units of [`crate::types::fixed::LSB_NATS`]).
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
    /// of a cell, in [`crate::sampler::patch`]'s bit order) into `out`, most probable first, and returns
    /// how many were written: at least 1 whenever `out` is not empty.
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize;
    /// [`PatchPrior::candidates`] for the sampler, which may remember results (the default does
    /// not): the same candidates for the same `border` and `out.len()`.
    #[inline]
    fn candidates_cached(&mut self, border: u16, out: &mut [PatchCandidate]) -> usize {
        self.candidates(border, out)
    }
    /// The candidates of `border` as static tables (configurations, log-priors; most probable
    /// first), when the prior stores them that way: lets the sampler's hot path read flash
    /// directly instead of copying. `None` (the default): use [`PatchPrior::candidates`].
    #[inline]
    fn table(&mut self, _border: u16) -> Option<(&'static [u16], &'static [i16])> {
        None
    }
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
    /// larger (see [`local`]).
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

/// Counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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
    /// Local rays examined for a patch (the block index's candidates).
    pub rays_examined: u64,
    /// Tile visits started.
    pub tile_visits: u64,
    /// Rays gathered into local lists, over all visits.
    pub rays_gathered: u64,
    /// Rays that crossed a tile but did not fit the local list.
    pub local_overflow: u64,
    /// Completed sweeps.
    pub sweeps: u32,
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

/// Entries of [`Gibbs`]'s estimate-restart memo (a power of two: the slot is the value's low
/// bits).
const RESTARTS: usize = 64;

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
    stats: SamplerStats,
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
fn weight_q16(d: u32) -> u32 {
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
fn next_gap(period: u32, rng: &mut Xoshiro128PlusPlus) -> u32 {
    1 + below(rng.next_u32(), period)
}

/// Uniform integer in `0..n` from a 32-bit random number (Lemire's multiply-shift).
#[inline]
fn below(r: u32, n: u32) -> u32 {
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
fn hybrid_gain(gain_q8: u16, s: &crate::sampler::ray_store::StoreStats) -> i32 {
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
            stats: SamplerStats::default(),
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
    fn set_occupied(&mut self, index: usize, v: bool) {
        if let Some(w) = self.buf.sample.as_mut().get_mut(index / 32) {
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

    /// `n` ≤ 25 consecutive sample bits starting at cell `index` (row-major), bit 0 first.
    #[inline]
    fn bits(&self, index: usize, n: u32) -> u32 {
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

    /// Tells the sampler that a scan changed cell `index`'s log-odds from `before` to `now`
    /// (what [`crate::session::Session::insert`] does for every cell it updates): marks its
    /// tile for a visit ([`SamplerConfig::hot_share`]) and, with [`Estimator::Average`]'s
    /// `reset_on_change`, restarts its estimate at `now`'s probability if the cell was
    /// unobserved (`before` = 0) or the sign of its evidence flipped. Evidence that only grew
    /// stronger keeps the estimate: on the simulated runs that is +0.002 to +0.007 of online
    /// max F1 at the same update count, and fewer instructions per scan (docs/results.md).
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

    /// The evidence gains in effect: the configured ones, scaled by the dropped share of the
    /// beams for [`DataTerm::Hybrid`], none for [`DataTerm::Rays`].
    fn set_gains(&mut self, store: &crate::sampler::ray_store::StoreStats) {
        let g = i32::from(self.config.evidence_gain_q8);
        self.ev_gain = match self.config.data {
            DataTerm::Evidence => g,
            DataTerm::Hybrid => hybrid_gain(self.config.evidence_gain_q8, store),
            DataTerm::Rays => 0,
        };
        // ≤ 2^12 · 2^12 before the shift.
        self.ev_free_gain = (self.ev_gain * i32::from(self.config.evidence_free_q8)) >> 8;
    }

    /// Picks a tile — a changed one for [`SamplerConfig::hot_share`] of the visits, else a
    /// uniformly random one — and gathers the rays its patches can meet.
    fn start_visit<S, R>(&mut self, store: &mut RayStore<S, R>)
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

    /// Collects the rays visiting the box of `grid` into the local list and block bitsets.
    fn gather<S, R>(&mut self, store: &mut RayStore<S, R>, grid: BlockGrid)
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
        self.stats.rays_gathered += self.n_local as u64;
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
    fn config_and_border(&self, c: CellCoord) -> (u16, u16) {
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

    fn update_one<S, R>(&mut self, store: &mut RayStore<S, R>, map: &[LogOdds])
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
    fn random_patch<S, R>(
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
    fn update_at<S, R>(
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

    /// [`DataTerm::Evidence`]'s update straight from the prior's flash tables (the hot path on
    /// the robot: no candidate copies, no ray work). The same distribution as the general path:
    /// candidates are the top-k of `configs` plus, with [`SamplerConfig::data_candidate`], the
    /// evidence's own configuration at the floor log-prior; weights are log-prior + evidence.
    /// Returns the new configuration (and updates the estimates), and whether it was the only
    /// candidate (the caller counts those in [`SamplerStats::single_candidate`]).
    #[allow(clippy::too_many_arguments)]
    fn evidence_update(
        &mut self,
        map: &[LogOdds],
        centre: CellCoord,
        current: u16,
        (known, occupied): (u16, u16),
        configs: &'static [u16],
        log_priors: &'static [i16],
    ) -> (u16, bool) {
        let k = usize::from(self.ev_k)
            .min(configs.len())
            .min(log_priors.len());
        let (configs, log_priors) = (
            configs.get(..k).unwrap_or(&[]),
            log_priors.get(..k).unwrap_or(&[]),
        );
        // The evidence's own configuration, a candidate (at the floor log-prior) when the
        // prior's top-k lacks it: checked against the first candidate here, and against the
        // others in the weights' pass (it is only needed where there are weights).
        let data_candidate = self.config.data_candidate;
        let d = (current & !known) | occupied;
        let first = configs.first().copied().unwrap_or(current);
        if k <= 1 && (!data_candidate || (k == 1 && first == d)) {
            self.average_config(centre, first);
            return (first, true);
        }
        let floor = i32::from(self.config.floor_log_prior);
        // The patch's log-odds, read only now that weights are needed, and only if a cell has
        // any (unobserved patches, common in the uniform share of tile visits, weigh by the
        // prior alone).
        let ev = if known != 0 {
            evidence::PatchTerms::new(
                map,
                usize::from(self.geometry.width()),
                centre,
                self.ev_gain,
                self.ev_free_gain,
            )
        } else {
            evidence::PatchTerms::default()
        };
        // Log-weights, the extra candidate last, and the best of them in the same pass; then,
        // in place, the weights (`weights_q16`'s, one array instead of two). The array is the
        // sampler's scratch: only its first `n` entries are read, each written first (a local
        // array would be zeroed on every update).
        let q = &mut self.scratch;
        let mut best = i32::MIN;
        let mut listed = false;
        for ((qi, &c), &lp) in q.iter_mut().zip(configs).zip(log_priors) {
            let w = i32::from(lp) + ev.of(c);
            best = best.max(w);
            *qi = w as u32;
            listed |= c == d;
        }
        let extra = (data_candidate && !listed).then_some(d);
        let n = match extra {
            Some(d) => {
                let w = floor + ev.of(d);
                best = best.max(w);
                if let Some(qi) = q.get_mut(k) {
                    *qi = w as u32;
                }
                k + 1
            }
            None => k,
        };
        // `weights_q16`'s loop, in place, without its saturation: a log-weight is an i16
        // log-prior plus nine cells' |log-odds| ≤ 2^15 times a gain ≤ 2^16 (Q8), so `best − w`
        // is below 2^29, and the sum of at most 17 weights ≤ 2^16 is below 2^21.
        let mut total = 0u32;
        for qi in q.iter_mut().take(n) {
            *qi = weight_q16(best.wrapping_sub(*qi as i32) as u32);
            total = total.wrapping_add(*qi);
        }
        let config_of = |j: usize| configs.get(j).copied().or(extra).unwrap_or(current);
        let mut r = below(self.rng.next_u32(), total.max(1));
        let mut new = first;
        for (j, &qj) in q.iter().take(n).enumerate() {
            if r < qj {
                new = config_of(j);
                break;
            }
            r -= qj;
        }
        if cfg!(feature = "rao-blackwell") && self.config.estimator.rao_blackwellised() {
            let mut cands = [PatchCandidate::default(); MAX_CANDIDATES + 1];
            for (j, c) in cands.iter_mut().enumerate().take(n) {
                c.config = config_of(j);
            }
            let q = self.scratch;
            self.rao_blackwell(
                centre,
                cands.get(..n).unwrap_or(&[]),
                q.get(..n).unwrap_or(&[]),
                total,
                new,
            );
        } else {
            self.average_config(centre, new);
        }
        (new, false)
    }

    /// The candidates of the patch at `centre` (the prior's top-k, plus the evidence's own
    /// configuration with [`SamplerConfig::data_candidate`]) into `cands`, and in `w` their
    /// log-prior plus the evidence term; returns how many.
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

    /// [`Estimator::Average`] after a multi-candidate update that drew `drawn`: with
    /// `rao_blackwell`, moves every cell's estimate towards its conditional occupancy
    /// probability, Σ of the weights `q` of the candidates that occupy it over their sum `total`;
    /// otherwise towards the draw.
    fn rao_blackwell(
        &mut self,
        centre: CellCoord,
        cands: &[PatchCandidate],
        q: &[u32],
        total: u32,
        drawn: u16,
    ) {
        let Estimator::Average { rao_blackwell, .. } = self.config.estimator else {
            return;
        };
        if !cfg!(feature = "rao-blackwell") || !rao_blackwell || total == 0 {
            self.average_config(centre, drawn);
            return;
        }
        // Each cell's occupied weight, one pass over the candidates' set bits; weights in Q11
        // so that occ · 2^16 fits a u32 (Σ q ≤ 17 · 2^11 < 2^16) and the division is one
        // hardware instruction.
        let mut occ = [0u32; 9];
        let mut tot = 0u32;
        for (k, &x) in cands.iter().zip(q) {
            let x = x >> 5;
            tot += x;
            let mut c = k.config;
            while c != 0 && x != 0 {
                let b = c.trailing_zeros() as usize;
                c &= c - 1;
                if let Some(o) = occ.get_mut(b) {
                    *o += x;
                }
            }
        }
        let tot = tot.max(1);
        let shift = self.visit_shift.shift;
        self.for_patch_counts(centre, |bit, c| {
            let o = occ.get(bit as usize).copied().unwrap_or(0);
            *c = c.ema((o << 16) / tot, shift);
        });
    }

    /// [`Estimator::Average`] towards a configuration: each cell's value is 0 or 1.
    #[inline]
    fn average_config(&mut self, centre: CellCoord, config: u16) {
        if self.config.estimator == Estimator::Counts {
            return;
        }
        let shift = &self.visit_shift;
        // xorshift32 (Marsaglia 2003): full period over the non-zero words.
        let mut dither = self.dither;
        dither ^= dither << 13;
        dither ^= dither >> 17;
        dither ^= dither << 5;
        self.dither = dither;
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let width = usize::from(self.geometry.width());
        let counts = self.buf.counts.as_mut();
        if size == 3 {
            // Patch centres keep the prior's margin from the edge: the patch is in the map.
            let start = (centre.y - 1) as usize * width + (centre.x - 1) as usize;
            N::average_patch3_at(counts, start, width, u32::from(config), shift, dither);
            return;
        }
        for (r, dy) in (-h..=h).enumerate() {
            // Patch centres keep the prior's margin from the edge: the row is in the map.
            let start = (centre.y + dy) as usize * width + (centre.x - h) as usize;
            let bits = u32::from(config) >> (r as i32 * size);
            N::average_row(
                counts,
                start,
                size as usize,
                bits,
                shift.shift,
                row_dither(dither, r),
            );
        }
    }

    /// Calls `f(bit, count)` for the marginal count of every cell of the patch at `centre`.
    #[inline]
    fn for_patch_counts(&mut self, centre: CellCoord, mut f: impl FnMut(u32, &mut N)) {
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let width = usize::from(self.geometry.width());
        let counts = self.buf.counts.as_mut();
        let mut bit = 0u32;
        for dy in -h..=h {
            // Patch centres keep the prior's margin from the edge: the row is in the map.
            let start = (centre.y + dy) as usize * width + (centre.x - h) as usize;
            let Some(row) = counts.get_mut(start..start + size as usize) else {
                return;
            };
            for c in row {
                f(bit, c);
                bit += 1;
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
    fn log_weights<S, R>(
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
        self.stats.rays_examined += examined;
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
    fn apply<S, R>(
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

    /// Writes the `n` ≤ 31 bits `v` into the sample at cells `index..index + n`. Not inlined:
    /// its callers (a changed patch's rows, a raster run's rows) are not the hot path.
    #[inline(never)]
    fn set_bits(&mut self, index: usize, n: u32, v: u32) {
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

    /// [`Gibbs::accumulate`] after `n` updates: at once for [`Estimator::Average`], whose
    /// estimates move in the update itself (only the sweep count is kept here).
    fn accumulate_n(&mut self, n: u32) {
        if self.config.estimator == Estimator::Counts {
            // (`accumulate` stays out of line: inlined in this loop it cost 2 KiB of flash.)
            for _ in 0..n {
                self.accumulate();
            }
            return;
        }
        self.count_sweeps(n);
    }

    /// The sweep count after `n` more updates, as `n` single steps: each wraps at `sweep_len`
    /// (≥ 1) and counts a sweep. Saturating: only a budget near 2^32 in one call could reach
    /// it, and it would only undercount sweeps (a 32-bit division; a 64-bit one is a library
    /// call on the M4).
    #[inline]
    fn count_sweeps(&mut self, n: u32) {
        let total = self.in_sweep.saturating_add(n);
        let len = self.sweep_len.max(1);
        self.stats.sweeps = self.stats.sweeps.saturating_add(total / len);
        self.in_sweep = total % len;
    }

    /// Advances the marginal-accumulation cursor by L cells; counts sweeps.
    #[inline(never)]
    fn accumulate(&mut self) {
        if self.config.estimator != Estimator::Counts {
            // Only the sweep count.
            self.count_sweeps(1);
            return;
        }
        let size = usize::from(self.prior.size());
        let k = self.geometry.len();
        let counting = self.stats.sweeps >= self.config.burn_in_sweeps
            && self.config.estimator == Estimator::Counts;
        if counting && self.cursor == 0 {
            self.halving = self.samples >= N::MAX;
        }
        if counting {
            let end = (self.cursor + size * size).min(k);
            for i in self.cursor..end {
                let bit = u32::from(self.occupied(i));
                let halving = self.halving;
                if let Some(c) = self.buf.counts.as_mut().get_mut(i) {
                    *c = N::set(if halving {
                        c.get() / 2 + bit
                    } else {
                        c.get() + bit
                    });
                }
            }
        }
        self.cursor = (self.cursor + size * size).min(k);
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

/// Crossings the likelihood computed for one patch, reused by the cache update.
struct CrossingCache {
    items: [(u32, Crossing); CrossingCache::CAP],
    n: usize,
    /// Every crossing of the patch is in `items`.
    valid: bool,
}

impl CrossingCache {
    /// Enough for a well-observed patch; more crossings fall back to recomputation.
    const CAP: usize = 48;

    fn new() -> Self {
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

    fn get(&self) -> Option<&[(u32, Crossing)]> {
        if self.valid {
            self.items.get(..self.n)
        } else {
            None
        }
    }
}

/// How a ray crosses a patch.
#[derive(Clone, Copy, Debug)]
struct Crossing {
    /// (step, patch bit) of the patch cells on the ray, in ray order (a Bresenham ray visits at
    /// most 3 cells of a 3×3 box: one per major coordinate).
    cells: [(u16, u16); 3],
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::noise::free_evidence_q8;
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
            }
        }
    }
}
