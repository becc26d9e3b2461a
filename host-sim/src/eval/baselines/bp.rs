//! Loopy belief propagation, sum-product and max-product (dhiman-modern-map-inference-ogm §V-A,
//! Eq. 17–21), with the pattern-based factor messages of §VI-C.
//!
//! Messages are binary, kept as log-ratios `λ = ln μ(1) − ln μ(0)`; a cell's belief is its prior
//! log-odds plus the incoming factor messages, and the message into a factor is the belief minus
//! that factor's own message (Eq. 18).
//!
//! **Factor → cell messages in O(|n(f)|).** For a ray with cells `1..M` in order, first-occupied
//! potentials `ψ_m` and `ψ_clear`, and incoming messages normalised so that a cell whose value does
//! not matter contributes 1 (sum-normalised for sum-product, max-normalised for max-product —
//! the *free* nodes of §VI-B), the message to cell `k` is (⊕ = sum or max, in the log domain):
//!
//! ```text
//! A_k = ⊕_{j<k} ψ_j μ_j(1) Π_{l<j} μ_l(0)          first occupied before k: k is free to vary
//! P_k = Π_{l<k} μ_l(0)                             nothing occupied before k
//! T_k = ψ_k μ_k(1) ⊕ μ_k(0) T_{k+1},  T_{M+1} = ψ_clear
//! μ_{f→k}(1) = A_k ⊕ P_k ψ_k,     μ_{f→k}(0) = A_k ⊕ P_k T_{k+1}
//! ```
//!
//! — prefix and suffix scans, so one factor costs O(|n(f)|) for all its messages (Eq. 33 costs
//! O(M·|n(f)|) per message; this is the same quantity with the sums shared).
//!
//! **Schedule**: factors are visited in a random order (reshuffled every iteration; Dhiman et al.
//! pick random edges) and their new messages update the beliefs at once. Optional damping mixes
//! the old message in. Stops when no message moved more than `tolerance`, or at the iteration or
//! time budget.

use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use super::factor_graph::FactorGraph;

/// Sum-product (marginals) or max-product (MAP).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BpKind {
    /// Sum-product: beliefs approximate the marginals (Eq. 17–19).
    Sum,
    /// Max-product: beliefs' signs give the MAP labels (Eq. 20–21).
    Max,
}

/// Belief propagation settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BpConfig {
    /// Most iterations (each updates every factor once).
    pub max_iterations: u32,
    /// Converged when no message changes by more than this (nats).
    pub tolerance: f64,
    /// New message = (1 − damping) · computed + damping · old.
    pub damping: f64,
    /// Stop after this many seconds.
    pub max_seconds: f64,
}

impl Default for BpConfig {
    fn default() -> Self {
        BpConfig {
            max_iterations: 50,
            tolerance: 1e-3,
            damping: 0.5,
            max_seconds: 120.0,
        }
    }
}

/// What a BP run produced.
#[derive(Clone, Debug)]
pub struct BpResult {
    /// Belief log-odds per cell (prior + Σ incoming messages).
    pub beliefs: Vec<f64>,
    /// Iterations done.
    pub iterations: u32,
    /// Whether the messages converged.
    pub converged: bool,
    /// Largest message change in the last iteration.
    pub last_change: f64,
    /// (seconds of BP, energy of the labels `belief > 0`) at the start and after each iteration.
    pub trace: Vec<(f64, f64)>,
    /// Wall-clock seconds of BP (energy evaluations for the trace excluded).
    pub seconds: f64,
}

/// ln(e^a + e^b).
#[inline]
fn lse(a: f64, b: f64) -> f64 {
    let (hi, lo) = if a > b { (a, b) } else { (b, a) };
    if lo == f64::NEG_INFINITY {
        hi
    } else {
        hi + (lo - hi).exp().ln_1p()
    }
}

/// ln(1 + e^x).
#[inline]
fn softplus(x: f64) -> f64 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// Labels of beliefs: occupied iff the belief log-odds is positive.
pub fn labels_of(beliefs: &[f64]) -> Vec<u8> {
    beliefs.iter().map(|&b| u8::from(b > 0.0)).collect()
}

/// Scratch for one factor update.
#[derive(Default)]
struct Scratch {
    lq: Vec<f64>,
    lf: Vec<f64>,
    tail: Vec<f64>,
}

/// Computes factor `f`'s outgoing messages from the current beliefs and messages, writes them
/// (damped) and updates the beliefs; returns the largest change.
fn update_factor(
    graph: &FactorGraph,
    kind: BpKind,
    damping: f64,
    f: usize,
    msg: &mut [f64],
    belief: &mut [f64],
    s: &mut Scratch,
) -> f64 {
    let r = graph.factor_edges(f);
    let n = r.len();
    let cells = &graph.edge_cells()[r.clone()];
    let psi = &graph.edge_log_psis()[r.clone()];
    s.lq.clear();
    s.lf.clear();
    for (k, &c) in cells.iter().enumerate() {
        let lam = belief[c as usize] - msg[r.start + k];
        let (lq, lf) = match kind {
            BpKind::Sum => (-softplus(-lam), -softplus(lam)),
            BpKind::Max => (lam.min(0.0), (-lam).min(0.0)),
        };
        s.lq.push(lq);
        s.lf.push(lf);
    }
    let op = |a: f64, b: f64| match kind {
        BpKind::Sum => lse(a, b),
        BpKind::Max => a.max(b),
    };
    // T_k for k = 0..=n (T_n = ψ_clear).
    s.tail.clear();
    s.tail.resize(n + 1, 0.0);
    s.tail[n] = graph.log_psi_clear(f);
    for k in (0..n).rev() {
        s.tail[k] = op(psi[k] + s.lq[k], s.lf[k] + s.tail[k + 1]);
    }
    let (mut a, mut p) = (f64::NEG_INFINITY, 0.0f64);
    let mut change = 0.0f64;
    for k in 0..n {
        let m1 = op(a, p + psi[k]);
        let m0 = op(a, p + s.tail[k + 1]);
        let out = m1 - m0;
        let e = r.start + k;
        let old = msg[e];
        let new = if damping > 0.0 {
            (1.0 - damping) * out + damping * old
        } else {
            out
        };
        if new.is_finite() {
            change = change.max((new - old).abs());
            belief[cells[k] as usize] += new - old;
            msg[e] = new;
        }
        a = op(a, p + s.lq[k] + psi[k]);
        p += s.lf[k];
    }
    change
}

/// Runs BP on `graph`.
pub fn run(graph: &FactorGraph, kind: BpKind, cfg: &BpConfig, seed: u64) -> BpResult {
    let t0 = Instant::now();
    let mut paused = 0.0f64;
    let l0 = graph.prior().map_or(0.0, |p| p.log_odds());
    let mut belief = vec![l0; graph.n_cells()];
    let mut msg = vec![0.0f64; graph.n_edges()];
    let mut order: Vec<usize> = (0..graph.n_factors()).collect();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut s = Scratch::default();
    let mut trace = vec![(0.0, graph.energy(&labels_of(&belief)).total())];
    paused += t0.elapsed().as_secs_f64();
    let (mut iterations, mut converged, mut last_change) = (0u32, false, f64::INFINITY);
    while iterations < cfg.max_iterations {
        order.shuffle(&mut rng);
        let mut change = 0.0f64;
        for &f in &order {
            change = change.max(update_factor(
                graph,
                kind,
                cfg.damping,
                f,
                &mut msg,
                &mut belief,
                &mut s,
            ));
        }
        iterations += 1;
        last_change = change;
        let t_alg = t0.elapsed().as_secs_f64() - paused;
        let tp = Instant::now();
        trace.push((t_alg, graph.energy(&labels_of(&belief)).total()));
        paused += tp.elapsed().as_secs_f64();
        if change <= cfg.tolerance {
            converged = true;
            break;
        }
        if t_alg > cfg.max_seconds {
            break;
        }
    }
    BpResult {
        beliefs: belief,
        iterations,
        converged,
        last_change,
        trace,
        seconds: t0.elapsed().as_secs_f64() - paused,
    }
}
