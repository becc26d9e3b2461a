//! The two steps of `eval-log` that every variant of it shares (the paper's protocol, the
//! odometry runs of [`crate::eval::eval_odometry`]): the benchmark of a log, and the maps of
//! one experiment's scans by traditional OGM and by the methods.

use std::collections::BTreeMap;

use ogm_field::world::World;

use crate::eval::eval_log::{
    benchmark_truth, map_scans, run_log_method, LogMethod, LogSetup, Mapped, MethodsConfig,
    BENCHMARK_THRESHOLD, NEAR_MAPPED_CELLS,
};
use crate::eval::metrics::{mask_within, PrAccumulator, Summary};
use crate::eval::noise::{NoiseEstimate, MIN_SIGMA_CELLS};
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

/// Maps `scans` (an experiment's selection) on `setup`'s grid traditionally and by each of
/// `methods`, with σ and the sensor estimated from the scans unless `cfg` fixes σ. `label`
/// prefixes the progress lines.
pub fn map_experiment(
    setup: &LogSetup,
    scans: &[ScanRecord],
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
    // The sensor's noise, from this experiment's own data.
    let noise = crate::eval::noise::estimate(&g, &setup.mapper, scans, &t.map);
    // The forward models read the MAD's σ; the robot's settings the mixture's σ and τ.
    let cfg = match (cfg.estimate_sigma, noise) {
        (true, Some(n)) => cfg
            .with_sigma(n.sigma_cells.max(MIN_SIGMA_CELLS))
            .with_sensor(n.sensor()),
        _ => cfg.clone(),
    };
    if let Some(n) = noise {
        eprintln!(
            "{label}: estimated range noise σ = {:.2} cells, {:.1} % outliers ({} hits); mixture σ {:.2}, ε {:.1} %, unmatched {:.1} %{}",
            n.sigma_cells,
            100.0 * n.outlier_rate,
            n.hits,
            n.sigma_mixture,
            100.0 * n.outlier_mixture,
            100.0 * n.unmatched,
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
