//! The exact posterior (merali-barfoot-mcmc-gibbs-ogm §II): by enumerating every map of a tiny
//! problem ([`enumerate`]), or — for 1-D problems whose rays all run along one line from one
//! cell — by enumerating the hidden first occupied cell ([`enumerate_first_occupied`], exact for
//! any length; the "full solution" of Merali & Barfoot's ref. 12).

use anyhow::{bail, ensure};

use super::factor_graph::FactorGraph;
use crate::eval::metrics::{kl_bernoulli, KL_Q_CLAMP};

/// Most cells (with at least one factor) [`enumerate`] accepts: 2^22 maps.
pub const MAX_ENUMERATED_CELLS: usize = 22;

/// The exact posterior of a small problem.
#[derive(Clone, Debug, PartialEq)]
pub struct ExactPosterior {
    /// p(m_k = 1 | z) per cell.
    pub marginals: Vec<f64>,
    /// A MAP labelling (ties between maps: the first in enumeration order; cells without
    /// factors take the prior's more probable label, free on a tie).
    pub map: Vec<u8>,
    /// Energy of [`ExactPosterior::map`].
    pub map_energy: f64,
    /// ln of the normaliser Σ_x exp(−E(x)).
    pub log_z: f64,
}

/// Marginal of a cell no factor touches: the prior (0.5 without one).
fn untouched_marginal(graph: &FactorGraph) -> f64 {
    graph.prior().map_or(0.5, |p| p.p_occupied)
}

/// Exact marginals and MAP by enumerating all 2^T labellings of the T cells that some factor
/// touches (T ≤ [`MAX_ENUMERATED_CELLS`]); the other cells are independent of the data.
pub fn enumerate(graph: &FactorGraph) -> anyhow::Result<ExactPosterior> {
    let n = graph.n_cells();
    let touched: Vec<usize> = (0..n).filter(|&i| graph.degree(i) > 0).collect();
    let t = touched.len();
    ensure!(
        t <= MAX_ENUMERATED_CELLS,
        "{t} cells have factors; enumeration handles at most {MAX_ENUMERATED_CELLS}"
    );
    let mut local = vec![usize::MAX; n];
    for (k, &i) in touched.iter().enumerate() {
        local[i] = k;
    }
    // Each factor as (local bit per position, ln ψ per position, ln ψ_clear).
    let factors: Vec<(Vec<u32>, Vec<f64>, f64)> = (0..graph.n_factors())
        .map(|f| {
            let r = graph.factor_edges(f);
            (
                r.clone()
                    .map(|e| local[graph.edge_cell(e)] as u32)
                    .collect(),
                r.map(|e| graph.edge_log_psi(e)).collect(),
                graph.log_psi_clear(f),
            )
        })
        .collect();
    let (u1, u0) = (graph.unary(true), graph.unary(false));
    let energy = |m: u64| -> f64 {
        let mut e = 0.0;
        for (bits, psi, clear) in &factors {
            e -= bits
                .iter()
                .position(|&b| m >> b & 1 != 0)
                .map_or(*clear, |p| psi[p]);
        }
        let occ = f64::from(m.count_ones());
        e + occ * u1 + (t as f64 - occ) * u0
    };
    // Streaming log-sum-exp: everything is scaled by exp(lowest energy so far).
    let (mut lowest, mut best_map) = (f64::INFINITY, 0u64);
    let mut z = 0.0f64;
    let mut acc = vec![0.0f64; t];
    for m in 0..1u64 << t {
        let e = energy(m);
        if e < lowest {
            let scale = if lowest.is_finite() {
                (-(lowest - e)).exp()
            } else {
                0.0
            };
            z *= scale;
            for a in &mut acc {
                *a *= scale;
            }
            lowest = e;
            best_map = m;
        }
        let w = (-(e - lowest)).exp();
        z += w;
        for (k, a) in acc.iter_mut().enumerate() {
            if m >> k & 1 != 0 {
                *a += w;
            }
        }
    }
    let p_other = untouched_marginal(graph);
    let mut marginals = vec![p_other; n];
    let mut map = vec![0u8; n];
    let other_label = graph.prior().is_some_and(|p| p.p_occupied > 0.5);
    let mut map_energy = lowest;
    for i in 0..n {
        if local[i] == usize::MAX {
            map[i] = u8::from(other_label);
            map_energy += graph.unary(other_label);
        }
    }
    for (k, &i) in touched.iter().enumerate() {
        marginals[i] = acc[k] / z;
        map[i] = (best_map >> k & 1) as u8;
    }
    // Untouched cells: Σ_x p(x) = 1 with a prior, 2 without.
    let other_z = if graph.prior().is_some() {
        0.0
    } else {
        (n - t) as f64 * std::f64::consts::LN_2
    };
    Ok(ExactPosterior {
        marginals,
        map,
        map_energy,
        log_z: z.ln() - lowest + other_z,
    })
}

/// Exact marginals of a 1-D problem in O(T · factors): every factor's cells must be a prefix of
/// the longest factor's cells (rays from one cell along one line, like Merali & Barfoot's
/// Fig. 2). The likelihood depends only on the first occupied cell `f` along the line, so
/// `p(f = j) ∝ Π_{l<j} p(m_l = 0) · p(m_j = 1) · Π_n ψ_n(j)`, cells before `f` are free and cells
/// after it keep the prior: `p(m_k = 1) = p(f = k) + p(f < k) · p`.
pub fn enumerate_first_occupied(graph: &FactorGraph) -> anyhow::Result<Vec<f64>> {
    let nf = graph.n_factors();
    let Some(longest) = (0..nf).max_by_key(|&f| graph.factor_edges(f).len()) else {
        return Ok(vec![untouched_marginal(graph); graph.n_cells()]);
    };
    let line: Vec<usize> = graph
        .factor_edges(longest)
        .map(|e| graph.edge_cell(e))
        .collect();
    for f in 0..nf {
        for (k, e) in graph.factor_edges(f).enumerate() {
            if graph.edge_cell(e) != line[k] {
                bail!("factor {f} is not a prefix of the longest ray: not a 1-D problem");
            }
        }
    }
    let p = untouched_marginal(graph);
    let (l1, l0) = (p.ln(), (1.0 - p).ln());
    let len = line.len();
    // log p(f = j) up to a constant, j = len meaning "no occupied cell on the line".
    let logw: Vec<f64> = (0..=len)
        .map(|j| {
            let prior = j as f64 * l0 + if j < len { l1 } else { 0.0 };
            prior
                + (0..nf)
                    .map(|f| graph.log_psi_at(f, j.min(graph.factor_edges(f).len())))
                    .sum::<f64>()
        })
        .collect();
    let top = logw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = logw.iter().map(|l| (l - top).exp()).collect();
    let z: f64 = w.iter().sum();
    let mut marginals = vec![p; graph.n_cells()];
    let mut before = 0.0;
    for (k, &c) in line.iter().enumerate() {
        let pk = w[k] / z;
        marginals[c] = pk + before * p;
        before += pk;
    }
    Ok(marginals)
}

/// Per-cell KL divergence `KL(p_k ‖ q_k)` of Bernoulli marginals (nats; `p` the exact
/// benchmark, `q` clamped like [`crate::eval::metrics::kl_sum`]).
pub fn kl_per_cell(p: &[f64], q: &[f64]) -> Vec<f64> {
    p.iter()
        .zip(q)
        .map(|(&p, &q)| kl_bernoulli(p, q.clamp(KL_Q_CLAMP, 1.0 - KL_Q_CLAMP)))
        .collect()
}
