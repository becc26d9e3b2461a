//! Metropolis–Hastings with single-cell flips (dhiman-modern-map-inference-ogm §IV, Alg. 1),
//! with or without the heat map (§IV-A).
//!
//! A proposal flips one cell `i`; the proposal is symmetric (the choice of `i` never depends on the
//! state), so the acceptance ratio is `exp(−ΔE)` with ΔE over `n(i)` only (Eq. 16) plus the cell's
//! prior. Every factor caches the position of its first occupied cell, so ΔE costs O(|n(i)|)
//! except when the first occupied cell of a ray is cleared (then the ray is scanned onwards).
//!
//! * **Uniform** proposals pick `i` uniformly among all cells (Eq. 15).
//! * **Heat map**: the beam-end cells of hits are `heat_bias` (paper: 4) times as likely to be
//!   picked as any other cell ("a sampling bias of 1 : 4").
//!
//! Marginals are time averages of the chain after burn-in (every proposal counts, accepted or
//! not), kept exactly with per-cell "occupied since" stamps.

use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use super::factor_graph::FactorGraph;

/// Metropolis–Hastings settings. A sweep is K proposals (K = cells).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MhConfig {
    /// Sweeps before marginals are accumulated.
    pub burn_in_sweeps: u32,
    /// Sweeps accumulated.
    pub sweeps: u32,
    /// Heat-map bias: a heat cell is this many times as likely to be proposed (paper: 4).
    pub heat_bias: f64,
    /// Stop after this many seconds (marginals are then averaged over what ran).
    pub max_seconds: f64,
}

impl Default for MhConfig {
    fn default() -> Self {
        MhConfig {
            burn_in_sweeps: 20,
            sweeps: 100,
            heat_bias: 4.0,
            max_seconds: 120.0,
        }
    }
}

/// What a Metropolis–Hastings run produced.
#[derive(Clone, Debug)]
pub struct MhResult {
    /// Time-averaged p(occupied) per cell after burn-in (the last sample if burn-in never ended).
    pub marginals: Vec<f64>,
    /// The last sample.
    pub sample: Vec<u8>,
    /// (seconds, energy of the current sample) at the start and after every sweep.
    pub trace: Vec<(f64, f64)>,
    /// Proposals made.
    pub proposals: u64,
    /// Proposals accepted.
    pub accepted: u64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Uniform integer in `0..n` (Lemire's multiply-shift; n ≥ 1).
#[inline]
fn below(r: u64, n: usize) -> usize {
    ((u128::from(r) * n as u128) >> 64) as usize
}

/// Runs the chain from `init` (0/1 per cell).
pub fn run(graph: &FactorGraph, init: &[u8], cfg: &MhConfig, heatmap: bool, seed: u64) -> MhResult {
    let n = graph.n_cells();
    assert_eq!(init.len(), n, "initial labels for every cell");
    let t0 = Instant::now();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut x: Vec<u8> = init.iter().map(|&v| u8::from(v != 0)).collect();
    let mut first: Vec<u32> = (0..graph.n_factors())
        .map(|f| graph.first_occupied(f, &x) as u32)
        .collect();
    let mut energy = graph.energy(&x).total();
    // Proposal distribution: heat cells with weight `heat_bias`, the rest with weight 1.
    let (heat, other): (Vec<u32>, Vec<u32>) = if heatmap {
        let mut is_heat = vec![false; n];
        for &c in graph.heat() {
            is_heat[c as usize] = true;
        }
        (
            graph.heat().to_vec(),
            (0..n as u32).filter(|&c| !is_heat[c as usize]).collect(),
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let heat_w = cfg.heat_bias.max(0.0) * heat.len() as f64;
    let p_heat = if heatmap && !heat.is_empty() {
        heat_w / (heat_w + other.len() as f64)
    } else {
        0.0
    };
    let u_delta = [
        graph.unary(true) - graph.unary(false),
        graph.unary(false) - graph.unary(true),
    ];

    let sweep = n.max(1) as u64;
    let burn = u64::from(cfg.burn_in_sweeps) * sweep;
    let total = burn + u64::from(cfg.sweeps) * sweep;
    let mut occ_time = vec![0u64; n];
    let mut since = vec![0u64; n];
    let mut trace = vec![(0.0, energy)];
    let mut scratch: Vec<(u32, u32)> = Vec::new();
    let (mut accepted, mut t) = (0u64, 0u64);
    while t < total {
        if t == burn {
            since.fill(burn);
        }
        let i = if p_heat > 0.0 && (other.is_empty() || rng.random::<f64>() < p_heat) {
            heat[below(rng.random(), heat.len())] as usize
        } else if p_heat > 0.0 {
            other[below(rng.random(), other.len())] as usize
        } else {
            below(rng.random(), n)
        };
        let old = x[i];
        let mut de = u_delta[old as usize];
        scratch.clear();
        for &e in graph.cell_edges(i) {
            let e = e as usize;
            let f = graph.edge_factor(e);
            let r = graph.factor_edges(f);
            let pos = (e - r.start) as u32;
            let cur = first[f];
            if old == 0 {
                if pos < cur {
                    de += graph.log_psi_at(f, cur as usize) - graph.edge_log_psi(e);
                    scratch.push((f as u32, pos));
                }
            } else if pos == cur {
                let next = (e + 1..r.end)
                    .find(|&k| x[graph.edge_cell(k)] != 0)
                    .map_or(r.len(), |k| k - r.start) as u32;
                de += graph.edge_log_psi(e) - graph.log_psi_at(f, next as usize);
                scratch.push((f as u32, next));
            }
        }
        if de <= 0.0 || rng.random::<f64>() < (-de).exp() {
            if t >= burn && old == 1 {
                occ_time[i] += t - since[i];
            }
            since[i] = t;
            x[i] = 1 - old;
            for &(f, p) in &scratch {
                first[f as usize] = p;
            }
            energy += de;
            accepted += 1;
        }
        t += 1;
        if t % sweep == 0 {
            trace.push((t0.elapsed().as_secs_f64(), energy));
        }
        if t % 65_536 == 0 && t0.elapsed().as_secs_f64() > cfg.max_seconds {
            break;
        }
    }
    let marginals = if t > burn {
        let span = (t - burn) as f64;
        (0..n)
            .map(|i| {
                let mut o = occ_time[i];
                if x[i] == 1 {
                    o += t - since[i].max(burn);
                }
                o as f64 / span
            })
            .collect()
    } else {
        x.iter().map(|&v| f64::from(v)).collect()
    };
    let seconds = t0.elapsed().as_secs_f64();
    if trace.last().is_some_and(|&(s, _)| s < seconds) {
        trace.push((seconds, energy));
    }
    MhResult {
        marginals,
        sample: x,
        trace,
        proposals: t,
        accepted,
        seconds,
    }
}
