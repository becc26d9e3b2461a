//! The options of `host-sim firmware`.

use std::path::PathBuf;

use ogm_core::config::RunConfig;

/// Command-line options of `host-sim firmware`.
#[derive(Clone, Debug, clap::Args)]
pub struct FirmwareArgs {
    /// Seed: world (when generated), exploration, lidar noise and the sampler.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Ground-truth map (PNG/PGM/YAML); resampled to 5 cm and cropped to 256 × 256 cells.
    /// Default: a generated 12.8 m building.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Firmware ELF (default: build it with scripts/firmware.sh build).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Use only the first N scans.
    #[arg(long)]
    pub max_scans: Option<usize>,
    /// Sampler time budget per scan, µs of the board's timer (under -icount shift=0 one µs is
    /// 1000 instructions: 6400 = what a 64 MHz Cortex-M4 executes between two 10 Hz scans).
    #[arg(long, default_value_t = 6400)]
    pub period_us: u32,
    /// Upper bound of sampler updates per scan under the time budget.
    #[arg(long, default_value_t = 20_000)]
    pub max_updates: u32,
    /// A fixed number of sampler updates per scan instead of the time budget.
    #[arg(long)]
    pub fixed_updates: Option<u32>,
    /// Log-odds tiles streamed per scan.
    #[arg(long, default_value_t = 8)]
    pub tiles_per_scan: u16,
    /// Marginal-count tiles streamed per scan.
    #[arg(long, default_value_t = 8)]
    pub count_tiles_per_scan: u16,
    /// Sweeps of a sampler tile per visit (more: the tile's ray gather is shared by more patch
    /// updates; fewer: the sampler moves over the map sooner). Default: `RunConfig::ROBOT`'s.
    #[arg(long)]
    pub visit_sweeps: Option<u8>,
    /// Mix garbage into the input (the firmware must skip it; the comparison still holds).
    #[arg(long)]
    pub garbage: bool,
    /// Corrupt this many of every million input bytes (XOR with a random non-zero byte, seeded
    /// by `--seed`): a noisy UART. The map must then also equal a host replay of only the
    /// packets and frames that arrived intact (10000 = 1 %).
    #[arg(long, default_value_t = 0)]
    pub noise_ppm: u32,
    /// Send every host frame this many times in a row (exact repeats are ignored by the robot;
    /// on a noisy link a frame is then lost only if every copy is damaged).
    #[arg(long, default_value_t = 1)]
    pub repeat_frames: usize,
    /// The robot scans while it drives, at the LD06's rate (10 Hz, 456 points per turn, 0.4 m/s),
    /// not only when stopped.
    #[arg(long)]
    pub moving: bool,
    /// The simulated lidar's range noise σ, cells (default: the paper's 3); the robot's settings
    /// are made for it (`RunConfig::with_sensor`).
    #[arg(long)]
    pub sigma_cells: Option<f64>,
    /// The robot loop: the lidar's LD06 bytes on the firmware's own UART (UART0) while the robot
    /// drives the simulated mission (`--moving`), its poses on the link at 25 Hz, stamped in the
    /// lidar's clock; the lidar sits 60 mm ahead of the robot's centre. Checks the map
    /// bit-exact against the host running the same library on the same two byte streams, and
    /// every turn's pose against the simulator's truth.
    #[arg(long)]
    pub robot: bool,
    /// With `--robot`: the lidar on the robot's UART, `ld06` or `rplidar` (an RPLIDAR A1:
    /// the firmware is built with its `rplidar` feature and sends the sensor `SCAN`).
    #[arg(long, value_enum, default_value_t = LidarArg::Ld06)]
    pub lidar: LidarArg,
    /// With `--robot`: how the simulated lidar turns, `ld06` (10 Hz, 456 points) or `a1`
    /// (5.6 Hz, 360 points 1° apart); default: the lidar's own. The same pattern sent as
    /// LD06 packets or as RPLIDAR nodes carries the same beams at the same times.
    #[arg(long, value_enum)]
    pub pattern: Option<PatternArg>,
    /// A long mission: the robot (scanning while it drives) keeps exploring, then patrolling,
    /// until it has taken this many scans.
    #[arg(long)]
    pub mission_scans: Option<usize>,
    /// After the last scan, let the robot stand still and sample for these many seconds of
    /// board time in all (cumulative marks, e.g. `1,5,30`), scoring the map at each mark with
    /// `--accuracy`.
    #[arg(long, value_delimiter = ',')]
    pub idle: Vec<f64>,
    /// Soak: send this many scans, cycling through the simulated run's scans.
    #[arg(long)]
    pub soak_scans: Option<usize>,
    /// QEMU timeout, seconds.
    #[arg(long, default_value_t = 300)]
    pub timeout: u64,
    /// Also measure the accuracy cost of the firmware's bounds: the eval-sim sampler (offline,
    /// 20 + 100 sweeps) with the firmware's compile-time sizes next to unbounded host buffers,
    /// scored against ground truth; and, after a QEMU run, the same online.
    #[arg(long)]
    pub accuracy: bool,
    /// No QEMU (with --accuracy).
    #[arg(long)]
    pub host_only: bool,
    /// Worlds (seeds `seed`, `seed + 1`, …) the accuracy comparison is pooled over.
    #[arg(long, default_value_t = 1)]
    pub runs: u32,
    /// Write report.json (and the raw stream) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Show QEMU's output (decoded defmt log) instead of writing it to a log file.
    #[arg(long)]
    pub verbose: bool,
    /// A real laser log (CARMEN, plain or gzip) through the firmware: its scans as LD06 turns
    /// on the lidar UART, its poses as pose messages (needs `--out DIR`: the robot's map as
    /// `map.yaml`, scored like `eval-log` in `report.json`).
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// With `--log`: `eval-log`'s experiment (1 = every 2nd beam, 2 = every 2nd pose and beam,
    /// 3 = every 10th pose and 2nd beam, 0 = everything).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub experiment: u8,
    /// With `--log`: make the robot's grid a rolling window that shifts when the robot comes
    /// closer than this many cells to an edge (`RunConfig::window_margin_cells`; at most half
    /// the grid less a tile, 112 on the QEMU board); 0: a fixed grid around the start.
    #[arg(long, default_value_t = 0)]
    pub window_margin: u16,
    /// With `--log` and `--window-margin`: the host does not send stored tiles back (a region
    /// visited again starts unknown on the robot; the host merges the visits' log-odds).
    #[arg(long)]
    pub no_restore: bool,
    /// With `--log`: map only up to this range, mm, as `eval-log --range-cap` does: the robot
    /// and the benchmark it is scored against both (0: eval-log's default). The window's map equals
    /// an unbounded one only while the margin is at least the mapper's reach
    /// (`Session::window_reach_cells`: the range and the face band, in cells, plus one).
    #[arg(long, default_value_t = 0)]
    pub range_cap: u32,
    /// Drifting wheel odometry on the link instead of the true poses: `MODEL[:SEED]` (SEED
    /// default: `--seed`). Per step between scans, with d the distance and dθ the turn:
    /// `issue39` — translation noise σ = 1 % of d per axis, turn noise σ = 2 % of dθ, heading
    /// bias 0.11°/m; `cheap` (a small uncalibrated robot) — translation noise 2 % of d, turn
    /// noise 5 % of dθ plus 0.2°/m, heading bias 0.5°/m, turn scale +2 %, distance scale +1 %
    /// (`ogm_core::localize::odometry::OdometryModel`). The maps are still scored against the
    /// true world; the report gives the odometry's and the robot's corrected poses' error
    /// against the truth.
    #[arg(long, value_parser = super::odometry::parse_odometry)]
    pub odometry_noise: Option<super::odometry::OdometryArg>,
    /// Pose correction on the robot (`RunConfig::correction`): `match` (scan-to-map matching,
    /// the robot's default) or `off` (poses used as sent). Default: `match` with
    /// `--odometry-noise`, else `off` (the true poses need no correction).
    #[arg(long, value_enum)]
    pub correction: Option<CorrectionArg>,
    /// What the robot is told of its odometry (`RunConfig::odometry`, the pose filter's
    /// expectation): `cheap` (2 % of the distance, 5 % of the turn, 0.5°/m; the robot's default)
    /// or `issue39` (1 %, 2 %, 0.11°/m: `--odometry-noise issue39` calibrated). Default: the
    /// robot's own default, whatever odometry the simulator sends.
    #[arg(long, value_enum)]
    pub robot_odometry: Option<RobotOdometryArg>,
    /// Only decode a captured map stream (e.g. firmware/target/qemu/uart1.out) and summarise it.
    #[arg(long)]
    pub decode: Option<PathBuf>,
    /// The sampler's settings (default: the robot's, `RunConfig::ROBOT`).
    #[command(flatten)]
    pub sampler: SamplerArgs,
}

impl Default for FirmwareArgs {
    fn default() -> Self {
        FirmwareArgs {
            seed: 1,
            map: None,
            elf: None,
            max_scans: None,
            period_us: 6400,
            max_updates: 20_000,
            fixed_updates: None,
            tiles_per_scan: 8,
            count_tiles_per_scan: 8,
            visit_sweeps: None,
            garbage: false,
            noise_ppm: 0,
            repeat_frames: 1,
            soak_scans: None,
            timeout: 300,
            moving: false,
            sigma_cells: None,
            robot: false,
            lidar: LidarArg::Ld06,
            pattern: None,
            mission_scans: None,
            idle: Vec::new(),
            sampler: SamplerArgs::default(),
            accuracy: false,
            host_only: false,
            runs: 1,
            out: None,
            verbose: false,
            decode: None,
            log: None,
            experiment: 1,
            window_margin: 0,
            no_restore: false,
            range_cap: 0,
            odometry_noise: None,
            correction: None,
            robot_odometry: None,
        }
    }
}

/// `--correction`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CorrectionArg {
    /// Poses used as sent.
    Off,
    /// Scan-to-map matching.
    Match,
}

impl CorrectionArg {
    /// The settings' value.
    pub fn setting(self) -> ogm_core::config::PoseCorrection {
        match self {
            CorrectionArg::Off => ogm_core::config::PoseCorrection::Off,
            CorrectionArg::Match => ogm_core::config::PoseCorrection::Match,
        }
    }
}

/// `--robot-odometry`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RobotOdometryArg {
    /// `OdometryNoise::CHEAP_ROBOT`.
    Cheap,
    /// `OdometryNoise::ISSUE_39`.
    Issue39,
}

impl RobotOdometryArg {
    /// The settings' value.
    pub fn setting(self) -> ogm_core::config::OdometryNoise {
        match self {
            RobotOdometryArg::Cheap => ogm_core::config::OdometryNoise::CHEAP_ROBOT,
            RobotOdometryArg::Issue39 => ogm_core::config::OdometryNoise::ISSUE_39,
        }
    }
}

/// `--lidar`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum LidarArg {
    /// LDROBOT LD06.
    #[default]
    Ld06,
    /// Slamtec RPLIDAR A1, standard scan (2 000 samples/s).
    Rplidar,
}

impl LidarArg {
    /// The settings' lidar.
    pub fn model(self) -> ogm_core::config::LidarModel {
        match self {
            LidarArg::Ld06 => ogm_core::config::LidarModel::Ld06,
            LidarArg::Rplidar => ogm_core::config::LidarModel::Rplidar { sample_us: 500 },
        }
    }

    /// The firmware features the image needs.
    pub fn features(self) -> Option<&'static str> {
        match self {
            LidarArg::Ld06 => None,
            LidarArg::Rplidar => Some("rplidar"),
        }
    }
}

/// `--pattern`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PatternArg {
    /// 10 Hz, 456 points ([`crate::firmware::robot::ScanPattern::LD06`]).
    Ld06,
    /// 5.6 Hz, 360 points ([`crate::firmware::robot::ScanPattern::A1`]).
    A1,
}

/// Sampler settings sent to the robot (each defaults to `RunConfig::ROBOT`'s).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct SamplerArgs {
    /// Measurement term: rays, evidence or hybrid.
    #[arg(long, value_parser = parse_data_term)]
    pub data: Option<ogm_core::config::DataTerm>,
    /// Evidence gain, Q8 (256 = the log-odds as they are).
    #[arg(long)]
    pub evidence_gain: Option<u16>,
    /// Relative scale of free evidence, Q8.
    #[arg(long)]
    pub evidence_free: Option<u16>,
    /// Scale of the mapper's free update, Q8, 1..=256 (256 = Hähnel's textbook model).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub free_update: Option<u16>,
    /// Offer the evidence's own configuration as a candidate (true/false).
    #[arg(long)]
    pub data_candidate: Option<bool>,
    /// Marginal estimator: `counts`, or `avg:SHIFT[-MAX][:reset]` / `rb:SHIFT[-MAX][:reset]`
    /// (average of draws / of conditional probabilities over about 2^SHIFT updates of a cell,
    /// lengthening to 2^MAX where a tile's evidence stays unchanged; `reset` restarts changed
    /// cells at their log-odds probability). The robot's: `avg:3-7:reset`.
    #[arg(long, value_parser = parse_estimator)]
    pub estimator: Option<ogm_core::config::Estimator>,
    /// Tile visits (of 256) that go to changed tiles.
    #[arg(long)]
    pub hot_share: Option<u8>,
    /// Candidates per patch (top-k of the prior).
    #[arg(long)]
    pub max_candidates: Option<u8>,
}

impl SamplerArgs {
    /// `config` with these settings applied.
    pub fn apply(&self, config: RunConfig) -> RunConfig {
        RunConfig {
            data: self.data.unwrap_or(config.data),
            evidence_gain_q8: self.evidence_gain.unwrap_or(config.evidence_gain_q8),
            evidence_free_q8: self.evidence_free.unwrap_or(config.evidence_free_q8),
            free_update_q8: self.free_update.unwrap_or(config.free_update_q8),
            data_candidate: self.data_candidate.unwrap_or(config.data_candidate),
            estimator: self.estimator.unwrap_or(config.estimator),
            hot_share: self.hot_share.unwrap_or(config.hot_share),
            max_candidates: self.max_candidates.unwrap_or(config.max_candidates),
            ..config
        }
    }
}

/// `rays`, `evidence` or `hybrid`.
pub fn parse_data_term(s: &str) -> Result<ogm_core::config::DataTerm, String> {
    use ogm_core::config::DataTerm;
    match s {
        "rays" => Ok(DataTerm::Rays),
        "evidence" => Ok(DataTerm::Evidence),
        "hybrid" => Ok(DataTerm::Hybrid),
        _ => Err(format!("`{s}`: expected rays, evidence or hybrid")),
    }
}

/// `counts`, or `avg:SHIFT[-MAX]` / `rb:SHIFT[-MAX]` followed by `:reset` (restart changed
/// cells): the average of draws, or of conditional probabilities (Rao-Blackwellised), whose
/// shift lengthens from SHIFT to MAX (default: SHIFT) where the evidence settles.
pub fn parse_estimator(s: &str) -> Result<ogm_core::config::Estimator, String> {
    use ogm_core::config::Estimator;
    let parts: Vec<&str> = s.split(':').collect();
    let bad =
        || format!("`{s}`: expected counts, avg:SHIFT[-MAX][:reset] or rb:SHIFT[-MAX][:reset]");
    match parts.as_slice() {
        ["counts"] => Ok(Estimator::Counts),
        [kind @ ("avg" | "rb"), shifts, rest @ ..] => {
            let (shift, max) = shifts.split_once('-').unwrap_or((shifts, shifts));
            let parse = |x: &str| x.parse::<u8>().ok().filter(|v| (1..=15).contains(v));
            let (Some(shift), Some(max_shift)) = (parse(shift), parse(max)) else {
                return Err(format!("`{s}`: SHIFT and MAX must be 1 to 15"));
            };
            if max_shift < shift {
                return Err(format!("`{s}`: MAX must be at least SHIFT"));
            }
            let reset_on_change = match rest {
                [] => false,
                ["reset"] => true,
                _ => return Err(bad()),
            };
            Ok(Estimator::Average {
                shift,
                max_shift,
                reset_on_change,
                rao_blackwell: *kind == "rb",
            })
        }
        _ => Err(bad()),
    }
}

#[cfg(test)]
mod tests {
    use super::parse_estimator;
    use ogm_core::config::Estimator;

    #[test]
    fn estimator_options_parse_and_bad_ones_say_why() {
        assert_eq!(parse_estimator("counts"), Ok(Estimator::Counts));
        assert_eq!(
            parse_estimator("avg:3-7:reset"),
            Ok(Estimator::Average {
                shift: 3,
                max_shift: 7,
                reset_on_change: true,
                rao_blackwell: false,
            })
        );
        assert_eq!(
            parse_estimator("rb:2"),
            Ok(Estimator::Average {
                shift: 2,
                max_shift: 2,
                reset_on_change: false,
                rao_blackwell: true,
            })
        );
        for bad in [
            "avg",
            "avg:0",
            "avg:16",
            "avg:5-3",
            "avg:3-x",
            "avg:3:later",
            "mean",
        ] {
            assert!(parse_estimator(bad).is_err(), "{bad}");
        }
        assert!(parse_estimator("avg:5-3").unwrap_err().contains("at least"));
    }
}
