//! A log as eval-log and export read it: the grid over its poses and hits, the mapper, the
//! experiments' selections of its scans, the traditional map of some of its scans, and the
//! benchmark's threshold (the protocol: [`crate::eval::eval_log`]'s docs).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, ensure};
use ogm_core::map::mapper::marks_len;
use ogm_core::{GridGeometry, LogOdds, MapperConfig, Pose, Range, ScanBuf};
use ogm_field::world::Truth;
use serde::{Deserialize, Serialize};

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
    /// all of the log's scans (`crate::eval::noise`; the paper's simulation used 3).
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

/// Files of `paths`, directories expanded to their `*.log` / `*.log.gz` files (sorted).
pub fn collect_logs(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    crate::eval::eval_sim::collect_files(paths, ".log or .log.gz files", |f| {
        let n = f.file_name().and_then(|n| n.to_str()).unwrap_or("");
        n.ends_with(".log") || n.ends_with(".log.gz")
    })
}
