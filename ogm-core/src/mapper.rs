//! Online log-odds mapping: one scan at a time, with the inverse sensor model.
//!
//! Within one scan every cell changes at most once, and **hits win**: a cell that is the end of
//! some beam gets the occupied update even if other beams of the same scan pass through it
//! (Cartographer does the same). This makes the result independent of the order of beams and of
//! how densely beams overlap near the robot. A bitset with one bit per cell (caller-provided,
//! `⌈K/32⌉` words) records which cells this scan already touched; only the words between the
//! lowest and highest touched cell are cleared afterwards.
//!
//! Beam handling: a `Hit` closer than `min_range_mm` is dropped (counted); a `Hit` at or beyond
//! `max_range_mm`, and every `NoReturn`, frees cells up to `max_range_mm` and marks nothing
//! occupied. Rays are clipped to the grid exactly (see [`crate::ray`]), so poses and readings
//! outside the map are harmless.
//!
//! The classification (which cell gets which update) is shared by the fixed-point [`Mapper`] and
//! the f64 reference ([`crate::reference`]), so they can only differ in arithmetic.

use crate::angle::Angle;
use crate::error::{Error, Result};
use crate::fixed::Clamp;
use crate::geometry::{CellCoord, GridGeometry, Pose};
use crate::grid::LogOddsGrid;
use crate::hal::{Beam, Range};
use crate::ray::Ray;
use crate::sensor_model::{InverseModelKind, InverseSensorModel};

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

    /// Checks that the model's increments fit inside the clamp and the range is sane.
    pub fn validate(&self) -> Result<()> {
        let span = self.clamp.span();
        if self.model.occ_increment().0 > span || self.model.free_increment().0 < -span {
            return Err(Error::InvalidModel);
        }
        if self.max_range_mm == 0 || self.min_range_mm >= self.max_range_mm {
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
}

/// Words of scan-mark bitset needed for `cells` cells.
pub const fn marks_len(cells: usize) -> usize {
    cells.div_ceil(32)
}

/// One bit per cell, with the touched range tracked so clearing is proportional to the scan.
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

    /// Sets the bit; returns `true` if it was clear (first touch in this scan).
    #[inline]
    fn first_touch(&mut self, index: usize) -> bool {
        let (w, bit) = (index / 32, 1u32 << (index % 32));
        match self.words.get_mut(w) {
            Some(word) if *word & bit == 0 => {
                *word |= bit;
                self.lo = self.lo.min(w);
                self.hi = self.hi.max(w);
                true
            }
            _ => false,
        }
    }
}

impl Drop for Marks<'_> {
    fn drop(&mut self) {
        if self.lo <= self.hi {
            if let Some(ws) = self.words.get_mut(self.lo..=self.hi) {
                ws.fill(0);
            }
        }
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

/// Classifies one scan into per-cell updates, calling `sink(index, update)` at most once per
/// cell, hits first. `marks` must hold at least `marks_len(geometry.len())` zeroed words and is
/// left zeroed. Shared by the fixed-point mapper and the f64 reference.
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
        InverseModelKind::Beam => Ok(classify_beam(geometry, cfg, pose, beams, marks, &mut sink)),
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
    let origin = g.cell_of_pose(pose);
    let end_cell = |range: u32, angle: Angle| {
        let (x, y) = pose.beam_end(angle, range);
        g.cell_of_point(x, y)
    };
    // Pass 1: hits.
    for beam in beams {
        match beam_extent(cfg, beam) {
            None => stats.beams_dropped += 1,
            Some((range, hit)) => {
                stats.beams_used += 1;
                if hit {
                    if let Some(i) = g.index(end_cell(range, beam.angle)) {
                        if marks.first_touch(i) {
                            stats.cells_hit += 1;
                            sink(i, CellUpdate::Hit);
                        }
                    }
                }
            }
        }
    }
    // Pass 2: free space up to (not including) each hit's end cell, or through max range.
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            continue;
        };
        let ray = Ray::new(origin, end_cell(range, beam.angle));
        let Some(mut steps) = ray.clip(g.width(), g.height()) else {
            continue;
        };
        // A hit's end cell is not freed (it was hit in pass 1).
        if hit && steps.last == ray.steps() {
            if steps.last == 0 || steps.first == steps.last {
                continue;
            }
            steps.last -= 1;
        }
        ray.for_each_index(steps, g.width(), |_, i| {
            if marks.first_touch(i) {
                stats.cells_freed += 1;
                sink(i, CellUpdate::Free);
            }
        });
    }
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

/// The online mapper: a log-odds grid plus the per-scan mark bitset.
#[derive(Clone, Debug)]
pub struct Mapper<S, M> {
    grid: LogOddsGrid<S>,
    marks: M,
    config: MapperConfig,
}

impl<S, M> Mapper<S, M>
where
    S: AsRef<[crate::fixed::LogOdds]> + AsMut<[crate::fixed::LogOdds]>,
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
        let Mapper {
            grid,
            marks,
            config,
        } = self;
        let (occ, free, clamp) = (
            config.model.occ_increment(),
            config.model.free_increment(),
            config.clamp,
        );
        let geometry = *grid.geometry();
        classify_scan(&geometry, config, pose, beams, marks.as_mut(), |i, u| {
            let delta = match u {
                CellUpdate::Hit => occ,
                CellUpdate::Free => free,
            };
            grid.apply(i, delta, &clamp);
        })
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
