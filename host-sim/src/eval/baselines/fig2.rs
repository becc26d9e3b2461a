//! `host-sim exact-1d`: merali-barfoot-mcmc-gibbs-ogm Fig. 2 (and Fig. 3) reproduced.
//!
//! A 1-D world of 31 cells (k = 0 … 30, 10 cm each): the robot at k = 0, the wall (first occupied
//! cell) at k = 20, maximum range F = 30 cells, eight readings drawn from N(20, 2²) cells. The
//! exact posterior (enumerating the first occupied cell, [`super::exact`]) is compared with
//!
//! * the traditional two-assumption algorithm with Hähnel's l_free = −1.3863, l_occ = 1.3863 and
//!   no clamp (`ogm_core::reference::ReferenceMapper`, the mapper's own beam classification);
//! * `ogm_core`'s L = 1 Gibbs sampler (fixed point, p_randPatch = 0, no burn-in, random start)
//!   after i = 10, 100, 1000, 10 000 sweeps, and this module's Metropolis–Hastings and sum-product
//!   BP on the same factor graph.
//!
//! Forward model: Gaussian σ = 2 cells (the readings' noise) with the project's 1 % outlier
//! mixture; prior p(m_k) = 0.5 (the paper's uninformed p(m^r) = 1/R).

use std::path::Path;

use anyhow::{anyhow, Context};
use ogm_core::map::mapper::marks_len;
use ogm_core::reference::{Increments, ReferenceMapper, ReferenceModel};
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::gibbs::{
    block_words, Buffers, ConstantCellPrior, Gibbs, LocalRay, SamplerConfig,
};
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::{Angle, Beam, GridGeometry, LogOdds, MapperConfig, Pose, Range};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::Serialize;

use super::exact::{enumerate_first_occupied, kl_per_cell};
use super::factor_graph::{FactorGraph, UnaryPrior};
use super::plot::{kl_vs_sweeps_svg, marginals_svg, Series, SeriesLabelPosition};
use super::{bp, mh};

/// Cells k = 0 … 30.
pub const CELLS: usize = 31;
/// The wall (true first occupied cell).
pub const WALL: usize = 20;
/// Maximum range F, cells.
pub const MAX_RANGE_CELLS: u32 = 30;
/// Readings.
pub const READINGS: usize = 8;
/// Reading noise σ (cells), also the forward model's.
pub const SIGMA: f64 = 2.0;
/// Outlier weight of the forward model.
pub const OUTLIER_WEIGHT: f64 = 0.01;
/// The cell prior p(m_k = 1).
pub const PRIOR: f64 = 0.5;
/// Sweep counts at which the sampled marginals are shown (Fig. 2's i).
pub const SHOWN_SWEEPS: [u32; 4] = [10, 100, 1000, 10_000];
const CELL_MM: u32 = 100;

/// The example's data: geometry, store, readings (cells) and the traditional map.
pub struct OneD {
    /// 31 × 1 cells of 10 cm.
    pub geometry: GridGeometry,
    /// One scan of one beam per reading.
    pub store: RayStore<Vec<StoredScan>, Vec<StoredRay>>,
    /// The readings, in cells from the robot's cell centre.
    pub readings: Vec<f64>,
    /// The factor graph (σ = 2, 1 % outliers, prior 0.5).
    pub graph: FactorGraph,
    /// Traditional (two-assumption) occupancy probabilities.
    pub traditional: Vec<f64>,
}

/// Builds the example with readings drawn with `seed`.
pub fn one_d(seed: u64) -> anyhow::Result<OneD> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let noise = Normal::new(WALL as f64, SIGMA).map_err(|e| anyhow!("{e}"))?;
    let readings: Vec<f64> = (0..READINGS)
        .map(|_| {
            noise
                .sample(&mut rng)
                .clamp(0.0, f64::from(MAX_RANGE_CELLS))
        })
        .collect();
    one_d_with(&readings)
}

/// Builds the example with the given readings (cells).
pub fn one_d_with(readings: &[f64]) -> anyhow::Result<OneD> {
    let geometry = GridGeometry::new(CELLS as u16, 1, CELL_MM, 0, 0).map_err(|e| anyhow!("{e}"))?;
    let max_mm = MAX_RANGE_CELLS * CELL_MM;
    let pose = Pose {
        x_mm: (CELL_MM / 2) as i32,
        y_mm: (CELL_MM / 2) as i32,
        heading: Angle::ZERO,
    };
    let mut store = RayStore::new(
        geometry,
        max_mm,
        0,
        vec![StoredScan::default(); readings.len().max(1)],
        vec![StoredRay::default(); readings.len().max(1)],
    )
    .map_err(|e| anyhow!("ray store: {e}"))?;
    let config = MapperConfig::new(max_mm);
    let ln4 = 4f64.ln();
    let inc = Increments {
        occ: ln4,
        free: -ln4,
        min: f64::NEG_INFINITY,
        max: f64::INFINITY,
    };
    let mut mapper = ReferenceMapper::new(
        geometry,
        config,
        inc,
        vec![0.0; CELLS],
        vec![0u32; marks_len(CELLS)],
    )
    .map_err(|e| anyhow!("mapper: {e}"))?;
    for &z in readings {
        let mm = (z * f64::from(CELL_MM)).round() as u32;
        let beam = Beam {
            angle: Angle::ZERO,
            range: if mm < max_mm {
                Range::Hit(mm)
            } else {
                Range::NoReturn
            },
        };
        store.add_scan(&pose, &[beam]);
        mapper
            .insert_scan(&pose, &[beam])
            .map_err(|e| anyhow!("mapper: {e}"))?;
    }
    let traditional = (0..CELLS)
        .map(|i| mapper.probability(i).unwrap_or(0.5))
        .collect();
    let graph = FactorGraph::from_store(&store, model(), Some(UnaryPrior { p_occupied: PRIOR }))?;
    Ok(OneD {
        geometry,
        store,
        readings: readings.to_vec(),
        graph,
        traditional,
    })
}

/// The example's f64 forward model.
pub fn model() -> ReferenceModel {
    ReferenceModel::Gaussian {
        sigma: SIGMA,
        w: OUTLIER_WEIGHT,
        max_range: f64::from(MAX_RANGE_CELLS),
    }
}

/// A random initial map (Merali & Barfoot: "select a random m(0)"), as log-odds ±ln 4.
pub fn random_init(seed: u64) -> Vec<LogOdds> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xF162);
    (0..CELLS)
        .map(|_| {
            if rand::RngExt::random::<bool>(&mut rng) {
                LogOdds(1024)
            } else {
                LogOdds(-1024)
            }
        })
        .collect()
}

/// The traditional map as an initial map (occupied iff p > 0.5), as the samplers start in
/// `eval-sim`.
pub fn traditional_init(d: &OneD) -> Vec<LogOdds> {
    d.traditional
        .iter()
        .map(|&p| {
            if p > 0.5 {
                LogOdds(1024)
            } else {
                LogOdds(-1024)
            }
        })
        .collect()
}

/// `ogm_core`'s L = 1 Gibbs sampler on the example from `init` (occupied iff log-odds > 0),
/// counting from the first sweep (no burn-in); returns the marginals after each of `checkpoints`
/// (increasing sweep counts).
pub fn gibbs_l1(
    d: &mut OneD,
    checkpoints: &[u32],
    seed: u64,
    init: &[LogOdds],
) -> anyhow::Result<Vec<(u32, Vec<f64>)>> {
    let fm = ForwardModel::gaussian(SIGMA, OUTLIER_WEIGHT, f64::from(MAX_RANGE_CELLS))
        .map_err(|e| anyhow!("{e}"))?;
    let prior = ConstantCellPrior::new(PRIOR).map_err(|e| anyhow!("{e}"))?;
    let cfg = SamplerConfig {
        burn_in_sweeps: 0,
        p_rand_patch: 0.0,
        // One tile holds the whole 31-cell line, visited one sweep at a time: a plain random
        // scan, so "i sweeps" means i·K updates spread over the whole map.
        tile_shift: 5,
        visit_sweeps: 1,
        seed,
        ..SamplerConfig::default()
    };
    let buf = Buffers {
        sample: vec![0u32; CELLS.div_ceil(32)],
        counts: vec![0u32; CELLS],
        local: vec![LocalRay::default(); 64],
        blocks: vec![
            0u32;
            block_words(
                64,
                ogm_core::sampler::gibbs::SamplerConfig::default().block_grid
            )
        ],
    };
    let mut g = Gibbs::<_, _, _, _, _, u32>::new(d.geometry, prior, fm, cfg, buf)
        .map_err(|e| anyhow!("sampler: {e}"))?;
    g.reset(init, &mut d.store)
        .map_err(|e| anyhow!("sampler: {e}"))?;
    let mut out = Vec::new();
    let mut done = 0u32;
    for &c in checkpoints {
        for _ in done..c {
            g.step(&mut d.store, init, CELLS as u32);
        }
        done = done.max(c);
        out.push((
            c,
            (0..CELLS)
                .map(|i| g.marginal(i).map_or(0.5, f64::from))
                .collect(),
        ));
    }
    Ok(out)
}

/// Metropolis–Hastings (uniform flips, no burn-in) on the example after `sweeps` sweeps.
pub fn mh_marginals(d: &OneD, sweeps: u32, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xF162);
    let init: Vec<u8> = (0..CELLS)
        .map(|_| u8::from(rand::RngExt::random::<bool>(&mut rng)))
        .collect();
    let cfg = mh::MhConfig {
        burn_in_sweeps: 0,
        sweeps,
        heat_bias: 4.0,
        max_seconds: 60.0,
    };
    mh::run(&d.graph, &init, &cfg, false, seed).marginals
}

#[derive(Serialize)]
struct CellRow {
    k: usize,
    ground_truth: Option<f64>,
    exact: f64,
    traditional: f64,
    gibbs_l1: Vec<(u32, f64)>,
    mh: f64,
    bp_sum: f64,
}

/// Sweep counts of the convergence curves (Fig. 3).
const KL_SWEEPS: [u32; 13] = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10_000];

/// Runs the example and writes `exact_1d.json`, `fig2_marginals.svg`, `fig2_zoom.svg`,
/// `fig2_gibbs_iterations.svg` and `fig3_kl.svg` into `out`; prints the cells 17–23.
pub fn run(out: &Path, seed: u64) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create output directory", out.display()))?;
    let mut d = one_d(seed)?;
    let exact = enumerate_first_occupied(&d.graph)?;
    let kl_sum = |q: &[f64]| kl_per_cell(&exact, q).iter().sum::<f64>();
    let curve = |runs: &[(u32, Vec<f64>)]| -> Vec<(f64, f64)> {
        runs.iter()
            .map(|(i, m)| (f64::from(*i), kl_sum(m)))
            .collect()
    };
    let gibbs = gibbs_l1(&mut d, &KL_SWEEPS, seed, &random_init(seed))?;
    let init_trad = traditional_init(&d);
    let gibbs_trad = gibbs_l1(&mut d, &KL_SWEEPS, seed, &init_trad)?;
    let mh_runs: Vec<(u32, Vec<f64>)> = KL_SWEEPS
        .iter()
        .map(|&i| (i, mh_marginals(&d, i, seed)))
        .collect();
    let bp_cfg = bp::BpConfig {
        max_iterations: 1000,
        tolerance: 1e-10,
        ..bp::BpConfig::default()
    };
    let bpr = bp::run(&d.graph, bp::BpKind::Sum, &bp_cfg, seed);
    let bp_sum: Vec<f64> = bpr
        .beliefs
        .iter()
        .map(|&b| 1.0 / (1.0 + (-b).exp()))
        .collect();
    let shown: Vec<&(u32, Vec<f64>)> = gibbs
        .iter()
        .filter(|(i, _)| SHOWN_SWEEPS.contains(i))
        .collect();
    let last = KL_SWEEPS[KL_SWEEPS.len() - 1];
    let gibbs_final = gibbs.last().map(|g| g.1.clone()).unwrap_or_default();
    let mh_final = mh_runs.last().map(|r| r.1.clone()).unwrap_or_default();
    let gibbs_trad_final = gibbs_trad.last().map(|g| g.1.clone()).unwrap_or_default();
    let truth = |k: usize| match k.cmp(&WALL) {
        std::cmp::Ordering::Less => Some(0.0),
        std::cmp::Ordering::Equal => Some(1.0),
        std::cmp::Ordering::Greater => None,
    };
    let rows: Vec<CellRow> = (0..CELLS)
        .map(|k| CellRow {
            k,
            ground_truth: truth(k),
            exact: exact[k],
            traditional: d.traditional[k],
            gibbs_l1: shown.iter().map(|(i, m)| (*i, m[k])).collect(),
            mh: mh_final[k],
            bp_sum: bp_sum[k],
        })
        .collect();
    let kl = |q: &[f64]| {
        let per = kl_per_cell(&exact, q);
        let sum: f64 = per.iter().sum();
        serde_json::json!({ "per_cell": per, "sum": sum })
    };
    let json = serde_json::json!({
        "setup": {
            "cells": CELLS, "robot_cell": 0, "wall_cell": WALL, "max_range_cells": MAX_RANGE_CELLS,
            "cell_mm": CELL_MM, "readings": READINGS, "reading_sigma_cells": SIGMA,
            "forward_model":
                format!("Gaussian sigma = {SIGMA} cells, outlier weight {OUTLIER_WEIGHT}"),
            "prior_p_occupied": PRIOR,
            "traditional": "Haehnel inverse model l_free = -1.3863, l_occ = 1.3863, no clamp",
            "gibbs_l1": concat!(
                "ogm_core::sampler::gibbs L = 1, ConstantCellPrior(0.5), p_rand_patch 0, no burn-in, ",
                "random start (gibbs_l1_from_traditional: started from the traditional map ",
                "thresholded at 0.5)"
            ),
            "mh": "baselines::mh uniform single-cell flips, no burn-in, random start",
            "bp_sum": { "iterations": bpr.iterations, "converged": bpr.converged },
            "seed": seed,
        },
        "readings_cells": d.readings,
        "cells": rows,
        "kl_to_exact": {
            "traditional": kl(&d.traditional),
            format!("gibbs_l1_{last}"): kl(&gibbs_final),
            format!("gibbs_l1_from_traditional_{last}"): kl(&gibbs_trad_final),
            format!("mh_{last}"): kl(&mh_final),
            "bp_sum": kl(&bp_sum),
        },
        "summed_kl_vs_sweeps": {
            "gibbs_l1": curve(&gibbs),
            "gibbs_l1_from_traditional": curve(&gibbs_trad),
            "mh": curve(&mh_runs),
        },
    });
    let jpath = out.join("exact_1d.json");
    std::fs::write(&jpath, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", jpath.display()))?;

    let xs = |v: &[f64]| -> Vec<(f64, f64)> {
        v.iter().enumerate().map(|(k, &p)| (k as f64, p)).collect()
    };
    let line = |name, points, markers, dashed| Series {
        name,
        points,
        markers,
        dashed,
    };
    // The ground truth as a step: free up to the wall, the wall occupied, unknown behind it.
    let w = WALL as f64;
    let gt = vec![(0.0, 0.0), (w - 0.5, 0.0), (w - 0.5, 1.0), (w + 0.5, 1.0)];
    let gibbs_name = format!("MCMC Gibbs L=1, i = {last}");
    let mh_name = format!("Metropolis-Hastings, i = {last}");
    let methods = [
        line("ground truth", gt.clone(), false, false),
        line("full Bayesian (exact)", xs(&exact), true, false),
        line(
            "traditional (two-assumption)",
            xs(&d.traditional),
            true,
            false,
        ),
        line(&gibbs_name, xs(&gibbs_final), false, false),
        line(&mh_name, xs(&mh_final), false, true),
        line("sum-product BP", xs(&bp_sum), false, true),
    ];
    let title =
        "1-D example (Merali & Barfoot Fig. 2): robot at k=0, wall at k=20, F=30, 8 readings";
    marginals_svg(
        out.join("fig2_marginals.svg"),
        title,
        (0.0, 30.0),
        &methods,
        SeriesLabelPosition::UpperLeft,
    )?;
    marginals_svg(
        out.join("fig2_zoom.svg"),
        "1-D example, cells 15-25",
        (15.0, 25.0),
        &methods,
        SeriesLabelPosition::UpperLeft,
    )?;
    let names: Vec<String> = shown
        .iter()
        .map(|(i, _)| format!("MCMC Gibbs L=1, i = {i}"))
        .collect();
    let mut iters = vec![
        line("ground truth", gt, false, false),
        line("full Bayesian (exact)", xs(&exact), true, false),
    ];
    for ((_, m), name) in shown.iter().zip(&names) {
        iters.push(line(name, xs(m), false, false));
    }
    marginals_svg(
        out.join("fig2_gibbs_iterations.svg"),
        "1-D example: Gibbs L=1 from a random map after i sweeps (no burn-in)",
        (0.0, 30.0),
        &iters,
        SeriesLabelPosition::LowerRight,
    )?;
    kl_vs_sweeps_svg(
        out.join("fig3_kl.svg"),
        "Convergence to the full solution (Merali & Barfoot Fig. 3), no burn-in",
        &[
            line("Gibbs L=1, random start", curve(&gibbs), true, false),
            line(
                "Gibbs L=1, from traditional map",
                curve(&gibbs_trad),
                true,
                false,
            ),
            line(
                "Metropolis-Hastings, random start",
                curve(&mh_runs),
                true,
                false,
            ),
        ],
    )?;

    println!(
        "readings (cells): {}",
        d.readings
            .iter()
            .map(|z| format!("{z:.2}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "{:>4} {:>8} {:>11} {}  {:>8} {:>8}",
        "k",
        "exact",
        "traditional",
        SHOWN_SWEEPS
            .iter()
            .map(|i| format!("{:>11}", format!("gibbs{i}")))
            .collect::<String>(),
        "mh",
        "bp_sum"
    );
    for r in &rows[17..=23] {
        println!(
            "{:>4} {:>8.4} {:>11.4} {}  {:>8.4} {:>8.4}",
            r.k,
            r.exact,
            r.traditional,
            r.gibbs_l1
                .iter()
                .map(|(_, p)| format!("{p:>11.4}"))
                .collect::<String>(),
            r.mh,
            r.bp_sum
        );
    }
    println!(
        "summed KL to exact (nats): traditional {:.4}, gibbs_l1 {:.4} (from traditional map \
         {:.4}), mh {:.4} after {last} sweeps; bp_sum {:.4}",
        kl_sum(&d.traditional),
        kl_sum(&gibbs_final),
        kl_sum(&gibbs_trad_final),
        kl_sum(&mh_final),
        kl_sum(&bp_sum),
    );
    println!("wrote {}", out.display());
    Ok(())
}
