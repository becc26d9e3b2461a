//! Which sampler an evaluation runs ([`Variant`]) and the settings each implies.

use ogm_core::config::{DataTerm, Estimator};
use serde::{Deserialize, Serialize};

use super::config::SamplingConfig;

/// Which sampler.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Variant {
    /// L = 1 with the constant data-driven prior p(m_k) (rays).
    L1,
    /// L = 1 conditioned on the 8 neighbours (rays; Table I's "L = 1, data-driven prior with
    /// border").
    L1Border,
    /// L = 9 with the unconditioned data-driven prior (rays).
    L9,
    /// L = 9 conditioned on the 16-cell border: the robot's sampler (the firmware's default).
    L9Border,
    /// L = 9 + border, the paper's sampler: rays, sample counts.
    L9BorderRays,
    /// The robot's sampler with the hybrid data term (stored rays + evidence of dropped ones).
    L9BorderHybrid,
    /// The robot's sampler ([`Variant::L9Border`]: evidence, the same chain), its marginals
    /// read out as the mean of every counted sweep (sample counts, like the paper's samplers)
    /// instead of the robot's short moving average, which an online robot needs (its evidence
    /// changes, and its estimates are bytes) but which keeps only the last ~8 draws of a cell.
    L9BorderMean,
    /// L = 25 (5 × 5 patches) with the unconditioned data-driven prior (rays; Table I's "L = 25,
    /// data-driven prior"): the host-only [`super::l25::L25Sampler`].
    L25,
}

impl Variant {
    /// The paper's Table II columns, then the robot's sampler and its other data terms, then
    /// Table I's L = 25.
    pub const ALL: [Variant; 8] = [
        Variant::L1,
        Variant::L1Border,
        Variant::L9,
        Variant::L9Border,
        Variant::L9BorderRays,
        Variant::L9BorderHybrid,
        Variant::L9BorderMean,
        Variant::L25,
    ];

    /// The method name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Variant::L1 => "gibbs_l1",
            Variant::L1Border => "gibbs_l1_border",
            Variant::L9 => "gibbs_l9",
            Variant::L9Border => "gibbs_l9_border",
            Variant::L9BorderRays => "gibbs_l9_border_rays",
            Variant::L9BorderHybrid => "gibbs_l9_border_hybrid",
            Variant::L9BorderMean => "gibbs_l9_border_mean",
            Variant::L25 => "gibbs_l25",
        }
    }

    /// Cells per patch.
    pub fn cells(self) -> u32 {
        match self {
            Variant::L1 | Variant::L1Border => 1,
            Variant::L25 => super::l25::CELLS,
            Variant::L9
            | Variant::L9Border
            | Variant::L9BorderRays
            | Variant::L9BorderHybrid
            | Variant::L9BorderMean => 9,
        }
    }

    /// `cfg` with this variant's data term and estimator: the robot's (`RunConfig::ROBOT` made
    /// for the sensor of `cfg.sensor()` by `RunConfig::with_sensor`: its face band, far edge and
    /// evidence gain) for
    /// [`Variant::L9Border`] and [`Variant::L9BorderHybrid`] ([`Variant::L9BorderMean`]: the
    /// robot's with sample counts), the paper's (rays, sample counts) for the others (for
    /// [`Variant::L25`] only the rays are implemented).
    pub fn configure(self, cfg: &SamplingConfig) -> SamplingConfig {
        match self {
            Variant::L9Border | Variant::L9BorderHybrid | Variant::L9BorderMean => {
                // The robot's settings for this data set's sensor. σ and τ are checked where
                // they are set (the options, the noise estimate); the robot's default otherwise.
                let base = ogm_core::config::RunConfig::ROBOT;
                let (sigma, tau) = cfg.sensor();
                let robot = base.with_sensor(sigma, tau).unwrap_or(base);
                SamplingConfig {
                    // The band's σ, where there is one: what the robot's mapper reads.
                    sigma_cells: if robot.face_band {
                        f64::from(robot.sigma_milli_cells) / 1000.0
                    } else {
                        cfg.sigma_cells
                    },
                    far_edge_q8: robot.band_far_edge_q8(),
                    data: if self == Variant::L9BorderHybrid {
                        DataTerm::Hybrid
                    } else {
                        DataTerm::Evidence
                    },
                    evidence_gain_q8: robot.evidence_gain_q8,
                    evidence_free_q8: robot.evidence_free_q8,
                    free_update_q8: robot.free_update_q8,
                    face_band: robot.face_band,
                    data_candidate: robot.data_candidate,
                    estimator: if self == Variant::L9BorderMean {
                        Estimator::Counts
                    } else {
                        robot.estimator
                    },
                    hot_share: robot.hot_share,
                    ..*cfg
                }
            }
            _ => SamplingConfig {
                data: DataTerm::Rays,
                data_candidate: false,
                estimator: Estimator::Counts,
                hot_share: 0,
                ..*cfg
            },
        }
    }
}
