//! The maps of a log that every variant of `eval-log` shares (the paper's protocol, the
//! odometry runs of [`crate::eval::eval_odometry`]) and `export`: the benchmark, and the maps of
//! one experiment's scans by traditional OGM and by the methods (samplers and baselines).

use std::collections::BTreeMap;

use ogm_field::world::World;

use anyhow::{bail, ensure};
use ogm_core::LogOdds;

use crate::eval::baselines::{self, BaselineConfig, Method as BaselineMethod, SensorModel};
use crate::eval::log_setup::{
    benchmark_truth, map_scans, LogMapArgs, LogSetup, Mapped, BENCHMARK_THRESHOLD,
    NEAR_MAPPED_CELLS,
};
use crate::eval::metrics::{mask_within, PrAccumulator, Summary};
use crate::eval::noise::{NoiseEstimate, MIN_SIGMA_CELLS};
use crate::eval::sampling::{run_sampler, SamplingConfig, Variant};
use crate::sim::explore::ScanRecord;
use crate::sim::probabilities;

/// The benchmark of `setup`'s scans (traditional OGM on all of them, cut at
/// [`BENCHMARK_THRESHOLD`], unobserved cells unknown) as a world, and its map.
pub fn benchmark(setup: &LogSetup) -> anyhow::Result<(World, Mapped)> {
    let g = setup.geometry;
    let bench = map_scans(g, setup.mapper, &setup.scans)?;
    let cells = benchmark_truth(
        &probabilities(&bench.map),
        &bench.observed,
        BENCHMARK_THRESHOLD,
    );
    let world = World {
        width: usize::from(g.width()),
        height: usize::from(g.height()),
        resolution_m: f64::from(g.cell_mm()) / 1000.0,
        origin_m: (
            f64::from(g.origin_mm().0) / 1000.0,
            f64::from(g.origin_mm().1) / 1000.0,
        ),
        cells,
    };
    Ok((world, bench))
}

/// One experiment's maps ([`map_experiment`]).
pub struct ExperimentMaps {
    /// The traditional map and the cells it observed.
    pub mapped: Mapped,
    /// Cells within [`NEAR_MAPPED_CELLS`] of an observed cell.
    pub near: Vec<bool>,
    /// p(occupied) per cell of `traditional` and of each method.
    pub maps: BTreeMap<String, Vec<f64>>,
    /// Wall-clock seconds of each.
    pub seconds: BTreeMap<String, f64>,
    /// Seconds per map sample of each method.
    pub per_sample: BTreeMap<String, f64>,
    /// Sweeps or iterations of each method.
    pub iterations: BTreeMap<String, u64>,
    /// The range noise estimated from the scans.
    pub noise: Option<NoiseEstimate>,
    /// The settings the methods ran with (σ and the sensor from `noise` unless given).
    pub cfg: MethodsConfig,
}

impl ExperimentMaps {
    /// Each map's precision-recall summary against `truth`, over all known cells and near the
    /// experiment's mapped cells.
    pub fn score(
        &self,
        truth: &World,
    ) -> anyhow::Result<(BTreeMap<String, Summary>, BTreeMap<String, Summary>)> {
        let mut all = BTreeMap::new();
        let mut near = BTreeMap::new();
        for (name, probs) in &self.maps {
            let mut a = PrAccumulator::new();
            a.add(probs, &truth.cells, None)?;
            all.insert(name.clone(), a.summary());
            let mut n = PrAccumulator::new();
            n.add(probs, &truth.cells, Some(&self.near))?;
            near.insert(name.clone(), n.summary());
        }
        Ok((all, near))
    }
}

/// The sensor's noise estimated from `all`, every scan the sensor produced (e.g. a whole log,
/// perturbed as the experiments read it), on `setup`'s grid: what [`map_experiment`] takes σ from.
/// `map` is `all`'s log-odds map if the caller has it already (the benchmark's, for an
/// unperturbed log), else it is made here. `None` if too few hits have an occupied cell near
/// them.
pub fn sensor_noise(
    setup: &LogSetup,
    all: &[ScanRecord],
    map: Option<&[LogOdds]>,
) -> anyhow::Result<Option<NoiseEstimate>> {
    let made;
    let map = match map {
        Some(m) => m,
        None => {
            made = map_scans(setup.geometry, setup.mapper, all)?.map;
            &made[..]
        }
    };
    Ok(crate::eval::noise::estimate(
        &setup.geometry,
        &setup.mapper,
        all,
        map,
    ))
}

/// The noise of `scans` (an experiment's selection) whose log-odds map is `map`: σ from `sensor`
/// (all the sensor's scans, [`sensor_noise`]) if given, else from `scans`; the shares of hits
/// that support no surface from `scans`.
pub fn experiment_noise(
    setup: &LogSetup,
    scans: &[ScanRecord],
    map: &[LogOdds],
    sensor: Option<&NoiseEstimate>,
) -> Option<NoiseEstimate> {
    let (g, mapper) = (&setup.geometry, &setup.mapper);
    match sensor {
        Some(n) => crate::eval::noise::estimate_with_sensor(g, mapper, scans, map, n),
        None => crate::eval::noise::estimate(g, mapper, scans, map),
    }
}

/// Maps `scans` (an experiment's selection) on `setup`'s grid traditionally and by each of
/// `methods`, with σ and the sensor estimated unless `cfg` fixes σ: σ from `sensor` (the
/// sensor's noise over all its scans, [`sensor_noise`]) if given, else from `scans`; the shares
/// of hits that support no surface always from `scans`. `label` prefixes the progress lines.
pub fn map_experiment(
    setup: &LogSetup,
    scans: &[ScanRecord],
    sensor: Option<&NoiseEstimate>,
    methods: &[LogMethod],
    cfg: &MethodsConfig,
    label: &str,
) -> anyhow::Result<ExperimentMaps> {
    let g = setup.geometry;
    let (w, h) = (usize::from(g.width()), usize::from(g.height()));
    let t = map_scans(g, setup.mapper, scans)?;
    let near = mask_within(&t.observed, w, h, NEAR_MAPPED_CELLS);
    let mut maps: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut seconds = BTreeMap::new();
    let mut per_sample = BTreeMap::new();
    maps.insert("traditional".into(), probabilities(&t.map));
    seconds.insert("traditional".to_string(), t.seconds);
    let mut iterations = BTreeMap::new();
    let mut graph = None;
    let noise = experiment_noise(setup, scans, &t.map, sensor);
    // The forward models read the MAD's σ; the robot's settings the mixture's σ and τ.
    let cfg = match (cfg.estimate_sigma, noise) {
        (true, Some(n)) => cfg
            .with_sigma(n.sigma_cells.max(MIN_SIGMA_CELLS))
            .with_sensor(n.sensor()),
        _ => cfg.clone(),
    };
    if let Some(n) = noise {
        eprintln!(
            "{label}: estimated range noise σ = {:.2} cells, {:.1} % outliers ({} hits); mixture σ {:.2}, ε {:.1} %, unmatched {:.1} %{}{}",
            n.sigma_cells,
            100.0 * n.outlier_rate,
            n.hits,
            n.sigma_mixture,
            100.0 * n.outlier_mixture,
            100.0 * n.unmatched,
            match n.sensor_hits {
                0 => String::new(),
                k => format!(" (σ from all the log's scans, {k} hits)"),
            },
            if cfg.estimate_sigma { "" } else { " (not used: --sigma-cells)" }
        );
    }
    for &m in methods {
        eprintln!("{label}: {}", m.name());
        let o = run_log_method(m, setup, scans, &t.map, &cfg, &mut graph)?;
        seconds.insert(m.name().to_string(), o.seconds);
        per_sample.insert(m.name().to_string(), o.seconds_per_sample);
        iterations.insert(m.name().to_string(), o.iterations);
        maps.insert(m.name().into(), o.probs);
    }
    Ok(ExperimentMaps {
        mapped: t,
        near,
        maps,
        seconds,
        per_sample,
        iterations,
        noise,
        cfg,
    })
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
