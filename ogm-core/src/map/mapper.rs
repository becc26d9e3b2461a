//! Online log-odds mapping: one scan at a time, with the inverse sensor model.
//!
//! Within one scan every cell changes at most once, and **hits win**: a cell that is the end of
//! some beam gets the occupied update even if other beams of the same scan pass through it
//! (Cartographer does the same). This makes the result independent of the order of beams and of
//! how densely beams overlap near the robot. A bitset with one bit per cell (caller-provided,
//! `⌈K/32⌉` words) records which cells this scan touched; only the words of the scan's box are
//! cleared afterwards.
//!
//! Speed (docs/insertion.md, docs/benchmarks.md "Online insertion"): the [`Mapper`]'s beam model
//! marks every ray's cells without testing them, run by run where a ray's runs allow it
//! ([`crate::map::ray`]), then applies the hits in beam order and sweeps the marks of the scan's box
//! for the freed cells (`insert_beam_model`).
//!
//! Beam handling: a `Hit` closer than `min_range_mm` is dropped (counted); a `Hit` at or beyond
//! `max_range_mm`, and every `NoReturn`, frees cells up to `max_range_mm` and marks nothing
//! occupied. Rays are clipped to the grid exactly (see [`crate::map::ray`]), so poses and readings
//! outside the map are harmless.
//!
//! The classification (which cell gets which update) is [`classify_scan`], which the f64
//! reference ([`crate::reference`]) and the [`Mapper`]'s cone model run; the [`Mapper`]'s beam
//! model computes the same updates its own way (property-tested against it, cell for cell), so
//! the fixed-point and f64 mappers can only differ in arithmetic.

use crate::error::{Error, Result};
use crate::map::grid::LogOddsGrid;
use crate::map::ray::{GridRay, IndexWalk, Ray, Steps};
use crate::map::sensor_model::{
    face_band_delta, InverseModelKind, InverseSensorModel, FACE_BAND_REACH_EIGHTHS,
};
use crate::types::angle::Angle;
use crate::types::fixed::{Clamp, LogOdds};
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::{Beam, Range};

/// Mapper settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MapperConfig {
    /// The inverse sensor model.
    pub model: InverseSensorModel,
    /// Log-odds bounds.
    pub clamp: Clamp,
    /// Readings at or beyond this range count as "no return" (free space only).
    pub max_range_mm: u32,
    /// Readings closer than this are dropped (sensor dead zone, robot body).
    pub min_range_mm: u32,
}

impl MapperConfig {
    /// Hähnel model, default clamp, the given maximum range, no minimum range.
    pub fn new(max_range_mm: u32) -> Self {
        MapperConfig {
            model: InverseSensorModel::hahnel(),
            clamp: Clamp::default(),
            max_range_mm,
            min_range_mm: 0,
        }
    }

    /// Checks that the model's increments fit inside the clamp and the range is sane (and, in a
    /// build without the `cone` feature, that the model is not the cone model).
    pub fn validate(&self) -> Result<()> {
        let span = self.clamp.span();
        if self.model.occ_increment().0 > span || self.model.free_increment().0 < -span {
            return Err(Error::InvalidModel);
        }
        if self.max_range_mm == 0 || self.min_range_mm >= self.max_range_mm {
            return Err(Error::InvalidModel);
        }
        if !cfg!(feature = "cone") && matches!(self.model.kind(), InverseModelKind::Cone { .. }) {
            return Err(Error::InvalidModel);
        }
        Ok(())
    }
}

/// What a scan did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanStats {
    /// Beams that were used.
    pub beams_used: u32,
    /// Beams dropped (closer than the minimum range).
    pub beams_dropped: u32,
    /// Cells that received the occupied update.
    pub cells_hit: u32,
    /// Cells that received the free update.
    pub cells_freed: u32,
}

/// The update a cell receives from a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellUpdate {
    /// Occupied (`l_occ − l₀`).
    Hit,
    /// Free (`l_free − l₀`).
    Free,
    /// In a reading's face band ([`InverseModelKind::FaceBand`]), this many eighths of σ past
    /// the reading (within ±[`crate::map::sensor_model::FACE_BAND_REACH_EIGHTHS`]):
    /// `Φ(t)·(l_occ − l₀) + (1 − Φ(t))·(l_free − l₀)`.
    Face(i8),
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

/// Who hears about a scan's updates ([`Mapper::insert_scan_into`]). Each cell changes at most
/// once per scan: with the beam model first the hit cells in beam order (with the face band,
/// each beam's band cells in turn, a band's from either end), then the freed cells in increasing
/// index order; with the cone model in [`classify_scan`]'s order.
///
/// Why not a closure per cell: the online sampler needs every changed cell's *tile* but the
/// values of only a few cells; with [`Reports::Notable`] it learns the tiles from the scan's mark
/// words (a few tiles per word) and the values of the notable cells: on the Cortex-M4 its share
/// of the per-scan step fell from ~83 to ~18 instructions per updated cell (docs/benchmarks.md).
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
struct EachCell<F>(F);

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
fn hears<L: UpdateListener>(before: LogOdds, after: LogOdds) -> bool {
    match L::REPORTS {
        Reports::Nothing => false,
        Reports::Notable => notable(before, after),
        Reports::Every => true,
    }
}

/// Words of scan-mark bitset needed for `cells` cells.
pub const fn marks_len(cells: usize) -> usize {
    cells.div_ceil(32)
}

/// One bit per cell, with the range of words touched this scan, so clearing is proportional to
/// the scan rather than to the grid.
///
/// The range is not tracked per cell (that kept two more live values in the hot loop, which a
/// Cortex-M4 spilled to the stack) but per ray: a ray's cells lie in the rows between its end
/// cells, so the words of those rows are covered.
struct Marks<'a> {
    words: &'a mut [u32],
    lo: usize,
    hi: usize,
}

impl<'a> Marks<'a> {
    fn new(words: &'a mut [u32]) -> Self {
        Marks {
            words,
            lo: usize::MAX,
            hi: 0,
        }
    }

    /// Sets the bit; returns `true` if it was clear (first touch in this scan). The caller
    /// records the word range with [`Marks::cover`].
    #[inline(always)]
    fn first_touch(words: &mut [u32], index: usize) -> bool {
        let (w, bit) = (index / 32, 1u32 << (index % 32));
        match words.get_mut(w) {
            Some(word) if *word & bit == 0 => {
                *word |= bit;
                true
            }
            _ => false,
        }
    }

    /// Records that cells with indices in `lo..=hi` may have been marked.
    #[inline]
    fn cover(&mut self, lo: usize, hi: usize) {
        self.lo = self.lo.min(lo / 32);
        self.hi = self.hi.max(hi / 32);
    }

    /// Records that a ray between cells `a` and `b` may have marked cells: its cells lie in the
    /// rows between its end cells, and in the grid.
    #[inline]
    fn cover_rows(&mut self, a: CellCoord, b: CellCoord, width: u16, height: u16) {
        let w = usize::from(width);
        let (y0, y1) = (a.y.min(b.y).max(0), a.y.max(b.y).min(i32::from(height) - 1));
        if y0 <= y1 {
            // 0 ≤ y0 ≤ y1 < height.
            self.cover(y0 as usize * w, y1 as usize * w + (w - 1));
        }
    }
}

impl Drop for Marks<'_> {
    fn drop(&mut self) {
        if self.lo <= self.hi {
            let hi = self.hi.min(self.words.len().saturating_sub(1));
            if let Some(ws) = self.words.get_mut(self.lo..=hi) {
                ws.fill(0);
            }
        }
    }
}

/// Cells a ray is marked in at a time before their updates are applied.
const CHUNK: usize = 128;

/// Whether [`mark_chunk`] marks without a data-dependent branch. Whether a cell was touched
/// before in this scan is hard to predict (rays overlap near the robot and part ways further out),
/// which costs a deeply pipelined host core more than the extra work of always storing; an
/// in-order microcontroller core has no such penalty to avoid and runs fewer instructions with
/// the branch (Cortex-M4 under QEMU: 53 vs 62 instructions per updated cell). 64-bit targets
/// stand for the former, 32-bit ones for the latter; both variants give identical results.
const BRANCH_FREE_MARKING: bool = cfg!(target_pointer_width = "64");

/// Marks up to [`CHUNK`] cells of `walk` and writes the indices of those it touched first this
/// scan to `out`; returns how many. Not inlined, so that its loop gets the registers to itself.
#[inline(never)]
fn mark_chunk<const BRANCH_FREE: bool>(
    walk: &mut IndexWalk,
    words: &mut [u32],
    out: &mut [u32; CHUNK],
) -> usize {
    let mut wk = *walk;
    let m = wk.take(CHUNK as u32);
    let mut n = 0usize;
    for _ in 0..m {
        let i = wk.index();
        let (w, bit) = (i / 32, 1u32 << (i % 32));
        if let Some(word) = words.get_mut(w) {
            let old = *word;
            if BRANCH_FREE {
                // Always set the bit and store the index; only a first touch advances `n`.
                *word = old | bit;
                // n ≤ cells visited so far < m ≤ CHUNK, a power of two: the mask changes
                // nothing, it only lets the compiler drop the bounds check. Grid indices are
                // < 2^32.
                if let Some(slot) = out.get_mut(n & (CHUNK - 1)) {
                    *slot = i as u32;
                }
                n += usize::from(old & bit == 0);
            } else if old & bit == 0 {
                *word = old | bit;
                if let Some(slot) = out.get_mut(n & (CHUNK - 1)) {
                    *slot = i as u32;
                }
                n += 1;
            }
        }
        wk.advance();
    }
    *walk = wk;
    n
}

/// [`GridGeometry::cell_of_point`] with 32-bit division when the operands fit (a Cortex-M4
/// divides `i32` in hardware but `i64` in a library routine); identical results.
#[derive(Clone, Copy)]
struct PointToCell {
    geometry: GridGeometry,
    origin: (i64, i64),
    cell_mm: i32,
    /// On a 64-bit host, division by the cell size as a multiply ([`FloorDiv`]); a 32-bit
    /// core divides in one instruction and keeps this struct as small as before.
    #[cfg(target_pointer_width = "64")]
    by_cell: Option<FloorDiv>,
}

impl PointToCell {
    fn new(geometry: &GridGeometry) -> Self {
        let (ox, oy) = geometry.origin_mm();
        // 0 (never: a geometry's cell size is ≥ 1) or > i32::MAX selects the slow path.
        let cell_mm = i32::try_from(geometry.cell_mm()).unwrap_or(0);
        PointToCell {
            geometry: *geometry,
            origin: (i64::from(ox), i64::from(oy)),
            cell_mm,
            #[cfg(target_pointer_width = "64")]
            by_cell: FloorDiv::new(cell_mm),
        }
    }

    #[inline]
    fn cell(&self, x_mm: i64, y_mm: i64) -> CellCoord {
        let dx = i32::try_from(x_mm.saturating_sub(self.origin.0));
        let dy = i32::try_from(y_mm.saturating_sub(self.origin.1));
        if let (Ok(dx), Ok(dy)) = (dx, dy) {
            if let Some(c) = self.cell_from_origin(dx, dy) {
                return c;
            }
        }
        self.geometry.cell_of_point(x_mm, y_mm)
    }

    /// The cell of the point `(dx, dy)` mm from the grid's origin, unless the cell size does
    /// not fit an `i32` (then only [`PointToCell::cell`]'s fallback can say).
    #[inline]
    fn cell_from_origin(&self, dx: i32, dy: i32) -> Option<CellCoord> {
        #[cfg(target_pointer_width = "64")]
        if let Some(d) = self.by_cell {
            return Some(CellCoord {
                x: d.floor(dx),
                y: d.floor(dy),
            });
        }
        Some(CellCoord {
            x: dx.checked_div_euclid(self.cell_mm)?,
            y: dy.checked_div_euclid(self.cell_mm)?,
        })
    }
}

/// `⌊n / d⌋` for any `i32` `n` and a fixed `d ≥ 1` as a multiply and a shift: a host's 32-bit
/// division takes several times longer, twice per beam ([`PointToCell::cell_from_origin`]); a
/// Cortex-M4's takes one instruction, so only hosts use this.
///
/// With `ℓ = ⌈log2 d⌉`, `k = 31 + ℓ` and `m = ⌈2^k / d⌉ ≤ 2^32`, `⌊u·m / 2^k⌋ = ⌊u / d⌋` for every
/// `u < 2^31` (`m·d − 2^k < d ≤ 2^ℓ`, so the error `u·(m·d − 2^k)/(d·2^k)` is below `1/d`), and
/// `u·m < 2^63`. A negative `n` is divided as `!n = −n − 1 ≥ 0`: `⌊n/d⌋ = !⌊!n / d⌋`.
#[cfg(any(test, target_pointer_width = "64"))]
#[derive(Clone, Copy, Debug)]
struct FloorDiv {
    m: u64,
    k: u32,
}

#[cfg(any(test, target_pointer_width = "64"))]
impl FloorDiv {
    /// The division by `d`, if `d ≥ 1`.
    fn new(d: i32) -> Option<FloorDiv> {
        let d = u32::try_from(d).ok().filter(|&d| d >= 1)?;
        // ⌈log2 d⌉ ≤ 31.
        let l = 32 - (d - 1).leading_zeros();
        let k = 31 + l;
        Some(FloorDiv {
            m: (1u64 << k).div_ceil(u64::from(d)),
            k,
        })
    }

    #[inline(always)]
    fn floor(self, n: i32) -> i32 {
        // 0 for n ≥ 0, −1 (all ones) for n < 0; u = n or !n, < 2^31.
        let s = n >> 31;
        let u = u64::from((n ^ s) as u32);
        // u < 2^31 and m ≤ 2^32: no overflow; the quotient is < 2^31.
        ((u * self.m) >> self.k) as i32 ^ s
    }
}

/// The range a beam is traced to, and whether it ends in a hit.
fn beam_extent(cfg: &MapperConfig, beam: &Beam) -> Option<(u32, bool)> {
    match beam.range {
        Range::Hit(mm) if mm < cfg.min_range_mm => None,
        Range::Hit(mm) if mm < cfg.max_range_mm => Some((mm, true)),
        Range::Hit(_) | Range::NoReturn => Some((cfg.max_range_mm, false)),
    }
}

/// The face band's geometry: σ and the band's half-width in mm, and the half-width in eighths
/// of σ, Q16.
#[derive(Clone, Copy)]
struct Band {
    sigma_mm: u32,
    reach_mm: u32,
    reach_t: i64,
}

impl Band {
    fn of(cfg: &MapperConfig) -> Option<Band> {
        match cfg.model.kind() {
            InverseModelKind::FaceBand { sigma_mm } => {
                let sigma_mm = sigma_mm.max(1);
                let reach_mm = sigma_mm.saturating_mul(u32::from(FACE_BAND_REACH_EIGHTHS)) / 8;
                Some(Band {
                    sigma_mm,
                    reach_mm,
                    // 8·reach/σ ≤ 12, in Q16.
                    reach_t: ((u64::from(reach_mm) << 19) / u64::from(sigma_mm)) as i64,
                })
            }
            _ => None,
        }
    }

    /// How far a beam's ray is traced: a hit's reading plus the band beyond it.
    fn traced(band: Option<Band>, range: u32, hit: bool) -> u32 {
        match band {
            Some(b) if hit => range.saturating_add(b.reach_mm),
            _ => range,
        }
    }

    /// The first step of the band on a ray of `n` steps traced to `traced` mm for a reading at
    /// `range` mm: the first step at least `reach` before the reading (step k lies k/n of the
    /// way, which is exact along the ray's major axis).
    #[inline]
    fn first_step(&self, range: u32, traced: u32, n: u64) -> u64 {
        let before = range.saturating_sub(self.reach_mm);
        // In 32 bits when the product fits (a robot's readings on a grid of under 2^16 cells a
        // side), else saturating in 64: only absurd rays come near the u64 range.
        match u32::try_from(n).ok().and_then(|n| before.checked_mul(n)) {
            Some(p) => u64::from(p.div_ceil(traced.max(1))),
            None => div_u64(
                u64::from(before).saturating_mul(n),
                u64::from(traced.max(1)),
                true,
            ),
        }
    }

    /// The offset of one step past the one before, in eighths of σ, Q16 (≤ 2^21), on a ray of
    /// `n` steps traced to `traced` mm: each step lies `8·traced/(σ·n)` eighths further on.
    fn step_t(&self, traced: u32, n: u64) -> u64 {
        let den = u64::from(self.sigma_mm).saturating_mul(n.max(1));
        div_u64(u64::from(traced) << 19, den.max(1), false).min(1 << 21)
    }
}

/// `a / b` (`b ≥ 1`), rounded up if `ceil`: one hardware division when both fit a `u32` (a
/// band's set-up on a robot's ranges), else the `u64` routine a 32-bit core calls.
#[inline]
fn div_u64(a: u64, b: u64, ceil: bool) -> u64 {
    let b = b.max(1);
    match (u32::try_from(a), u32::try_from(b)) {
        (Ok(a), Ok(b)) if ceil => u64::from(a.div_ceil(b)),
        (Ok(a), Ok(b)) => u64::from(a / b),
        _ if ceil => a.div_ceil(b),
        _ => a / b,
    }
}

/// One reading's face band on its ray: the band's steps in the grid, and the offset past the
/// reading, in eighths of σ, of each.
struct BandRay {
    ray: Ray,
    end: CellCoord,
    steps: Steps,
    /// Offset of `steps.first` in eighths of σ, Q16.
    t0: i64,
    /// Offset of one step in eighths of σ, Q16 (≤ 2^21).
    dt: i64,
}

impl BandRay {
    /// The offset of `steps.first` and of one step, in eighths of σ, Q16, as `i32`s: a walk over
    /// the band adds `dt` per step. On a band `|t0| ≤ 36·2^16` and every step's offset lies in
    /// `t0 ..= 12·2^16` (`Rays::band`), far inside the `i32` range.
    #[inline]
    fn offsets(&self) -> (i32, i32) {
        let to_i32 = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        (to_i32(self.t0), to_i32(self.dt))
    }

    /// Step `k`'s (`k ≥ steps.first`) offset past the reading in eighths of σ, rounded half
    /// away from zero, clamped to the band: one multiply-add per cell, no division.
    #[inline]
    fn eighths(&self, k: u64) -> i8 {
        // Fewer than 2^20 in-grid steps (the grid is under 2^16 cells a side), dt ≤ 2^21 and
        // |t0| ≤ 2^41: no overflow.
        let j = k.saturating_sub(self.steps.first).min(1 << 20) as i64;
        let t = self.t0 + j * self.dt;
        let r = ((t.unsigned_abs() + (1 << 15)) >> 16).min(u64::from(FACE_BAND_REACH_EIGHTHS));
        // r ≤ 12.
        if t < 0 {
            -(r as i8)
        } else {
            r as i8
        }
    }
}

/// The face table slot ([`face_deltas`]) of an offset `t` in eighths of σ, Q16, on a band
/// (`−36·2^16 ≤ t ≤ 12·2^16`, [`Rays::band`]): [`BandRay::eighths`]'s rounding half away from
/// zero, + [`FACE_LOW`]; the table holds the clamp, so none is needed here.
#[inline(always)]
fn face_slot(t: i32) -> usize {
    // Half away from zero: ⌊(t + 2^15)/2^16⌋ for t ≥ 0, and for t < 0 ⌈(t − 2^15)/2^16⌉, which
    // is ⌊(t + 2^15 − 1)/2^16⌋. Saturating: outside a band's range the slot is past the table.
    let r = t.saturating_add((1 << 15) + (t >> 31)) >> 16;
    r.wrapping_add(FACE_LOW) as usize
}

/// A scan's rays from the pose's cell: where a beam's ray ends and which of its steps lie in
/// the grid. One home for the classification and the fast pass, so the two agree.
struct Rays<'a> {
    g: &'a GridGeometry,
    pose: &'a Pose,
    to_cell: PointToCell,
    origin: CellCoord,
    origin_inside: bool,
    /// The pose relative to the grid's origin, in mm, when both coordinates lie within ±2^30
    /// and the cell size fits an `i32` (every real map): then a beam end's cell is found in
    /// 32 bits ([`Rays::end`]).
    pose_in_grid_mm: Option<(i32, i32)>,
}

/// Readings shorter than this (mm) take [`Rays::end`]'s 32-bit path.
const SHORT_RANGE_MM: u32 = 1 << 30;

impl<'a> Rays<'a> {
    fn new(g: &'a GridGeometry, pose: &'a Pose) -> Self {
        let to_cell = PointToCell::new(g);
        let origin = to_cell.cell(i64::from(pose.x_mm), i64::from(pose.y_mm));
        let within = |v: i64| (v.unsigned_abs() < 1 << 30).then_some(v as i32);
        let pose_in_grid_mm = match (
            to_cell.cell_mm > 0,
            within(i64::from(pose.x_mm) - to_cell.origin.0),
            within(i64::from(pose.y_mm) - to_cell.origin.1),
        ) {
            (true, Some(x), Some(y)) => Some((x, y)),
            _ => None,
        };
        Rays {
            g,
            pose,
            to_cell,
            origin,
            origin_inside: g.contains(origin),
            pose_in_grid_mm,
        }
    }

    /// The cell `range` mm from the pose along `angle`. Out of line: called once per beam, and
    /// its sine lookups and divisions would otherwise be copied into every pass.
    #[inline(never)]
    fn end(&self, range: u32, angle: Angle) -> CellCoord {
        let (dx, dy) = self.pose.beam_offset(angle, range);
        if let Some((px, py)) = self.pose_in_grid_mm.filter(|_| range < SHORT_RANGE_MM) {
            // |p| < 2^30 and |d| ≤ range < 2^30: the point relative to the grid's origin fits
            // an i32, and it is `PointToCell::cell`'s, so the same cell.
            if let Some(c) = self
                .to_cell
                .cell_from_origin(px + dx as i32, py + dy as i32)
            {
                return c;
            }
        }
        let (x, y) = (
            i64::from(self.pose.x_mm) + dx,
            i64::from(self.pose.y_mm) + dy,
        );
        self.to_cell.cell(x, y)
    }

    /// The ray to `end` and its steps in the grid, if any.
    #[inline]
    fn in_grid(&self, end: CellCoord) -> Option<(Ray, Steps)> {
        let ray = Ray::new(self.origin, end);
        // Both ends inside: the whole ray is (what `clip` would find, without its arithmetic).
        let steps = if self.origin_inside && self.g.contains(end) {
            Steps {
                first: 0,
                last: ray.steps(),
            }
        } else {
            ray.clip(self.g.width(), self.g.height())?
        };
        Some((ray, steps))
    }

    /// The ray to `end` when it and the pose's cell are both in the grid (the usual case), set
    /// up in 32 bits; `None` otherwise ([`Rays::in_grid`] then clips it).
    #[inline]
    fn grid_ray(&self, end: CellCoord) -> Option<GridRay> {
        (self.origin_inside && self.g.contains(end))
            .then(|| GridRay::new(self.origin, end, self.g.width()))
    }

    /// The walk over the face band of a reading at `range` mm whose ray (traced to `range` plus
    /// the band's reach) ends at `end`, backwards from `end`, with the offset past the reading of
    /// its first cell (`end`'s) and of each step, in eighths of σ, Q16 (for [`face_slot`]): the
    /// usual case, where the pose's cell and `end` are both in the grid, so the band ends at the
    /// ray's last cell. `None` otherwise ([`Rays::band`] then walks it forwards) or if the band
    /// has no cell.
    ///
    /// The same cells and offsets as [`Rays::band`]'s walk, in reverse, without its clipping and
    /// the division that finds where its walk starts ([`GridRay::walk_back`]): step `k` lies
    /// `(n − k)·dt` before the end, which is `8·reach/σ` past the reading (`reach_t`).
    #[inline]
    fn band_back(
        &self,
        b: Band,
        range: u32,
        end: Option<CellCoord>,
    ) -> Option<(IndexWalk, (i32, i32))> {
        let end = end?;
        let ray = self.grid_ray(end)?;
        let end_index = self.g.index(end)?;
        let n = u64::from(ray.steps());
        let traced = range.saturating_add(b.reach_mm);
        // N < 2^16: the count fits a u32.
        let cells = (n.checked_sub(b.first_step(range, traced, n))? + 1) as u32;
        let walk = ray.walk_back(end_index, cells);
        // reach_t ≤ 12·2^16 and dt ≤ 2^21 (`Band::of`, `Band::step_t`): both fit an i32.
        Some((walk, (b.reach_t as i32, -(b.step_t(traced, n) as i32))))
    }

    /// The face band of a reading at `range` mm along `angle`, if any of it is in the grid;
    /// `end`, if known, is the end cell of its ray (traced to `range` plus the band's reach).
    #[inline(never)]
    fn band(&self, b: Band, range: u32, angle: Angle, end: Option<CellCoord>) -> Option<BandRay> {
        let traced = range.saturating_add(b.reach_mm);
        let end = end.unwrap_or_else(|| self.end(traced, angle));
        let (ray, mut steps) = self.in_grid(end)?;
        let n = ray.steps();
        steps.first = steps.first.max(b.first_step(range, traced, n));
        if steps.first > steps.last {
            return None;
        }
        // In eighths of σ (Q16): the ray's end lies 8·reach/σ past the reading and each step
        // 8·traced/(σ·n) after the one before, so step k lies (n − k) steps before the end.
        // From the first step on, (n − first)·dt ≤ 2·reach·2^19/σ ≤ 24·2^16: |t0| ≤ 36·2^16.
        let dt = b.step_t(traced, n);
        let back = n
            .saturating_sub(steps.first)
            .saturating_mul(dt)
            .min(1 << 41);
        Some(BandRay {
            ray,
            end,
            steps,
            t0: b.reach_t - back as i64,
            dt: dt as i64,
        })
    }
}

/// The box of cells a scan can change under the beam model, as inclusive `(min, max)` corners:
/// the pose's cell and the end cell of every beam the mapper uses (traced to the maximum range
/// for no-returns), inside the grid or not. The firmware streams the tiles it covers.
pub fn scan_box(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
) -> (CellCoord, CellCoord) {
    // The mapper's own end cells (32-bit cell conversion: no 64-bit division per beam).
    let rays = Rays::new(g, pose);
    let c = rays.origin;
    let (mut lo, mut hi) = (c, c);
    let band = Band::of(cfg);
    for b in beams {
        let Some((range, hit)) = beam_extent(cfg, b) else {
            continue;
        };
        let e = rays.end(Band::traced(band, range, hit), b.angle);
        lo = CellCoord {
            x: lo.x.min(e.x),
            y: lo.y.min(e.y),
        };
        hi = CellCoord {
            x: hi.x.max(e.x),
            y: hi.y.max(e.y),
        };
    }
    (lo, hi)
}

/// Classifies one scan into per-cell updates, calling `sink(index, update)` at most once per
/// cell, hits first. `marks` must hold at least `marks_len(geometry.len())` zeroed words and is
/// left zeroed. The f64 reference's classification, and the fixed-point mapper's for the cone
/// model (its beam model makes the same updates in `insert_beam_model`).
pub fn classify_scan(
    geometry: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    mut sink: impl FnMut(usize, CellUpdate),
) -> Result<ScanStats> {
    if marks.len() < marks_len(geometry.len()) {
        return Err(Error::BufferSize {
            expected: marks_len(geometry.len()),
            actual: marks.len(),
        });
    }
    match cfg.model.kind() {
        InverseModelKind::Beam | InverseModelKind::FaceBand { .. } => {
            Ok(classify_beam(geometry, cfg, pose, beams, marks, &mut sink))
        }
        InverseModelKind::Cone { alpha_mm, beta } => {
            classify_cone(geometry, cfg, pose, beams, alpha_mm, beta, &mut sink)
        }
    }
}

fn classify_beam(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    sink: &mut impl FnMut(usize, CellUpdate),
) -> ScanStats {
    let mut stats = ScanStats::default();
    let mut marks = Marks::new(marks);
    let rays = Rays::new(g, pose);
    let (width, height) = (g.width(), g.height());
    let band = Band::of(cfg);
    // Pass 1: hits (the end cell, or the face band).
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            stats.beams_dropped += 1;
            continue;
        };
        stats.beams_used += 1;
        match band {
            _ if !hit => {}
            None => {
                if let Some(i) = g.index(rays.end(range, beam.angle)) {
                    if Marks::first_touch(marks.words, i) {
                        marks.cover(i, i);
                        stats.cells_hit += 1;
                        sink(i, CellUpdate::Hit);
                    }
                }
            }
            Some(b) => {
                let Some(face) = rays.band(b, range, beam.angle, None) else {
                    continue;
                };
                let words = &mut *marks.words;
                face.ray.for_each_index(face.steps, width, |k, i| {
                    if Marks::first_touch(words, i) {
                        stats.cells_hit += 1;
                        sink(i, CellUpdate::Face(face.eighths(k)));
                    }
                });
                marks.cover_rows(rays.origin, face.end, width, height);
            }
        }
    }
    // Pass 2: free space up to (not including) each hit's end cell or band, or through max
    // range.
    let mut freed = 0u32;
    let mut chunk = [0u32; CHUNK];
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            continue;
        };
        let traced = Band::traced(band, range, hit);
        let end = rays.end(traced, beam.angle);
        let Some((ray, mut steps)) = rays.in_grid(end) else {
            continue;
        };
        if let (Some(b), true) = (band, hit) {
            // The band was updated in pass 1; free only what lies before it.
            match b.first_step(range, traced, ray.steps()).checked_sub(1) {
                Some(last) if last >= steps.first => steps.last = steps.last.min(last),
                _ => continue,
            }
        } else if hit && steps.last == ray.steps() {
            // A hit's end cell is not freed (it was hit in pass 1).
            if steps.last == 0 || steps.first == steps.last {
                continue;
            }
            steps.last -= 1;
        }
        match ray.index_walk(steps, width) {
            Some(mut walk) => {
                // Mark a chunk of the ray, then update the cells it touched first: the marking
                // loop keeps its whole state in registers (a fused loop spilled on a Cortex-M4).
                while walk.left() > 0 {
                    let n = mark_chunk::<BRANCH_FREE_MARKING>(&mut walk, marks.words, &mut chunk);
                    for &i in chunk.get(..n).unwrap_or_default() {
                        sink(i as usize, CellUpdate::Free);
                    }
                    freed += n as u32;
                }
            }
            None => {
                let words = &mut *marks.words;
                ray.for_each_index(steps, width, |_, i| {
                    if Marks::first_touch(words, i) {
                        freed += 1;
                        sink(i, CellUpdate::Free);
                    }
                });
            }
        }
        marks.cover_rows(rays.origin, end, width, height);
    }
    stats.cells_freed = freed;
    stats
}

/// The lecture's α/β model, cell by cell over the square around the pose that the sensor can
/// reach (`r_max + α/2`).
fn classify_cone(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    alpha_mm: u32,
    beta: Angle,
    sink: &mut impl FnMut(usize, CellUpdate),
) -> Result<ScanStats> {
    if !beams
        .windows(2)
        .all(|w| matches!(w, [a, b] if a.angle.0 <= b.angle.0))
    {
        return Err(Error::UnsortedScan);
    }
    let mut stats = ScanStats::default();
    for b in beams {
        match beam_extent(cfg, b) {
            Some(_) => stats.beams_used += 1,
            None => stats.beams_dropped += 1,
        }
    }
    if beams.is_empty() {
        return Ok(stats);
    }
    let half_alpha = i64::from(alpha_mm / 2);
    let half_beta = i32::from(beta.0 / 2);
    let r_max = i64::from(cfg.max_range_mm);
    let reach = r_max + half_alpha;
    let lo = g.cell_of_point(i64::from(pose.x_mm) - reach, i64::from(pose.y_mm) - reach);
    let hi = g.cell_of_point(i64::from(pose.x_mm) + reach, i64::from(pose.y_mm) + reach);
    let (x0, x1) = (lo.x.max(0), hi.x.min(i32::from(g.width()) - 1));
    let (y0, y1) = (lo.y.max(0), hi.y.min(i32::from(g.height()) - 1));
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            let c = CellCoord { x: cx, y: cy };
            let (mx, my) = g.cell_center_mm(c);
            let (dx, dy) = (mx - i64::from(pose.x_mm), my - i64::from(pose.y_mm));
            let r2 = (dx * dx + dy * dy) as u64;
            if r2 > (reach * reach) as u64 {
                continue;
            }
            let r = r2.isqrt() as i64;
            let phi = Angle::atan2(dy, dx).wrapping_sub(pose.heading);
            let Some(beam) = nearest_beam(beams, phi) else {
                continue;
            };
            if i32::from(phi.signed_diff(beam.angle)).abs() > half_beta {
                continue;
            }
            let Some((range, hit)) = beam_extent(cfg, beam) else {
                continue;
            };
            let rk = i64::from(range);
            if r > r_max.min(rk + half_alpha) {
                continue;
            }
            let Some(i) = g.index(c) else { continue };
            if hit && (r - rk).abs() < half_alpha {
                stats.cells_hit += 1;
                sink(i, CellUpdate::Hit);
            } else if r <= rk {
                stats.cells_freed += 1;
                sink(i, CellUpdate::Free);
            }
        }
    }
    Ok(stats)
}

/// The beam closest in angle to `phi` (wrapping), in a slice sorted by angle.
fn nearest_beam(beams: &[Beam], phi: Angle) -> Option<&Beam> {
    let k = beams.partition_point(|b| b.angle.0 < phi.0);
    let after = beams.get(k).or(beams.first());
    let before = k.checked_sub(1).and_then(|j| beams.get(j)).or(beams.last());
    match (before, after) {
        (Some(a), Some(b)) => {
            let da = i32::from(phi.signed_diff(a.angle)).abs();
            let db = i32::from(phi.signed_diff(b.angle)).abs();
            Some(if da <= db { a } else { b })
        }
        (a, b) => a.or(b),
    }
}

/// A cell update with the mapper's increments and clamp, in `i32`: the bounds lie inside the
/// `i16` range, so clamping the exact sum equals [`Clamp::apply`]'s clamp of the saturated one,
/// and all four values stay in registers.
#[derive(Clone, Copy)]
struct Update {
    occ: i32,
    free: i32,
    min: i32,
    max: i32,
}

impl Update {
    fn new(config: &MapperConfig) -> Self {
        Update {
            occ: i32::from(config.model.occ_increment().0),
            free: i32::from(config.model.free_increment().0),
            min: i32::from(config.clamp.min().0),
            max: i32::from(config.clamp.max().0),
        }
    }

    /// `value + delta` clamped to the bounds (`|value|, |delta| ≤ 2^15`, so the sum fits an
    /// `i32`; `min < max`, so the result lies in `[min, max]` ⊂ `i16`).
    #[inline(always)]
    fn apply(&self, value: LogOdds, delta: i32) -> LogOdds {
        // The bounds came from `i16`s: saying so lets the compiler see that the result fits
        // one (no sign extension before a notable test).
        let (lo, hi) = (i32::from(self.min as i16), i32::from(self.max as i16));
        LogOdds((i32::from(value.0) + delta).max(lo).min(hi) as i16)
    }

    /// [`Update::apply`] of the free increment to each of the 32 cells whose bit is set in
    /// `bits`, without a data-dependent branch: every lane is computed and the set ones kept,
    /// which a host compiles to a few vector instructions per word instead of a loop over its
    /// bits. In `i16` with a saturating add, which equals the `i32` sum clamped, since the
    /// bounds lie inside the `i16` range. Each byte of `bits` selects its eight lanes through
    /// [`LANE_MASKS`] (a load per eight lanes instead of testing each bit), and lane `i` of
    /// `count` gains the number of bits `i`, `i + 8`, `i + 16`, `i + 24` set (≤ 4 per word).
    #[inline(always)]
    fn free_lanes(&self, cells: &mut [LogOdds; 32], bits: u32, count: &mut [u16; 8]) {
        // All three came from `i16` values.
        let (d, lo, hi) = (self.free as i16, self.min as i16, self.max as i16);
        for (j, eight) in cells.chunks_exact_mut(8).enumerate() {
            // `& 0xff` < 256: always found, the check folds away.
            let masks = LANE_MASKS
                .get(((bits >> (8 * j)) & 0xff) as usize)
                .copied()
                .unwrap_or_default();
            for ((cell, m), n) in eight.iter_mut().zip(masks).zip(count.iter_mut()) {
                let v = cell.0.saturating_add(d).max(lo).min(hi);
                // m is 0 or −1: keeps the cell, or takes v.
                cell.0 ^= (cell.0 ^ v) & m;
                *n = n.wrapping_sub(m as u16);
            }
        }
    }
}

/// For each value of a byte, its eight bits as `i16` lane masks (−1 where the bit is set):
/// [`Update::free_lanes`]'s selection, 4 KiB, used on 64-bit hosts only.
// Indexing in a constant: out of bounds would fail the build, not panic at run time.
#[allow(clippy::indexing_slicing)]
const LANE_MASKS: [[i16; 8]; 256] = {
    let mut t = [[0i16; 8]; 256];
    let mut v = 0;
    while v < 256 {
        let mut b = 0;
        while b < 8 {
            if (v >> b) & 1 != 0 {
                t[v][b] = -1;
            }
            b += 1;
        }
        v += 1;
    }
    t
};

/// The cells a scan's rays can have marked: the bounding box, clipped to the grid, of the end
/// cells of the rays that cross the grid (a ray's cells lie between its end cells).
struct ScanBox {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl ScanBox {
    fn empty() -> Self {
        ScanBox {
            x0: i32::MAX,
            y0: i32::MAX,
            x1: i32::MIN,
            y1: i32::MIN,
        }
    }

    #[inline]
    fn cover(&mut self, a: CellCoord, b: CellCoord) {
        self.x0 = self.x0.min(a.x.min(b.x));
        self.x1 = self.x1.max(a.x.max(b.x));
        self.y0 = self.y0.min(a.y.min(b.y));
        self.y1 = self.y1.max(a.y.max(b.y));
    }
}

/// [`FACE_BAND_REACH_EIGHTHS`] as an `i32`.
const FACE_REACH: i32 = FACE_BAND_REACH_EIGHTHS as i32;

/// How far before the reading, in eighths of σ, the face table reaches: a band's offsets lie
/// within `−36 ..= R` eighths ([`Rays::band`]); those before `−R` get the update of `−R`.
const FACE_LOW: i32 = 40;

/// The face band's updates by eighths of σ past the reading, `−FACE_LOW ..= R` (clamped to
/// `−R ..= R`), once per scan: a band walk looks each cell's up without a clamp.
fn face_deltas(update: &Update) -> [i32; (FACE_LOW + FACE_REACH + 1) as usize] {
    core::array::from_fn(|j| {
        // |j − FACE_LOW| ≤ 40 and then ≤ R = 12: fits an i8.
        let t8 = (j as i32 - FACE_LOW).clamp(-FACE_REACH, FACE_REACH);
        face_band_delta(update.occ, update.free, t8 as i8)
    })
}

/// Hit cells remembered between marking and applying the hits, so that their end points are
/// computed once per scan; hits beyond this many are computed again.
const HIT_TABLE: usize = if cfg!(target_pointer_width = "64") {
    1024
} else {
    480
};

/// "No cell": a hit whose end cell is outside the grid. Grid indices are < 2^32 − 1 (a grid
/// has at most 65535² cells).
const NO_CELL: u32 = u32::MAX;

/// A band ray's end cell in a hit table slot, `x` and `y` as `i16`s, or [`NO_CELL`] (then
/// pass 2 computes it again) if they do not fit or pack to [`NO_CELL`] itself.
#[inline]
fn pack_end(c: CellCoord) -> u32 {
    match (i16::try_from(c.x), i16::try_from(c.y)) {
        (Ok(x), Ok(y)) => u32::from(x as u16) << 16 | u32::from(y as u16),
        _ => NO_CELL,
    }
}

/// [`pack_end`]'s cell, if it packed one.
#[inline]
fn unpack_end(v: u32) -> Option<CellCoord> {
    (v != NO_CELL).then(|| CellCoord {
        x: i32::from((v >> 16) as u16 as i16),
        y: i32::from(v as u16 as i16),
    })
}

/// The beam model's insertion, in three passes over the scan:
/// 1. **mark**: every used beam's ray, clipped to the grid and *including* a hit's end cell, sets
///    its cells' bits in `marks` (run by run where the ray is x-major, [`IndexWalk::mark_all`]);
///    the box of the marked cells is kept, and each hit's end cell is remembered;
/// 2. **hits**, in beam order: a hit cell's bit was set by its own ray, so the first beam that
///    hits it finds the bit set, clears it and applies the occupied update; later hits of the
///    same cell find it clear;
/// 3. **frees**: the bits still set are the cells the rays crossed that no beam hit (hits win),
///    found word by word over the box, each freed once and its word cleared, in increasing
///    index order, which walks the grid the way it is laid out in memory.
///
/// The cells and updates are exactly [`classify_scan`]'s (`tests::fast_insert_matches_
/// classification`); only the order of the free updates differs, which cannot change the map
/// since each cell changes at most once per scan. Marking no longer tests bits (a test per
/// walked cell, where rays overlap near the robot, was most of the old cost) and a cell is
/// updated where the sweep finds it rather than through a queue.
#[allow(clippy::too_many_arguments)]
fn insert_beam_model<L: UpdateListener>(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    cells: &mut [LogOdds],
    update: Update,
    listener: &mut L,
) -> ScanStats {
    let mut stats = ScanStats::default();
    let rays = Rays::new(g, pose);
    let (width, height) = (g.width(), g.height());
    let mut hits = [NO_CELL; HIT_TABLE];
    let mut n_hits = 0usize;
    let mut area = ScanBox::empty();
    let band = Band::of(cfg);
    // Pass 1: mark every ray (with the face band, through its band).
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            stats.beams_dropped += 1;
            continue;
        };
        stats.beams_used += 1;
        let end = rays.end(Band::traced(band, range, hit), beam.angle);
        if hit {
            if let Some(slot) = hits.get_mut(n_hits) {
                *slot = if band.is_some() {
                    // The band's set-up in pass 2 starts from the same end cell.
                    pack_end(end)
                } else {
                    // In-grid indices are < 2^32 − 1 (see NO_CELL).
                    g.index(end).map_or(NO_CELL, |i| i as u32)
                };
            }
            n_hits += 1;
        }
        if let Some(ray) = rays.grid_ray(end) {
            ray.walk().mark_all(marks);
        } else {
            let Some((ray, steps)) = rays.in_grid(end) else {
                continue;
            };
            match ray.index_walk(steps, width) {
                Some(walk) => walk.mark_all(marks),
                None => ray.for_each_index(steps, width, |_, i| {
                    if let Some(word) = marks.get_mut(i / 32) {
                        *word |= 1 << (i % 32);
                    }
                }),
            }
        }
        area.cover(rays.origin, end);
    }
    // The listener learns which cells will change from the marks, before passes 2-3 clear them.
    if L::REPORTS == Reports::Notable {
        box_words(&area, width, height, |first, last| {
            listener.marked_words(first, marks.get(first..=last).unwrap_or(&[]));
        });
    }
    // Pass 2: hits, in beam order; each in-grid hit cell's bit was set by its own ray. With the
    // face band, each hit's band cells, in beam order (set by its own ray too), each band from
    // its ray's end where it can (`Rays::band_back`).
    if let Some(b) = band {
        let face = face_deltas(&update);
        let mut k = 0usize;
        for beam in beams {
            let Some((range, true)) = beam_extent(cfg, beam) else {
                continue;
            };
            let end = hits.get(k).and_then(|&v| unpack_end(v));
            k += 1;
            // Claims band cell `i` at face slot `slot` (its offset in eighths of σ, + FACE_LOW).
            let mut claim = |i: usize, slot: usize| {
                let (w, bit) = (i / 32, 1u32 << (i % 32));
                if let (Some(word), Some(cell)) = (marks.get_mut(w), cells.get_mut(i)) {
                    if *word & bit != 0 {
                        *word &= !bit;
                        let before = *cell;
                        *cell = update.apply(before, face.get(slot).copied().unwrap_or(0));
                        stats.cells_hit += 1;
                        if hears::<L>(before, *cell) {
                            listener.changed(i, before, *cell);
                        }
                    }
                }
            };
            // Backwards from the ray's end where it is in the grid, else forwards from the
            // band's first cell in the grid.
            let (mut walk, (mut t, dt)) = match rays.band_back(b, range, end) {
                Some(back) => back,
                None => {
                    let Some(band) = rays.band(b, range, beam.angle, end) else {
                        continue;
                    };
                    match band.ray.index_walk(band.steps, width) {
                        Some(walk) => (walk, band.offsets()),
                        None => {
                            band.ray.for_each_index(band.steps, width, |k, i| {
                                claim(i, (i32::from(band.eighths(k)) + FACE_LOW) as usize)
                            });
                            continue;
                        }
                    }
                }
            };
            // The offset by one addition per step (no multiply), in registers.
            loop {
                claim(walk.index(), face_slot(t));
                if walk.left() <= 1 {
                    break;
                }
                walk.take(1);
                walk.advance();
                t = t.saturating_add(dt);
            }
        }
    }
    let mut k = 0usize;
    for beam in beams.iter().filter(|_| band.is_none()) {
        let Some((range, true)) = beam_extent(cfg, beam) else {
            continue;
        };
        let index = match hits.get(k) {
            Some(&NO_CELL) => None,
            Some(&i) => Some(i as usize),
            None => g.index(rays.end(range, beam.angle)),
        };
        k += 1;
        let Some(i) = index else { continue };
        let (w, bit) = (i / 32, 1u32 << (i % 32));
        if let (Some(word), Some(cell)) = (marks.get_mut(w), cells.get_mut(i)) {
            if *word & bit != 0 {
                *word &= !bit;
                let before = *cell;
                *cell = update.apply(before, update.occ);
                stats.cells_hit += 1;
                if hears::<L>(before, *cell) {
                    listener.changed(i, before, *cell);
                }
            }
        }
    }
    // Pass 3: free what is left, clearing the marks.
    if LANE_SWEEP && L::REPORTS == Reports::Nothing {
        let mut count = LaneCount::default();
        box_words(&area, width, height, |first, last| {
            free_words_lanes(marks, first, last, cells, update, &mut count);
        });
        stats.cells_freed += count.total();
    } else {
        box_words(&area, width, height, |first, last| {
            stats.cells_freed += free_words(marks, first, last, cells, update, listener);
        });
    }
    stats
}

/// Calls `f(first, last)` for each row of `area` (clipped to the grid), with the range of mark
/// words that hold the row's part of the box, less any word the previous row's range ended in:
/// each word of the box once, in increasing order.
#[inline(always)]
fn box_words(area: &ScanBox, width: u16, height: u16, mut f: impl FnMut(usize, usize)) {
    let max_x = i32::from(width) - 1;
    let max_y = i32::from(height) - 1;
    let (x0, x1) = (area.x0.max(0), area.x1.min(max_x));
    let (y0, y1) = (area.y0.max(0), area.y1.min(max_y));
    if x0 > x1 || y0 > y1 {
        return;
    }
    // All four lie in the grid now, so these are in-grid cell indices.
    let w = usize::from(width);
    let (x0, x1) = (x0 as usize, x1 as usize);
    let mut next = 0usize;
    for y in y0 as usize..=y1 as usize {
        let first = ((y * w + x0) / 32).max(next);
        let last = (y * w + x1) / 32;
        if first > last {
            continue;
        }
        f(first, last);
        next = last + 1;
    }
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

/// Whether the sweep updates a word's 32 cells lane-wise ([`Update::free_lanes`]) when nobody
/// needs to hear about each cell: on 64-bit hosts, whose vector units do 32 lanes in a handful of
/// instructions; a 32-bit microcontroller has no such unit and visits the set bits one by one.
const LANE_SWEEP: bool = cfg!(target_pointer_width = "64");

/// Frees the cells whose bits are set in `marks[first..=last]`, in increasing index order, and
/// clears those words; returns how many cells it freed, and tells `listener` (see [`Reports`]).
// Out of line on a 32-bit core, whose registers then hold the sweep's state instead of the
// whole insertion's; inlined on a 64-bit host, where it serves only listeners that hear about
// cells (the lane-wise sweep is `free_words_lanes`).
#[cfg_attr(target_pointer_width = "32", inline(never))]
#[cfg_attr(not(target_pointer_width = "32"), inline(always))]
fn free_words<L: UpdateListener>(
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
fn free_words_lanes(
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
struct LaneCount {
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
    fn total(mut self) -> u32 {
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

/// The online mapper: a log-odds grid plus the per-scan mark bitset.
#[derive(Clone, Debug)]
pub struct Mapper<S, M> {
    grid: LogOddsGrid<S>,
    marks: M,
    config: MapperConfig,
}

impl<S, M> Mapper<S, M>
where
    S: AsRef<[crate::types::fixed::LogOdds]> + AsMut<[crate::types::fixed::LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
{
    /// A mapper over `grid`, using `marks` (≥ [`marks_len`] words, zeroed here) as scratch.
    pub fn new(grid: LogOddsGrid<S>, mut marks: M, config: MapperConfig) -> Result<Self> {
        config.validate()?;
        let need = marks_len(grid.geometry().len());
        if marks.as_ref().len() < need {
            return Err(Error::BufferSize {
                expected: need,
                actual: marks.as_ref().len(),
            });
        }
        marks.as_mut().fill(0);
        Ok(Mapper {
            grid,
            marks,
            config,
        })
    }

    /// Integrates one scan taken at `pose`.
    pub fn insert_scan(&mut self, pose: &Pose, beams: &[Beam]) -> Result<ScanStats> {
        self.insert_scan_into(pose, beams, &mut ())
    }

    /// [`Mapper::insert_scan`] that also reports every cell it changes as
    /// `on_update(index, before, after)`, each cell exactly once per scan: with the beam model
    /// first the hit cells in beam order (see [`UpdateListener`] for the face band), then the
    /// freed cells in increasing index order; with the cone model in [`classify_scan`]'s order.
    #[inline]
    pub fn insert_scan_with(
        &mut self,
        pose: &Pose,
        beams: &[Beam],
        on_update: impl FnMut(usize, LogOdds, LogOdds),
    ) -> Result<ScanStats> {
        self.insert_scan_into(pose, beams, &mut EachCell(on_update))
    }

    /// [`Mapper::insert_scan`] that tells `listener` what it changes (see [`UpdateListener`]).
    /// The online sampler listens this way ([`crate::session::Session::insert`]).
    #[inline]
    pub fn insert_scan_into<L: UpdateListener>(
        &mut self,
        pose: &Pose,
        beams: &[Beam],
        listener: &mut L,
    ) -> Result<ScanStats> {
        let Mapper {
            grid,
            marks,
            config,
        } = self;
        let update = Update::new(config);
        let geometry = *grid.geometry();
        let cells = grid.cells_mut();
        match config.model.kind() {
            InverseModelKind::Beam | InverseModelKind::FaceBand { .. } => {
                let marks = marks.as_mut();
                if marks.len() < marks_len(geometry.len()) {
                    return Err(Error::BufferSize {
                        expected: marks_len(geometry.len()),
                        actual: marks.len(),
                    });
                }
                Ok(insert_beam_model(
                    &geometry, config, pose, beams, marks, cells, update, listener,
                ))
            }
            // Rejected by `MapperConfig::validate` without the feature.
            #[cfg(not(feature = "cone"))]
            InverseModelKind::Cone { .. } => Err(Error::InvalidModel),
            #[cfg(feature = "cone")]
            InverseModelKind::Cone { .. } => {
                classify_scan(&geometry, config, pose, beams, marks.as_mut(), |i, u| {
                    let delta = match u {
                        CellUpdate::Hit => update.occ,
                        CellUpdate::Free => update.free,
                        // Only the face band's classification reports these.
                        CellUpdate::Face(t8) => face_band_delta(update.occ, update.free, t8),
                    };
                    let Some(cell) = cells.get_mut(i) else {
                        return;
                    };
                    let before = *cell;
                    let after = update.apply(before, delta);
                    *cell = after;
                    if L::REPORTS == Reports::Notable {
                        listener.marked_words(i / 32, &[1 << (i % 32)]);
                    }
                    if hears::<L>(before, after) {
                        listener.changed(i, before, after);
                    }
                })
            }
        }
    }

    /// The map.
    pub fn grid(&self) -> &LogOddsGrid<S> {
        &self.grid
    }

    /// The map, mutable (e.g. to reset it).
    pub fn grid_mut(&mut self) -> &mut LogOddsGrid<S> {
        &mut self.grid
    }

    /// The settings.
    pub fn config(&self) -> &MapperConfig {
        &self.config
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::HashSet;

    /// Any coordinate, mostly near the grid, sometimes anywhere in the i32 range.
    fn mm() -> impl Strategy<Value = i32> {
        prop_oneof![4 => -6_000i32..6_000, 1 => any::<i32>()]
    }

    fn geometry() -> impl Strategy<Value = GridGeometry> {
        (
            1u16..50,
            1u16..50,
            prop_oneof![1u32..200, Just(1), any::<u32>().prop_map(|s| s.max(1))],
            -3_000i32..3_000,
            -3_000i32..3_000,
        )
            .prop_map(|(w, h, s, ox, oy)| GridGeometry::new(w, h, s, ox, oy).unwrap())
    }

    fn beams() -> impl Strategy<Value = Vec<Beam>> {
        let range = prop_oneof![
            4 => (0u32..8_000).prop_map(Range::Hit),
            1 => any::<u32>().prop_map(Range::Hit),
            1 => Just(Range::NoReturn),
        ];
        prop::collection::vec(
            (any::<u16>(), range).prop_map(|(a, range)| Beam {
                angle: Angle(a),
                range,
            }),
            0..40,
        )
    }

    /// The mapper's beam classification as it was written first: `GridGeometry`'s i64
    /// conversions, the all-i128 clip, `cell_at` step by step, a hash set for the marks.
    fn classify_reference(
        g: &GridGeometry,
        cfg: &MapperConfig,
        pose: &Pose,
        beams: &[Beam],
    ) -> (Vec<(usize, CellUpdate)>, ScanStats) {
        let (mut calls, mut stats, mut seen) = (Vec::new(), ScanStats::default(), HashSet::new());
        let origin = g.cell_of_pose(pose);
        let end_cell = |range: u32, angle: Angle| {
            let (x, y) = pose.beam_end(angle, range);
            g.cell_of_point(x, y)
        };
        for beam in beams {
            match beam_extent(cfg, beam) {
                None => stats.beams_dropped += 1,
                Some((range, hit)) => {
                    stats.beams_used += 1;
                    if let Some(i) = hit.then(|| g.index(end_cell(range, beam.angle))).flatten() {
                        if seen.insert(i) {
                            stats.cells_hit += 1;
                            calls.push((i, CellUpdate::Hit));
                        }
                    }
                }
            }
        }
        for beam in beams {
            let Some((range, hit)) = beam_extent(cfg, beam) else {
                continue;
            };
            let ray = Ray::new(origin, end_cell(range, beam.angle));
            let Some(mut steps) = ray.clip_reference(g.width(), g.height()) else {
                continue;
            };
            if hit && steps.last == ray.steps() {
                if steps.last == 0 || steps.first == steps.last {
                    continue;
                }
                steps.last -= 1;
            }
            for s in steps.first..=steps.last {
                let i = g.index(ray.cell_at_reference(s)).unwrap();
                if seen.insert(i) {
                    stats.cells_freed += 1;
                    calls.push((i, CellUpdate::Free));
                }
            }
        }
        (calls, stats)
    }

    /// A [`Reports::Notable`] listener that records what it hears.
    #[derive(Default)]
    struct Heard {
        marked: Vec<usize>,
        words: std::collections::HashSet<usize>,
        notable: Vec<(usize, LogOdds, LogOdds)>,
    }

    impl UpdateListener for Heard {
        const REPORTS: Reports = Reports::Notable;
        fn changed(&mut self, index: usize, before: LogOdds, after: LogOdds) {
            self.notable.push((index, before, after));
        }
        fn fresh_word(&mut self, word: usize, bits: u32, after: LogOdds) {
            assert_ne!(bits, 0, "word {word}");
            self.notable.extend(
                (0..32)
                    .filter(|b| bits & (1 << b) != 0)
                    .map(|b| (32 * word + b, LogOdds(0), after)),
            );
        }
        fn marked_words(&mut self, first: usize, words: &[u32]) {
            for (k, &bits) in words.iter().enumerate() {
                let word = first + k;
                assert!(self.words.insert(word), "word {word} passed twice");
                self.marked.extend(
                    (0..32)
                        .filter(|b| bits & (1 << b) != 0)
                        .map(|b| 32 * word + b),
                );
            }
        }
    }

    /// Inserts `scans` (the pose moving a little between them) with `insert_scan_with`,
    /// `insert_scan_into` (a [`Reports::Notable`] listener) and `insert_scan` into maps that start
    /// from `start` repeated (values outside the clamp included) and checks them against `classify_scan` applied with `Clamp::apply`: the same
    /// hits in the same order, the same freed cells in increasing index order, the same
    /// statistics, the same map, bit for bit, scan after scan; and the marks left zeroed.
    fn check_against_classification(
        g: GridGeometry,
        cfg: MapperConfig,
        (x, y, heading): (i32, i32, u16),
        scans: &[Vec<Beam>],
        start: &[i16],
    ) -> std::result::Result<(), TestCaseError> {
        let cells: Vec<LogOdds> = (0..g.len())
            .map(|i| LogOdds(start[i % start.len()]))
            .collect();
        let grid = LogOddsGrid::new(g, cells.clone()).unwrap();
        let mut mapper =
            Mapper::new(grid.clone(), vec![0u32; marks_len(g.len()) + 1], cfg).unwrap();
        // `insert_scan` takes the lane-wise sweep on 64-bit hosts.
        let mut quiet = Mapper::new(grid.clone(), vec![0u32; marks_len(g.len())], cfg).unwrap();
        let mut listened = Mapper::new(grid, vec![0u32; marks_len(g.len())], cfg).unwrap();
        let mut want = cells;
        let mut marks = vec![0u32; marks_len(g.len())];
        for (k, beams) in scans.iter().enumerate() {
            let pose = Pose {
                x_mm: x.wrapping_add(k as i32 * 37),
                y_mm: y,
                heading: Angle(heading),
            };
            let mut got = Vec::new();
            let stats = mapper
                .insert_scan_with(&pose, beams, |i, before, after| {
                    got.push((i, before, after))
                })
                .unwrap();
            let mut expected = Vec::new();
            let want_stats = classify_scan(&g, &cfg, &pose, beams, &mut marks, |i, u| {
                let before = want[i];
                let delta = match u {
                    CellUpdate::Hit => cfg.model.occ_increment(),
                    CellUpdate::Free => cfg.model.free_increment(),
                    CellUpdate::Face(t8) => LogOdds(crate::map::sensor_model::face_band_delta(
                        i32::from(cfg.model.occ_increment().0),
                        i32::from(cfg.model.free_increment().0),
                        t8,
                    ) as i16),
                };
                want[i] = cfg.clamp.apply(before, delta);
                expected.push((i, before, want[i], u));
            })
            .unwrap();
            prop_assert_eq!(stats, want_stats);
            prop_assert_eq!(quiet.insert_scan(&pose, beams).unwrap(), want_stats);
            let mut heard = Heard::default();
            prop_assert_eq!(
                listened.insert_scan_into(&pose, beams, &mut heard).unwrap(),
                want_stats
            );
            // `Reports::Notable`: the mark words name exactly the changed cells, each once,
            // and only the notable changes are heard.
            let mut changed: Vec<usize> = got.iter().map(|c| c.0).collect();
            changed.sort_unstable();
            heard.marked.sort_unstable();
            prop_assert_eq!(&heard.marked, &changed);
            // The hits' in beam order, then the sweep's (the fresh ones a word at a time).
            let notables = |c: &[(usize, LogOdds, LogOdds)]| -> Vec<_> {
                c.iter()
                    .copied()
                    .filter(|&(_, before, after)| notable(before, after))
                    .collect()
            };
            let hits = (stats.cells_hit as usize).min(got.len());
            let (hit_notables, freed_notables) = (notables(&got[..hits]), notables(&got[hits..]));
            let n = hit_notables.len().min(heard.notable.len());
            heard.notable[n..].sort_unstable();
            prop_assert_eq!(&heard.notable[..n], &hit_notables[..]);
            prop_assert_eq!(&heard.notable[n..], &freed_notables[..]);
            prop_assert_eq!(listened.grid().cells(), &want[..]);
            prop_assert!(listened.marks.iter().all(|&w| w == 0));
            let hits = (stats.cells_hit as usize).min(got.len());
            let want_hits: Vec<_> = expected
                .iter()
                .filter(|c| c.3 != CellUpdate::Free)
                .map(|c| (c.0, c.1, c.2))
                .collect();
            let mut want_frees: Vec<_> = expected
                .iter()
                .filter(|c| c.3 == CellUpdate::Free)
                .map(|c| (c.0, c.1, c.2))
                .collect();
            want_frees.sort_unstable();
            if matches!(cfg.model.kind(), InverseModelKind::FaceBand { .. }) {
                // A band is walked backwards from its ray's end where that is in the grid
                // (`Rays::band_back`): the same cells and values, each beam's in either order.
                let mut got_hits = got[..hits].to_vec();
                got_hits.sort_unstable();
                let mut want_hits = want_hits;
                want_hits.sort_unstable();
                prop_assert_eq!(got_hits, want_hits);
            } else {
                prop_assert_eq!(&got[..hits], &want_hits[..]);
            }
            prop_assert_eq!(&got[hits..], &want_frees[..]);
            prop_assert_eq!(mapper.grid().cells(), &want[..]);
            prop_assert_eq!(quiet.grid().cells(), &want[..]);
            prop_assert!(mapper.marks.iter().all(|&w| w == 0));
            prop_assert!(quiet.marks.iter().all(|&w| w == 0));
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// The band walk's 32-bit face slot finds the update of `BandRay::eighths`'s rounded
        /// and clamped offset, over a band's range of offsets.
        #[test]
        fn face_slot_matches_eighths(t in prop_oneof![(-36i32..=24).prop_map(|k| k << 15),
                -(36i32 << 16)..=(12 << 16)], occ in 1i32..2000, free in -2000i32..0) {
            let r = ((u64::from(t.unsigned_abs()) + (1 << 15)) >> 16).min(12) as i8;
            let want = face_band_delta(occ, free, if t < 0 { -r } else { r });
            let update = Update { occ, free, min: -30_000, max: 30_000 };
            prop_assert_eq!(face_deltas(&update).get(face_slot(t)).copied(), Some(want));
        }

        /// The band's first step in 32 bits equals the 64-bit formula.
        #[test]
        fn band_first_step_matches_u64(sigma in 1u32..200, range in prop_oneof![0u32..20_000, any::<u32>()],
                                       n in prop_oneof![0u64..70_000, any::<u64>()]) {
            let cfg = MapperConfig {
                model: InverseSensorModel::hahnel_face_band(sigma).unwrap(),
                ..MapperConfig::new(20_000)
            };
            let b = Band::of(&cfg).unwrap();
            let traced = range.saturating_add(b.reach_mm);
            let before = u64::from(range.saturating_sub(b.reach_mm));
            let want = before.saturating_mul(n).div_ceil(u64::from(traced.max(1)));
            prop_assert_eq!(b.first_step(range, traced, n), want);
        }

        /// A packed end cell unpacks to itself, or to nothing (then it is computed again).
        #[test]
        fn end_cells_pack(x in prop_oneof![-40_000i32..40_000, any::<i32>()],
                          y in prop_oneof![-40_000i32..40_000, any::<i32>()]) {
            let c = CellCoord { x, y };
            match unpack_end(pack_end(c)) {
                Some(u) => prop_assert_eq!(u, c),
                None => prop_assert!(i16::try_from(x).is_err() || i16::try_from(y).is_err()
                    || (x, y) == (-1, -1)),
            }
        }

        /// The narrow division equals the `u64` one.
        #[test]
        fn narrow_division_matches_u64(a in prop_oneof![any::<u32>().prop_map(u64::from), any::<u64>()],
                b in prop_oneof![1u64..1000, 1..=u64::from(u32::MAX), 1..=u64::MAX], ceil in any::<bool>()) {
            let want = if ceil { a.div_ceil(b) } else { a / b };
            prop_assert_eq!(div_u64(a, b, ceil), want);
        }

        /// The 32-bit point → cell conversion equals `GridGeometry::cell_of_point`.
        #[test]
        fn point_to_cell_matches_geometry(g in geometry(),
                                          x in prop_oneof![-100_000i64..100_000, any::<i64>()],
                                          y in prop_oneof![-100_000i64..100_000, any::<i64>()]) {
            prop_assert_eq!(PointToCell::new(&g).cell(x, y), g.cell_of_point(x, y));
        }

        /// A beam's end cell (32-bit path or not) is the cell of `Pose::beam_end`'s point.
        #[test]
        fn beam_end_cell_matches_geometry(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                          angle in any::<u16>(),
                                          range in prop_oneof![0u32..20_000, (1u32 << 30) - 2..(1 << 30) + 2, any::<u32>()]) {
            let pose = Pose { x_mm: x, y_mm: y, heading: Angle(heading) };
            let (px, py) = pose.beam_end(Angle(angle), range);
            prop_assert_eq!(Rays::new(&g, &pose).end(range, Angle(angle)), g.cell_of_point(px, py));
        }

        /// `classify_scan` (beam model) makes exactly the calls, in exactly the order, of the
        /// straightforward reference, and leaves the marks zeroed.
        #[test]
        fn classification_matches_reference(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                            beams in beams(), max_range in 1u32..10_000, min_range in 0u32..300) {
            let mut cfg = MapperConfig::new(max_range.max(min_range + 1));
            cfg.min_range_mm = min_range;
            let pose = Pose { x_mm: x, y_mm: y, heading: Angle(heading) };
            let mut marks = vec![0u32; marks_len(g.len()) + 1];
            let mut calls = Vec::new();
            let stats = classify_scan(&g, &cfg, &pose, &beams, &mut marks, |i, u| calls.push((i, u))).unwrap();
            let (want_calls, want_stats) = classify_reference(&g, &cfg, &pose, &beams);
            prop_assert_eq!(stats, want_stats);
            prop_assert_eq!(calls, want_calls);
            prop_assert!(marks.iter().all(|&w| w == 0));
        }

        /// The mapper's beam-model insertion makes exactly the updates of the classification
        /// (the algorithm it replaced, which the f64 reference still runs): see
        /// [`check_against_classification`].
        #[test]
        fn fast_insert_matches_classification(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                              scans in prop::collection::vec(beams(), 1..4),
                                              max_range in 1u32..10_000, min_range in 0u32..300,
                                              start in prop::collection::vec(any::<i16>(), 16),
                                              p_occ in 0.55f64..0.97, p_free in 0.03f64..0.45,
                                              wide_clamp in any::<bool>(),
                                              band in prop::option::of((1u32..400, 1u16..=256))) {
            let mut cfg = MapperConfig::new(max_range.max(min_range + 1));
            cfg.min_range_mm = min_range;
            cfg.model = match band {
                Some((sigma, q8)) => InverseSensorModel::hahnel_face_band(sigma).unwrap().with_free_scale(q8).unwrap(),
                None => InverseSensorModel::beam(p_occ, p_free, 0.5).unwrap(),
            };
            if wide_clamp {
                cfg.clamp = Clamp::new(LogOdds(-i16::MAX), LogOdds(i16::MAX)).unwrap();
            }
            check_against_classification(g, cfg, (x, y, heading), &scans, &start)?;
        }

        /// The same with what skipping the cells shared with the previous ray is for: dense,
        /// sorted scans from a pose on the map, many beams per octant and long rays.
        #[test]
        fn dense_scans_match_classification(w in 3u16..90, h in 1u16..90, cell in 10u32..120,
                                            fx in 0.0f64..1.0, fy in 0.0f64..1.0, heading in any::<u16>(),
                                            n in 8usize..400, jitter in prop::collection::vec(0u16..200, 400),
                                            ranges in prop::collection::vec(prop_oneof![6 => 0u32..12_000, 1 => Just(u32::MAX)], 400),
                                            max_range in 500u32..10_000,
                                            band in prop::option::of(1u32..300)) {
            let g = GridGeometry::new(w, h, cell, -1_000, 2_000).unwrap();
            let x = -1_000 + (fx * f64::from(w) * f64::from(cell)) as i32;
            let y = 2_000 + (fy * f64::from(h) * f64::from(cell)) as i32;
            let mut beams: Vec<Beam> = (0..n)
                .map(|k| Beam {
                    angle: Angle(((k * 65_536 / n) as u16).wrapping_add(jitter[k])),
                    range: match ranges[k] { u32::MAX => Range::NoReturn, r => Range::Hit(r) },
                })
                .collect();
            beams.sort_by_key(|b| b.angle.0);
            let mut cfg = MapperConfig::new(max_range);
            if let Some(sigma) = band {
                cfg.model = InverseSensorModel::hahnel_face_band(sigma).unwrap();
            }
            check_against_classification(g, cfg, (x, y, heading), &[beams.clone(), beams], &[3, -2000, 7000, 0])?;
        }

        /// Marking a walk run by run sets exactly the bits of its cells.
        #[test]
        // Widths of whole words too (32, 64: the strided runs' one-bit path), and heights that
        // give long y-major runs.
        fn run_marking_sets_the_walked_cells(x0 in -20i32..80, y0 in -20i32..80, x1 in -20i32..80, y1 in -20i32..80,
                                             w in prop_oneof![1u16..70, Just(32u16), Just(64u16)],
                                             h in prop_oneof![1u16..9, 9u16..90]) {
            let r = Ray::new(CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let Some(steps) = r.clip(w, h) else { return Ok(()); };
            let Some(walk) = r.index_walk(steps, w) else { return Ok(()); };
            let mut want = vec![0u32; marks_len(usize::from(w) * usize::from(h))];
            r.for_each_index(steps, w, |_, i| want[i / 32] |= 1 << (i % 32));
            let mut got = vec![0u32; want.len()];
            walk.mark_all(&mut got);
            prop_assert_eq!(got, want);
        }

        /// Both marking loops (branch-free for hosts, branchy for microcontrollers) mark the
        /// same bits and report the same first touches.
        #[test]
        fn marking_variants_agree(x0 in -20i32..80, y0 in -20i32..80, x1 in -20i32..80, y1 in -20i32..80,
                                  premarked in prop::collection::vec(any::<u32>(), 7)) {
            let (w, h) = (50u16, 4u16);
            let r = Ray::new(CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let Some(steps) = r.clip(w, h) else { return Ok(()); };
            let Some(walk) = r.index_walk(steps, w) else { return Ok(()); };
            let run = |branch_free: bool| {
                let (mut words, mut wk, mut out) = (premarked.clone(), walk, Vec::new());
                let mut chunk = [0u32; CHUNK];
                while wk.left() > 0 {
                    let n = if branch_free {
                        mark_chunk::<true>(&mut wk, &mut words, &mut chunk)
                    } else {
                        mark_chunk::<false>(&mut wk, &mut words, &mut chunk)
                    };
                    out.extend_from_slice(&chunk[..n]);
                }
                (words, out)
            };
            prop_assert_eq!(run(true), run(false));
        }

        /// [`FloorDiv`] equals `div_euclid` for any `i32` and any divisor ≥ 1.
        #[test]
        fn floor_div_matches_any(n in any::<i32>(), d in prop_oneof![1i32..200, 1i32..=i32::MAX]) {
            prop_assert_eq!(FloorDiv::new(d).unwrap().floor(n), n.div_euclid(d));
        }

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

    /// The multiply-and-shift division equals `div_euclid` (floor, for a positive divisor) at
    /// the extremes of `n` and of `d`, and on a spread of values between.
    #[test]
    fn floor_div_matches_div_euclid() {
        let ds = [
            1,
            2,
            3,
            5,
            7,
            10,
            50,
            64,
            100,
            127,
            1000,
            65_537,
            1 << 30,
            i32::MAX - 1,
            i32::MAX,
        ];
        let mut ns = vec![i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX];
        let mut x = 0x9E37_79B9u32;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            ns.push(x as i32);
            ns.push((x as i32) >> (x % 31));
        }
        for d in ds {
            let f = FloorDiv::new(d).unwrap();
            for &n in &ns {
                for n in [n, n.wrapping_add(d), n.wrapping_sub(d), n.wrapping_sub(1)] {
                    assert_eq!(f.floor(n), n.div_euclid(d), "{n} / {d}");
                }
            }
        }
        assert!(FloorDiv::new(0).is_none() && FloorDiv::new(-5).is_none());
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

    /// The scan box: the pose's cell and the used beams' end cells (no-returns and ranges past
    /// the maximum at the maximum range; beams below the minimum range ignored).
    #[test]
    fn scan_box_covers_the_pose_and_the_used_beam_ends() {
        // 100 mm cells, cell (0, 0) at the origin; pose in cell (5, 5).
        let g = GridGeometry::new(20, 20, 100, 0, 0).unwrap();
        let mut cfg = MapperConfig::new(1_000);
        cfg.min_range_mm = 100;
        let pose = Pose {
            x_mm: 550,
            y_mm: 550,
            heading: Angle(0),
        };
        let beam = |deg: f64, range| Beam {
            angle: Angle::from_degrees(deg),
            range,
        };
        let beams = [
            beam(0.0, Range::Hit(300)),      // +x to cell 8
            beam(90.0, Range::NoReturn),     // +y to the maximum range: cell 15
            beam(180.0, Range::Hit(50_000)), // -x, clamped to 1 000 mm: cell -5
            beam(270.0, Range::Hit(50)),     // below the minimum range: ignored
        ];
        let (lo, hi) = scan_box(&g, &cfg, &pose, &beams);
        assert_eq!((lo.x, lo.y, hi.x, hi.y), (-5, 5, 8, 15));
        assert_eq!(
            scan_box(&g, &cfg, &pose, &[]),
            (CellCoord { x: 5, y: 5 }, CellCoord { x: 5, y: 5 })
        );
    }

    /// Rays so long that the walk falls back to 64-bit state: 1 mm cells, a pose near the far
    /// end of the i32 range, a range of 4·10⁹ mm.
    #[test]
    fn very_long_rays_match_reference() {
        let g = GridGeometry::new(40, 30, 1, 0, 0).unwrap();
        let mut cfg = MapperConfig::new(u32::MAX);
        cfg.min_range_mm = 0;
        let beams: Vec<Beam> = (0..64u16)
            .map(|k| Beam {
                angle: Angle(k.wrapping_mul(1021)),
                range: Range::Hit(4_000_000_000),
            })
            .collect();
        for pose in [
            Pose {
                x_mm: -2_000_000_000,
                y_mm: 15,
                heading: Angle(0),
            },
            Pose {
                x_mm: 20,
                y_mm: 2_000_000_000,
                heading: Angle(49_152),
            },
            Pose {
                x_mm: 10,
                y_mm: 10,
                heading: Angle(77),
            },
        ] {
            let mut marks = vec![0u32; marks_len(g.len())];
            let mut calls = Vec::new();
            let stats = classify_scan(&g, &cfg, &pose, &beams, &mut marks, |i, u| {
                calls.push((i, u))
            })
            .unwrap();
            let (want_calls, want_stats) = classify_reference(&g, &cfg, &pose, &beams);
            assert!(stats.cells_freed > 20, "{stats:?}");
            assert_eq!(stats, want_stats);
            assert_eq!(calls, want_calls);
            assert!(marks.iter().all(|&w| w == 0));
        }
    }
}
