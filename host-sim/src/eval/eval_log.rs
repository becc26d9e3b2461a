//! `host-sim eval-log`: the paper's hardware protocol (Merali & Barfoot §IV, Table III, Fig. 7)
//! on real CARMEN logs.
//!
//! * **Grid.** The bounding box of the log's poses and of the end points of its hits within the
//!   mapping range, plus [`MARGIN_M`] on every side, in cells of `--cell-size` (default 0.05 m:
//!   the cell size the patch prior was learnt at; the paper used 2 cm for the Intel lab).
//! * **Mapper.** `ogm_core`'s Hähnel mapper ([`crate::sim::new_mapper`]) with maximum range
//!   `min(sensor range, --range-cap)`: a hit at or beyond it frees cells up to the cap and marks
//!   nothing, like a no-return. A [`ReplaySensor`] reads the recorded scans into the engine's
//!   scan buffer, one [`crate::sim::insert_scan`] each.
//! * **Benchmark.** Traditional OGM on all of the log's scans and beams; a cell some
//!   measurement updated is occupied iff p > [`BENCHMARK_THRESHOLD`] (0.20; see
//!   [`benchmark_truth`] for why strictly), else free; cells no measurement updated are unknown
//!   and never scored.
//! * **Experiments** (Table III): 1 = every 2nd beam of every pose, 2 = every 2nd beam of every
//!   2nd pose, 3 = every 2nd beam of every 10th pose. Each is mapped traditionally and then by
//!   the samplers (`host_sim::sampling::run_sampler`) and the baselines
//!   ([`crate::eval::baselines`]) on the same scans.
//! * **Method settings.** Forward model N(f, σ²) with σ = 3 cells (`--sigma-cells`, the paper's
//!   simulation value); 10 burn-in + 50 counted sweeps (`--burn-in`, `--sweeps`; Metropolis–
//!   Hastings the same, every baseline stopped after `--baseline-seconds`, 10 s). The initial
//!   sample is the online map cut at log-odds 0 (`--init-threshold 0`): never-observed cells start
//!   **free**. The samplers' own default (−1) starts them occupied, which suits a simulated
//!   building whose unseen cells are wall interiors, but on a log the benchmark knows many cells
//!   an experiment never saw — the corridors between the poses it kept — and they are free.
//! * **Metrics** ([`crate::eval::metrics`]): `methods` pools every cell with a known benchmark value;
//!   `methods_near_mapped` only cells within [`NEAR_MAPPED_CELLS`] cells of a cell the
//!   experiment's measurements updated (the paper's hardware F1).
//!
//! Output: `DIR/report.json` ([`LogReport`]: per experiment the `methods` shape of `eval-sim`'s
//! report plus poses, measurements and the fraction of cells mapped), `benchmark.png`, per
//! experiment `expN_comparison.png` (benchmark | traditional | samplers), `expN_<method>.png`
//! (probability) and `expN_<method>_errors.png` (TP black, FP red, FN blue at the method's
//! max-F1 threshold), and with `--export-ros` ROS map_server maps of all of them in `DIR/ros/`
//! (`.yaml` + trinary `.pgm` + `.png`, probabilities cut at map_server's 0.65 / 0.196). With several
//! logs each gets `DIR/<name>/` and `DIR/summary.md` / `summary.json` hold the table.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, ensure, Context};
use ogm_core::map::mapper::marks_len;
use ogm_core::{GridGeometry, LogOdds, MapperConfig, Pose, Range, ScanBuf};
use ogm_field::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use ogm_field::world::{Truth, World};
use serde::{Deserialize, Serialize};

use crate::eval::baselines::{self, BaselineConfig, Method as BaselineMethod, SensorModel};
use crate::eval::log_maps::{benchmark, map_experiment, ExperimentMaps};
use crate::eval::metrics::{mask_within, Summary};
use crate::eval::render;
use crate::eval::report::{MapInfo, Report};
use crate::eval::sampling::{run_sampler, SamplingConfig, Variant};
use crate::sim::carmen::{read_log, LogInfo, ReadOptions};
use crate::sim::explore::ScanRecord;
use crate::sim::{insert_scan, mark_observed, new_mapper, MAX_BEAMS};

/// The benchmark threshold of the paper: occupied iff p > 0.20.
pub const BENCHMARK_THRESHOLD: f64 = 0.20;

/// Radius (cells) of the "near a mapped cell" restriction.
pub const NEAR_MAPPED_CELLS: f64 = 10.0;

/// Margin (m) around the bounding box of poses and hits.
pub const MARGIN_M: f64 = 1.0;

/// Default cap (m) on the mapping range.
pub const DEFAULT_RANGE_CAP_M: f64 = 20.0;

/// Default methods besides traditional OGM: every sampler and baseline.
pub const DEFAULT_METHODS: &str = "all";

/// How a log is mapped: grid, sensor range and the methods' settings (shared by `eval-log` and
/// `export`).
#[derive(clap::Args, Clone, Debug)]
pub struct LogMapArgs {
    /// Cell size in metres.
    #[arg(long, default_value_t = 0.05)]
    pub cell_size: f64,
    /// Sensor maximum range in metres for FLASER lines (readings at or beyond it are no-returns);
    /// default: detected from the log.
    #[arg(long)]
    pub max_range: Option<f64>,
    /// Cap on the mapping range in metres (hits beyond it only free space up to it).
    #[arg(long, default_value_t = DEFAULT_RANGE_CAP_M)]
    pub range_cap: f64,
    /// Sampler sweeps (map samples) counted after burn-in; also Metropolis–Hastings' sweeps.
    #[arg(long, default_value_t = 50)]
    pub sweeps: u32,
    /// Sampler burn-in sweeps.
    #[arg(long, default_value_t = 10)]
    pub burn_in: u32,
    /// Forward-model σ in cells, for the samplers and the baselines; default: estimated from
    /// each experiment's own data (`crate::eval::noise`; the paper's simulation used 3).
    #[arg(long)]
    pub sigma_cells: Option<f64>,
    /// Initial sample: a cell starts occupied iff its online log-odds exceeds this (raw LSB,
    /// 1024 = ln 4). The default 0 starts never-observed cells free (see the module docs).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub init_threshold: i16,
    /// Wall-clock limit (s) of each baseline run (Metropolis–Hastings: sweeps as for the
    /// samplers, up to this limit; belief propagation and dual decomposition: iterations).
    #[arg(long, default_value_t = 10.0)]
    pub baseline_seconds: f64,
    /// Seed of the samplers and baselines.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl Default for LogMapArgs {
    fn default() -> Self {
        LogMapArgs {
            cell_size: 0.05,
            max_range: None,
            range_cap: DEFAULT_RANGE_CAP_M,
            sweeps: 50,
            burn_in: 10,
            sigma_cells: None,
            init_threshold: 0,
            baseline_seconds: 10.0,
            seed: 1,
        }
    }
}

/// `host-sim eval-log` options.
#[derive(clap::Args, Clone, Debug)]
pub struct EvalLogArgs {
    /// CARMEN logs (plain or gzip), or directories of `*.log` / `*.log.gz` files.
    #[arg(long, num_args = 1.., required = true)]
    pub log: Vec<PathBuf>,
    /// Run only this experiment (1, 2 or 3; default: all three).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub experiment: Option<u8>,
    /// Output directory.
    #[arg(long, default_value = "out/eval-log")]
    pub out: PathBuf,
    /// Methods besides traditional OGM (comma-separated): the samplers gibbs_l1, gibbs_l9,
    /// gibbs_l9_border, the baselines mh, mh_heatmap, bp_sum, bp_max, dd, "all", or "none".
    #[arg(long, default_value = DEFAULT_METHODS)]
    pub methods: String,
    /// Grid, range and method settings.
    #[command(flatten)]
    pub map: LogMapArgs,
    /// Also write every map as a ROS map_server map (`.yaml` + trinary `.pgm`).
    #[arg(long)]
    pub export_ros: bool,
    /// Seeded perturbation of the experiments' scans ([`crate::eval::perturb`]; the benchmark
    /// is made from the unperturbed log).
    #[command(flatten)]
    pub perturb: crate::eval::perturb::PerturbArgs,
    /// Wheel odometry instead of the log's poses, with and without scan matching
    /// ([`crate::eval::eval_odometry`]).
    #[command(flatten)]
    pub odometry: crate::eval::eval_odometry::OdometryArgs,
}

/// Replays recorded scans in order, like a sensor; `Err(EndOfLog)` after the last.
#[derive(Clone, Debug)]
pub struct ReplaySensor<'a> {
    scans: &'a [ScanRecord],
    next: usize,
}

/// The replayed log has no more scans.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EndOfLog;

impl<'a> ReplaySensor<'a> {
    /// Replays `scans` from the first.
    pub fn new(scans: &'a [ScanRecord]) -> Self {
        ReplaySensor { scans, next: 0 }
    }

    /// The pose of the scan that the next [`ReplaySensor::read_scan`] returns.
    pub fn next_pose(&self) -> Option<Pose> {
        self.scans.get(self.next).map(|s| s.pose)
    }
}

impl ReplaySensor<'_> {
    /// The next scan into `scan` (cleared first; beams beyond its capacity are counted as its
    /// overflow).
    pub fn read_scan<const N: usize>(&mut self, scan: &mut ScanBuf<N>) -> Result<(), EndOfLog> {
        let s = self.scans.get(self.next).ok_or(EndOfLog)?;
        self.next += 1;
        scan.clear();
        for b in &s.beams {
            scan.push(*b);
        }
        Ok(())
    }
}

/// A traditional map of some scans.
#[derive(Clone, Debug)]
pub struct Mapped {
    /// Log-odds per cell.
    pub map: Vec<LogOdds>,
    /// Cells some measurement updated.
    pub observed: Vec<bool>,
    /// Beams the scan buffer had no room for.
    pub beams_overflowed: u64,
    /// Wall-clock seconds of the mapping (pipeline and observed-cell marking).
    pub seconds: f64,
}

/// Maps `scans` online, one [`crate::sim::insert_scan`] each.
pub fn map_scans(
    geometry: GridGeometry,
    config: MapperConfig,
    scans: &[ScanRecord],
) -> anyhow::Result<Mapped> {
    let t0 = Instant::now();
    let mut mapper = new_mapper(geometry, config)?;
    let mut sensor = ReplaySensor::new(scans);
    let mut buf: Box<ScanBuf<MAX_BEAMS>> = Box::default();
    let mut observed = vec![false; geometry.len()];
    let mut marks = vec![0u32; marks_len(geometry.len())];
    let mut overflowed = 0u64;
    while let Some(pose) = sensor.next_pose() {
        sensor
            .read_scan(&mut *buf)
            .map_err(|_| anyhow!("the log ended before its last pose"))?;
        insert_scan(&mut mapper, &pose, &mut *buf)?;
        overflowed += u64::from(buf.overflow());
        mark_observed(
            &geometry,
            &config,
            &pose,
            buf.beams(),
            &mut marks,
            &mut observed,
        )?;
    }
    Ok(Mapped {
        map: mapper.grid().cells().to_vec(),
        observed,
        beams_overflowed: overflowed,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The grid over the poses and the hit end points within `max_range_mm`, plus `margin_m`.
pub fn log_geometry(
    scans: &[ScanRecord],
    cell_m: f64,
    max_range_mm: u32,
    margin_m: f64,
) -> anyhow::Result<GridGeometry> {
    ensure!(
        cell_m.is_finite() && cell_m >= 0.001,
        "--cell-size {cell_m} m: must be at least 1 mm"
    );
    let cell_mm = (cell_m * 1000.0).round();
    ensure!(
        (cell_mm / 1000.0 - cell_m).abs() < 1e-9,
        "--cell-size {cell_m} m is not a whole number of millimetres"
    );
    ensure!(!scans.is_empty(), "the log has no usable scan");
    let (mut x0, mut y0, mut x1, mut y1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    let mut add = |x: i64, y: i64| {
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    };
    for s in scans {
        add(i64::from(s.pose.x_mm), i64::from(s.pose.y_mm));
        for b in &s.beams {
            if let Range::Hit(mm) = b.range {
                if mm < max_range_mm {
                    let (x, y) = s.pose.beam_end(b.angle, mm);
                    add(x, y);
                }
            }
        }
    }
    let margin = (margin_m * 1000.0).round() as i64;
    let c = cell_mm as i64;
    let ox = (x0 - margin).div_euclid(c) * c;
    let oy = (y0 - margin).div_euclid(c) * c;
    let w = (x1 + margin - ox).div_euclid(c) + 1;
    let h = (y1 + margin - oy).div_euclid(c) + 1;
    let w = u16::try_from(w).map_err(|_| {
        anyhow!("the map would be {w} cells wide; at most 65535: use a larger --cell-size")
    })?;
    let h = u16::try_from(h).map_err(|_| {
        anyhow!("the map would be {h} cells tall; at most 65535: use a larger --cell-size")
    })?;
    let ox = i32::try_from(ox).map_err(|_| anyhow!("map origin out of range"))?;
    let oy = i32::try_from(oy).map_err(|_| anyhow!("map origin out of range"))?;
    GridGeometry::new(w, h, cell_mm as u32, ox, oy).map_err(|e| anyhow!("{e}"))
}

/// An experiment of Table III: which poses and beams it keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Experiment {
    /// 0 = the benchmark (all data), 1..=3 as in Table III.
    pub id: u8,
    /// Every `pose_step`-th scan (starting with the first).
    pub pose_step: usize,
    /// Every `beam_step`-th beam of a scan (starting with the first).
    pub beam_step: usize,
}

impl Experiment {
    /// The benchmark's data: everything.
    pub const BENCHMARK: Experiment = Experiment {
        id: 0,
        pose_step: 1,
        beam_step: 1,
    };

    /// Experiment `id` (0 = benchmark, 1..=3).
    pub fn new(id: u8) -> anyhow::Result<Experiment> {
        let (pose_step, beam_step) = match id {
            0 => (1, 1),
            1 => (1, 2),
            2 => (2, 2),
            3 => (10, 2),
            _ => bail!("experiment {id}: expected 0 (benchmark), 1, 2 or 3"),
        };
        Ok(Experiment {
            id,
            pose_step,
            beam_step,
        })
    }

    /// The scans it keeps.
    pub fn select(&self, scans: &[ScanRecord]) -> Vec<ScanRecord> {
        scans
            .iter()
            .step_by(self.pose_step.max(1))
            .map(|s| ScanRecord {
                pose: s.pose,
                beams: s
                    .beams
                    .iter()
                    .step_by(self.beam_step.max(1))
                    .copied()
                    .collect(),
            })
            .collect()
    }
}

/// The benchmark ground truth: observed cells are occupied iff `p > threshold`, else free;
/// unobserved cells are unknown.
///
/// Strictly greater: with the Hähnel model (±ln 4 per reading) a cell freed once more than it
/// was hit sits at exactly p = 0.20, and `≥` would call every cell a single free ray crossed
/// occupied (`p > 0.20` ⇔ hits ≥ frees).
pub fn benchmark_truth(probs: &[f64], observed: &[bool], threshold: f64) -> Vec<Truth> {
    probs
        .iter()
        .zip(observed)
        .map(|(&p, &o)| match (o, p > threshold) {
            (false, _) => Truth::Unknown,
            (true, true) => Truth::Occupied,
            (true, false) => Truth::Free,
        })
        .collect()
}

/// A method besides traditional OGM.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogMethod {
    /// A patch Gibbs sampler.
    Sampler(Variant),
    /// A baseline of [`crate::eval::baselines`].
    Baseline(BaselineMethod),
}

impl LogMethod {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            LogMethod::Sampler(v) => v.name(),
            LogMethod::Baseline(m) => m.name(),
        }
    }
}

/// Parses `--methods`: names of samplers and baselines, `all` or `none`.
pub fn parse_methods(methods: &str) -> anyhow::Result<Vec<LogMethod>> {
    let all: Vec<LogMethod> = Variant::ALL
        .iter()
        .map(|v| LogMethod::Sampler(*v))
        .chain(BaselineMethod::ALL.iter().map(|m| LogMethod::Baseline(*m)))
        .collect();
    let mut out = Vec::new();
    for m in methods
        .split(',')
        .map(str::trim)
        .filter(|m| !m.is_empty() && *m != "none")
    {
        let found: Vec<LogMethod> = if m == "all" {
            all.clone()
        } else {
            match all.iter().find(|x| x.name() == m) {
                Some(x) => vec![*x],
                None => bail!(
                    "--methods: unknown method `{m}` (expected {}, all or none)",
                    all.iter().map(|x| x.name()).collect::<Vec<_>>().join(", ")
                ),
            }
        };
        for x in found {
            if !out.contains(&x) {
                out.push(x);
            }
        }
    }
    Ok(out)
}

/// The mapping set-up of a log, shared by `eval-log` and `export`.
#[derive(Clone, Debug)]
pub struct LogSetup {
    /// Log name (file name without `.gz` / `.log`).
    pub name: String,
    /// Scans as read.
    pub scans: Vec<ScanRecord>,
    /// What the reader found.
    pub info: LogInfo,
    /// The grid.
    pub geometry: GridGeometry,
    /// The mapper.
    pub mapper: MapperConfig,
}

/// Reads a log and derives its grid and mapper (see the module docs).
pub fn setup_log(path: &Path, a: &LogMapArgs) -> anyhow::Result<LogSetup> {
    let (max_range_m, range_cap_m, cell_m) = (a.max_range, a.range_cap, a.cell_size);
    ensure!(
        range_cap_m.is_finite() && range_cap_m > 0.0,
        "--range-cap must be positive"
    );
    if let Some(r) = max_range_m {
        ensure!(r.is_finite() && r > 0.0, "--max-range must be positive");
    }
    let log = read_log(path, &ReadOptions { max_range_m })?;
    for w in &log.info.warnings {
        eprintln!("warning: {}: {w}", path.display());
    }
    if log.info.malformed_lines > log.info.warnings.len() {
        eprintln!(
            "warning: {}: {} more malformed lines",
            path.display(),
            log.info.malformed_lines - log.info.warnings.len()
        );
    }
    ensure!(
        !log.scans.is_empty(),
        "{}: no FLASER or ROBOTLASER1 scan",
        path.display()
    );
    let range_m = log.info.max_range_m().min(range_cap_m);
    let max_mm = ((range_m * 1000.0).round() as u32).max(1);
    let geometry = log_geometry(&log.scans, cell_m, max_mm, MARGIN_M)?;
    ensure!(
        u64::from(max_mm) / u64::from(geometry.cell_mm()) < 4000,
        "mapping range {range_m} m is {} cells; the ray store holds at most 4000: lower --range-cap or raise --cell-size",
        max_mm / geometry.cell_mm()
    );
    Ok(LogSetup {
        name: log_name(path),
        scans: log.scans,
        info: log.info,
        geometry,
        mapper: MapperConfig::new(max_mm),
    })
}

/// `foo.log.gz` → `foo`.
pub fn log_name(path: &Path) -> String {
    let mut name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("log")
        .to_string();
    for ext in [".gz", ".log"] {
        if let Some(s) = name.strip_suffix(ext) {
            name = s.to_string();
        }
    }
    name
}

/// Counts of one data set (benchmark or experiment).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DataCounts {
    /// Scans (poses).
    pub poses: usize,
    /// Range measurements (beams).
    pub measurements: usize,
    /// Cells some measurement updated.
    pub cells_mapped: usize,
    /// `cells_mapped` / all cells of the grid (Table III's "portion of cells mapped").
    pub fraction_mapped: f64,
    /// Cells within [`NEAR_MAPPED_CELLS`] of a mapped cell / all cells.
    pub fraction_near_mapped: f64,
}

fn counts(scans: &[ScanRecord], observed: &[bool], near: &[bool]) -> DataCounts {
    let k = observed.len().max(1) as f64;
    let cells_mapped = observed.iter().filter(|&&o| o).count();
    DataCounts {
        poses: scans.len(),
        measurements: scans.iter().map(|s| s.beams.len()).sum(),
        cells_mapped,
        fraction_mapped: cells_mapped as f64 / k,
        fraction_near_mapped: near.iter().filter(|&&o| o).count() as f64 / k,
    }
}

/// The benchmark map's description in the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchmarkInfo {
    /// Data counts.
    #[serde(flatten)]
    pub counts: DataCounts,
    /// Threshold (occupied iff p > it).
    pub threshold: f64,
    /// Occupied cells.
    pub occupied_cells: usize,
    /// Free cells.
    pub free_cells: usize,
    /// Seconds to map.
    pub seconds: f64,
}

/// One experiment in the report: `eval-sim`'s report shape plus the data counts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExperimentReport {
    /// 1, 2 or 3.
    pub experiment: u8,
    /// Every how many-th pose and beam.
    pub pose_step: usize,
    /// Every how many-th beam.
    pub beam_step: usize,
    /// Data counts.
    #[serde(flatten)]
    pub counts: DataCounts,
    /// Wall-clock seconds per map sample: per sweep (K/L patch updates) of each sampler and per
    /// sweep (K proposals) of Metropolis–Hastings; per iteration of belief propagation and dual
    /// decomposition.
    pub seconds_per_map_sample: BTreeMap<String, f64>,
    /// The range noise estimated from the experiment's data.
    #[serde(default)]
    pub noise: Option<crate::eval::noise::NoiseEstimate>,
    /// The forward model's σ (cells) the methods used.
    #[serde(default)]
    pub sigma_cells: f64,
    /// The sensor's σ (cells) and share of hits without evidence the robot's settings were
    /// made for (`RunConfig::with_sensor`; the estimate's [`NoiseEstimate::sensor`]).
    ///
    /// [`NoiseEstimate::sensor`]: crate::eval::noise::NoiseEstimate::sensor
    #[serde(default)]
    pub sensor: (f64, f64),
    /// The perturbation of the experiment's scans, if any ([`crate::eval::perturb`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<crate::eval::perturb::PerturbStats>,
    /// Methods (`methods`, `methods_near_mapped`, ...), as in `eval-sim`.
    #[serde(flatten)]
    pub report: Report,
}

/// `DIR/report.json` of one log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogReport {
    /// Log name.
    pub log: String,
    /// Log path as given.
    pub path: String,
    /// What the reader found (warnings included).
    pub reader: LogInfo,
    /// Cells wide.
    pub width: usize,
    /// Cells tall.
    pub height: usize,
    /// Cell size (m).
    pub cell_size_m: f64,
    /// World position (m) of the lower-left corner of cell (0, 0).
    pub origin_m: (f64, f64),
    /// Mapping range (m): the sensor's, capped.
    pub mapping_range_m: f64,
    /// The mapping range in cells (the forward model's F).
    pub mapping_range_cells: f64,
    /// The benchmark.
    pub benchmark: BenchmarkInfo,
    /// The experiments run.
    pub experiments: Vec<ExperimentReport>,
}

/// Runs `eval-log` (one or several logs).
pub fn run(args: &EvalLogArgs) -> anyhow::Result<()> {
    let logs = collect_logs(&args.log)?;
    let variants = parse_methods(&args.methods)?;
    let experiments: Vec<u8> = match args.experiment {
        Some(e) => vec![e],
        None => vec![1, 2, 3],
    };
    let cfg = MethodsConfig::new(&args.map)?;
    args.perturb.validate()?;
    if args.odometry.is_active() {
        return crate::eval::eval_odometry::run(args, &logs, &variants, &cfg, &experiments);
    }
    ensure!(
        !args.odometry.no_match,
        "--no-match needs --odometry-drift or --truth-poses"
    );
    let mut reports = Vec::new();
    for log in &logs {
        let dir = if logs.len() == 1 {
            args.out.clone()
        } else {
            args.out.join(log_name(log))
        };
        let r = eval_one(log, &dir, args, &variants, &cfg, &experiments)
            .with_context(|| format!("evaluating {}", log.display()))?;
        reports.push(r);
    }
    let table = results_table(&reports);
    println!("\n{table}");
    if logs.len() > 1 {
        std::fs::write(args.out.join("summary.md"), &table)
            .with_context(|| format!("writing {}", args.out.join("summary.md").display()))?;
        let json = serde_json::to_string_pretty(&reports)?;
        std::fs::write(args.out.join("summary.json"), json + "\n")
            .with_context(|| format!("writing {}", args.out.join("summary.json").display()))?;
        println!("wrote {}", args.out.join("summary.md").display());
    }
    Ok(())
}

/// Files of `paths`, directories expanded to their `*.log` / `*.log.gz` files (sorted).
pub fn collect_logs(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    crate::eval::eval_sim::collect_files(paths, ".log or .log.gz files", |f| {
        let n = f.file_name().and_then(|n| n.to_str()).unwrap_or("");
        n.ends_with(".log") || n.ends_with(".log.gz")
    })
}

/// The settings of the samplers and baselines.
#[derive(Clone, Debug)]
pub struct MethodsConfig {
    /// Samplers.
    pub sampling: SamplingConfig,
    /// Baselines.
    pub baseline: BaselineConfig,
    /// Seed.
    pub seed: u64,
    /// Estimate σ from each data set ([`MethodsConfig::with_sigma`]).
    pub estimate_sigma: bool,
}

impl MethodsConfig {
    /// These settings with the forward model's σ set to `sigma_cells`.
    pub fn with_sigma(&self, sigma_cells: f64) -> MethodsConfig {
        let mut c = self.clone();
        c.sampling.sigma_cells = sigma_cells;
        if let SensorModel::Gaussian { sigma_cells: s, .. } = &mut c.baseline.model {
            *s = sigma_cells;
        }
        c
    }

    /// These settings with the robot's made for a sensor of σ `sensor.0` cells and a share
    /// `sensor.1` of hits without evidence ([`SamplingConfig::sensor`]).
    pub fn with_sensor(&self, sensor: (f64, f64)) -> MethodsConfig {
        let mut c = self.clone();
        c.sampling.sensor_sigma_cells = Some(sensor.0);
        c.sampling.outlier_share = sensor.1;
        c
    }

    /// From the command-line options.
    pub fn new(a: &LogMapArgs) -> anyhow::Result<Self> {
        ensure!(
            a.baseline_seconds.is_finite() && a.baseline_seconds > 0.0,
            "--baseline-seconds must be positive"
        );
        ensure!(
            a.sigma_cells.is_none_or(|s| s.is_finite() && s > 0.0),
            "--sigma-cells must be positive"
        );
        let sampling = SamplingConfig {
            sweeps: a.sweeps,
            burn_in: a.burn_in,
            init_threshold: a.init_threshold,
            sigma_cells: a
                .sigma_cells
                .unwrap_or(SamplingConfig::default().sigma_cells),
            ..SamplingConfig::default()
        };
        let mut baseline = BaselineConfig {
            init_threshold: a.init_threshold,
            ..BaselineConfig::default()
        };
        if let (SensorModel::Gaussian { sigma_cells, .. }, Some(s)) =
            (&mut baseline.model, a.sigma_cells)
        {
            *sigma_cells = s;
        }
        baseline.mh.sweeps = a.sweeps;
        baseline.mh.burn_in_sweeps = a.burn_in;
        baseline.mh.max_seconds = a.baseline_seconds;
        baseline.bp.max_seconds = a.baseline_seconds;
        baseline.dd.max_seconds = a.baseline_seconds;
        Ok(MethodsConfig {
            sampling,
            baseline,
            seed: a.seed,
            estimate_sigma: a.sigma_cells.is_none(),
        })
    }
}

/// What one method produced on one data set.
#[derive(Clone, Debug)]
pub struct MethodOutput {
    /// p(occupied) per cell (0/1 labels for the MAP baselines).
    pub probs: Vec<f64>,
    /// Wall-clock seconds of inference.
    pub seconds: f64,
    /// Seconds per map sample (sampler / MH sweep) or per iteration (BP, DD).
    pub seconds_per_sample: f64,
    /// Sweeps or iterations done.
    pub iterations: u64,
}

/// Runs one method on `scans` (whose online map is `map`). `graph` caches the baselines'
/// factor graph between calls on the same scans.
pub fn run_log_method(
    m: LogMethod,
    setup: &LogSetup,
    scans: &[ScanRecord],
    map: &[LogOdds],
    cfg: &MethodsConfig,
    graph: &mut Option<baselines::FactorGraph>,
) -> anyhow::Result<MethodOutput> {
    let g = setup.geometry;
    Ok(match m {
        LogMethod::Sampler(v) => {
            let o = run_sampler(
                g,
                &setup.mapper,
                scans,
                map,
                v,
                &v.configure(&cfg.sampling),
                cfg.seed,
            )?;
            MethodOutput {
                probs: o.marginals,
                seconds: o.seconds,
                seconds_per_sample: o.seconds_per_sweep,
                iterations: u64::from(cfg.sampling.burn_in + cfg.sampling.sweeps),
            }
        }
        LogMethod::Baseline(b) => {
            if graph.is_none() {
                *graph = Some(baselines::build_graph(
                    &g,
                    &setup.mapper,
                    scans,
                    &cfg.baseline,
                )?);
            }
            let Some(fg) = graph.as_ref() else {
                bail!("factor graph missing");
            };
            let o = baselines::run_on_graph(b, fg, map, &cfg.baseline, cfg.seed)?;
            MethodOutput {
                seconds_per_sample: o.seconds / (o.iterations.max(1) as f64),
                probs: o.probs,
                seconds: o.seconds,
                iterations: o.iterations,
            }
        }
    })
}

fn eval_one(
    path: &Path,
    out: &Path,
    args: &EvalLogArgs,
    methods: &[LogMethod],
    cfg: &MethodsConfig,
    experiments: &[u8],
) -> anyhow::Result<LogReport> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create output directory", out.display()))?;
    let setup = setup_log(path, &args.map)?;
    let g = setup.geometry;
    let (w, h) = (usize::from(g.width()), usize::from(g.height()));
    let res = f64::from(g.cell_mm()) / 1000.0;
    let origin = (
        f64::from(g.origin_mm().0) / 1000.0,
        f64::from(g.origin_mm().1) / 1000.0,
    );
    eprintln!(
        "{}: {} scans, {w}x{h} cells of {res} m, mapping range {} m",
        setup.name,
        setup.scans.len(),
        f64::from(setup.mapper.max_range_mm) / 1000.0
    );
    let (world, bench) = benchmark(&setup)?;
    let bench_near = mask_within(&bench.observed, w, h, NEAR_MAPPED_CELLS);
    let tc = world.counts();
    let benchmark = BenchmarkInfo {
        counts: counts(&setup.scans, &bench.observed, &bench_near),
        threshold: BENCHMARK_THRESHOLD,
        occupied_cells: tc.occupied,
        free_cells: tc.free,
        seconds: bench.seconds,
    };
    render::truth_png(out.join("benchmark.png"), &world)?;
    if args.export_ros {
        ogm_field::export::export_world(&out.join("ros").join("benchmark.yaml"), &world)?;
    }
    // The experiments read the perturbed log (if asked); the benchmark above the unperturbed.
    let (perturbed, perturbation) = if args.perturb.is_active() {
        let (p, st) = crate::eval::perturb::perturb(
            &setup.scans,
            &args.perturb,
            g.cell_mm(),
            // Far outliers reach the sensor's own range (beyond the mapping cap they free space
            // up to it, like a real far reading).
            (setup.info.max_range_m() * 1000.0).clamp(0.0, f64::from(u32::MAX)) as u32,
        );
        eprintln!("{}: perturbed: {st:?}", setup.name);
        (Some(p), Some(st))
    } else {
        (None, None)
    };
    let mut exps = Vec::new();
    for &id in experiments {
        let e = Experiment::new(id)?;
        let scans = e.select(perturbed.as_deref().unwrap_or(&setup.scans));
        let em = map_experiment(
            &setup,
            &scans,
            methods,
            cfg,
            &format!("{} experiment {id}", setup.name),
        )?;
        let (all, near_sum) = em.score(&world)?;
        let ExperimentMaps {
            mapped: t,
            near,
            maps,
            seconds,
            per_sample,
            iterations,
            noise,
            cfg,
        } = em;
        let cfg = &cfg;
        write_experiment_images(
            out,
            id,
            &world,
            &maps,
            &t.observed,
            &near_sum,
            args.export_ros,
        )?;
        let report = Report {
            methods: all,
            methods_near_mapped: near_sum,
            restricted_radius_cells: NEAR_MAPPED_CELLS,
            datasets: 1,
            maps: vec![MapInfo {
                name: setup.name.clone(),
                width: w,
                height: h,
                resolution_m: res,
                runs: 1,
                mean_scans: scans.len() as f64,
            }],
            settings: serde_json::json!({
                "sampling": cfg.sampling,
                "baselines": cfg.baseline,
                "iterations": iterations,
                "seed": cfg.seed,
                "mapper_max_range_mm": setup.mapper.max_range_mm,
                "benchmark_threshold": BENCHMARK_THRESHOLD,
                "beams_overflowed": t.beams_overflowed,
            }),
            seconds,
        };
        eprintln!("{} experiment {id}:\n{}", setup.name, report.table());
        exps.push(ExperimentReport {
            experiment: id,
            pose_step: e.pose_step,
            beam_step: e.beam_step,
            counts: counts(&scans, &t.observed, &near),
            seconds_per_map_sample: per_sample,
            noise,
            sigma_cells: cfg.sampling.sigma_cells,
            sensor: cfg.sampling.sensor(),
            perturbation,
            report,
        });
    }
    let r = LogReport {
        log: setup.name.clone(),
        path: path.display().to_string(),
        reader: setup.info,
        width: w,
        height: h,
        cell_size_m: res,
        origin_m: origin,
        mapping_range_m: f64::from(setup.mapper.max_range_mm) / 1000.0,
        mapping_range_cells: f64::from(setup.mapper.max_range_mm) / f64::from(g.cell_mm()),
        benchmark,
        experiments: exps,
    };
    let json = serde_json::to_string_pretty(&r)?;
    std::fs::write(out.join("report.json"), json + "\n")
        .with_context(|| format!("writing {}", out.join("report.json").display()))?;
    eprintln!("wrote {}", out.join("report.json").display());
    Ok(r)
}

fn write_experiment_images(
    out: &Path,
    id: u8,
    world: &World,
    maps: &BTreeMap<String, Vec<f64>>,
    observed: &[bool],
    near: &BTreeMap<String, Summary>,
    export_ros: bool,
) -> anyhow::Result<()> {
    let (w, h) = (world.width, world.height);
    let mut panels = vec![("benchmark".to_string(), render::truth_image(world)?)];
    // Traditional first, then the samplers.
    let mut names: Vec<&String> = maps.keys().collect();
    names.sort_by_key(|n| (n.as_str() != "traditional", n.as_str()));
    for name in names {
        let probs = &maps[name];
        // What this experiment's measurements never reached is drawn and exported unknown.
        let shown = render::unknown_where_unobserved(probs, observed);
        panels.push((name.clone(), render::probability_image(&shown, w, h)?));
        render::probability_png(out.join(format!("exp{id}_{name}.png")), &shown, w, h)?;
        let t = near.get(name).map_or(0.5, |s| s.threshold_at_max_f1);
        render::comparison_png(
            out.join(format!("exp{id}_{name}_errors.png")),
            probs,
            world,
            t,
        )?;
        if export_ros {
            let trinary = ogm_field::world::probabilities_to_world(
                &shown,
                w,
                h,
                world.resolution_m,
                world.origin_m,
                DEFAULT_OCCUPIED_THRESH,
                DEFAULT_FREE_THRESH,
            );
            let path = out.join("ros").join(format!("exp{id}_{name}.yaml"));
            ogm_field::export::export_world(&path, &trinary)?;
        }
    }
    render::side_by_side_png(out.join(format!("exp{id}_comparison.png")), &panels)
}

/// The Markdown table of max F1 (near mapped cells) and seconds per map sample.
pub fn results_table(reports: &[LogReport]) -> String {
    let mut s = String::new();
    s.push_str("| log | exp | poses | measurements | mapped | method | max F1 (near) | thr | max F1 (all) | s / map sample |\n");
    s.push_str("|---|---|---|---|---|---|---|---|---|---|\n");
    for r in reports {
        for e in &r.experiments {
            for (name, m) in &e.report.methods_near_mapped {
                let all = e.report.methods.get(name).map_or(f64::NAN, |a| a.max_f1);
                let t = e
                    .seconds_per_map_sample
                    .get(name)
                    .map_or("—".to_string(), |v| format!("{v:.3}"));
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {:.2} % | {} | {:.4} | {:.3} | {:.4} | {} |\n",
                    r.log,
                    e.experiment,
                    e.counts.poses,
                    e.counts.measurements,
                    100.0 * e.counts.fraction_mapped,
                    name,
                    m.max_f1,
                    m.threshold_at_max_f1,
                    all,
                    t
                ));
            }
        }
    }
    s
}
