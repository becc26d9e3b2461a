//! The evaluation's sampler settings ([`SamplingConfig`]) and buffer bounds ([`Bounds`]).

use anyhow::anyhow;
use ogm_core::config::{DataTerm, Estimator};
use ogm_core::map::sensor_model::InverseSensorModel;
use ogm_core::{GridGeometry, MapperConfig};
use serde::{Deserialize, Serialize};

/// Sampler settings for an evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SamplingConfig {
    /// Sweeps discarded before marginals are counted.
    pub burn_in: u32,
    /// Sweeps counted.
    pub sweeps: u32,
    /// Candidates per patch.
    pub max_candidates: u8,
    /// Forward model σ, cells.
    pub sigma_cells: f64,
    /// Forward model outlier weight.
    pub outlier_weight: f64,
    /// p_randPatch.
    pub p_rand_patch: f32,
    /// Log2 of the tile edge.
    pub tile_shift: u8,
    /// Sweeps of a tile per visit.
    pub visit_sweeps: u8,
    /// Blocks per side of the tile-visit ray index.
    pub block_grid: u8,
    /// Initial sample: occupied iff the online log-odds exceeds this (raw LSB).
    pub init_threshold: i16,
    /// Buffer bounds.
    pub bounds: Bounds,
    /// The measurement term.
    pub data: DataTerm,
    /// Evidence gain, Q8.
    pub evidence_gain_q8: u16,
    /// Relative scale of free evidence, Q8.
    pub evidence_free_q8: u16,
    /// Scale of the free update of the map the evidence term reads, Q8 (256: the dataset's
    /// own log-odds map; otherwise the scans are mapped again with the scaled model, as the
    /// robot's mapper does).
    pub free_update_q8: u16,
    /// The robot's mapper uses the face band of σ = `sigma_cells` for the map the evidence term
    /// reads (`RunConfig::face_band`; the scans are mapped again with it).
    #[serde(default)]
    pub face_band: bool,
    /// The face band's far-edge share, Q8 (`InverseSensorModel::with_far_edge`;
    /// `RunConfig::band_far_edge_q8`).
    #[serde(default)]
    pub far_edge_q8: u16,
    /// The range sensor's σ (cells) the robot's settings are made for
    /// (`RunConfig::with_sensor`), where it differs from `sigma_cells` (the forward models'):
    /// `eval-log` estimates the two differently ([`crate::eval::noise`]).
    #[serde(default)]
    pub sensor_sigma_cells: Option<f64>,
    /// Share of hits that support no surface near their end, 0 ..= 1, for the robot's
    /// settings (`RunConfig::with_sensor`; [`crate::eval::noise::NoiseEstimate::sensor`]).
    #[serde(default)]
    pub outlier_share: f64,
    /// Offer the evidence's configuration as a candidate.
    pub data_candidate: bool,
    /// Marginal estimator.
    pub estimator: Estimator,
    /// Change-driven share of tile visits, of 256.
    pub hot_share: u8,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        SamplingConfig {
            burn_in: 20,
            sweeps: 100,
            max_candidates: 16,
            sigma_cells: 3.0,
            outlier_weight: 0.01,
            p_rand_patch: 0.001,
            tile_shift: 4,
            visit_sweeps: 16,
            block_grid: 16,
            init_threshold: -1,
            bounds: Bounds::default(),
            data: DataTerm::Rays,
            evidence_gain_q8: 256,
            evidence_free_q8: 256,
            free_update_q8: 256,
            face_band: false,
            far_edge_q8: 0,
            sensor_sigma_cells: None,
            outlier_share: 0.0,
            data_candidate: false,
            estimator: Estimator::Counts,
            hot_share: 0,
        }
    }
}

impl SamplingConfig {
    /// The sensor the robot's settings are made for: σ (cells; `sensor_sigma_cells`, else
    /// `sigma_cells`) and the share of hits without evidence.
    pub fn sensor(&self) -> (f64, f64) {
        (
            self.sensor_sigma_cells.unwrap_or(self.sigma_cells),
            self.outlier_share,
        )
    }

    /// The inverse model of the map the evidence term reads: `mapper`'s with the free update
    /// scaled by `free_update_q8` and, with `face_band`, the band of σ = `sigma_cells` and
    /// far edge `far_edge_q8`.
    pub fn evidence_model(
        &self,
        geometry: &GridGeometry,
        mapper: &MapperConfig,
    ) -> anyhow::Result<InverseSensorModel> {
        let q8 = self.free_update_q8;
        let model = mapper
            .model
            .with_free_scale(q8)
            .map_err(|e| anyhow!("free update scale {q8}: {e}"))?;
        if !self.face_band {
            return Ok(model);
        }
        let sigma_mm = (self.sigma_cells * f64::from(geometry.cell_mm())).round();
        anyhow::ensure!(
            sigma_mm >= 1.0 && sigma_mm < f64::from(u32::MAX),
            "face band: σ = {} cells is not a whole number of mm ≥ 1",
            self.sigma_cells
        );
        let band = InverseSensorModel::hahnel_face_band(sigma_mm as u32)
            .and_then(|b| b.with_far_edge(self.far_edge_q8))
            .map_err(|e| anyhow!("face band: {e}"))?;
        band.with_free_scale(q8)
            .map_err(|e| anyhow!("free update scale {q8}: {e}"))
    }
}

/// Buffer sizes: `None` = large enough for everything (the host's unbounded configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Bounds {
    /// Stored rays.
    pub rays: Option<usize>,
    /// Stored scans.
    pub scans: Option<usize>,
    /// Rays per tile visit.
    pub local: Option<usize>,
    /// Marginal counters are `u8` (firmware) instead of `u32`.
    pub u8_counts: bool,
}
