//! Online log-odds mapping: one scan at a time, with the inverse sensor model.
//!
//! Within one scan every cell changes at most once, and **hits win**: a cell that is the end of
//! some beam gets the occupied update even if other beams of the same scan pass through it
//! (Cartographer does the same). This makes the result independent of the order of beams and of
//! how densely beams overlap near the robot. A bitset with one bit per cell (caller-provided,
//! `⌈K/32⌉` words) records which cells this scan touched; only the words of the scan's box are
//! cleared afterwards.
//!
//! Speed (docs/performance.md): the [`Mapper`]'s beam model marks every ray's cells without
//! testing them, run by run where a ray's runs allow it ([`crate::map::ray`]), then applies the
//! hits in beam order and sweeps the marks of the scan's box for the freed cells
//! (`insert_beam_model`).
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
//!
//! One file per part: `listener` (who hears about a scan's updates), `marks` (the per-scan mark
//! bits and the marking of a ray), `rays` (a scan's rays from the pose's cell), `band` (the face
//! band), `classify` ([`classify_scan`]), `update` (the cell update), `insert` (the beam model's
//! insertion) and `sweep` (its free sweep).

mod band;
mod classify;
mod insert;
mod listener;
mod marks;
mod rays;
#[cfg(test)]
mod strategies;
mod sweep;
mod update;

pub use classify::{classify_scan, CellUpdate};
pub use listener::{notable, Reports, UpdateListener};
pub use marks::marks_len;
pub use rays::{beams_leaving, reach_cells, scan_box};

use crate::error::{Error, Result};
use crate::map::grid::LogOddsGrid;
#[cfg(feature = "cone")]
use crate::map::sensor_model::face_band_delta;
use crate::map::sensor_model::{InverseModelKind, InverseSensorModel};
use crate::types::fixed::{Clamp, LogOdds};
use crate::types::geometry::Pose;
use crate::types::scan::Beam;
use insert::insert_beam_model;
#[cfg(feature = "cone")]
use listener::hears;
use listener::EachCell;
use update::Update;

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

    /// Moves the map by `(dx, dy)` whole cells ([`LogOddsGrid::shift`]); `false` if the new
    /// origin leaves the `i32` mm range (nothing changes then). The per-scan marks are zero
    /// between scans and stay so.
    pub fn shift(&mut self, dx: i32, dy: i32) -> bool {
        self.grid.shift(dx, dy)
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

    /// The map and the marks at once. The marks are zero between scans and must be zero again
    /// before the next insert: a caller may use them as scratch in between (the session's scan
    /// matcher keeps its points there).
    pub fn grid_and_marks(&mut self) -> (&LogOddsGrid<S>, &mut M) {
        (&self.grid, &mut self.marks)
    }

    /// The settings.
    pub fn config(&self) -> &MapperConfig {
        &self.config
    }
}

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

pub use crate::types::scan::ScanStats;
