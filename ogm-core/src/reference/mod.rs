//! f64 reference implementations the fixed-point code is tested (and benchmarked) against.
//!
//! [`ReferenceMapper`] classifies scans with exactly the same code as [`crate::map::mapper::Mapper`]
//! and differs only in arithmetic: f64 log-odds, f64 increments, the clamp bounds as f64. With
//! the default Hähnel model the fixed-point increments are exact (±1024 LSB = ±ln 4), so the two
//! agree to f64 rounding after any number of scans. For other models, compare against a
//! reference built with [`Increments::effective`] (no drift at all), or with
//! [`Increments::nominal`] and allow half an LSB of log-odds drift per scan (each scan changes a
//! cell at most once).

use crate::error::{Error, Result};
use crate::map::mapper::{classify_scan, marks_len, CellUpdate, MapperConfig, ScanStats};
use crate::types::fixed::probability_of_nats;
use crate::types::geometry::{GridGeometry, Pose};
use crate::types::scan::Beam;

/// Increments (nats) and clamp (nats) a reference mapper applies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Increments {
    /// Added for an occupied cell.
    pub occ: f64,
    /// Added for a free cell.
    pub free: f64,
    /// Lower clamp.
    pub min: f64,
    /// Upper clamp.
    pub max: f64,
}

impl Increments {
    /// The model's requested (unrounded) increments and the config's clamp.
    pub fn nominal(cfg: &MapperConfig) -> Self {
        let (occ, free) = cfg.model.nominal_increments();
        Increments {
            occ,
            free,
            min: cfg.clamp.min().to_nats(),
            max: cfg.clamp.max().to_nats(),
        }
    }

    /// The increments the fixed-point mapper really applies.
    pub fn effective(cfg: &MapperConfig) -> Self {
        let (occ, free) = cfg.model.effective_increments();
        Increments {
            occ,
            free,
            min: cfg.clamp.min().to_nats(),
            max: cfg.clamp.max().to_nats(),
        }
    }
}

/// An f64 log-odds mapper over caller storage (`geometry.len()` cells and `marks_len` words).
#[derive(Clone, Debug)]
pub struct ReferenceMapper<S, M> {
    geometry: GridGeometry,
    config: MapperConfig,
    inc: Increments,
    cells: S,
    marks: M,
}

impl<S, M> ReferenceMapper<S, M>
where
    S: AsRef<[f64]> + AsMut<[f64]>,
    M: AsMut<[u32]>,
{
    /// A reference mapper; `cells` is reset to 0 (p = 0.5).
    pub fn new(
        geometry: GridGeometry,
        config: MapperConfig,
        inc: Increments,
        mut cells: S,
        mut marks: M,
    ) -> Result<Self> {
        if cells.as_ref().len() != geometry.len() {
            return Err(Error::BufferSize {
                expected: geometry.len(),
                actual: cells.as_ref().len(),
            });
        }
        if marks.as_mut().len() < marks_len(geometry.len()) {
            return Err(Error::BufferSize {
                expected: marks_len(geometry.len()),
                actual: marks.as_mut().len(),
            });
        }
        cells.as_mut().fill(0.0);
        marks.as_mut().fill(0);
        Ok(ReferenceMapper {
            geometry,
            config,
            inc,
            cells,
            marks,
        })
    }

    /// Integrates one scan.
    pub fn insert_scan(&mut self, pose: &Pose, beams: &[Beam]) -> Result<ScanStats> {
        let ReferenceMapper {
            geometry,
            config,
            inc,
            cells,
            marks,
        } = self;
        let cells = cells.as_mut();
        classify_scan(geometry, config, pose, beams, marks.as_mut(), |i, u| {
            if let Some(c) = cells.get_mut(i) {
                let d = match u {
                    CellUpdate::Hit => inc.occ,
                    CellUpdate::Free => inc.free,
                    CellUpdate::Face(t8) => {
                        // Φ(t), the probability that the surface lies before the cell.
                        let t = f64::from(t8) / 8.0;
                        let phi = 0.5 * libm::erfc(-t / core::f64::consts::SQRT_2);
                        phi * inc.occ + (1.0 - phi) * inc.free
                    }
                };
                *c = (*c + d).clamp(inc.min, inc.max);
            }
        })
    }

    /// Log-odds (nats) of every cell.
    pub fn log_odds(&self) -> &[f64] {
        self.cells.as_ref()
    }

    /// Probability of cell `index`.
    pub fn probability(&self, index: usize) -> Option<f64> {
        self.cells
            .as_ref()
            .get(index)
            .map(|&l| probability_of_nats(l))
    }
}

mod gibbs;
pub use gibbs::{ReferenceGibbs, ReferenceModel};
