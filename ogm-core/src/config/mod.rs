//! The run's settings as plain data: [`RunConfig`], what a host sends the robot first
//! ([`crate::wire::HostMsg::Config`]) and what a robot without a host runs with, and the choices
//! it names (the sampler's data term and estimator, the work budget, the lidar, where poses come
//! from). Each part of the engine is built from it by [`crate::session::Session::new`];
//! [`noise`] holds the settings matched to a sensor's range noise.

pub mod noise;
pub mod sensor;

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::types::angle::Angle;
use crate::types::geometry::{GridGeometry, Pose};

/// How many sampler patch updates the robot runs after each scan.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Budget {
    /// Exactly this many.
    Fixed {
        /// Patch updates per scan.
        updates: u32,
    },
    /// As many as fit until `period_us` (board time) after the scan was complete, at most
    /// `max_updates`; the count actually run is reported in [`crate::wire::ScanReport::sampler_updates`].
    Time {
        /// Scan period, µs of the board's timer.
        period_us: u32,
        /// Upper bound per scan.
        max_updates: u32,
    },
}

/// The run's settings, sent by the host before the first scan. The grid size and the buffer
/// capacities are compile-time constants of the firmware ([`crate::wire::Hello`]); everything else is here.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RunConfig {
    /// World x of the grid's lower-left corner, mm.
    pub origin_x_mm: i32,
    /// World y of the grid's lower-left corner, mm.
    pub origin_y_mm: i32,
    /// Cell edge, mm.
    pub cell_mm: u32,
    /// Sensor maximum range, mm (readings at or beyond it are "no return").
    pub max_range_mm: u32,
    /// Readings closer than this are dropped, mm.
    pub min_range_mm: u32,
    /// Sampler seed.
    pub seed: u64,
    /// Forward model σ, 1/1000 cells.
    pub sigma_milli_cells: u32,
    /// Forward model outlier weight, parts per million.
    pub outlier_ppm: u32,
    /// p_randPatch, parts per million.
    pub p_rand_patch_ppm: u32,
    /// Sweeps before marginals are counted.
    pub burn_in_sweeps: u32,
    /// Candidates per patch.
    pub max_candidates: u8,
    /// Sampler tiles are 2^this cells square.
    pub sampler_tile_shift: u8,
    /// Sweeps of a tile per visit (0 counts as 1).
    pub visit_sweeps: u8,
    /// Sampler work per scan.
    pub budget: Budget,
    /// Changed log-odds tiles streamed after each scan (the rest follow later).
    pub tiles_per_scan: u16,
    /// Marginal-count tiles streamed after each scan (round robin).
    pub count_tiles_per_scan: u16,
    /// The sampler's measurement term.
    pub data: DataTerm,
    /// Scale of the evidence term, Q8 (256 = the log-odds map as it is).
    pub evidence_gain_q8: u16,
    /// Relative scale of free evidence, Q8 (`SamplerConfig::evidence_free_q8`).
    pub evidence_free_q8: u16,
    /// Scale of the mapper's free update, Q8, 1..=256 (256 = Hähnel's textbook model;
    /// [`noise::noise_matched_free_q8`] for a noisy sensor). A settings file written
    /// before the field existed (JSON without it) reads as 256, the model it then meant;
    /// postcard always carries it.
    #[serde(default = "textbook_free_update")]
    pub free_update_q8: u16,
    /// The mapper's face band ([`crate::map::sensor_model::InverseModelKind::FaceBand`], σ =
    /// `sigma_milli_cells`): a reading updates the cells within 1.5 σ of it by how likely the
    /// surface lies before them, instead of hitting its end cell. For sensors whose σ spans
    /// several cells ([`noise::face_band_for`]). A settings file without it reads as
    /// `false`, the model it then meant.
    #[serde(default)]
    pub face_band: bool,
    /// Offer the evidence's own configuration as a candidate (`SamplerConfig::data_candidate`).
    pub data_candidate: bool,
    /// The marginal estimator.
    pub estimator: Estimator,
    /// Of every 256 tile visits, how many go to tiles that changed (`SamplerConfig::hot_share`).
    pub hot_share: u8,
    /// Where the lidar sits on the robot (x forward, y left, mm; its 0° relative to the robot's
    /// heading): [`crate::lidar::pose_track::Mount`]. Zero (the robot's own pose) where a settings file
    /// lacks it.
    #[serde(default)]
    pub mount: Pose,
    /// Where the poses of lidar turns read on the robot's own UART come from. A settings file
    /// without it reads as [`PoseInput::Link`].
    #[serde(default)]
    pub poses: PoseInput,
    /// The range sensor on the robot's own UART. A settings file without it reads as
    /// [`LidarModel::Ld06`].
    #[serde(default)]
    pub lidar: LidarModel,
    /// The rolling window's margin, cells (wire version 6): when a scan's pose lies closer than
    /// this to an edge of the grid, the session moves the grid by whole tiles so that the pose
    /// is near its centre ([`crate::session::Session::shift_for`]); 0 = a fixed grid (the
    /// default, and what a settings file without it reads). The window's log-odds equal those
    /// of an unbounded map while the margin is at least the mapper's reach
    /// ([`crate::map::mapper::reach_cells`]).
    #[serde(default)]
    pub window_margin_cells: u16,
    /// Pose correction (wire version 7): whether each scan's pose — odometry, from the link or
    /// a tunnelled scan — is corrected by matching the scan against the robot's own map before
    /// it is inserted ([`crate::session::Session::insert`]). A settings file without it reads
    /// as [`PoseCorrection::Off`], the behaviour it then meant.
    #[serde(default = "no_correction")]
    pub correction: PoseCorrection,
    /// The host answers every window shift (wire version 8): with a rolling window, the lidar
    /// turn whose pose shifted the window is held, unmapped, until the host has sent back the
    /// stored tiles that entered and then [`crate::wire::HostMsg::Resume`], so the turn maps
    /// onto them however far the robot moved since the turn before. `false` (the default, and
    /// what a settings file without it reads): the turn is mapped at once, and a tile it
    /// reaches is refused when it comes back (the margin must then exceed the reach plus the
    /// farthest step between turns). Lidar turns only; tunnelled scans are never held.
    #[serde(default)]
    pub window_hold: bool,
    /// How good the robot's wheel odometry is (wire version 9), for the filter that weighs it
    /// against each match ([`crate::localize::fuse`]). A settings file without it reads as
    /// [`OdometryNoise::CHEAP_ROBOT`].
    #[serde(default = "cheap_odometry")]
    pub odometry: OdometryNoise,
}

/// The noise of the robot's wheel odometry, per step between scans: what the pose filter
/// ([`crate::localize::fuse`]) expects of it ([`RunConfig::odometry`] on the wire,
/// [`crate::localize::MatchConfig::odometry`] in the matcher). As in
/// [`crate::localize::odometry`], variances add per step, so each σ is of one step's motion.
/// Errors larger than these are still corrected (a match the filter cannot explain widens it),
/// but more slowly; smaller ones leave the matches' own errors more say than they deserve.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OdometryNoise {
    /// σ per axis, ‰ of the step's distance.
    pub trans_permille: u16,
    /// σ of the step's turn, ‰ of that turn.
    pub turn_permille: u16,
    /// Heading drift over the step, millidegrees per metre of it (a bias taken as noise, so the
    /// filter follows it).
    pub drift_mdeg_per_m: u16,
}

impl OdometryNoise {
    /// A small uncalibrated differential-drive robot (the figures and their sources:
    /// [`crate::localize::odometry::OdometryModel::CHEAP_ROBOT`]): 2 % of the distance, 5 % of
    /// the turn, 0.5° per metre. The default: it does not flatter odometry.
    pub const CHEAP_ROBOT: OdometryNoise = OdometryNoise {
        trans_permille: 20,
        turn_permille: 50,
        drift_mdeg_per_m: 500,
    };

    /// Issue 39's odometry, calibrated ([`crate::localize::odometry::OdometryModel::ISSUE_39`]):
    /// 1 % of the distance, 2 % of the turn, 0.11° per metre.
    pub const ISSUE_39: OdometryNoise = OdometryNoise {
        trans_permille: 10,
        turn_permille: 20,
        drift_mdeg_per_m: 110,
    };
}

impl Default for OdometryNoise {
    fn default() -> Self {
        OdometryNoise::CHEAP_ROBOT
    }
}

fn cheap_odometry() -> OdometryNoise {
    OdometryNoise::CHEAP_ROBOT
}

/// Whether the robot corrects its poses by scan-to-map matching ([`crate::localize`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PoseCorrection {
    /// Poses are used as they come (exact poses: a simulator's truth, a log's corrected poses).
    Off,
    /// Each scan is matched against the map, starting from the odometry prediction, and
    /// inserted at the corrected pose when the match can be trusted (else at the prediction).
    /// With [`PoseInput::Fixed`] (no odometry at all) the robot tracks itself from matching
    /// alone. The robot's default.
    #[default]
    Match,
}

/// `RunConfig::correction`'s value where a settings file lacks it.
fn no_correction() -> PoseCorrection {
    PoseCorrection::Off
}

/// The range sensor on the robot's own UART ([`crate::lidar::turn`]); scans a host tunnels do not use
/// it.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LidarModel {
    /// LDROBOT LD06 (or LD19), [`crate::lidar::ld06`]: 230 400 baud, streams 12-point packets stamped
    /// with its own millisecond clock; the device never writes to it.
    #[default]
    Ld06,
    /// Slamtec RPLIDAR A1/A2 in standard scan mode, [`crate::lidar::rplidar`]: 115 200 baud; the
    /// device starts it with `STOP`, `SCAN`. Its nodes carry no time, so the lidar clock is
    /// the count of nodes received × `sample_us` (the sensor's `GET_SAMPLERATE` standard
    /// period; about 500 µs on an A1 at 2 000 samples/s). A node lost to a bit error shifts
    /// the later ones by one period.
    Rplidar {
        /// Time between two nodes, µs (1 or more).
        sample_us: u16,
    },
}

impl LidarModel {
    /// The UART baud rate the sensor talks at.
    pub const fn baud(&self) -> u32 {
        match self {
            LidarModel::Ld06 => 230_400,
            LidarModel::Rplidar { .. } => 115_200,
        }
    }

    /// Whether the settings can be used (an RPLIDAR needs a sample period).
    pub const fn is_valid(&self) -> bool {
        match self {
            LidarModel::Ld06 => true,
            LidarModel::Rplidar { sample_us } => *sample_us > 0,
        }
    }
}

/// Where the robot's poses come from when the lidar is on the robot's own UART
/// ([`crate::lidar::turn`]); scans tunnelled by a host carry their own pose and ignore it.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PoseInput {
    /// Timestamped [`crate::wire::HostMsg::Pose`] messages on the link (odometry or a localiser), at their own
    /// rate, interpolated to each lidar packet's time.
    #[default]
    Link,
    /// None: the robot stands at the world origin (what a robot powered without a host does).
    Fixed,
}

/// `RunConfig::free_update_q8`'s value where a settings file lacks it: the textbook model.
fn textbook_free_update() -> u16 {
    256
}

impl Budget {
    /// One LD06 turn of sampling after each scan: until 100 ms of board time after the scan
    /// was complete (the sensor turns at 10 Hz), with no cap on the updates. The robot's
    /// default ([`RunConfig::ROBOT`]).
    pub const LD06_TURN: Budget = Budget::Time {
        period_us: 100_000,
        max_updates: u32::MAX,
    };
}

impl Default for Budget {
    /// [`Budget::LD06_TURN`].
    fn default() -> Self {
        Budget::LD06_TURN
    }
}

impl Default for RunConfig {
    /// [`RunConfig::ROBOT`].
    fn default() -> Self {
        RunConfig::ROBOT
    }
}

impl RunConfig {
    /// The paper's settings: 5 cm cells, σ = 3 cells, 1 % outliers, p_randPatch = 0.001,
    /// border prior with 16 candidates, 16-cell sampler tiles visited for 8 sweeps; and, like
    /// [`RunConfig::ROBOT`], the grid's lower-left corner at the world origin, an LD06's
    /// 12 m range, seed 1 and [`Budget::LD06_TURN`] (set them with the `with_` builders).
    pub const PAPER: RunConfig = RunConfig {
        origin_x_mm: 0,
        origin_y_mm: 0,
        cell_mm: 50,
        max_range_mm: 12_000,
        min_range_mm: 0,
        seed: 1,
        sigma_milli_cells: 3000,
        outlier_ppm: 10_000,
        p_rand_patch_ppm: 1000,
        burn_in_sweeps: 10,
        max_candidates: 16,
        sampler_tile_shift: 4,
        // 8 sweeps share each tile's ray gather: on the firmware's simulated run (6.4 ms
        // budget) 2 475 instructions per patch instead of 4 705 with 2 (seed 1), and online
        // max F1 0.72 instead of 0.59 (mean of seeds 1-3; docs/firmware.md, "Figures").
        visit_sweeps: 8,
        budget: Budget::LD06_TURN,
        tiles_per_scan: 8,
        count_tiles_per_scan: 8,
        data: DataTerm::Rays,
        evidence_gain_q8: 256,
        evidence_free_q8: 256,
        free_update_q8: 256,
        face_band: false,
        data_candidate: false,
        estimator: Estimator::Counts,
        hot_share: 0,
        mount: Pose {
            x_mm: 0,
            y_mm: 0,
            heading: Angle(0),
        },
        poses: PoseInput::Link,
        lidar: LidarModel::Ld06,
        window_margin_cells: 0,
        correction: PoseCorrection::Off,
        window_hold: false,
        odometry: OdometryNoise::CHEAP_ROBOT,
    };

    /// The robot's settings ([`Default`]; what the firmware runs with when no host configures
    /// it, and what `host-sim firmware` sends): the paper's grid and forward model, and the
    /// sampler made for online use on a microcontroller — per-cell evidence instead of rays (no
    /// memory that grows with the mission, a bounded cost per patch), the evidence's own
    /// configuration as a candidate, the mapper's face band with the evidence as it is (what
    /// [`RunConfig::with_noise_matched`] gives at the paper's σ = 3 cells; tested), averaged
    /// estimates restarted where the evidence changes, and three quarters of the tile visits
    /// where it changed. Why each: docs/results.md, "Online sampler". A constant, so a
    /// firmware's stored settings carry no floating-point code.
    ///
    /// Grid origin (0, 0) mm, 12 m (an LD06's range), seed 1, one LD06 turn of sampling per
    /// scan ([`Budget::LD06_TURN`]): a robot sets its origin (e.g. centred on where it was
    /// switched on) with [`RunConfig::with_origin_mm`].
    pub const ROBOT: RunConfig = RunConfig {
        data: DataTerm::Evidence,
        evidence_gain_q8: 256,
        evidence_free_q8: 256,
        free_update_q8: 256,
        face_band: true,
        data_candidate: true,
        estimator: Estimator::Average {
            shift: 3,
            max_shift: 7,
            reset_on_change: true,
            rao_blackwell: false,
        },
        hot_share: 192,
        burn_in_sweeps: 2,
        correction: PoseCorrection::Match,
        ..RunConfig::PAPER
    };

    /// These settings with the grid's lower-left corner at (`x`, `y`) mm.
    #[must_use]
    pub const fn with_origin_mm(self, x: i32, y: i32) -> Self {
        RunConfig {
            origin_x_mm: x,
            origin_y_mm: y,
            ..self
        }
    }

    /// These settings with the sensor's maximum range `max_range_mm`.
    #[must_use]
    pub const fn with_max_range_mm(self, max_range_mm: u32) -> Self {
        RunConfig {
            max_range_mm,
            ..self
        }
    }

    /// These settings with sampler seed `seed`.
    #[must_use]
    pub const fn with_seed(self, seed: u64) -> Self {
        RunConfig { seed, ..self }
    }

    /// These settings with the sampler budget `budget`.
    #[must_use]
    pub const fn with_budget(self, budget: Budget) -> Self {
        RunConfig { budget, ..self }
    }

    /// These settings with a rolling window of margin `cells` (0: a fixed grid).
    #[must_use]
    pub const fn with_window_margin_cells(self, cells: u16) -> Self {
        RunConfig {
            window_margin_cells: cells,
            ..self
        }
    }

    /// These settings with the robot holding a turn that shifts the window until the host
    /// answers ([`RunConfig::window_hold`]).
    #[must_use]
    pub const fn with_window_hold(self, hold: bool) -> Self {
        RunConfig {
            window_hold: hold,
            ..self
        }
    }

    /// These settings with the robot's odometry noise `odometry` ([`RunConfig::odometry`]).
    #[must_use]
    pub const fn with_odometry_noise(self, odometry: OdometryNoise) -> Self {
        RunConfig { odometry, ..self }
    }

    /// These settings with pose correction `correction`.
    #[must_use]
    pub const fn with_correction(self, correction: PoseCorrection) -> Self {
        RunConfig { correction, ..self }
    }

    /// These settings with poses from `poses`.
    #[must_use]
    pub const fn with_poses(self, poses: PoseInput) -> Self {
        RunConfig { poses, ..self }
    }

    /// These settings with the robot's noise-matched mapper and evidence for a sensor whose
    /// range noise is `sigma` cells (and `sigma_milli_cells` set to it): the face band where
    /// σ spans several cells ([`noise::face_band_for`]; then no free scaling and the
    /// evidence as it is), else the free update split between the mapper and the evidence
    /// term ([`noise::noise_matched_free_q8`]) and the evidence gain of
    /// [`noise::noise_matched_gain_q8`].
    pub fn with_noise_matched(self, sigma: f64) -> Self {
        let sigma_milli_cells = libm::round((sigma * 1000.0).clamp(1.0, 1e9)) as u32;
        if noise::face_band_for(sigma) {
            return RunConfig {
                sigma_milli_cells,
                face_band: true,
                free_update_q8: 256,
                evidence_free_q8: 256,
                evidence_gain_q8: 256,
                ..self
            };
        }
        let free = noise::noise_matched_free_q8(sigma);
        RunConfig {
            sigma_milli_cells,
            face_band: false,
            free_update_q8: free,
            evidence_free_q8: free,
            evidence_gain_q8: noise::noise_matched_gain_q8(sigma),
            ..self
        }
    }

    /// The grid this config places a `width × height` map on.
    pub fn geometry(&self, width: u16, height: u16) -> Result<GridGeometry> {
        GridGeometry::new(
            width,
            height,
            self.cell_mm,
            self.origin_x_mm,
            self.origin_y_mm,
        )
    }
}

/// Which measurement term weights a patch's candidates (Eq. 1's product).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataTerm {
    /// The forward-model likelihood of every stored ray crossing the patch (the paper's
    /// Eq. 1). Needs the ray store; memory grows with the mission until the store thins.
    Rays,
    /// Per-cell log-odds evidence times the patch prior: no rays (see the module docs). The
    /// firmware's default.
    #[default]
    Evidence,
    /// The rays still in the store, plus the log-odds evidence scaled by the share of beams the
    /// store has dropped (decimated or thinned): equal to [`DataTerm::Rays`] until the store
    /// fills, and never losing what it drops. The share is global, which is exact in
    /// expectation because the store thins uniformly (every scan, every other ray).
    Hybrid,
}

impl DataTerm {
    /// Whether this term reads the ray store (never without the `rays` feature, which is
    /// required for [`DataTerm::Rays`] and [`DataTerm::Hybrid`]).
    #[inline]
    pub fn uses_rays(self) -> bool {
        cfg!(feature = "rays") && !matches!(self, DataTerm::Evidence)
    }

    /// Whether this build can run the term.
    #[inline]
    pub fn available(self) -> bool {
        cfg!(feature = "rays") || matches!(self, DataTerm::Evidence)
    }
}

/// The marginal estimator.
///
/// * [`Estimator::Counts`] — the paper's: after burn-in, count how often each cell is occupied
///   in the sample, one sample of every cell per sweep (see [`crate::sampler::gibbs`]).
/// * [`Estimator::Average`] — every patch update moves its cells' estimates `2^-shift` of the
///   way towards their new value: an exponentially-forgetting average that follows a map that
///   keeps changing online. The value is the drawn sample, or with `rao_blackwell` the cell's
///   *conditional* occupancy probability under Eq. 1 (the normalised weights of the candidates
///   that occupy it), which carries the information of every candidate instead of one draw.
///   Estimates start at the log-odds map's probability and, with `reset_on_change`
///   ([`crate::sampler::gibbs::Gibbs::note_changed`]), restart there when a scan first observes a cell or flips
///   the sign of its evidence — so what has not been sampled since reads as the traditional map,
///   never as a stale or empty estimate — while evidence that only grows stronger keeps the
///   draws already averaged (they were drawn under evidence of the same sign).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Estimator {
    /// Sample counts after burn-in.
    Counts,
    /// Exponentially-forgetting average per cell, weight `2^-shift` per update, the shift
    /// lengthening to `max_shift` where the evidence stays unchanged.
    Average {
        /// Log2 of the averaging length, in updates of a cell (a cell is in 9 patches, so about
        /// 9 updates per sweep), on a tile visit right after its evidence changed: 1 ..= 15.
        shift: u8,
        /// Longest averaging, `shift ..= 15`: each tile visit uses `shift` plus the log2 of
        /// one more than the tile's visits since a scan last changed a cell in it, up to this
        /// — about a running mean since the last change, where the chain has had time to mix,
        /// and a short memory where a scan just changed the posterior. `u8` estimates average
        /// at most `2^-7` per update (stochastically rounded: [`crate::sampler::gibbs::Count::average_row`]).
        max_shift: u8,
        /// Restart a cell's estimate at its log-odds probability when a scan first observes it
        /// or flips the sign of its log-odds.
        reset_on_change: bool,
        /// Average conditional probabilities (Rao-Blackwellised) instead of the draws.
        rao_blackwell: bool,
    },
}

impl Estimator {
    /// The averaging shift of a tile visit `age` visits after a scan last changed the tile:
    /// `shift + ⌊log2(age + 1)⌋`, at most `max_shift`; 0 for [`Estimator::Counts`].
    #[inline]
    pub fn shift_at(self, age: u8) -> u8 {
        match self {
            Estimator::Counts => 0,
            Estimator::Average {
                shift, max_shift, ..
            } => {
                let grow = (u32::from(age) + 1).ilog2() as u8;
                shift.saturating_add(grow).min(max_shift.max(shift))
            }
        }
    }

    /// Whether the averaging lengthens where the evidence settles (`max_shift > shift`).
    #[inline]
    pub fn lengthens(self) -> bool {
        matches!(self, Estimator::Average { shift, max_shift, .. } if max_shift > shift)
    }

    /// Whether this build can run the estimator (Rao-Blackwellised averages need the
    /// `rao-blackwell` feature).
    #[inline]
    pub fn available(self) -> bool {
        cfg!(feature = "rao-blackwell") || !self.rao_blackwellised()
    }

    /// Whether the estimator averages conditional probabilities instead of draws.
    #[inline]
    pub fn rao_blackwellised(self) -> bool {
        matches!(
            self,
            Estimator::Average {
                rao_blackwell: true,
                ..
            }
        )
    }

    /// Whether the estimator restarts cells whose evidence changed.
    #[inline]
    pub fn resets(self) -> bool {
        matches!(
            self,
            Estimator::Average {
                reset_on_change: true,
                ..
            }
        )
    }
}
