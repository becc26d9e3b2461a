//! The source papers' other inference methods as host-side (std, f64) baselines, on the same
//! posterior as the samplers:
//!
//! * [`exact`] — the exact posterior by enumeration (merali-barfoot-mcmc-gibbs-ogm §II) and the
//!   per-cell / summed KL divergence; [`fig2`] reproduces that paper's Fig. 2;
//! * [`mh`] — Metropolis–Hastings with single-cell flips, with and without the heat map
//!   (dhiman-modern-map-inference-ogm §IV): `mh`, `mh_heatmap`;
//! * [`bp`] — loopy belief propagation, sum-product and max-product, with O(|n(f)|) pattern-based
//!   factor messages (§V-A, §VI): `bp_sum`, `bp_max`;
//! * [`dd`] — subgradient dual decomposition (§V-B, Alg. 2): `dd`.
//!
//! All of them run on a [`FactorGraph`] built from `ogm_core`'s ray store (Bresenham rays from
//! the pose's cell to the far end at maximum range) with `ogm_core::reference::ReferenceModel` —
//! the forward model of the f64 reference Gibbs sampler (Gaussian σ = 3 cells with 1 % outliers by
//! default, or Dhiman's piecewise-constant model) — and a constant cell prior
//! (`ogm_core::sampler::prior::occupancy_prior()`, p ≈ 0.23, the L = 1 sampler's; or none, as in Dhiman).
//!
//! **Energy** (reported for every method in `eval-sim`): `E(x) = −Σ_rays ln p(z | x) −
//! Σ_cells ln p(x_i)` of the method's map: the MAP labels for `bp_max` and `dd`, and the marginals
//! thresholded at 0.5 (occupied iff p > 0.5) for everything else. The clocks ([`BaselineOutput::
//! seconds`]) measure inference only, not building the graph.

pub mod bp;
pub mod dd;
pub mod exact;
pub mod factor_graph;
pub mod fig2;
pub mod mh;
pub mod plot;

use std::collections::BTreeMap;

use anyhow::bail;
use ogm_core::reference::ReferenceModel;
use ogm_core::{GridGeometry, LogOdds, MapperConfig};
use serde::{Deserialize, Serialize};

pub use factor_graph::{Energy, FactorGraph, UnaryPrior};

use crate::sim::explore::ScanRecord;

/// A baseline method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Metropolis–Hastings, uniform single-cell flips.
    Mh,
    /// Metropolis–Hastings with the heat map.
    MhHeatmap,
    /// Sum-product belief propagation (marginals).
    BpSum,
    /// Max-product belief propagation (MAP).
    BpMax,
    /// Subgradient dual decomposition (MAP).
    Dd,
}

impl Method {
    /// All methods, in report order.
    pub const ALL: [Method; 5] = [
        Method::Mh,
        Method::MhHeatmap,
        Method::BpSum,
        Method::BpMax,
        Method::Dd,
    ];

    /// The name in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Mh => "mh",
            Method::MhHeatmap => "mh_heatmap",
            Method::BpSum => "bp_sum",
            Method::BpMax => "bp_max",
            Method::Dd => "dd",
        }
    }

    /// The method called `name`, if any.
    pub fn from_name(name: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the method outputs labels (0/1) rather than marginals.
    pub fn is_map(self) -> bool {
        matches!(self, Method::BpMax | Method::Dd)
    }
}

/// The forward sensor model of the factors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum SensorModel {
    /// Gaussian N(f, σ²) mixed with a uniform outlier weight over the maximum range (the
    /// samplers' model).
    Gaussian {
        /// σ in cells.
        sigma_cells: f64,
        /// Outlier weight w.
        outlier_weight: f64,
    },
    /// Dhiman's piecewise-constant model (Eq. 26).
    Pcsm,
}

impl SensorModel {
    /// The `ogm_core` f64 model for a sensor of maximum range `max_range_cells`.
    pub fn reference(self, max_range_cells: f64) -> ReferenceModel {
        match self {
            SensorModel::Gaussian {
                sigma_cells,
                outlier_weight,
            } => ReferenceModel::Gaussian {
                sigma: sigma_cells,
                w: outlier_weight,
                max_range: max_range_cells,
            },
            SensorModel::Pcsm => ReferenceModel::Pcsm,
        }
    }
}

/// Settings shared by the baselines.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BaselineConfig {
    /// Forward model.
    pub model: SensorModel,
    /// Constant cell prior p(m = 1); `None` = no prior (Dhiman et al.).
    pub prior_p_occupied: Option<f64>,
    /// Metropolis–Hastings starts from the online map thresholded like the samplers: occupied
    /// iff the log-odds (raw LSB) exceeds this.
    pub init_threshold: i16,
    /// Metropolis–Hastings.
    pub mh: mh::MhConfig,
    /// Belief propagation.
    pub bp: bp::BpConfig,
    /// Dual decomposition.
    pub dd: dd::DdConfig,
}

impl Default for BaselineConfig {
    fn default() -> Self {
        BaselineConfig {
            model: SensorModel::Gaussian {
                sigma_cells: 3.0,
                outlier_weight: 0.01,
            },
            prior_p_occupied: Some(ogm_core::sampler::prior::occupancy_prior().p_occupied()),
            init_threshold: -1,
            mh: mh::MhConfig::default(),
            bp: bp::BpConfig::default(),
            dd: dd::DdConfig::default(),
        }
    }
}

impl BaselineConfig {
    /// The cell prior as unary factors.
    pub fn prior(&self) -> Option<UnaryPrior> {
        self.prior_p_occupied
            .map(|p_occupied| UnaryPrior { p_occupied })
    }
}

/// What a baseline produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BaselineOutput {
    /// Per cell: the marginal p(occupied) (`mh`, `mh_heatmap`, `bp_sum`); for the MAP methods
    /// a max-marginal score σ(l) (`bp_max`: the belief log-odds; `dd`: the summed min-marginal
    /// differences of its slaves), which is > 0.5 exactly on the MAP labels and stays at the
    /// prior where the data say nothing — so precision–recall curves rank cells by confidence
    /// instead of collapsing to one point.
    pub probs: Vec<f64>,
    /// The method's map: the MAP labels (`bp_max`, `dd`) or the marginals thresholded at 0.5
    /// (occupied iff p > 0.5).
    pub labels: Vec<u8>,
    /// Energy of the method's map (see the module documentation).
    pub energy: f64,
    /// Its data term alone (negative log-likelihood).
    pub nll: f64,
    /// Wall-clock seconds of inference.
    pub seconds: f64,
    /// (seconds, energy) during the run: the current sample (MH), the labels `belief > 0` (BP),
    /// each iteration's labels (DD).
    pub trace: Vec<(f64, f64)>,
    /// Sweeps (MH) or iterations (BP, DD) done.
    pub iterations: u64,
    /// BP: messages converged; DD: all slaves agree; MH: false.
    pub converged: bool,
    /// DD's dual bound on the minimum energy.
    pub lower_bound: Option<f64>,
}

/// Maximum range of the mapper in cells (the forward model's F, as in `sampling.rs`).
pub fn max_range_cells(geometry: &GridGeometry, mapper: &MapperConfig) -> f64 {
    f64::from(mapper.max_range_mm) / f64::from(geometry.cell_mm())
}

/// The factor graph of a dataset for `cfg` (model and prior).
pub fn build_graph(
    geometry: &GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    cfg: &BaselineConfig,
) -> anyhow::Result<FactorGraph> {
    FactorGraph::from_scans(
        *geometry,
        mapper,
        scans,
        cfg.model.reference(max_range_cells(geometry, mapper)),
        cfg.prior(),
    )
}

/// Runs the method called `name` (`mh`, `mh_heatmap`, `bp_sum`, `bp_max`, `dd`) on a dataset
/// whose online log-odds map is `map` (used to initialise Metropolis–Hastings).
pub fn run_method(
    name: &str,
    geometry: &GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    cfg: &BaselineConfig,
    seed: u64,
) -> anyhow::Result<BaselineOutput> {
    let Some(method) = Method::from_name(name) else {
        bail!(
            "unknown baseline `{name}` (expected one of {})",
            Method::ALL.map(Method::name).join(", ")
        );
    };
    let graph = build_graph(geometry, mapper, scans, cfg)?;
    run_on_graph(method, &graph, map, cfg, seed)
}

/// Runs `method` on a prebuilt graph (so `eval-sim` builds it once per dataset).
pub fn run_on_graph(
    method: Method,
    graph: &FactorGraph,
    map: &[LogOdds],
    cfg: &BaselineConfig,
    seed: u64,
) -> anyhow::Result<BaselineOutput> {
    anyhow::ensure!(
        map.len() == graph.n_cells(),
        "map has {} cells, the graph {}",
        map.len(),
        graph.n_cells()
    );
    let out = match method {
        Method::Mh | Method::MhHeatmap => {
            let init: Vec<u8> = map
                .iter()
                .map(|l| u8::from(l.0 > cfg.init_threshold))
                .collect();
            let r = mh::run(graph, &init, &cfg.mh, method == Method::MhHeatmap, seed);
            let labels = factor_graph::threshold_labels(&r.marginals);
            let e = graph.energy(&labels);
            BaselineOutput {
                labels,
                energy: e.total(),
                nll: e.nll,
                probs: r.marginals,
                seconds: r.seconds,
                trace: r.trace,
                iterations: r.proposals / graph.n_cells().max(1) as u64,
                converged: false,
                lower_bound: None,
            }
        }
        Method::BpSum | Method::BpMax => {
            let kind = if method == Method::BpSum {
                bp::BpKind::Sum
            } else {
                bp::BpKind::Max
            };
            let r = bp::run(graph, kind, &cfg.bp, seed);
            // Sum-product: marginals; max-product: max-marginals (σ of the belief log-odds,
            // > 0.5 exactly on the MAP labels).
            let probs: Vec<f64> = r.beliefs.iter().map(|&b| sigmoid(b)).collect();
            let labels = bp::labels_of(&r.beliefs);
            let e = graph.energy(&labels);
            BaselineOutput {
                probs,
                labels,
                energy: e.total(),
                nll: e.nll,
                seconds: r.seconds,
                trace: r.trace,
                iterations: u64::from(r.iterations),
                converged: r.converged,
                lower_bound: None,
            }
        }
        Method::Dd => {
            let r = dd::run(graph, &cfg.dd);
            let e = graph.energy(&r.labels);
            BaselineOutput {
                probs: r.log_odds.iter().map(|&l| sigmoid(l)).collect(),
                labels: r.labels,
                energy: e.total(),
                nll: e.nll,
                seconds: r.seconds,
                trace: r.trace,
                iterations: u64::from(r.iterations),
                converged: r.converged,
                lower_bound: Some(r.lower_bound),
            }
        }
    };
    Ok(out)
}

/// The logistic function.
fn sigmoid(l: f64) -> f64 {
    1.0 / (1.0 + (-l).exp())
}

/// Energies per map and method (mean over the map's datasets), for `report.json`'s
/// `settings.energy` and the terminal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EnergyTable {
    /// `map → method → (Σ energy, Σ nll, datasets)`.
    sums: BTreeMap<String, BTreeMap<String, (f64, f64, u32)>>,
    /// One entry per baseline run.
    runs: Vec<RunInfo>,
}

/// How one baseline run went (`report.json`: `settings.energy.runs`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Map name.
    pub map: String,
    /// Method name.
    pub method: String,
    /// Energy of its map.
    pub energy: f64,
    /// Seconds of inference.
    pub seconds: f64,
    /// Sweeps or iterations.
    pub iterations: u64,
    /// Converged (BP, DD).
    pub converged: bool,
    /// DD's dual bound.
    pub lower_bound: Option<f64>,
}

impl EnergyTable {
    /// Adds one dataset's energy of `method` on `map`.
    pub fn add(&mut self, map: &str, method: &str, e: Energy) {
        let s = self
            .sums
            .entry(map.to_string())
            .or_default()
            .entry(method.to_string())
            .or_insert((0.0, 0.0, 0));
        s.0 += e.total();
        s.1 += e.nll;
        s.2 += 1;
    }

    /// Records a baseline run on `map` (its energy enters the table through [`EnergyTable::add`]).
    pub fn add_run(&mut self, map: &str, method: &str, o: &BaselineOutput) {
        self.runs.push(RunInfo {
            map: map.to_string(),
            method: method.to_string(),
            energy: o.energy,
            seconds: o.seconds,
            iterations: o.iterations,
            converged: o.converged,
            lower_bound: o.lower_bound,
        });
    }

    /// Whether nothing was added.
    pub fn is_empty(&self) -> bool {
        self.sums.is_empty()
    }

    /// `{"definition": …, "maps": {map: {method: {"energy", "nll", "delta_to_best"}}},
    /// "runs": [RunInfo]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let maps: serde_json::Map<String, serde_json::Value> = self
            .sums
            .iter()
            .map(|(map, methods)| {
                let best = methods
                    .values()
                    .map(|s| s.0 / f64::from(s.2))
                    .fold(f64::INFINITY, f64::min);
                let m: serde_json::Map<String, serde_json::Value> = methods
                    .iter()
                    .map(|(k, s)| {
                        let e = s.0 / f64::from(s.2);
                        (
                            k.clone(),
                            serde_json::json!({
                                "energy": e, "nll": s.1 / f64::from(s.2), "delta_to_best": e - best,
                            }),
                        )
                    })
                    .collect();
                (map.clone(), serde_json::Value::Object(m))
            })
            .collect();
        serde_json::json!({
            "definition": "E(x) = -sum_rays ln p(z|x) - sum_cells ln p(x_i) (nats, mean over a \
                map's datasets) of each method's map: MAP labels for bp_max and dd, marginals \
                thresholded at 0.5 (occupied iff p > 0.5) otherwise; 'nll' is the data term; \
                forward model and cell prior as in settings.eval.baseline",
            "maps": maps,
            "runs": self.runs,
        })
    }

    /// A table of energy above the best method per map (nats), methods as columns; with DD runs,
    /// a last column with DD's mean dual bound (the optimum lies between it and 0).
    pub fn table(&self) -> String {
        let mut methods: Vec<&String> = self.sums.values().flat_map(|m| m.keys()).collect();
        methods.sort();
        methods.dedup();
        let bound = |map: &str| {
            let b: Vec<f64> = self
                .runs
                .iter()
                .filter(|r| r.map == map)
                .filter_map(|r| r.lower_bound)
                .collect();
            (!b.is_empty()).then(|| b.iter().sum::<f64>() / b.len() as f64)
        };
        let with_bound = self.runs.iter().any(|r| r.lower_bound.is_some());
        let mut s = format!("{:<18}", "E - best (nats)");
        for m in &methods {
            s.push_str(&format!(" {:>15}", m));
        }
        if with_bound {
            s.push_str(&format!(" {:>15}", "dd bound"));
        }
        s.push('\n');
        for (map, ms) in &self.sums {
            let best = ms
                .values()
                .map(|v| v.0 / f64::from(v.2))
                .fold(f64::INFINITY, f64::min);
            s.push_str(&format!("{:<18}", map));
            for m in &methods {
                match ms.get(*m) {
                    Some(v) => s.push_str(&format!(" {:>15.1}", v.0 / f64::from(v.2) - best)),
                    None => s.push_str(&format!(" {:>15}", "-")),
                }
            }
            if with_bound {
                match bound(map) {
                    Some(b) => s.push_str(&format!(" {:>15.1}", b - best)),
                    None => s.push_str(&format!(" {:>15}", "-")),
                }
            }
            s.push('\n');
        }
        s
    }
}
