//! Subgradient dual decomposition (dhiman-modern-map-inference-ogm §V-B, Alg. 2, with the
//! pattern-based slave minimisation of §VI-D).
//!
//! Every ray is a slave `min θ_f(x^f) + Σ_{i∈n(f)} μ_if(x_i^f)` (Eq. 23); with a cell prior every
//! observed cell also gets a unary slave `θ_i(x) + μ_i(x)`. Only `δ = μ(1) − μ(0)` matters for a
//! binary label, so one number per edge is kept.
//!
//! **Slave minimisation in O(|n(f)|).** For the pattern "first occupied cell at m" the fixed
//! cells cost `θ_m + δ_m` and every free cell after m takes its cheaper label, `min(0, δ_l)`; the
//! "all free" pattern costs `θ_clear`. A suffix sum of `min(0, δ_l)` gives every pattern's cost.
//!
//! **Update.** Alg. 2 raises every disagreeing slave's multiplier on the label it chose by `α/r`.
//! We apply that step projected onto the dual feasible set `Σ_f μ_if(x) = 0` (the standard
//! subgradient step of Sontag et al., Dhiman's ref. 19): `δ_if += 2·(α/r)·(x_i^f − x̄_i)`,
//! `x̄_i` the slaves' mean label for cell i. The projection keeps `Σ_f min(slave_f)` a lower
//! bound on the optimal energy, reported as [`DdResult::lower_bound`]. (The literal step adds
//! `(α/r)·(2x̄_i − 1)` to all of a cell's `δ` on top, pushing every slave towards the minority
//! label, and voids the bound.)
//!
//! **Labels** (Eq. 24, which reads the multipliers of disagreeing cells): every slave also
//! returns its min-marginal differences `min E_f(x_i = 1) − min E_f(x_i = 0)` (prefix and suffix
//! minima, O(|n(f)|)), and a cell takes the label their sum (plus the unary slave's) prefers — a
//! vote weighted by how much each slave cares, so a ray for which the cell is a free node does
//! not vote (ties go to free). Where all slaves agree this is their label. Each iteration's
//! labelling is scored and the lowest energy seen is returned. Stops when every cell's slaves
//! agree (the labelling is then optimal), or at the iteration or time budget.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::factor_graph::FactorGraph;

/// Dual decomposition settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DdConfig {
    /// Step size α (step α/r at iteration r; paper: 50 with its piecewise-constant model).
    pub step_size: f64,
    /// Most iterations.
    pub max_iterations: u32,
    /// Stop after this many seconds.
    pub max_seconds: f64,
}

impl Default for DdConfig {
    fn default() -> Self {
        DdConfig {
            step_size: 5.0,
            max_iterations: 500,
            max_seconds: 120.0,
        }
    }
}

/// What a DD run produced.
#[derive(Clone, Debug)]
pub struct DdResult {
    /// The lowest-energy labelling found.
    pub labels: Vec<u8>,
    /// Its cells' summed min-marginal differences `min E(x_i = 0) − min E(x_i = 1)` over all
    /// slaves (the reparametrised unaries; the prior log-odds where no factor is): positive
    /// exactly where the label is occupied.
    pub log_odds: Vec<f64>,
    /// Its energy.
    pub energy: f64,
    /// The best dual value: a lower bound on the minimum energy.
    pub lower_bound: f64,
    /// Iterations done.
    pub iterations: u32,
    /// Whether all slaves agreed (then `energy` is the minimum).
    pub converged: bool,
    /// Cells whose slaves disagreed in the last iteration.
    pub disagreeing: usize,
    /// (seconds, energy of that iteration's labelling) at the start and after each iteration.
    pub trace: Vec<(f64, f64)>,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Scratch of a slave minimisation.
#[derive(Default)]
struct Scratch {
    /// Suffix sums of min(0, δ).
    suffix: Vec<f64>,
    /// Cost of each pattern "first occupied at j".
    cost: Vec<f64>,
    /// Suffix minima of `cost` (then "all free").
    after: Vec<f64>,
}

/// Minimises factor `f`'s slave under `delta`: writes its labels into `x` (a free cell the slave
/// is indifferent about, δ = 0, takes its label in `hint`), adds its min-marginal differences
/// `min E(x_k = 1) − min E(x_k = 0)` to `vote` (per cell), returns its cost.
fn solve_slave(
    graph: &FactorGraph,
    f: usize,
    delta: &[f64],
    hint: &[u8],
    x: &mut [u8],
    vote: &mut [f64],
    s: &mut Scratch,
) -> f64 {
    let r = graph.factor_edges(f);
    let n = r.len();
    let d = &delta[r.clone()];
    let psi = &graph.edge_log_psis()[r.clone()];
    let cells = &graph.edge_cells()[r.clone()];
    s.suffix.clear();
    s.suffix.resize(n + 1, 0.0);
    for k in (0..n).rev() {
        s.suffix[k] = s.suffix[k + 1] + d[k].min(0.0);
    }
    s.cost.clear();
    s.cost
        .extend((0..n).map(|k| -psi[k] + d[k] + s.suffix[k + 1]));
    let clear = -graph.log_psi_clear(f);
    s.after.clear();
    s.after.resize(n + 1, clear);
    for k in (0..n).rev() {
        s.after[k] = s.after[k + 1].min(s.cost[k]);
    }
    let best = s.after[0];
    let at = s.cost.iter().position(|&c| c == best).unwrap_or(n);
    let xs = &mut x[r];
    let mut before = f64::INFINITY; // min over patterns j < k
    for k in 0..n {
        xs[k] = match k.cmp(&at) {
            std::cmp::Ordering::Less => 0,
            std::cmp::Ordering::Equal => 1,
            std::cmp::Ordering::Greater if d[k] == 0.0 => hint[cells[k] as usize],
            std::cmp::Ordering::Greater => u8::from(d[k] < 0.0),
        };
        // Before k the cell is free to choose: forcing it costs its label's δ minus min(0, δ).
        let free = d[k].min(0.0);
        let m1 = (before + d[k] - free).min(s.cost[k]);
        let m0 = (before - free).min(s.after[k + 1]);
        vote[cells[k] as usize] += m1 - m0;
        before = before.min(s.cost[k]);
    }
    best
}

/// Runs subgradient DD on `graph`.
pub fn run(graph: &FactorGraph, cfg: &DdConfig) -> DdResult {
    let t0 = Instant::now();
    let n = graph.n_cells();
    let prior = graph.prior();
    let (u1, u0) = (graph.unary(true), graph.unary(false));
    let mut delta = vec![0.0f64; graph.n_edges()];
    let mut delta_u = vec![0.0f64; n];
    let mut x = vec![0u8; graph.n_edges()];
    let mut vote = vec![0.0f64; n];
    let mut scratch = Scratch::default();
    // Cells without factors take their prior label; their unary minimum is a constant.
    let lone_label = u8::from(prior.is_some_and(|p| p.p_occupied > 0.5));
    let mut labels = vec![lone_label; n];
    let lone_cost: f64 = (0..n)
        .filter(|&i| graph.degree(i) == 0)
        .map(|_| u1.min(u0))
        .sum();
    let mut best_labels = labels.clone();
    // Cells without factors keep their prior log-odds.
    let mut scores = vec![u0 - u1; n];
    let mut best_scores = scores.clone();
    let mut hint = labels.clone();
    let mut best_energy = f64::INFINITY;
    let mut lower_bound = f64::NEG_INFINITY;
    let mut trace = Vec::new();
    let (mut iterations, mut converged, mut disagreeing) = (0u32, false, usize::MAX);
    while iterations < cfg.max_iterations {
        let r = iterations + 1;
        let mut dual = lone_cost;
        vote.fill(0.0);
        for f in 0..graph.n_factors() {
            dual += solve_slave(graph, f, &delta, &hint, &mut x, &mut vote, &mut scratch);
        }
        let alpha = cfg.step_size / f64::from(r);
        disagreeing = 0;
        for i in 0..n {
            let edges = graph.cell_edges(i);
            if edges.is_empty() {
                continue;
            }
            let mut ones = edges.iter().filter(|&&e| x[e as usize] != 0).count();
            let mut slaves = edges.len();
            let mut unary_label = 0u8;
            if prior.is_some() {
                let c1 = u1 + delta_u[i];
                unary_label = u8::from(c1 < u0);
                dual += c1.min(u0);
                ones += usize::from(unary_label);
                slaves += 1;
            }
            let v = vote[i]
                + if prior.is_some() {
                    u1 + delta_u[i] - u0
                } else {
                    0.0
                };
            scores[i] = -v;
            labels[i] = u8::from(v < 0.0);
            if ones == 0 || ones == slaves {
                continue;
            }
            disagreeing += 1;
            let mean = ones as f64 / slaves as f64;
            for &e in edges {
                let e = e as usize;
                delta[e] += 2.0 * alpha * (f64::from(x[e]) - mean);
            }
            if prior.is_some() {
                delta_u[i] += 2.0 * alpha * (f64::from(unary_label) - mean);
            }
        }
        iterations = r;
        hint.copy_from_slice(&labels);
        lower_bound = lower_bound.max(dual);
        let e = graph.energy(&labels).total();
        if e < best_energy {
            best_energy = e;
            best_labels.copy_from_slice(&labels);
            best_scores.copy_from_slice(&scores);
        }
        trace.push((t0.elapsed().as_secs_f64(), e));
        if disagreeing == 0 {
            converged = true;
            break;
        }
        if t0.elapsed().as_secs_f64() > cfg.max_seconds {
            break;
        }
    }
    if best_energy == f64::INFINITY {
        best_energy = graph.energy(&best_labels).total();
    }
    DdResult {
        labels: best_labels,
        log_odds: best_scores,
        energy: best_energy,
        lower_bound,
        iterations,
        converged,
        disagreeing,
        trace,
        seconds: t0.elapsed().as_secs_f64(),
    }
}
