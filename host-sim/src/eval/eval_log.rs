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

use anyhow::{ensure, Context};
use ogm_field::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use ogm_field::world::World;
use serde::{Deserialize, Serialize};

pub use crate::eval::log_maps::{
    parse_methods, run_log_method, LogMethod, MethodOutput, MethodsConfig,
};
pub use crate::eval::log_setup::{
    benchmark_truth, collect_logs, log_geometry, log_name, map_scans, setup_log, EndOfLog,
    Experiment, LogMapArgs, LogSetup, Mapped, ReplaySensor, BENCHMARK_THRESHOLD,
    DEFAULT_RANGE_CAP_M, MARGIN_M, NEAR_MAPPED_CELLS,
};

use crate::eval::log_maps::{benchmark, map_experiment, sensor_noise, ExperimentMaps};
use crate::eval::metrics::{mask_within, Summary};
use crate::eval::render;

/// Default methods besides traditional OGM: every sampler and baseline.
pub const DEFAULT_METHODS: &str = "all";
use crate::eval::report::{MapInfo, Report};
use crate::sim::carmen::LogInfo;
use crate::sim::explore::ScanRecord;

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
    /// Wheel odometry instead of the log's poses, with and without scan matching (run by
    /// [`crate::eval::eval_odometry::run`], not [`run`]).
    #[command(flatten)]
    pub odometry: crate::eval::odometry_args::OdometryArgs,
}

impl EvalLogArgs {
    /// The experiments to run: `--experiment`'s, else all three.
    pub fn experiments(&self) -> Vec<u8> {
        match self.experiment {
            Some(e) => vec![e],
            None => vec![1, 2, 3],
        }
    }
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
    /// The sensor's noise over all the log's scans (perturbed as the experiments read them),
    /// which the experiments' σ comes from; `None` with `--sigma-cells` or too few hits.
    #[serde(default)]
    pub sensor: Option<crate::eval::noise::NoiseEstimate>,
    /// The experiments run.
    pub experiments: Vec<ExperimentReport>,
}

/// Runs `eval-log` (one or several logs).
pub fn run(args: &EvalLogArgs) -> anyhow::Result<()> {
    let logs = collect_logs(&args.log)?;
    let variants = parse_methods(&args.methods)?;
    let experiments = args.experiments();
    let cfg = MethodsConfig::new(&args.map)?;
    args.perturb.validate()?;
    ensure!(
        !args.odometry.is_active(),
        "--odometry-drift / --truth-poses are run by eval_odometry::run"
    );
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
        write_summary(&args.out, &table, &reports)?;
    }
    Ok(())
}

/// `OUT/summary.md` (the table) and `OUT/summary.json` (every log's report) of a run over
/// several logs.
pub(crate) fn write_summary(
    out: &Path,
    table: &str,
    reports: &impl serde::Serialize,
) -> anyhow::Result<()> {
    std::fs::write(out.join("summary.md"), table)
        .with_context(|| format!("writing {}", out.join("summary.md").display()))?;
    let json = serde_json::to_string_pretty(reports)?;
    std::fs::write(out.join("summary.json"), json + "\n")
        .with_context(|| format!("writing {}", out.join("summary.json").display()))?;
    println!("wrote {}", out.join("summary.md").display());
    Ok(())
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
    // The sensor's σ from every scan it produced (as the experiments read them); each
    // experiment's own data says how much of it supports a surface.
    let all = perturbed.as_deref().unwrap_or(&setup.scans);
    let sensor = if cfg.estimate_sigma {
        // Unperturbed, `all` is the benchmark's scans and its map is made already.
        let map = perturbed.is_none().then_some(&bench.map[..]);
        sensor_noise(&setup, all, map)?
    } else {
        None
    };
    let mut exps = Vec::new();
    for &id in experiments {
        let e = Experiment::new(id)?;
        let scans = e.select(all);
        let em = map_experiment(
            &setup,
            &scans,
            sensor.as_ref(),
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
        sensor,
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
