//! How a session reads the run's settings: the mapper's, the forward model's and the sampler's
//! configuration, each derived from the one [`RunConfig`].

use crate::config::{DataTerm, PoseCorrection, PoseInput, RunConfig};
use crate::error::Result;
use crate::localize::MatchConfig;
use crate::map::mapper::MapperConfig;
use crate::map::sensor_model::InverseSensorModel;
use crate::sampler::forward_model::ForwardModel;
use crate::sampler::gibbs::SamplerConfig;
use crate::LogOdds;

/// Cell reads per scan for the matcher's search and passes: with an LD06 turn's 456 beams at
/// most ~1.4 M Cortex-M4 instructions per scan (the bar: 1.5 M, a quarter of a 64 MHz
/// M4's 10 Hz period), measured in QEMU (docs/firmware.md, "Pose correction").
const MATCH_BUDGET_READS: u32 = 36_000;
/// A face band's hit offset, in σ (Q8).
const OFFSET_PER_SIGMA_Q8: u32 = 256;
/// A face band's least overlap (‰): its thick walls let a wrong pose touch some of them. 350
/// rather than 500: points entering a new area still fix the pose from the rest (host replay,
/// drives 1–20 and missions 1–4, docs/firmware.md "Pose correction").
const MIN_OVERLAP_PERMILLE: u16 = 350;
/// A face band's quality probe, in σ (Q8).
const PROBE_PER_SIGMA_Q8: u32 = 256;
/// A face band's priors are the defaults' divided by this. The defaults weigh the prediction
/// against points of about one cell's noise; a band's points (σ of several cells) each say
/// less, so the same prior holds the pose at the prediction. Measured on the firmware's
/// simulated runs (σ = 3 cells, issue 39's odometry, online max F1, docs/firmware.md): ÷4
/// lifts the stop-and-scan runs (seeds 1–15) from a mean of 0.526 to 0.576 and leaves the
/// runs scanning while driving (seeds 1–8) where they were (0.527); ÷2 and ÷8 did less on
/// seeds 1–5. (Measured before the filter of `crate::localize::fuse`, with the defaults'
/// priors then four times today's; with the filter ÷4 of today's defaults was kept, as a
/// sixteenth of today's did no better while driving, seeds 1–10.)
const BAND_PRIOR_DIVISOR: u16 = 4;
/// The match's σ per axis ([`MatchConfig::match_sigma_mm`]) in the sensor's σ (Q8): a match
/// is off by about a fifth of its beams' noise (one match at its true pose against the
/// true-pose map, simulated runs: 16 mm at σ = 50 mm, 22 mm at σ = 150 mm; `match_eval
/// --per-scan --oracle --fresh`).
const MATCH_SIGMA_PER_SIGMA_Q8: u32 = 51;
/// The match's heading σ, millidegrees per mm of the sensor's σ (Q8): 0.8° at σ = 150 mm,
/// twice one match's measured heading error, because successive scans share its bias and so
/// average it out less than independent noise (`host-sim firmware --moving --host-only`,
/// seeds 1–8, mean max F1: 0.592 at 0.4°, 0.618 at 0.8°, 0.608 at 1.6°).
const MATCH_MDEG_PER_SIGMA_MM_Q8: u32 = 1366;
/// The match's σ never falls below these (mm, millidegrees): a cell's quantisation.
const MIN_MATCH_SIGMA_MM: u32 = 5;
const MIN_MATCH_SIGMA_MDEG: u32 = 60;

impl RunConfig {
    /// The sensor's σ in mm (`sigma_milli_cells` of `cell_mm`, saturating).
    fn sigma_mm(&self) -> u32 {
        let mm = u64::from(self.sigma_milli_cells) * u64::from(self.cell_mm) / 1000;
        u32::try_from(mm).unwrap_or(u32::MAX)
    }

    /// The mapper settings: Hähnel's ray model with the free update scaled by
    /// `free_update_q8` and, with `face_band`, the band of σ = `sigma_milli_cells`; default
    /// clamp. [`crate::Error::InvalidModel`] if the scale is out of range or σ rounds to 0 mm.
    pub fn mapper_config(&self) -> Result<MapperConfig> {
        let model = InverseSensorModel::hahnel_free_scaled(self.free_update_q8)?;
        let model = if self.face_band {
            // The far edge is 0 for a band of 3 cells or more (the firmware's default); a
            // narrower band (`RunConfig::with_sensor`) takes f64 arithmetic here, once per
            // configuration, the same on the board and the host.
            model
                .with_face_band(self.sigma_mm())?
                .with_far_edge(self.band_far_edge_q8())?
        } else {
            model
        };
        Ok(MapperConfig {
            max_range_mm: self.max_range_mm,
            min_range_mm: self.min_range_mm,
            model,
            ..MapperConfig::new(self.max_range_mm)
        })
    }

    /// The forward model (maximum range in cells = `max_range_mm / cell_mm`).
    pub fn forward_model(&self) -> Result<ForwardModel> {
        ForwardModel::gaussian(
            f64::from(self.sigma_milli_cells) / 1000.0,
            f64::from(self.outlier_ppm) / 1e6,
            f64::from(self.max_range_mm) / f64::from(self.cell_mm.max(1)),
        )
    }

    /// The scan matcher's settings ([`MatchConfig::default`], measured on the shared logs),
    /// hits matched up to the sensor's range and from its minimum range on; with no odometry
    /// ([`PoseInput::Fixed`]) [`MatchConfig::without_odometry`]. `None` when correction is off.
    pub fn match_config(&self) -> Option<MatchConfig> {
        if self.correction == PoseCorrection::Off {
            return None;
        }
        let d = MatchConfig::default();
        let sigma = self.sigma_mm();
        let c = MatchConfig {
            max_range_mm: d.max_range_mm.min(self.max_range_mm),
            min_range_mm: d.min_range_mm.max(self.min_range_mm),
            budget_reads: MATCH_BUDGET_READS,
            odometry: self.odometry,
            match_sigma_mm: to_u16(
                (sigma.saturating_mul(MATCH_SIGMA_PER_SIGMA_Q8) / 256).max(MIN_MATCH_SIGMA_MM),
            ),
            match_sigma_mdeg: to_u16(
                (sigma.saturating_mul(MATCH_MDEG_PER_SIGMA_MM_Q8) / 256).max(MIN_MATCH_SIGMA_MDEG),
            ),
            ..d
        };
        let c = if self.face_band {
            // The band's occupied mass lies behind the reading (its weighted centre about σ
            // behind it), and it is several cells thick: points go where it is, the quality
            // probes step across it, and a wrong pose touching a few thick walls is not an
            // overlap; its noisier points weigh less against the prediction.
            MatchConfig {
                hit_offset_mm: to_u16(sigma.saturating_mul(OFFSET_PER_SIGMA_Q8) / 256),
                probe_mm: c
                    .probe_mm
                    .max(sigma.saturating_mul(PROBE_PER_SIGMA_Q8) / 256),
                min_overlap_permille: c.min_overlap_permille.max(MIN_OVERLAP_PERMILLE),
                prior_trans_q8: c.prior_trans_q8 / BAND_PRIOR_DIVISOR,
                prior_rot: c.prior_rot / BAND_PRIOR_DIVISOR,
                ..c
            }
        } else {
            c
        };
        Some(match self.poses {
            PoseInput::Link => c,
            PoseInput::Fixed => c.without_odometry(),
        })
    }

    /// The sampler settings. Never-observed cells start as [`RunConfig::unknown_threshold`]
    /// says; online, cells are seeded from their log-odds when first observed
    /// ([`crate::session::Session::insert`]).
    pub fn sampler_config(&self) -> SamplerConfig {
        SamplerConfig {
            // f32 arithmetic: the Cortex-M4F has it in hardware (f64 would be ~2.6 KiB of
            // software floating point in flash). Exact for every ppm below 2^24.
            p_rand_patch: self.p_rand_patch_ppm as f32 / 1e6,
            burn_in_sweeps: self.burn_in_sweeps,
            max_candidates: self.max_candidates,
            init_threshold: self.unknown_threshold(),
            tile_shift: self.sampler_tile_shift,
            visit_sweeps: self.visit_sweeps,
            seed: self.seed,
            block_grid: crate::sampler::gibbs::DEFAULT_BLOCK_GRID,
            data: self.data,
            evidence_gain_q8: self.evidence_gain_q8,
            evidence_free_q8: self.evidence_free_q8,
            data_candidate: self.data_candidate,
            floor_log_prior: crate::sampler::gibbs::FLOOR_LOG_PRIOR,
            estimator: self.estimator,
            hot_share: self.hot_share,
        }
    }
}

impl RunConfig {
    /// The sampler's initial-sample threshold ([`SamplerConfig::init_threshold`]): which state
    /// a never-observed cell (log-odds 0) starts in, in the sample and wherever the window
    /// brings in unknown cells. Occupied (−1 LSB, [`SamplerConfig`]'s default) unless the
    /// evidence term is read without a face band; free (0) then.
    ///
    /// Why: the evidence term gives a never-observed cell no data, so it keeps its start until
    /// the border prior flips it, which the prior seldom does inside a consistent region — an
    /// online budget rarely gets there. With the face band (a noisy sensor: the simulator's
    /// σ = 3 cells) the unobserved cells next to mapped ones are mostly behind the band's
    /// thick walls, and starting them occupied is right (online max F1 0.828 against 0.816
    /// started free, seeds 1-5 at 2 000 updates). Without it (a precise sensor: the textbook
    /// model, every shared log) they are mostly gaps between diverging beams in free space —
    /// on fhw, experiment 1, 11 949 of the 13 752 scored ones — and starting them occupied
    /// left the robot's sampler below its own log-odds map (0.720 against 0.732; started free
    /// 0.799, eval-log's offline chain 0.837; docs/results.md, "Never-observed cells start free without a band").
    /// The rays and hybrid terms carve free space along every ray and keep the default.
    pub fn unknown_threshold(&self) -> LogOdds {
        if self.face_band || self.data != DataTerm::Evidence {
            SamplerConfig::default().init_threshold
        } else {
            LogOdds::ZERO
        }
    }
}

/// `v` as a `u16`, saturating.
fn to_u16(v: u32) -> u16 {
    u16::try_from(v).unwrap_or(u16::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Budget;
    use crate::LogOdds;

    /// A session's mapper gets the far edge of a band narrower than 3 cells (what eval-log's
    /// robot mode maps with), and none at the firmware's σ = 3 cells.
    #[test]
    fn a_narrow_band_keeps_its_far_edge() {
        let narrow = RunConfig::ROBOT.with_sensor(1.5, 0.0).unwrap();
        assert!(narrow.face_band);
        let far = narrow.band_far_edge_q8();
        assert!(far > 0 && far < 256, "{far}");
        let sigma_mm = narrow.sigma_milli_cells * narrow.cell_mm / 1000;
        let want = InverseSensorModel::hahnel()
            .with_face_band(sigma_mm)
            .and_then(|m| m.with_far_edge(far))
            .unwrap();
        assert_eq!(narrow.mapper_config().unwrap().model, want);
        assert_eq!(RunConfig::ROBOT.band_far_edge_q8(), 0);
    }

    /// Never-observed cells start occupied with the face band (the simulator's robot) or a ray
    /// term, and free on the evidence without a band (a precise sensor's settings): in the
    /// sample a session starts with and wherever a scan leaves cells unobserved.
    #[cfg(feature = "alloc")]
    #[test]
    fn unknown_cells_start_free_on_the_evidence_without_a_band() {
        use crate::session::{Owned, Session, Sizes};
        use crate::{Angle, Beam, Pose, Range};
        let band = RunConfig::ROBOT
            .with_origin_mm(-1600, -1600)
            .with_max_range_mm(1500)
            .with_correction(PoseCorrection::Off)
            .with_budget(Budget::Fixed { updates: 0 });
        // An fhw-like sensor (σ 0.82 cells, 61 % unsupported hits): the textbook model.
        let precise = band.with_sensor(0.82, 0.61).unwrap();
        assert!(band.face_band && !precise.face_band);
        assert_eq!(band.sampler_config().init_threshold, LogOdds(-1));
        assert_eq!(precise.sampler_config().init_threshold, LogOdds::ZERO);
        assert_eq!(RunConfig::PAPER.unknown_threshold(), LogOdds(-1));
        // A robot in a round room of radius 1 m, every 8th degree: gaps between the beams.
        let beams: Vec<Beam> = (0..45)
            .map(|d| Beam {
                angle: Angle::from_centidegrees(800 * d),
                range: Range::Hit(1000),
            })
            .collect();
        for (config, unknown_occupied) in [(band, true), (precise, false)] {
            let mut s = Session::new(config, Owned::<u8>::buffers(&Sizes::grid(64, 64))).unwrap();
            s.insert(&Pose::default(), &beams).unwrap();
            let (mut observed, mut unobserved) = (0, 0);
            for (i, l) in s.log_odds().iter().enumerate() {
                let want = if l.0 == 0 {
                    unobserved += 1;
                    unknown_occupied
                } else {
                    observed += 1;
                    l.0 > 0
                };
                assert_eq!(s.gibbs().occupied(i), want, "cell {i}, log-odds {}", l.0);
            }
            assert!(
                observed > 100 && unobserved > 1000,
                "{observed} {unobserved}"
            );
        }
    }

    #[test]
    fn config_builds_the_models() {
        let budget = Budget::Fixed { updates: 100 };
        let c = RunConfig::PAPER
            .with_origin_mm(-6400, -6400)
            .with_max_range_mm(3750)
            .with_seed(7)
            .with_budget(budget);
        let g = c.geometry(256, 256).unwrap();
        assert_eq!(g.origin_mm(), (-6400, -6400));
        assert_eq!(c.mapper_config(), Ok(MapperConfig::new(3750)));
        let robot = RunConfig::ROBOT
            .with_max_range_mm(3750)
            .with_seed(7)
            .with_budget(budget);
        // The constant is the robot's noise matching at its own σ.
        assert_eq!(robot, robot.with_noise_matched(3.0));
        // The default: the robot's, at the origin, an LD06's range and turn, seed 1.
        let d = RunConfig::default();
        assert_eq!(d, RunConfig::ROBOT);
        assert_eq!(
            (d.origin_x_mm, d.origin_y_mm, d.max_range_mm, d.seed),
            (0, 0, 12_000, 1)
        );
        assert_eq!(
            d.budget,
            Budget::Time {
                period_us: 100_000,
                max_updates: u32::MAX
            }
        );
        // σ = 3 cells of 50 mm: the face band, the evidence as it is.
        assert!(robot.face_band);
        assert_eq!(
            (
                robot.free_update_q8,
                robot.evidence_free_q8,
                robot.evidence_gain_q8
            ),
            (256, 256, 256)
        );
        let m = robot.mapper_config().unwrap();
        assert_eq!(
            m.model.kind(),
            crate::map::sensor_model::InverseModelKind::FaceBand { sigma_mm: 150 }
        );
        assert_eq!(m.model.occ_increment(), LogOdds(1024));
        // A precise sensor (σ = 0.67 cells): no band; the free update split, the 1/σ gain.
        let precise = robot.with_noise_matched(0.67);
        assert!(!precise.face_band);
        assert_eq!(precise.sigma_milli_cells, 670);
        assert_eq!(
            (precise.free_update_q8, precise.evidence_free_q8),
            (256, 256)
        );
        assert_eq!(
            precise.evidence_gain_q8,
            crate::config::noise::noise_matched_gain_q8(0.67)
        );
        // σ = 1.5 cells: the band.
        assert!(robot.with_noise_matched(1.5).face_band);
        let split = RunConfig {
            face_band: false,
            free_update_q8: 141,
            ..robot
        };
        let m = split.mapper_config().unwrap();
        assert_eq!(m.model.free_increment(), LogOdds(-564));
        for bad in [0, 257] {
            let c = RunConfig {
                free_update_q8: bad,
                ..robot
            };
            assert_eq!(c.mapper_config(), Err(crate::Error::InvalidModel));
        }
        assert_eq!(
            c.forward_model().unwrap(),
            ForwardModel::gaussian(3.0, 0.01, 75.0).unwrap()
        );
        assert_eq!(c.sampler_config().seed, 7);
        assert_eq!(c.sampler_config().p_rand_patch, 0.001);
    }
}
