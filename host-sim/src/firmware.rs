//! `host-sim firmware`: the firmware in QEMU on a simulated run, checked cell for cell against
//! ogm-core on the host.
//!
//! 1. A world that fits the firmware's 256 × 256 grid (generated, or `--map` cropped), explored
//!    with the simulator's lidar ([`crate::sim::simulate`]).
//! 2. The robot's input ([`crate::link::encode_run`]): settings, then per scan `ScanStart`
//!    (known pose), the scan as LD06 packets, `ScanEnd`; `Finish`. Optionally with garbage.
//! 3. The ELF (`scripts/firmware.sh build`, or `--elf`) boots in QEMU mps2-an386
//!    (`scripts/firmware.sh qemu`, `-icount shift=0`, defmt decoded into the log) with UART1 on a
//!    Unix socket: the input goes in, the map stream comes out.
//! 4. **Replay**: the same input bytes go through the same ogm-core code on the host — link
//!    demultiplexer, mapper, ray store, sampler with the firmware's compile-time sizes, the seed
//!    from the settings and exactly the number of sampler updates the firmware reported per scan
//!    — and every report, every streamed tile (at the time it was sent) and the final map
//!    (log-odds, marginal counts, sample) must be identical.
//! 5. Figures: instructions per cell update / scan / sampled patch (QEMU `-icount shift=0`: one
//!    instruction = 1 ns of the board's timer), stack high-water mark, stream size.
//!
//! `--accuracy` adds the cost of the firmware's bounds: the same replay with unbounded buffers
//! (every ray, every scan, no per-tile list limit, `u32` counts), both scored against ground
//! truth like `eval-sim`.

use ogm_firmware::sizes::MPS2_AN386 as FW;
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, ensure, Context};
use ogm_core::config::{Budget, LidarModel, RunConfig};
use ogm_core::sampler::gibbs::Count;
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{Counters, Done, SamplerReport, ScanReport};
use ogm_core::ScanBuf;
use ogm_firmware::app::MAX_BEAMS;
use ogm_firmware::{App, Fed, Memory, Platform, Work};
use serde::Serialize;

use crate::link::{
    encode_run_idle, DeviceEvent, HelloInfo, OwnedTile, RunInput, StreamDecoder, StreamedMap, Unit,
    UnitKind,
};
use crate::metrics::Summary;
use crate::sim::{simulate, SimConfig};
use crate::world::{generate, load_world, GenParams, World};

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
    /// updates; fewer: the sampler moves over the map sooner). Default: `RunConfig::robot`'s.
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
    /// Only decode a captured map stream (e.g. firmware/target/qemu/uart1.out) and summarise it.
    #[arg(long)]
    pub decode: Option<PathBuf>,
    /// The sampler's settings (default: the robot's, `RunConfig::robot`).
    #[command(flatten)]
    pub sampler: SamplerArgs,
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
    /// 10 Hz, 456 points ([`crate::robot::ScanPattern::LD06`]).
    Ld06,
    /// 5.6 Hz, 360 points ([`crate::robot::ScanPattern::A1`]).
    A1,
}

/// Sampler settings sent to the robot (each defaults to `RunConfig::robot`'s).
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
        }
    }
}

/// Instruction counts (QEMU `-icount shift=0`: 1 ns of board time = 1 instruction).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Figures {
    /// Scans processed.
    pub scans: u32,
    /// Mean beams per scan.
    pub beams_per_scan: f64,
    /// Mean cells updated per scan.
    pub cells_per_scan: f64,
    /// `insert_and_seed` (log-odds update, seeding, ray store, first-occupied refresh):
    /// instructions per scan (mean).
    pub insert_per_scan: f64,
    /// … the largest.
    pub insert_per_scan_max: u64,
    /// … per updated cell.
    pub insert_per_cell: f64,
    /// The largest per-scan step plus sampling after it (`insert_ticks + store_ticks +
    /// sampler_ticks`), instructions: under a time budget, at most the period plus the
    /// sampler's last call past it.
    pub cycle_per_scan_max: u64,
    /// Ray store add + first-occupied refresh, per scan, when the firmware times it separately
    /// (older firmware; 0 since both are part of `insert_and_seed`, i.e. of `insert_per_scan`).
    pub store_per_scan: f64,
    /// Sampler patch updates in total.
    pub sampler_updates: u64,
    /// Sampler updates per scan (mean).
    pub updates_per_scan: f64,
    /// Instructions per sampled patch (amortised: tile visits' ray gathering included).
    pub per_patch: f64,
    /// Stack high-water mark of the mapping loop, bytes.
    pub stack_used: u32,
    /// Stack high-water mark while the settings were applied (building the sampler), bytes.
    pub stack_config: u32,
    /// Stack size, bytes.
    pub stack_size: u32,
}

/// The outcome of one `host-sim firmware` run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FirmwareReport {
    /// The firmware's boot message.
    pub hello: Option<HelloInfo>,
    /// Settings sent.
    pub config: Option<RunConfig>,
    /// Scans sent.
    pub scans_sent: usize,
    /// Bytes sent to the robot (garbage included).
    pub input_bytes: usize,
    /// Garbage bytes mixed in.
    pub garbage_bytes: usize,
    /// Map-stream bytes received.
    pub stream_bytes: u64,
    /// Map-stream frames (and bad ones).
    pub stream_frames: u64,
    /// Bad frames in the stream.
    pub stream_bad_frames: u64,
    /// Tiles received.
    pub tiles: u64,
    /// Error messages the firmware sent.
    pub device_errors: usize,
    /// The firmware's final counters.
    pub counters: Option<Counters>,
    /// The firmware's final sampler statistics.
    pub sampler: Option<SamplerReport>,
    /// The firmware's `Done`.
    pub done: Option<Done>,
    /// QEMU's exit status (the firmware's exit code).
    pub exit_code: Option<i32>,
    /// Wall-clock seconds in QEMU.
    pub qemu_seconds: f64,
    /// Instruction counts.
    pub figures: Figures,
    /// Differences between the firmware and the host replay (empty = identical).
    pub mismatches: Vec<String>,
    /// Comparisons made (reports, tiles, cells).
    pub checks: u64,
    /// Accuracy of the firmware's bounds vs the unbounded host configuration (`--accuracy`).
    pub accuracy: Option<Accuracy>,
    /// Where QEMU's log went.
    pub log: Option<PathBuf>,
    /// `Hello` messages received (1 = the firmware never reset).
    pub hellos: usize,
    /// What `--noise-ppm` did to the input.
    pub noise: Option<NoiseReport>,
    /// `--robot`: the two serial lines and how well the turns were placed.
    pub robot: Option<RobotReport>,
}

/// `--robot`: what the lidar's UART and the link carried, and the placement error of the turns
/// the firmware mapped against the simulator's true sensor pose at each turn's time.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RobotReport {
    /// Turns the lidar sent (complete ones).
    pub turns_sent: u32,
    /// Lidar bytes.
    pub lidar_bytes: usize,
    /// Pose messages sent.
    pub poses_sent: usize,
    /// Pose period, µs.
    pub pose_period_us: u64,
    /// Turns the firmware reported.
    pub turns_mapped: usize,
    /// Largest position error of a turn's pose, mm.
    pub max_position_error_mm: f64,
    /// Largest heading error of a turn's pose, degrees.
    pub max_heading_error_deg: f64,
}

/// `--noise-ppm`: the damage done to the robot's input.
#[derive(Clone, Debug, Default, Serialize)]
pub struct NoiseReport {
    /// Bytes corrupted.
    pub corrupted_bytes: usize,
    /// LD06 packets sent / of which damaged (at least one corrupted byte).
    pub packets: usize,
    /// …
    pub damaged_packets: usize,
    /// Host frames sent (repeats included) / of which damaged.
    pub frames: usize,
    /// …
    pub damaged_frames: usize,
    /// Damaged packets that still pass the LD06's checks (header and 8-bit CRC: one damaged
    /// packet in 256 does), so the firmware rightly accepts them.
    pub undetected_packets: usize,
    /// Packets and frames the firmware can accept before the first intact `Finish` (it stops
    /// reading there): the intact ones, and for packets also the undetectably damaged ones.
    pub intact_packets_before_finish: usize,
    /// …
    pub intact_frames_before_finish: usize,
    /// Points of the rejected damaged packets inside scans whose framing arrived (the ones the
    /// firmware must report lost).
    pub points_in_damaged_packets: u64,
    /// Whether a host replay of only the packets and frames the firmware can accept (intact,
    /// or damaged past detection) gives its final map (log-odds, marginal counts, sample), cell
    /// for cell.
    pub surviving_replay_identical: bool,
}

impl FirmwareReport {
    /// Whether the firmware's map equals the host's, cell for cell (and it ran to the end).
    pub fn identical(&self) -> bool {
        self.mismatches.is_empty() && self.done.is_some() && self.checks > 0
    }
}

/// `--accuracy`: metrics of the maps of the same runs.
#[derive(Clone, Debug, Serialize)]
pub struct Accuracy {
    /// Worlds pooled.
    pub runs: u32,
    /// Scans per world.
    pub scans: Vec<usize>,
    /// All cells with known truth: `traditional` (Hähnel's textbook log-odds map),
    /// `traditional_noise_matched` (the robot's own log-odds map, when its free update is
    /// scaled), `offline_firmware_sizes`, `offline_unbounded` (and `online_*` after a QEMU
    /// run).
    pub methods: BTreeMap<String, Summary>,
    /// Cells within 10 cells of a mapped cell.
    pub methods_near_mapped: BTreeMap<String, Summary>,
    /// Rays that did not fit the per-tile list, summed over the runs (offline, firmware sizes).
    pub local_overflow_firmware: u64,
    /// … unbounded (0 by construction).
    pub local_overflow_unbounded: u64,
    /// Tile visits, summed (offline, firmware sizes).
    pub tile_visits: u64,
    /// Ray-store thinnings (firmware sizes), summed.
    pub thinnings: u32,
    /// Max F1 (all cells) of the on-board marginals and of the log-odds map as the scans come
    /// in (first world; at most ~200 points).
    pub anytime: Vec<AnytimePoint>,
}

/// One point of the anytime curve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AnytimePoint {
    /// Scans inserted.
    pub scans: u32,
    /// Max F1 of the sampler's marginals.
    pub online: f64,
    /// Max F1 of the log-odds map.
    pub log_odds: f64,
}

/// What the online replay needs: the robot's input and the sampler work it reported.
#[derive(Clone, Copy, Debug)]
struct Online<'a> {
    input: &'a [u8],
    scan_updates: &'a [u32],
    idle_updates: &'a [u32],
    /// Cumulative idle seconds at the end of each idle period.
    idle_marks: &'a [f64],
}

/// The ray store's sizes as a firmware reports them in its Hello (one of each without its
/// `rays` feature).
pub fn sizes_of(hello: &HelloInfo) -> Sizes {
    Sizes {
        width: hello.width,
        height: hello.height,
        rays: (hello.ray_capacity as usize).max(1),
        scans: (hello.scan_capacity as usize).max(1),
        local: (hello.local_capacity as usize).max(1),
    }
}

/// The compile-time sizes of the firmware built with its `rays` feature.
pub const FIRMWARE_SIZES: Sizes = Sizes {
    width: FW.width,
    height: FW.height,
    rays: FW.rays,
    scans: FW.scans,
    local: FW.local_rays,
};

/// The engine of a replay: the firmware's, over `Vec`s with counters of type `N`.
pub type ReplaySession<N> = Session<Owned<N>>;

/// Marginal p(occupied) per cell of `s` as the robot streams it: 0.5 (unknown) where no
/// measurement reached the cell (log-odds 0, the rule of `map_export::stream_probabilities`)
/// or before the first sample.
pub fn marginals<N: Count>(s: &ReplaySession<N>) -> Vec<f64> {
    s.log_odds()
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if l.0 == 0 {
                0.5
            } else {
                s.marginal(i).map_or(0.5, f64::from)
            }
        })
        .collect()
}

/// The host as the firmware application's platform: no clock, and exactly the sampler updates
/// the firmware reported for each scan and idle period.
struct HostPlatform<F> {
    updates: F,
    missing: Option<Work>,
}

impl<F: Fn(Work) -> Option<u32>> Platform for HostPlatform<F> {
    const NAME: &'static str = "host replay";
    const TICK_HZ: u32 = 1_000_000_000;

    fn now(&self) -> u32 {
        0
    }

    fn fixed_updates(&mut self, work: Work) -> Option<u32> {
        let n = (self.updates)(work);
        if n.is_none() {
            self.missing.get_or_insert(work);
        }
        Some(n.unwrap_or(0))
    }
}

/// The firmware application's memory on the host, as a board places it in statics.
pub struct HostMemory<N: Count> {
    session: Option<ReplaySession<N>>,
    scan: ScanBuf<MAX_BEAMS>,
    turn: ScanBuf<MAX_BEAMS>,
    turns: ogm_core::lidar::turn::Turns,
    tx: [u8; ogm_core::wire::MAX_DEVICE_FRAME],
    tile: [u8; ogm_core::wire::MAX_TILE_BYTES],
}

impl<N: Count> HostMemory<N> {
    /// Empty memory (boxed: the scan buffer is ~5.5 KiB).
    pub fn new() -> Box<Self> {
        Box::new(HostMemory {
            session: None,
            scan: ScanBuf::new(),
            turn: ScanBuf::new(),
            turns: ogm_core::lidar::turn::Turns::new(
                ogm_core::lidar::pose_track::Mount::ZERO,
                false,
            ),
            tx: [0; ogm_core::wire::MAX_DEVICE_FRAME],
            tile: [0; ogm_core::wire::MAX_TILE_BYTES],
        })
    }

    /// The firmware's application over this memory and engine buffers of `sizes`, not yet
    /// configured.
    pub fn app(&mut self, sizes: &Sizes) -> App<'_, Owned<N>> {
        App::new(Memory {
            buffers: Owned::<N>::buffers(sizes),
            session: &mut self.session,
            scan: &mut self.scan,
            turn: &mut self.turn,
            turns: &mut self.turns,
            tx: &mut self.tx,
            tile: &mut self.tile,
        })
    }
}

/// Runs the robot's input through **the firmware's own application** (`ogm_firmware::App`, the
/// library every board binary runs) on the host, byte by byte, with `sizes` and
/// `updates(work)` sampler updates for each scan and idle period; `hook` sees the engine after
/// every scan and idle period, `end` the final engine (`None` if no valid `Config` arrived) and
/// everything the application streamed (its `Hello` first).
///
/// `input` is the link; `lidar` what the lidar's own UART carried (empty when a host tunnels
/// the scans). The two are read as the firmware's main loop reads its UARTs — the lidar
/// whenever the application wants it, the link when the application wants it or the lidar has
/// nothing left — and the application's result does not depend on how they interleave
/// (`ogm_core::lidar::turn`), so this gives the board's map.
fn replay<N: Count, R>(
    input: &[u8],
    lidar: &[u8],
    sizes: Sizes,
    updates: impl Fn(Work) -> Option<u32>,
    mut hook: impl FnMut(Fed, &ReplaySession<N>),
    end: impl FnOnce(Option<&ReplaySession<N>>, &[u8]) -> R,
) -> anyhow::Result<R> {
    let mut memory = HostMemory::<N>::new();
    let mut app = memory.app(&sizes);
    let mut platform = HostPlatform {
        updates,
        missing: None,
    };
    let mut out = Vec::new();
    app.hello(&mut out, &platform);
    let (mut link, mut lidar) = (input, lidar);
    loop {
        let fed = if app.wants_lidar() && !lidar.is_empty() {
            let (b, rest) = lidar.split_at(1);
            lidar = rest;
            app.feed_lidar(b, &mut out, &mut platform)
        } else if let Some((b, rest)) = link.split_first() {
            link = rest;
            app.feed(std::slice::from_ref(b), &mut out, &mut platform)
        } else {
            break;
        };
        if let Some(w) = platform.missing {
            bail!("the firmware did not report {w:?}");
        }
        match (fed, app.session()) {
            (Fed::Scan(_) | Fed::Idle(_), Some(s)) => hook(fed, s),
            (Fed::Finished(_), _) => break,
            _ => {}
        }
    }
    Ok(end(app.session(), &out))
}

/// The map the firmware's application ends with on `input` (its `Config`, scans, idle periods),
/// with the sampler work the firmware reported in `events` (its decoded stream, which must
/// hold its `Hello`): the host replay as a [`StreamedMap`], and its final sampler report.
pub fn replay_map(
    input: &[u8],
    events: &[DeviceEvent],
) -> anyhow::Result<(StreamedMap, SamplerReport)> {
    use ogm_core::wire::TileSource;
    let g = Groups::of(events);
    let hello = g
        .hello
        .as_ref()
        .context("no Hello in the firmware's stream")?;
    let (w, h) = (usize::from(hello.width), usize::from(hello.height));
    let edge = usize::from(hello.tile_edge);
    let state = replay::<u8, _>(
        input,
        &[],
        sizes_of(hello),
        |work| g.updates(work),
        |_, _| {},
        |m, _| {
            m.map(|m| {
                let mut map = StreamedMap::new(w, h, edge);
                map.log_odds = m.log_odds().iter().map(|l| l.raw()).collect();
                map.counts = (0..w * h).map(|i| m.count(i)).collect();
                map.sample = (0..w * h).map(|i| m.occupied(i)).collect();
                (map, m.sampler_report())
            })
        },
    )?;
    state.context("the input carries no valid Config")
}

/// The firmware's messages grouped by scan.
#[derive(Default)]
struct Groups {
    scans: HashMap<u32, ScanGroup>,
    final_tiles: Vec<OwnedTile>,
    final_sampler: Option<SamplerReport>,
    final_counters: Option<Counters>,
    done: Option<Done>,
    hello: Option<HelloInfo>,
    configured: Option<RunConfig>,
    errors: usize,
    all_tiles: Vec<OwnedTile>,
    idles: HashMap<u32, ogm_core::wire::IdleReport>,
}

#[derive(Default)]
struct ScanGroup {
    report: ScanReport,
    tiles: Vec<OwnedTile>,
    sampler: Option<SamplerReport>,
    counters: Option<Counters>,
    ranges: Option<crate::link::OwnedRanges>,
}

impl Groups {
    fn of(events: &[DeviceEvent]) -> Groups {
        let mut g = Groups::default();
        let mut current: Option<u32> = None;
        for ev in events {
            match ev {
                DeviceEvent::Hello(h) => g.hello = Some(h.clone()),
                DeviceEvent::Configured(c) => g.configured = Some(*c),
                DeviceEvent::Scan(r) => {
                    g.scans.insert(
                        r.seq,
                        ScanGroup {
                            report: *r,
                            ..ScanGroup::default()
                        },
                    );
                    current = Some(r.seq);
                }
                DeviceEvent::Tile(t) => {
                    g.all_tiles.push(t.clone());
                    match current.and_then(|s| g.scans.get_mut(&s)) {
                        Some(s) => s.tiles.push(t.clone()),
                        None => g.final_tiles.push(t.clone()),
                    }
                }
                DeviceEvent::Sampler(r) => match current.and_then(|s| g.scans.get_mut(&s)) {
                    Some(s) => s.sampler = Some(*r),
                    None => g.final_sampler = Some(*r),
                },
                DeviceEvent::Counters(c) => {
                    match current.take().and_then(|s| g.scans.get_mut(&s)) {
                        Some(s) => s.counters = Some(*c),
                        None => g.final_counters = Some(*c),
                    }
                }
                DeviceEvent::Error(_) => g.errors += 1,
                DeviceEvent::Done(d) => g.done = Some(*d),
                DeviceEvent::Idle(r) => {
                    g.idles.insert(r.seq, *r);
                }
                DeviceEvent::Ranges(r) => {
                    if let Some(s) = g.scans.get_mut(&r.seq) {
                        s.ranges = Some(r.clone());
                    }
                }
            }
        }
        g
    }

    /// The sampler updates the firmware reported for `w`.
    fn updates(&self, w: Work) -> Option<u32> {
        match w {
            Work::Scan(seq) => self.scans.get(&seq).map(|s| s.report.sampler_updates),
            Work::Idle(seq) => self.idles.get(&seq).map(|r| r.sampler_updates),
        }
    }
}

/// Collects mismatches (bounded) and counts checks.
#[derive(Default)]
struct Checker {
    mismatches: Vec<String>,
    checks: u64,
}

impl Checker {
    fn eq<T: PartialEq + std::fmt::Debug>(
        &mut self,
        what: impl FnOnce() -> String,
        fw: &T,
        host: &T,
    ) {
        self.checks += 1;
        if fw != host && self.mismatches.len() < 50 {
            self.mismatches
                .push(format!("{}: firmware {fw:?}, host {host:?}", what()));
        }
    }

    fn fail(&mut self, msg: String) {
        if self.mismatches.len() < 50 {
            self.mismatches.push(msg);
        }
    }
}

/// Compares the firmware's stream with the host's run of the same application on the same
/// input: every message equal except the board's timing and stack figures, and the streamed
/// map equal to the host's engine cell for cell.
fn compare(input: &[u8], lidar: &[u8], g: &Groups, c: &mut Checker) -> anyhow::Result<()> {
    let hello = g.hello.as_ref().context("no Hello from the firmware")?;
    ensure!(
        (hello.width, hello.height, hello.tile_edge) == (FW.width, FW.height, FW.tile_edge)
            && hello.max_beams as usize == FW.max_beams
            && hello.count_max == 255,
        "the firmware's sizes {hello:?} are not ogm_firmware::sizes::MPS2_AN386 (rebuild it?)"
    );
    let edge = usize::from(FW.tile_edge);
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    let (stream, state) = replay::<u8, _>(
        input,
        lidar,
        sizes_of(hello),
        |w| g.updates(w),
        |_, _| {},
        |m, out| {
            let state = m.map(|m| {
                (
                    *m.config(),
                    m.log_odds().iter().map(|l| l.raw()).collect::<Vec<_>>(),
                    (0..w * h)
                        .map(|i| ogm_core::wire::TileSource::count(m, i))
                        .collect::<Vec<_>>(),
                    (0..w * h)
                        .map(|i| ogm_core::wire::TileSource::occupied(m, i))
                        .collect::<Vec<_>>(),
                )
            });
            (out.to_vec(), state)
        },
    )?;
    let (config, host_lo, host_counts, host_sample) =
        state.context("the replay never got a valid Config")?;
    let mut decoder = StreamDecoder::new();
    let events: Vec<DeviceEvent> = decoder
        .push(&stream)
        .into_iter()
        .collect::<Result<_, _>>()
        .map_err(|e| anyhow!("the host's own stream does not decode: {e}"))?;
    let host = Groups::of(&events);
    c.eq(|| "configured".into(), &g.configured, &host.configured);
    c.eq(|| "configured".into(), &g.configured, &Some(config));
    c.eq(|| "scans".into(), &g.scans.len(), &host.scans.len());
    c.eq(|| "error reports".into(), &g.errors, &host.errors);
    let mut seqs: Vec<u32> = g.scans.keys().copied().collect();
    seqs.sort_unstable();
    for seq in seqs {
        let (fwg, hg) = (&g.scans[&seq], host.scans.get(&seq));
        let Some(hg) = hg else {
            c.fail(format!("scan {seq}: the host did not map it"));
            continue;
        };
        let mut fr = fwg.report;
        // Timing is the firmware's own business.
        (fr.insert_ticks, fr.store_ticks, fr.sampler_ticks) = (0, 0, 0);
        c.eq(|| format!("scan {seq} report"), &fr, &hg.report);
        c.eq(
            || format!("scan {seq} tiles"),
            &fwg.tiles.len(),
            &hg.tiles.len(),
        );
        for (a, b) in fwg.tiles.iter().zip(&hg.tiles) {
            c.checks += 1;
            if a != b {
                let n = a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count()
                    + a.data.len().abs_diff(b.data.len());
                c.fail(format!(
                    "scan {seq}: tile {:?} ({}, {}) differs from the host's {:?} ({}, {}) in {n} bytes",
                    a.layer, a.tx, a.ty, b.layer, b.tx, b.ty
                ));
            }
        }
        c.eq(
            || format!("scan {seq} sampler report"),
            &fwg.sampler,
            &hg.sampler,
        );
        c.eq(|| format!("scan {seq} ranges"), &fwg.ranges, &hg.ranges);
        // With the robot's two lines, how far each had been read when a turn finished is
        // timing (QEMU's scheduling of two sockets), not behaviour: what was counted of the
        // turns themselves must agree, the bytes and packets read so far need not (the final
        // counters, after everything was read, are compared in full below).
        if !lidar.is_empty() {
            let settled = |c: &Option<Counters>| {
                c.map(|c| {
                    let l = c.lidar;
                    (c.scans, c.beams_overflowed, l.turns, l.packets_overflowed)
                })
            };
            c.eq(
                || {
                    format!(
                        "scan {seq} counters (scans, beams overflowed, turns, packets overflowed)"
                    )
                },
                &settled(&fwg.counters),
                &settled(&hg.counters),
            );
        } else {
            c.eq(
                || format!("scan {seq} counters"),
                &fwg.counters,
                &hg.counters,
            );
        }
    }
    for (seq, r) in &g.idles {
        let host_updates = host.idles.get(seq).map(|r| r.sampler_updates);
        c.eq(
            || format!("idle {seq} updates"),
            &Some(r.sampler_updates),
            &host_updates,
        );
    }
    c.eq(
        || "final tiles".into(),
        &g.final_tiles.len(),
        &host.final_tiles.len(),
    );
    if g.final_tiles != host.final_tiles {
        c.fail("the final tiles differ from the host's".into());
    }
    c.checks += g.final_tiles.len() as u64;
    c.eq(
        || "final sampler report".into(),
        &g.final_sampler,
        &host.final_sampler,
    );
    c.eq(
        || "final counters".into(),
        &g.final_counters,
        &host.final_counters,
    );
    let done = g.done.as_ref().context("no Done from the firmware")?;
    let host_done = host.done.as_ref().context("no Done from the host")?;
    c.eq(
        || "Done (scans, grid FNV, counts FNV)".into(),
        &(done.scans, done.grid_fnv, done.counts_fnv),
        &(host_done.scans, host_done.grid_fnv, host_done.counts_fnv),
    );
    // The map as streamed, cell for cell, against the host's engine.
    let mut streamed = StreamedMap::new(w, h, edge);
    for t in &g.all_tiles {
        streamed.apply(t)?;
    }
    for (name, diff) in [
        ("log-odds", first_diff(&streamed.log_odds, &host_lo)),
        (
            "marginal counts",
            first_diff(&streamed.counts, &host_counts),
        ),
        ("sample", first_diff(&streamed.sample, &host_sample)),
    ] {
        c.checks += (w * h) as u64;
        if let Some((i, n, a, b)) = diff {
            c.fail(format!(
                "streamed {name}: {n} cells differ, first at ({}, {}): firmware {a}, host {b}",
                i % w,
                i / w
            ));
        }
    }
    Ok(())
}

fn first_diff<T: PartialEq + std::fmt::Display>(
    a: &[T],
    b: &[T],
) -> Option<(usize, usize, String, String)> {
    let n = a.iter().zip(b).filter(|(x, y)| x != y).count() + a.len().abs_diff(b.len());
    let i = a.iter().zip(b).position(|(x, y)| x != y)?;
    Some((i, n, a[i].to_string(), b[i].to_string()))
}

/// The figures from the firmware's reports.
fn figures(g: &Groups, hello: &HelloInfo) -> Figures {
    let ns_per_tick = 1e9 / f64::from(hello.tick_hz.max(1));
    let mut f = Figures::default();
    let (mut beams, mut cells, mut insert, mut store, mut sampler, mut updates) =
        (0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
    for s in g.scans.values() {
        let r = &s.report;
        f.scans += 1;
        beams += u64::from(r.beams);
        cells += u64::from(r.cells_hit + r.cells_freed);
        insert += u64::from(r.insert_ticks);
        store += u64::from(r.store_ticks);
        sampler += u64::from(r.sampler_ticks);
        updates += u64::from(r.sampler_updates);
        f.insert_per_scan_max = f
            .insert_per_scan_max
            .max((f64::from(r.insert_ticks) * ns_per_tick) as u64);
        let cycle =
            u64::from(r.insert_ticks) + u64::from(r.store_ticks) + u64::from(r.sampler_ticks);
        f.cycle_per_scan_max = f
            .cycle_per_scan_max
            .max((cycle as f64 * ns_per_tick) as u64);
    }
    let n = f64::from(f.scans.max(1));
    f.beams_per_scan = beams as f64 / n;
    f.cells_per_scan = cells as f64 / n;
    f.insert_per_scan = insert as f64 * ns_per_tick / n;
    f.insert_per_cell = insert as f64 * ns_per_tick / cells.max(1) as f64;
    f.store_per_scan = store as f64 * ns_per_tick / n;
    f.sampler_updates = updates;
    f.updates_per_scan = updates as f64 / n;
    f.per_patch = sampler as f64 * ns_per_tick / updates.max(1) as f64;
    if let Some(d) = &g.done {
        (f.stack_used, f.stack_config, f.stack_size) = (d.stack_used, d.stack_config, d.stack_size);
    }
    f
}

/// The repository root (host-sim's parent directory).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Why the firmware cannot run here, if it cannot: `firmware/target/toolchain.env` (written by
/// `scripts/firmware-toolchain.sh`) and the QEMU it names must exist.
pub fn toolchain_missing() -> Option<String> {
    let env = repo_root().join("firmware/target/toolchain.env");
    let Ok(text) = std::fs::read_to_string(&env) else {
        return Some(format!(
            "{} not found: run `bash scripts/firmware-toolchain.sh` first",
            env.display()
        ));
    };
    let qemu = text
        .lines()
        .find_map(|l| l.strip_prefix("FW_QEMU="))
        .unwrap_or("");
    if qemu.is_empty() || !Path::new(qemu).exists() {
        return Some(format!(
            "QEMU ({}) from {} does not exist: rerun `bash scripts/firmware-toolchain.sh`",
            if qemu.is_empty() { "unset" } else { qemu },
            env.display()
        ));
    }
    None
}

/// Builds the firmware with `scripts/firmware.sh build`; returns the ELF.
pub fn build_elf(log: &Path) -> anyhow::Result<PathBuf> {
    build_elf_with(log, None)
}

/// [`build_elf`] with optional firmware `features` (comma-separated; their own target dir).
pub fn build_elf_with(log: &Path, features: Option<&str>) -> anyhow::Result<PathBuf> {
    let root = repo_root();
    let log_file =
        std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
    let mut cmd = Command::new("bash");
    if let Some(f) = features {
        cmd.env("FIRMWARE_FEATURES", f);
    }
    let out = cmd
        .arg(root.join("scripts/firmware.sh"))
        .arg("build")
        .stdin(Stdio::null())
        .stderr(Stdio::from(log_file))
        .output()
        .context("running scripts/firmware.sh build")?;
    if !out.status.success() {
        bail!(
            "scripts/firmware.sh build failed ({}):\n{}",
            out.status,
            tail(log, 30)
        );
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let elf = stdout
        .lines()
        .last()
        .map(|l| PathBuf::from(l.trim()))
        .context("scripts/firmware.sh build printed no ELF path")?;
    ensure!(elf.exists(), "ELF {} does not exist", elf.display());
    Ok(elf)
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

/// The robot loop's second serial line and its end: the lidar's bytes on UART0, the order
/// the two lines carry their bytes in, and the `Finish` frame the link sends once the firmware
/// has reported turn `last_turn`.
struct LidarLine<'a> {
    bytes: &'a [u8],
    schedule: &'a [(crate::robot::Line, std::ops::Range<usize>)],
    finish: &'a [u8],
    last_turn: u32,
    /// The request the sensor waits for before its first byte (an RPLIDAR's `SCAN`; an LD06
    /// streams on its own).
    answers: Option<[u8; 2]>,
}

/// How long the simulated sensor waits for the request it answers (wall time).
const REQUEST_WAIT: Duration = Duration::from_secs(30);

/// Reads `line` until `request` arrived (or `REQUEST_WAIT` passed); every byte the firmware
/// wrote to the sensor meanwhile goes to `heard`.
fn await_request(
    line: &mut UnixStream,
    request: [u8; 2],
    heard: &mut Vec<u8>,
) -> std::io::Result<()> {
    line.set_read_timeout(Some(Duration::from_millis(50)))?;
    let t0 = Instant::now();
    let mut buf = [0u8; 64];
    while !heard.windows(2).any(|w| w == request) && t0.elapsed() < REQUEST_WAIT {
        match line.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => heard.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e),
        }
    }
    line.set_read_timeout(None)
}

/// What [`run_qemu`] returns.
struct QemuRun {
    /// The map stream (UART1).
    stream: Vec<u8>,
    /// QEMU's exit status (`None`: killed at the timeout).
    status: Option<ExitStatus>,
    /// Wall time, s.
    secs: f64,
    /// What the firmware wrote to the lidar (UART0) before the sensor's first byte.
    heard: Vec<u8>,
}

/// Boots `elf` in QEMU with UART1 (the link) on a Unix socket, sends `input`, returns the
/// stream bytes, the exit status, the wall time and what the firmware wrote to the lidar. With
/// `lidar`, UART0 is a second socket that carries its bytes, written by their own thread at
/// their own pace (after the request the sensor answers, if it waits for one).
fn run_qemu(
    elf: &Path,
    input: &[u8],
    lidar: Option<LidarLine<'_>>,
    timeout: Duration,
    log: Option<&Path>,
) -> anyhow::Result<QemuRun> {
    let root = repo_root();
    let dir = std::env::temp_dir().join(format!("ogm-fw-{}-{}", std::process::id(), rand_seed()));
    std::fs::create_dir_all(&dir)?;
    let sock = dir.join("u1.sock");
    let listener =
        UnixListener::bind(&sock).with_context(|| format!("binding {}", sock.display()))?;
    listener.set_nonblocking(true)?;
    let sock0 = dir.join("u0.sock");
    let listener0 = match &lidar {
        Some(_) => Some(
            UnixListener::bind(&sock0).with_context(|| format!("binding {}", sock0.display()))?,
        ),
        None => None,
    };
    let mut cmd = Command::new("bash");
    cmd.arg(root.join("scripts/firmware.sh"))
        .arg("qemu")
        .arg(elf)
        .args(["--timeout", &timeout.as_secs().max(1).to_string()])
        .args(["--uart1", "chardev:u1"]);
    if lidar.is_some() {
        cmd.args(["--uart0", "chardev:u0"]);
    }
    cmd.arg("--");
    if lidar.is_some() {
        cmd.arg("-chardev")
            .arg(format!("socket,id=u0,path={}", sock0.display()));
    }
    cmd.arg("-chardev")
        .arg(format!("socket,id=u1,path={}", sock.display()));
    cmd.stdin(Stdio::null());
    if let Some(log) = log {
        let f =
            std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
        cmd.stdout(Stdio::from(f.try_clone()?))
            .stderr(Stdio::from(f));
    }
    let t0 = Instant::now();
    let mut child = cmd.spawn().context("starting scripts/firmware.sh qemu")?;
    let log_tail = || log.map(|l| tail(l, 40)).unwrap_or_default();
    let mut accept = |listener: &UnixListener, path: &Path| -> anyhow::Result<UnixStream> {
        loop {
            match listener.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false)?;
                    return Ok(s);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if let Some(st) = child.try_wait()? {
                        let _ = std::fs::remove_dir_all(&dir);
                        bail!(
                            "QEMU exited ({st}) before connecting to {}:\n{}",
                            path.display(),
                            log_tail()
                        );
                    }
                    if t0.elapsed() > Duration::from_secs(60) {
                        let _ = child.kill();
                        let _ = std::fs::remove_dir_all(&dir);
                        bail!("QEMU did not connect to {} within 60 s", path.display());
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(e) => return Err(e.into()),
            }
        }
    };
    let stream = accept(&listener, &sock)?;
    let lidar_stream = match &listener0 {
        Some(l) => {
            l.set_nonblocking(true)?;
            Some(accept(l, &sock0)?)
        }
        None => None,
    };
    let mut writer = stream.try_clone()?;
    // Send only once the firmware has spoken (its Hello): its UART is initialised by then.
    // Bytes that arrive earlier can meet the init's dummy read of the data register (board
    // `Uart::new`, which QEMU needs to start delivering input) and be lost: seen once in ~20
    // noisy-link runs as a lost first frame delimiter.
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
    // The robot loop: both lines from this one thread in their schedule's order, as a robot's
    // run in step; `Finish` only once the last turn is reported (a second go from the reader).
    // The lidar's socket is handed back, not closed, when its bytes are written: QEMU's socket
    // chardev drops a connection, and whatever of it is still unread, the moment the peer
    // hangs up; it stays open until QEMU has exited.
    let (finish_tx, finish_rx) = std::sync::mpsc::channel::<()>();
    let last_turn = lidar.as_ref().map(|l| l.last_turn);
    let data = input.to_vec();
    let robot = lidar.map(|l| {
        let bytes = l.bytes.to_vec();
        let schedule = l.schedule.to_vec();
        (bytes, schedule, l.finish.to_vec(), l.answers)
    });
    type Written = (Option<UnixStream>, Vec<u8>);
    let writer = std::thread::spawn(move || -> std::io::Result<Written> {
        let mut heard = Vec::new();
        if ready_rx.recv().is_err() {
            return Ok((lidar_stream, heard)); // the firmware never spoke; the reader reports it
        }
        match (robot, lidar_stream) {
            (Some((bytes, schedule, finish, mut answers)), Some(mut w)) => {
                for (line, r) in schedule {
                    match line {
                        crate::robot::Line::Link => writer.write_all(&data[r])?,
                        crate::robot::Line::Lidar => {
                            if let Some(req) = answers.take() {
                                await_request(&mut w, req, &mut heard)?;
                            }
                            w.write_all(&bytes[r])?
                        }
                    }
                }
                if finish_rx.recv().is_ok() {
                    writer.write_all(&finish)?;
                }
                Ok((Some(w), heard))
            }
            (_, w) => {
                writer.write_all(&data)?;
                Ok((w, heard))
            }
        }
    });
    let mut ready = Some(ready_tx);
    let mut finish_go = Some(finish_tx);
    let mut watch = StreamDecoder::new();
    let mut reader = stream;
    reader.set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut out = Vec::new();
    let mut buf = [0u8; 16 * 1024];
    let deadline = t0 + timeout + Duration::from_secs(10);
    let mut status = None;
    loop {
        match reader.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                out.extend_from_slice(&buf[..n]);
                if let Some(go) = ready.take() {
                    let _ = go.send(());
                }
                if let Some(last) = last_turn {
                    let reported = watch
                        .push(&buf[..n])
                        .into_iter()
                        .any(|e| matches!(e, Ok(DeviceEvent::Scan(r)) if r.seq >= last));
                    if reported {
                        if let Some(go) = finish_go.take() {
                            let _ = go.send(());
                        }
                    }
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                if let Some(st) = child.try_wait()? {
                    status = Some(st);
                    // Drain what is left.
                    reader.set_nonblocking(true)?;
                    while let Ok(n) = reader.read(&mut buf) {
                        if n == 0 {
                            break;
                        }
                        out.extend_from_slice(&buf[..n]);
                    }
                    break;
                }
                if Instant::now() > deadline {
                    let _ = child.kill();
                    break;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => break,
            Err(e) => return Err(e.into()),
        }
    }
    if status.is_none() {
        let wait_until = Instant::now() + Duration::from_secs(15);
        loop {
            if let Some(st) = child.try_wait()? {
                status = Some(st);
                break;
            }
            if Instant::now() > wait_until {
                let _ = child.kill();
                status = child.wait().ok();
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    drop(ready);
    drop(finish_go);
    let heard = match writer.join() {
        Ok(Ok((_, heard))) => heard,
        _ => Vec::new(),
    };
    let _ = std::fs::remove_dir_all(&dir);
    Ok(QemuRun {
        stream: out,
        status,
        secs,
        heard,
    })
}

/// The messages of a stream captured from the board (bad frames skipped, counted in the
/// decoder's statistics).
fn decode_captured(stream: &[u8]) -> (Vec<DeviceEvent>, crate::link::DecoderStats) {
    let mut dec = StreamDecoder::new();
    let events = dec
        .push(stream)
        .into_iter()
        .filter_map(Result::ok)
        .collect();
    (events, dec.stats())
}

/// Checks that `path` is an ELF executable (one-line errors naming the file).
pub fn check_elf(path: &Path) -> anyhow::Result<()> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{}: file not found", path.display())
        }
        Err(e) => bail!("{}: cannot read: {e}", path.display()),
    };
    ensure!(!bytes.is_empty(), "{}: file is empty", path.display());
    ensure!(
        bytes.starts_with(b"\x7fELF"),
        "{}: wrong format: not an ELF file",
        path.display()
    );
    // 32-bit ELF header: 52 bytes; the program headers it points to must be in the file too.
    let u32_at = |o: usize| {
        bytes
            .get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let u16_at = |o: usize| {
        bytes
            .get(o..o + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    let ph_end = match (u32_at(28), u16_at(42), u16_at(44)) {
        (Some(off), Some(size), Some(n)) => off as usize + usize::from(size) * usize::from(n),
        _ => usize::MAX,
    };
    ensure!(
        bytes.len() >= 52 && bytes.len() >= ph_end,
        "{}: truncated ELF file ({} bytes)",
        path.display(),
        bytes.len()
    );
    Ok(())
}

/// Corrupts `ppm` of every million bytes of `bytes` (distinct positions, each XORed with a
/// random non-zero byte; seeded); returns the positions in ascending order.
pub fn corrupt(bytes: &mut [u8], ppm: u32, seed: u64) -> Vec<usize> {
    use rand::{RngExt, SeedableRng};
    let n = (bytes.len() as u64 * u64::from(ppm)).div_ceil(1_000_000) as usize;
    let n = n.min(bytes.len());
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x006e_6f69_7379);
    let mut positions = std::collections::BTreeSet::new();
    while positions.len() < n {
        positions.insert(rng.random_range(0..bytes.len()));
    }
    for &p in &positions {
        bytes[p] ^= rng.random_range(1..=255u8);
    }
    positions.into_iter().collect()
}

/// The streamed map: every tile the firmware sent, applied in order.
fn streamed_map(g: &Groups) -> anyhow::Result<StreamedMap> {
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    let mut m = StreamedMap::new(w, h, usize::from(FW.tile_edge));
    for t in &g.all_tiles {
        m.apply(t)?;
    }
    Ok(m)
}

/// `--noise-ppm`: which packets and frames were damaged, and whether a host replay of only the
/// ones the firmware can accept (intact, or damaged past the LD06's 8-bit CRC; in order;
/// garbage dropped) gives the firmware's final map.
fn noise_report(input: &RunInput, corrupted: &[usize], g: &Groups) -> anyhow::Result<NoiseReport> {
    let mut n = NoiseReport {
        corrupted_bytes: corrupted.len(),
        ..NoiseReport::default()
    };
    let damaged = |u: &Unit| {
        let i = corrupted.partition_point(|&p| p < u.start);
        corrupted.get(i).is_some_and(|&p| p < u.start + u.len)
    };
    let mut surviving = Vec::new();
    let mut finished = false;
    // Per scan: its intact-framing state and damaged packets.
    let (mut in_scan, mut scan_damaged) = (false, 0u64);
    for u in &input.units {
        let mut bad = damaged(u);
        let bytes = &input.bytes[u.start..u.start + u.len];
        match u.kind {
            UnitKind::Garbage => continue,
            UnitKind::Packet => {
                n.packets += 1;
                if bad {
                    n.damaged_packets += 1;
                    let valid = <&[u8; ogm_core::lidar::ld06::PACKET_LEN]>::try_from(bytes)
                        .is_ok_and(|b| ogm_core::lidar::ld06::Packet::parse(b).is_ok());
                    if valid {
                        // Past the LD06's own checks: the robot cannot tell, nor lose it.
                        n.undetected_packets += 1;
                        bad = false;
                    } else {
                        scan_damaged += ogm_core::lidar::ld06::POINTS as u64;
                    }
                }
                if !bad && !finished {
                    n.intact_packets_before_finish += 1;
                }
            }
            UnitKind::Frame => {
                n.frames += 1;
                if bad {
                    n.damaged_frames += 1;
                } else {
                    let mut body = bytes[1..bytes.len() - 1].to_vec();
                    match ogm_core::wire::decode::<ogm_core::wire::HostMsg>(&mut body) {
                        Ok(ogm_core::wire::HostMsg::ScanStart { .. }) => {
                            in_scan = true;
                            scan_damaged = 0;
                        }
                        Ok(ogm_core::wire::HostMsg::ScanEnd { .. }) if in_scan => {
                            n.points_in_damaged_packets += scan_damaged;
                            in_scan = false;
                        }
                        Ok(ogm_core::wire::HostMsg::Finish) => {
                            if !finished {
                                n.intact_frames_before_finish += 1;
                            }
                            finished = true;
                        }
                        _ => {}
                    }
                    if !finished {
                        n.intact_frames_before_finish += 1;
                    }
                }
            }
        }
        if !bad {
            surviving.extend_from_slice(bytes);
        }
    }
    let sizes = g.hello.as_ref().map_or(FIRMWARE_SIZES, sizes_of);
    let streamed = streamed_map(g)?;
    let identical = replay::<u8, _>(
        &surviving,
        &[],
        sizes,
        |w| g.updates(w),
        |_, _| {},
        |m, _| {
            m.map(|m| {
                use ogm_core::wire::TileSource;
                let cells = streamed.log_odds.len();
                m.log_odds()
                    .iter()
                    .map(|l| l.raw())
                    .eq(streamed.log_odds.iter().copied())
                    && (0..cells).all(|i| m.count(i) == streamed.counts[i])
                    && (0..cells).all(|i| m.occupied(i) == streamed.sample[i])
            })
        },
    )?;
    n.surviving_replay_identical =
        identical.context("the surviving packets carry no valid Config")?;
    Ok(n)
}

fn rand_seed() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The simulation of a run: the paper's robot that scans when stopped, or with `--moving` /
/// `--mission-scans` one that scans at the LD06's rate while it drives.
pub fn sim_config(args: &FirmwareArgs) -> SimConfig {
    let mut cfg = SimConfig::default();
    if args.moving || args.mission_scans.is_some() {
        cfg.explore =
            crate::explore::ExploreConfig::moving(10.0, 0.4, args.mission_scans.unwrap_or(0));
        if args.mission_scans.is_none() {
            cfg.explore.max_stops = SimConfig::default().explore.max_stops * 25;
        }
        // 4 500 points/s at 10 Hz, rounded up to whole 12-point LD06 packets.
        cfg.lidar.beams = 456;
    }
    cfg
}

/// The world of a run: `--map` (5 cm, cropped to the firmware grid) or a generated building.
pub fn firmware_world(args: &FirmwareArgs) -> anyhow::Result<World> {
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    Ok(match &args.map {
        Some(p) => load_world(p, None)
            .with_context(|| format!("loading {}", p.display()))?
            .resample(crate::eval::EVAL_RESOLUTION_M)
            .crop(0, 0, w, h),
        None => generate(
            &GenParams {
                width: w,
                height: h,
                ..GenParams::default()
            },
            args.seed,
        ),
    })
}

/// The settings sent to the robot for `world`.
pub fn run_config(world: &World, args: &FirmwareArgs, max_range_mm: u32) -> RunConfig {
    let budget = match args.fixed_updates {
        Some(updates) => Budget::Fixed { updates },
        None => Budget::Time {
            period_us: args.period_us,
            max_updates: args.max_updates,
        },
    };
    let origin = (
        (world.origin_m.0 * 1000.0).round() as i32,
        (world.origin_m.1 * 1000.0).round() as i32,
    );
    let robot = RunConfig::robot(origin, max_range_mm, args.seed, budget);
    args.sampler.apply(RunConfig {
        cell_mm: (world.resolution_m * 1000.0).round() as u32,
        tiles_per_scan: args.tiles_per_scan,
        count_tiles_per_scan: args.count_tiles_per_scan,
        visit_sweeps: args.visit_sweeps.unwrap_or(robot.visit_sweeps),
        ..robot
    })
}

/// The idle periods (µs) between the cumulative marks `secs` (increasing, positive).
fn idle_periods_us(secs: &[f64]) -> anyhow::Result<Vec<u32>> {
    let mut prev = 0.0;
    let mut out = Vec::new();
    for &s in secs {
        ensure!(
            s.is_finite() && s > prev && s <= 600.0,
            "--idle: marks must increase, from above 0 to at most 600 s (got {secs:?})"
        );
        out.push(((s - prev) * 1e6).round() as u32);
        prev = s;
    }
    Ok(out)
}

/// Runs `host-sim firmware` (see the module docs).
pub fn run(args: &FirmwareArgs) -> anyhow::Result<FirmwareReport> {
    ensure!(
        args.robot || (args.lidar == LidarArg::Ld06 && args.pattern.is_none()),
        "--lidar and --pattern describe the lidar on the robot's own UART: add --robot"
    );
    if args.robot {
        return run_robot(args);
    }
    let root = repo_root();
    let qemu_dir = root.join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let world = firmware_world(args)?;
    ensure!(
        world.width <= usize::from(FW.width) && world.height <= usize::from(FW.height),
        "world is {}x{} cells, the firmware's grid {}x{}",
        world.width,
        world.height,
        FW.width,
        FW.height
    );
    let sim = simulate(&world, &sim_config(args), args.seed)?;
    let mut scans = sim.scans.clone();
    if let Some(n) = args.max_scans {
        scans.truncate(n);
    }
    if let Some(n) = args.soak_scans {
        ensure!(
            !scans.is_empty(),
            "the simulated run has no scans to soak with"
        );
        scans = scans.iter().cycle().take(n).cloned().collect();
    }
    let config = run_config(&world, args, sim.mapper_config.max_range_mm);
    let idle_us = idle_periods_us(&args.idle)?;
    let mut input = encode_run_idle(&config, &scans, args.garbage, args.repeat_frames, &idle_us)?;
    let corrupted = corrupt(&mut input.bytes, args.noise_ppm, args.seed);
    let mut report = FirmwareReport {
        config: Some(config),
        scans_sent: input.scans,
        input_bytes: input.bytes.len(),
        garbage_bytes: input.garbage_bytes,
        ..FirmwareReport::default()
    };
    let mut updates_used: Vec<u32> = Vec::new();
    let mut idle_used: Vec<u32> = Vec::new();
    if !args.host_only {
        let elf = match &args.elf {
            Some(e) => e.clone(),
            None => build_elf(&qemu_dir.join("host-sim-build.log"))?,
        };
        let log = (!args.verbose).then(|| qemu_dir.join("host-sim-firmware.log"));
        let QemuRun {
            stream,
            status,
            secs,
            ..
        } = run_qemu(
            &elf,
            &input.bytes,
            None,
            Duration::from_secs(args.timeout),
            log.as_deref(),
        )?;
        report.log = log.clone();
        report.qemu_seconds = secs;
        report.exit_code = status.and_then(|s| s.code());
        if let Some(out) = &args.out {
            std::fs::create_dir_all(out)?;
            std::fs::write(out.join("stream.bin"), &stream)?;
            std::fs::write(out.join("input.bin"), &input.bytes)?;
        }
        let (events, ds) = decode_captured(&stream);
        (
            report.stream_bytes,
            report.stream_frames,
            report.stream_bad_frames,
        ) = (ds.bytes, ds.frames, ds.bad_frames);
        let groups = Groups::of(&events);
        report.hellos = events
            .iter()
            .filter(|e| matches!(e, DeviceEvent::Hello(_)))
            .count();
        report.hello = groups.hello.clone();
        report.tiles = groups.all_tiles.len() as u64;
        report.device_errors = groups.errors;
        report.counters = groups.final_counters;
        report.sampler = groups.final_sampler;
        report.done = groups.done;
        let mut checker = Checker::default();
        if report.exit_code != Some(0) {
            checker.fail(format!(
                "firmware exit status {:?} (log: {})",
                report.exit_code,
                log.as_ref()
                    .map_or("stdout".into(), |l| l.display().to_string())
            ));
        }
        match compare(&input.bytes, &[], &groups, &mut checker) {
            Ok(()) => {}
            Err(e) => checker.fail(format!("{e:#}")),
        }
        if args.noise_ppm > 0 {
            match noise_report(&input, &corrupted, &groups) {
                Ok(n) => {
                    if !n.surviving_replay_identical {
                        checker.fail(
                            "a replay of only the intact packets and frames gives another map"
                                .into(),
                        );
                    }
                    report.noise = Some(n);
                }
                Err(e) => checker.fail(format!("surviving-packets replay: {e:#}")),
            }
        }
        if let Some(h) = &groups.hello {
            report.figures = figures(&groups, h);
        }
        report.mismatches = checker.mismatches;
        report.checks = checker.checks;
        let mut seqs: Vec<&u32> = groups.scans.keys().collect();
        seqs.sort();
        updates_used = seqs
            .iter()
            .map(|s| groups.scans[s].report.sampler_updates)
            .collect();
        idle_used = (0..idle_us.len() as u32)
            .map(|s| groups.idles.get(&s).map_or(0, |r| r.sampler_updates))
            .collect();
    }
    if args.host_only {
        // No firmware to report its update counts: the fixed number per scan, if given.
        if let Some(n) = args.fixed_updates {
            updates_used = vec![n; input.scans];
            // Idle at the same rate: `n` updates per 10 Hz scan period.
            idle_used = idle_us
                .iter()
                .map(|&us| (u64::from(n) * u64::from(us) / 100_000).min(u64::from(u32::MAX)) as u32)
                .collect();
        }
    }
    if args.accuracy {
        let online = (!updates_used.is_empty()).then_some(Online {
            input: &input.bytes,
            scan_updates: &updates_used,
            idle_updates: &idle_used,
            idle_marks: &args.idle,
        });
        report.accuracy = Some(accuracy(args, &config, &world, &sim, &scans, online)?);
    }
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out)?;
        let json = serde_json::to_string_pretty(&report)?;
        std::fs::write(out.join("report.json"), json + "\n")?;
        if let Some(a) = report.accuracy.as_ref().filter(|a| !a.anytime.is_empty()) {
            let pts = |f: fn(&AnytimePoint) -> f64| -> Vec<(f64, f64)> {
                a.anytime
                    .iter()
                    .map(|p| (f64::from(p.scans), f(p)))
                    .collect()
            };
            crate::render::anytime_svg(
                out.join("anytime.svg"),
                &[
                    ("online marginals (firmware)", pts(|p| p.online)),
                    ("log-odds map", pts(|p| p.log_odds)),
                ],
                &format!("Online map quality, seed {}", args.seed),
            )?;
        }
    }
    Ok(report)
}

/// The LD06 sits this far ahead of the robot's centre in `--robot` runs, mm.
pub const ROBOT_MOUNT_X_MM: i32 = 60;

/// `--robot`: the robot loop in QEMU (see [`FirmwareArgs::robot`]).
fn run_robot(args: &FirmwareArgs) -> anyhow::Result<FirmwareReport> {
    ensure!(
        !args.accuracy
            && args.idle.is_empty()
            && args.noise_ppm == 0
            && !args.garbage
            && args.soak_scans.is_none()
            && args.repeat_frames <= 1,
        "--robot runs the robot loop only: no --accuracy, --idle, --noise-ppm, --garbage, \
         --soak-scans or --repeat-frames with it"
    );
    let root = repo_root();
    let qemu_dir = root.join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let world = firmware_world(args)?;
    let moving = FirmwareArgs {
        moving: true,
        ..args.clone()
    };
    let sim_cfg = sim_config(&moving);
    let sim = simulate(&world, &sim_cfg, args.seed)?;
    let mut poses: Vec<ogm_core::Pose> = sim.scans.iter().map(|s| s.pose).collect();
    if let Some(n) = args.max_scans {
        // `n` turns, and the pose where the next one begins.
        poses.truncate(n + 1);
    }
    let config = RunConfig {
        mount: ogm_core::Pose {
            x_mm: ROBOT_MOUNT_X_MM,
            y_mm: 0,
            heading: ogm_core::Angle(0),
        },
        lidar: args.lidar.model(),
        ..run_config(&world, args, sim.mapper_config.max_range_mm)
    };
    let pattern = match args.pattern {
        None => crate::robot::ScanPattern::of(&config.lidar),
        Some(PatternArg::Ld06) => crate::robot::ScanPattern::LD06,
        Some(PatternArg::A1) => crate::robot::ScanPattern::A1,
    };
    let input = crate::robot::robot_input(
        &world,
        &poses,
        &config,
        pattern,
        sim_cfg.lidar.sigma_cells,
        crate::robot::POSE_PERIOD_US,
        args.seed,
    )?;
    let link: Vec<u8> = [&input.link[..], &input.finish[..]].concat();
    if args.host_only {
        // The firmware's application on the host, on the same two byte streams, with a fixed
        // number of sampler updates per turn.
        let n = args.fixed_updates.unwrap_or(0);
        let stream = replay::<u8, _>(
            &link,
            &input.lidar,
            FIRMWARE_SIZES,
            |_| Some(n),
            |_, _| {},
            |_, out| out.to_vec(),
        )?;
        let events: Vec<DeviceEvent> = StreamDecoder::new()
            .push(&stream)
            .into_iter()
            .collect::<Result<_, _>>()
            .map_err(|e| anyhow!("the host's own stream does not decode: {e}"))?;
        let groups = Groups::of(&events);
        return Ok(robot_report(&config, &input, &link, &groups, &events));
    }
    let elf = match &args.elf {
        Some(e) => e.clone(),
        None => build_elf_with(&qemu_dir.join("host-sim-build.log"), args.lidar.features())?,
    };
    let log = (!args.verbose).then(|| qemu_dir.join("host-sim-firmware.log"));
    let line = LidarLine {
        bytes: &input.lidar,
        schedule: &input.schedule,
        finish: &input.finish,
        last_turn: input.turns.saturating_sub(1),
        answers: matches!(config.lidar, LidarModel::Rplidar { .. })
            .then_some(ogm_core::lidar::rplidar::REQ_SCAN),
    };
    let QemuRun {
        stream,
        status,
        secs,
        heard,
    } = run_qemu(
        &elf,
        &input.link,
        Some(line),
        Duration::from_secs(args.timeout),
        log.as_deref(),
    )?;
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out)?;
        std::fs::write(out.join("stream.bin"), &stream)?;
        std::fs::write(out.join("input.bin"), &link)?;
        std::fs::write(out.join("lidar.bin"), &input.lidar)?;
    }
    let (events, ds) = decode_captured(&stream);
    let groups = Groups::of(&events);
    let mut checker = Checker::default();
    let exit_code = status.and_then(|s| s.code());
    if exit_code != Some(0) {
        checker.fail(format!(
            "firmware exit status {exit_code:?} (log: {})",
            log.as_ref()
                .map_or("stdout".into(), |l| l.display().to_string())
        ));
    }
    if let Err(e) = compare(&link, &input.lidar, &groups, &mut checker) {
        checker.fail(format!("{e:#}"));
    }
    // What an RPLIDAR must hear before it scans: STOP, then SCAN; an LD06 nothing.
    let want: &[u8] = match config.lidar {
        LidarModel::Rplidar { .. } => &[
            ogm_core::lidar::rplidar::REQ_STOP,
            ogm_core::lidar::rplidar::REQ_SCAN,
        ]
        .concat(),
        LidarModel::Ld06 => &[],
    };
    checker.eq(
        || "bytes the firmware sent the lidar".into(),
        &heard.as_slice(),
        &want,
    );
    let r = robot_report(&config, &input, &link, &groups, &events);
    Ok(FirmwareReport {
        stream_bytes: ds.bytes,
        stream_frames: ds.frames,
        stream_bad_frames: ds.bad_frames,
        exit_code,
        qemu_seconds: secs,
        mismatches: checker.mismatches,
        checks: checker.checks,
        log,
        ..r
    })
}

/// What a `--robot` run's stream says: the turns and how well they were placed.
fn robot_report(
    config: &RunConfig,
    input: &crate::robot::RobotInput,
    link: &[u8],
    groups: &Groups,
    events: &[DeviceEvent],
) -> FirmwareReport {
    let mut reports: Vec<ScanReport> = groups.scans.values().map(|g| g.report).collect();
    reports.sort_by_key(|r| r.seq);
    let (pos, head) = crate::robot::pose_errors(&reports, input, config);
    FirmwareReport {
        hello: groups.hello.clone(),
        config: Some(*config),
        scans_sent: input.turns as usize,
        input_bytes: link.len() + input.lidar.len(),
        tiles: groups.all_tiles.len() as u64,
        device_errors: groups.errors,
        counters: groups.final_counters,
        sampler: groups.final_sampler,
        done: groups.done,
        figures: groups
            .hello
            .as_ref()
            .map(|h| figures(groups, h))
            .unwrap_or_default(),
        hellos: events
            .iter()
            .filter(|e| matches!(e, DeviceEvent::Hello(_)))
            .count(),
        robot: Some(RobotReport {
            turns_sent: input.turns,
            lidar_bytes: input.lidar.len(),
            poses_sent: input.poses,
            pose_period_us: crate::robot::POSE_PERIOD_US,
            turns_mapped: reports.len(),
            max_position_error_mm: pos,
            max_heading_error_deg: head,
        }),
        ..FirmwareReport::default()
    }
}

/// The accuracy cost of the firmware's bounds: the eval-sim sampler (`crate::sampling`,
/// offline: the online map, then 20 burn-in + 100 counted sweeps) with the firmware's
/// compile-time buffer sizes next to unbounded host buffers, on `args.runs` generated worlds
/// (the first is `world`, already simulated), pooled and scored against ground truth. After a
/// QEMU run (`online`: its input and update counts) the online replay is scored the same way,
/// with firmware sizes and unbounded.
fn accuracy(
    args: &FirmwareArgs,
    config: &RunConfig,
    world: &World,
    sim: &crate::sim::SimRun,
    scans: &[crate::explore::ScanRecord],
    online: Option<Online<'_>>,
) -> anyhow::Result<Accuracy> {
    use crate::eval::NEAR_MAPPED_CELLS;
    use crate::metrics::{mask_within, PrAccumulator};
    use crate::sampling::{run_sampler, SamplingConfig, Variant};

    let mut all: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut near: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut acc = Accuracy {
        runs: args.runs.max(1),
        scans: Vec::new(),
        methods: BTreeMap::new(),
        methods_near_mapped: BTreeMap::new(),
        local_overflow_firmware: 0,
        local_overflow_unbounded: 0,
        tile_visits: 0,
        thinnings: 0,
        anytime: Vec::new(),
    };
    // The robot's sampler, offline.
    let host_cfg = SamplingConfig {
        data: config.data,
        evidence_gain_q8: config.evidence_gain_q8,
        evidence_free_q8: config.evidence_free_q8,
        free_update_q8: config.free_update_q8,
        face_band: config.face_band,
        sigma_cells: f64::from(config.sigma_milli_cells) / 1000.0,
        data_candidate: config.data_candidate,
        estimator: config.estimator,
        hot_share: config.hot_share,
        max_candidates: config.max_candidates,
        ..SamplingConfig::default()
    };
    let fw_cfg = crate::eval::with_firmware_bounds(host_cfg);
    for run in 0..acc.runs {
        let (w, s);
        let (world, sim, scans) = if run == 0 {
            (world, sim, scans)
        } else {
            w = firmware_world(&FirmwareArgs {
                seed: args.seed + u64::from(run),
                ..args.clone()
            })?;
            s = simulate(&w, &sim_config(args), args.seed + u64::from(run))?;
            (&w, &s, s.scans.as_slice())
        };
        acc.scans.push(scans.len());
        let mask = mask_within(&sim.observed, world.width, world.height, NEAR_MAPPED_CELLS);
        let mut score = |name: &str, probs: &[f64]| -> anyhow::Result<()> {
            all.entry(name.into())
                .or_default()
                .add(probs, &world.cells, None)?;
            near.entry(name.into())
                .or_default()
                .add(probs, &world.cells, Some(&mask))?;
            Ok(())
        };
        let seed = args.seed + u64::from(run);
        let trad: Vec<f64> = sim.map.iter().map(|l| l.probability()).collect();
        score("traditional", &trad)?;
        // The robot's own log-odds map (its mapper matched to the noise): the sampler is
        // measured against both.
        if config.free_update_q8 != 256 || config.face_band {
            let model = config
                .mapper_config()
                .map_err(|e| anyhow!("settings: {e}"))?
                .model;
            let own =
                crate::sampling::evidence_map(sim.geometry, &sim.mapper_config, scans, model)?;
            let own: Vec<f64> = own.iter().map(|l| l.probability()).collect();
            score("traditional_noise_matched", &own)?;
        }
        for (name, cfg) in [
            ("offline_firmware_sizes", &fw_cfg),
            ("offline_unbounded", &host_cfg),
        ] {
            let o = run_sampler(
                sim.geometry,
                &sim.mapper_config,
                scans,
                &sim.map,
                Variant::L9Border,
                cfg,
                seed,
            )?;
            // Unobserved cells unknown, as in every map the robot streams.
            let m: Vec<f64> = o
                .marginals
                .iter()
                .zip(&sim.observed)
                .map(|(&p, &seen)| if seen { p } else { 0.5 })
                .collect();
            score(name, &m)?;
            if cfg.bounds.rays.is_some() {
                acc.local_overflow_firmware += o.stats.local_overflow;
                acc.tile_visits += o.stats.tile_visits;
                acc.thinnings += o.store.thinnings;
            } else {
                acc.local_overflow_unbounded += o.stats.local_overflow;
            }
        }
        if let (0, Some(online)) = (run, online) {
            let get = |w: Work| match w {
                Work::Scan(seq) => online.scan_updates.get(seq as usize).copied(),
                Work::Idle(seq) => online.idle_updates.get(seq as usize).copied(),
            };
            let total_rays: usize = scans.iter().map(|s| s.beams.len()).sum();
            let unbounded = Sizes {
                rays: total_rays.max(1),
                scans: scans.len().max(1),
                local: total_rays.clamp(1, 1 << 16),
                ..FIRMWARE_SIZES
            };
            let (gw, ww, wh) = (usize::from(FW.width), world.width, world.height);
            let crop = |v: &[f64]| -> Vec<f64> {
                (0..wh)
                    .flat_map(|y| (0..ww).map(move |x| y * gw + x))
                    .map(|i| v[i])
                    .collect()
            };
            let f1 = |v: &[f64]| -> anyhow::Result<f64> {
                let mut a = PrAccumulator::default();
                a.add(&crop(v), &world.cells, None)?;
                Ok(a.summary().max_f1)
            };
            let last = scans.len().saturating_sub(1) as u32;
            let every = (scans.len() / 200).max(1) as u32;
            let mut end_of_scans: Option<Vec<f64>> = None;
            let mut idle_maps: Vec<Vec<f64>> = Vec::new();
            let mut failure: Option<anyhow::Error> = None;
            let configured = replay::<u8, _>(
                online.input,
                &[],
                FIRMWARE_SIZES,
                get,
                |fed, m| {
                    let r = (|| -> anyhow::Result<()> {
                        match fed {
                            Fed::Scan(seq) => {
                                if seq % every == 0 || seq == last {
                                    let lo: Vec<f64> =
                                        m.log_odds().iter().map(|l| l.probability()).collect();
                                    acc.anytime.push(AnytimePoint {
                                        scans: seq + 1,
                                        online: f1(&marginals(m))?,
                                        log_odds: f1(&lo)?,
                                    });
                                }
                                if seq == last {
                                    end_of_scans = Some(marginals(m));
                                }
                            }
                            Fed::Idle(_) => idle_maps.push(marginals(m)),
                            _ => {}
                        }
                        Ok(())
                    })();
                    if let (Err(e), None) = (r, &failure) {
                        failure = Some(e);
                    }
                },
                |m, _| m.is_some(),
            )?;
            if let Some(e) = failure {
                return Err(e);
            }
            let unbounded_map = replay::<u32, _>(
                online.input,
                &[],
                unbounded,
                get,
                |_, _| {},
                |m, _| m.map(marginals),
            )?;
            if let (true, Some(online_map)) = (configured, &end_of_scans) {
                score("online_firmware_sizes", &crop(online_map))?;
            }
            if let Some(u) = unbounded_map {
                // Unbounded buffers and u32 estimates, at the end of the run (idle included).
                score("online_unbounded", &crop(&u))?;
            }
            for (secs, m) in online.idle_marks.iter().zip(&idle_maps) {
                score(&format!("online_idle_{secs}s"), &crop(m))?;
            }
        }
    }
    acc.methods = all.iter().map(|(k, v)| (k.clone(), v.summary())).collect();
    acc.methods_near_mapped = near.iter().map(|(k, v)| (k.clone(), v.summary())).collect();
    Ok(acc)
}

/// Prints a report.
pub fn print_report(r: &FirmwareReport) {
    if let Some(h) = &r.hello {
        println!(
            "firmware: {} on {}; grid {}x{}, {} rays, {} scans, {} local rays, {} beams/scan",
            h.firmware,
            h.board,
            h.width,
            h.height,
            h.ray_capacity,
            h.scan_capacity,
            h.local_capacity,
            h.max_beams
        );
    }
    if r.exit_code.is_some() || r.stream_bytes > 0 {
        println!(
            "link: {} scans, {} bytes in ({} garbage); stream {} bytes, {} frames ({} bad), {} tiles, {} error reports; QEMU {:.1} s, exit {:?}",
            r.scans_sent, r.input_bytes, r.garbage_bytes, r.stream_bytes, r.stream_frames,
            r.stream_bad_frames, r.tiles, r.device_errors, r.qemu_seconds, r.exit_code
        );
    }
    if let Some(c) = &r.counters {
        println!("counters: {c:?}");
    }
    if let Some(rb) = &r.robot {
        println!(
            "robot loop: {} turns on the lidar UART ({} bytes), {} poses on the link every {} ms; {} turns mapped, placed within {:.1} mm and {:.2} deg of the true sensor pose",
            rb.turns_sent,
            rb.lidar_bytes,
            rb.poses_sent,
            rb.pose_period_us / 1000,
            rb.turns_mapped,
            rb.max_position_error_mm,
            rb.max_heading_error_deg
        );
    }
    if let Some(n) = &r.noise {
        println!(
            "noise: {} bytes corrupted; {} of {} LD06 packets ({} of them past the 8-bit CRC) and {} of {} frames damaged; {} points in rejected packets of framed scans; replay of the acceptable packets alone {}",
            n.corrupted_bytes, n.damaged_packets, n.packets, n.undetected_packets, n.damaged_frames, n.frames,
            n.points_in_damaged_packets,
            if n.surviving_replay_identical { "identical" } else { "DIFFERENT" }
        );
    }
    if r.hellos > 1 {
        println!("the firmware reset: {} Hello messages", r.hellos);
    }
    if let Some(s) = &r.sampler {
        println!("sampler: {s:?}");
    }
    let f = &r.figures;
    if f.scans > 0 {
        println!(
            "instructions (qemu -icount shift=0): insert+seed+store+refresh per updated cell {:.1}, per scan {:.0} (max {}, {:.0} beams, {:.0} cells; separate store+refresh {:.0}/scan); per sampled patch {:.0} ({} updates, {:.0}/scan); stack {} B (mapping loop) / {} B (building the sampler) of {} B",
            f.insert_per_cell, f.insert_per_scan, f.insert_per_scan_max, f.beams_per_scan,
            f.cells_per_scan, f.store_per_scan, f.per_patch, f.sampler_updates,
            f.updates_per_scan, f.stack_used, f.stack_config, f.stack_size
        );
    }
    if let Some(a) = &r.accuracy {
        println!("accuracy, L = 9 + border (all cells | near mapped cells): max F1, max precision; online_*: first world only");
        for (k, v) in &a.methods {
            let n = &a.methods_near_mapped[k];
            println!(
                "  {k:<28} {:.4} {:.4} | {:.4} {:.4}",
                v.max_f1, v.max_precision, n.max_f1, n.max_precision
            );
        }
        println!(
            "  {} world(s), {:?} scans; offline local-list overflow: firmware sizes {} / unbounded {}; ray-store thinnings {}",
            a.runs, a.scans, a.local_overflow_firmware, a.local_overflow_unbounded, a.thinnings
        );
    }
    if r.exit_code.is_some() {
        if r.identical() {
            println!(
                "IDENTICAL: the streamed map equals ogm-core on the host, cell for cell ({} checks)",
                r.checks
            );
        } else {
            println!("DIFFERENT ({} checks):", r.checks);
            for m in &r.mismatches {
                println!("  {m}");
            }
            if let Some(l) = &r.log {
                println!("QEMU log: {}", l.display());
            }
        }
    }
}

/// The CLI entry point.
pub fn cli(args: &FirmwareArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.decode {
        let events = crate::link::decode_file(path)?;
        let g = Groups::of(&events);
        if let Some(h) = &g.hello {
            println!("{h:?}");
            let f = figures(&g, h);
            println!("{}", serde_json::to_string_pretty(&f)?);
        }
        println!(
            "{} scans, {} tiles, {} errors, done: {:?}",
            g.scans.len(),
            g.all_tiles.len(),
            g.errors,
            g.done
        );
        // The latest counters (the final ones, else the last scan's): what a cut-off run saw.
        let last = g.final_counters.or_else(|| {
            let seq = g.scans.keys().max()?;
            g.scans.get(seq)?.counters
        });
        if let Some(c) = last {
            println!("counters: {c:?}");
        }
        ensure!(
            g.done.is_some(),
            "{}: truncated map stream: {} frames but no Done message",
            path.display(),
            events.len()
        );
        return Ok(());
    }
    if args.host_only && !args.accuracy && !args.robot {
        bail!("--host-only only makes sense with --accuracy or --robot");
    }
    // Bad input files first, each with a one-line error naming it (before the toolchain check).
    if let Some(elf) = &args.elf {
        check_elf(elf)?;
    }
    if args.map.is_some() {
        firmware_world(args)?;
    }
    if !args.host_only {
        if let Some(why) = toolchain_missing() {
            bail!("{why}");
        }
    }
    let r = run(args)?;
    print_report(&r);
    if !args.host_only && !r.identical() {
        bail!("the firmware's map differs from the host's");
    }
    if let Some(rb) = &r.robot {
        ensure!(
            rb.turns_mapped == rb.turns_sent as usize,
            "{} of {} turns were mapped",
            rb.turns_mapped,
            rb.turns_sent
        );
    }
    Ok(())
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
