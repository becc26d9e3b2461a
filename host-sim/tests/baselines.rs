//! The baselines against the exact posterior: BP is exact on a tree-shaped factor graph, MH and
//! the L = 1 Gibbs sampler converge to the exact 1-D posterior, DD and max-product find the
//! enumerated MAP on a tiny loopy problem.

use host_sim::eval::baselines::bp::{self, BpConfig, BpKind};
use host_sim::eval::baselines::dd::{self, DdConfig};
use host_sim::eval::baselines::exact::{enumerate, enumerate_first_occupied, kl_per_cell};
use host_sim::eval::baselines::factor_graph::{FactorGraph, FactorSpec, UnaryPrior};
use host_sim::eval::baselines::{
    build_graph, fig2, mh, run_method, BaselineConfig, Method, SensorModel,
};
use host_sim::eval::sampling::{run_sampler, SamplingConfig, Variant};
use host_sim::sim::explore::ScanRecord;
use ogm_core::reference::ReferenceModel;
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::{Angle, Beam, GridGeometry, LogOdds, MapperConfig, Pose, Range};

const CELL: u32 = 100;

/// A pose at the centre of cell (x, y).
fn pose(x: i32, y: i32, heading: Angle) -> Pose {
    Pose {
        x_mm: x * CELL as i32 + CELL as i32 / 2,
        y_mm: y * CELL as i32 + CELL as i32 / 2,
        heading,
    }
}

fn graph_of(
    g: GridGeometry,
    max_cells: u32,
    scans: &[(Pose, Vec<Beam>)],
    model: ReferenceModel,
    prior: Option<f64>,
) -> FactorGraph {
    let n_rays: usize = scans.iter().map(|s| s.1.len()).sum();
    let mut st = RayStore::new(
        g,
        max_cells * CELL,
        0,
        vec![StoredScan::default(); scans.len()],
        vec![StoredRay::default(); n_rays],
    )
    .unwrap();
    for (p, b) in scans {
        st.add_scan(p, b);
    }
    FactorGraph::from_store(
        &st,
        model,
        prior.map(|p_occupied| UnaryPrior { p_occupied }),
    )
    .unwrap()
}

fn beam(angle: Angle, mm: Option<u32>) -> Beam {
    Beam {
        angle,
        range: mm.map_or(Range::NoReturn, Range::Hit),
    }
}

/// Four rays on a 5×5 grid whose factor graph is a tree: rows 2, 0 and 4 (left to right) each
/// meet column 2 (bottom to top) in one cell, and nowhere else.
fn tree(model: ReferenceModel, prior: Option<f64>) -> FactorGraph {
    let g = GridGeometry::new(5, 5, CELL, 0, 0).unwrap();
    let scans = vec![
        (pose(0, 2, Angle::ZERO), vec![beam(Angle::ZERO, Some(200))]),
        (
            pose(2, 0, Angle::QUARTER),
            vec![beam(Angle::ZERO, Some(310))],
        ),
        (pose(0, 0, Angle::ZERO), vec![beam(Angle::ZERO, Some(280))]),
        (pose(0, 4, Angle::ZERO), vec![beam(Angle::ZERO, None)]),
    ];
    graph_of(g, 4, &scans, model, prior)
}

fn gaussian(sigma: f64, max_range: f64) -> ReferenceModel {
    ReferenceModel::Gaussian {
        sigma,
        w: 0.01,
        max_range,
    }
}

fn sigmoid(b: f64) -> f64 {
    1.0 / (1.0 + (-b).exp())
}

fn exact_bp() -> BpConfig {
    BpConfig {
        max_iterations: 200,
        tolerance: 1e-12,
        ..BpConfig::default()
    }
}

#[test]
fn the_tree_fixture_is_a_tree() {
    let fg = tree(gaussian(1.0, 4.0), None);
    assert_eq!(fg.n_factors(), 4);
    assert_eq!(fg.n_edges(), 20);
    // 17 distinct cells for 20 edges in 4 factors: a connected bipartite graph with
    // V + F − 1 = 17 + 4 − 1 = 20 edges has no cycle.
    let touched = (0..fg.n_cells()).filter(|&i| fg.degree(i) > 0).count();
    assert_eq!(touched, 17);
    assert_eq!(fg.degree(2 * 5 + 2), 2);
    assert_eq!(fg.degree(2), 2);
    assert_eq!(fg.degree(4 * 5 + 2), 2);
}

#[test]
fn sum_product_bp_is_exact_on_a_tree() {
    for (model, prior) in [
        (gaussian(1.0, 4.0), Some(0.3)),
        (gaussian(0.7, 4.0), None),
        (ReferenceModel::Pcsm, Some(0.23)),
    ] {
        let fg = tree(model, prior);
        let exact = enumerate(&fg).unwrap();
        let r = bp::run(&fg, BpKind::Sum, &exact_bp(), 3);
        assert!(r.converged, "{model:?}: BP did not converge");
        let worst = r
            .beliefs
            .iter()
            .zip(&exact.marginals)
            .map(|(&b, &p)| (sigmoid(b) - p).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-9,
            "{model:?} prior {prior:?}: BP marginals off by {worst}"
        );
        // The interesting cells are not trivially 0 or 1 with the Gaussian model.
        if matches!(model, ReferenceModel::Gaussian { .. }) {
            assert!(exact.marginals.iter().any(|&p| p > 0.05 && p < 0.95));
        }
    }
}

#[test]
fn max_product_bp_finds_the_map_on_a_tree() {
    for (model, prior) in [
        (gaussian(1.0, 4.0), Some(0.3)),
        (ReferenceModel::Pcsm, None),
    ] {
        let fg = tree(model, prior);
        let exact = enumerate(&fg).unwrap();
        let r = bp::run(&fg, BpKind::Max, &exact_bp(), 5);
        assert!(r.converged);
        let labels = bp::labels_of(&r.beliefs);
        let e = fg.energy(&labels).total();
        assert!(
            (e - exact.map_energy).abs() < 1e-9,
            "{model:?}: max-product energy {e} vs MAP {}",
            exact.map_energy
        );
    }
}

/// Readings (cells) of the 1-D test problem: Fig. 2's setting (wall at 20, σ = 2).
const READINGS: [f64; 8] = [19.3, 21.4, 20.2, 17.9, 22.6, 19.8, 20.9, 18.6];

/// The 1-D problem as a dataset (scans of one beam from cell 0 along +x) on 31 × 1 cells.
fn one_d_dataset() -> (GridGeometry, MapperConfig, Vec<ScanRecord>, Vec<LogOdds>) {
    let g = GridGeometry::new(31, 1, CELL, 0, 0).unwrap();
    let mapper = MapperConfig::new(30 * CELL);
    let scans: Vec<ScanRecord> = READINGS
        .iter()
        .map(|z| ScanRecord {
            pose: pose(0, 0, Angle::ZERO),
            beams: vec![beam(
                Angle::ZERO,
                Some((z * f64::from(CELL)).round() as u32),
            )],
        })
        .collect();
    (g, mapper, scans, vec![LogOdds::ZERO; 31])
}

fn one_d_config() -> BaselineConfig {
    BaselineConfig {
        model: SensorModel::Gaussian {
            sigma_cells: 2.0,
            outlier_weight: 0.01,
        },
        ..BaselineConfig::default()
    }
}

#[test]
fn first_occupied_enumeration_equals_brute_force() {
    // Nested rays along one line (hits and a no-return) on 14 cells.
    let g = GridGeometry::new(14, 1, CELL, 0, 0).unwrap();
    let p = pose(0, 0, Angle::ZERO);
    let scans: Vec<(Pose, Vec<Beam>)> = [Some(820), Some(760), None, Some(905), Some(300)]
        .into_iter()
        .map(|z| (p, vec![beam(Angle::ZERO, z)]))
        .collect();
    for prior in [Some(0.23), None] {
        let fg = graph_of(g, 12, &scans, gaussian(1.5, 12.0), prior);
        let brute = enumerate(&fg).unwrap();
        let fast = enumerate_first_occupied(&fg).unwrap();
        for (a, b) in brute.marginals.iter().zip(&fast) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        // Cells beyond the far end have no factor: the prior.
        assert_eq!(fg.degree(13), 0);
        assert!((fast[13] - prior.unwrap_or(0.5)).abs() < 1e-15);
    }
}

#[test]
fn mh_and_gibbs_l1_converge_to_the_exact_1d_posterior() {
    let (g, mapper, scans, map) = one_d_dataset();
    let mut cfg = one_d_config();
    let graph = build_graph(&g, &mapper, &scans, &cfg).unwrap();
    let exact = enumerate_first_occupied(&graph).unwrap();
    // The wall region is uncertain, the cells before it free, those behind it at the prior.
    assert!(
        exact[10] < 1e-3 && exact[20] > 0.1 && exact[20] < 0.9,
        "{exact:?}"
    );
    assert!((exact[30] - cfg.prior_p_occupied.unwrap()).abs() < 0.02);
    let kl = |q: &[f64]| kl_per_cell(&exact, q).iter().sum::<f64>();

    // Metropolis-Hastings, uniform and heat map, through the eval entry point.
    for (method, sweeps) in [("mh", 20_000), ("mh_heatmap", 20_000)] {
        cfg.mh = mh::MhConfig {
            burn_in_sweeps: 50,
            sweeps,
            ..mh::MhConfig::default()
        };
        let o = run_method(method, &g, &mapper, &scans, &map, &cfg, 11).unwrap();
        let d = kl(&o.probs);
        assert!(d < 0.01, "{method}: summed KL {d}");
    }
    let short = {
        cfg.mh.sweeps = 20;
        cfg.mh.burn_in_sweeps = 0;
        run_method("mh", &g, &mapper, &scans, &map, &cfg, 11).unwrap()
    };
    assert!(
        kl(&short.probs) > 0.01,
        "20 sweeps should not be converged yet"
    );

    // The project's L = 1 sampler (fixed point, same model and prior) via the eval runner.
    let sampling = SamplingConfig {
        burn_in: 20,
        sweeps: 80_000,
        sigma_cells: 2.0,
        outlier_weight: 0.01,
        p_rand_patch: 0.0,
        ..SamplingConfig::default()
    };
    let o = run_sampler(g, &mapper, &scans, &map, Variant::L1, &sampling, 5).unwrap();
    let d = kl(&o.marginals);
    assert!(d < 0.01, "gibbs_l1: summed KL {d}");
}

#[test]
fn fig2_example_shows_the_traditional_bias() {
    let d = fig2::one_d_with(&READINGS).unwrap();
    let exact = enumerate_first_occupied(&d.graph).unwrap();
    // The traditional algorithm is over-confident before the wall and misplaces the
    // uncertainty around it; the exact posterior is smooth around k = 20.
    assert!(d.traditional[5] < 1e-3 && exact[5] < 1e-3);
    let kl_trad: f64 = kl_per_cell(&exact, &d.traditional).iter().sum();
    assert!(kl_trad > 0.5, "traditional KL {kl_trad}");
    // From an empty map with burn-in, MH reaches the exact marginals (from a random map the
    // flat outlier floor of the likelihood makes the transient long; see docs/results.md).
    let cfg = mh::MhConfig {
        burn_in_sweeps: 100,
        sweeps: 20_000,
        ..mh::MhConfig::default()
    };
    let r = mh::run(&d.graph, &[0; 31], &cfg, false, 3);
    let kl_mh: f64 = kl_per_cell(&exact, &r.marginals).iter().sum();
    assert!(kl_mh < 0.01, "MH KL {kl_mh}");
    // The incrementally tracked energy is the energy of the final sample.
    let tracked = r.trace.last().unwrap().1;
    assert!((tracked - d.graph.energy(&r.sample).total()).abs() < 1e-9);
}

/// A tiny loopy problem: 5 × 4 cells, two poses, rays fanning out against walls.
fn tiny_loopy(model: ReferenceModel, prior: Option<f64>) -> FactorGraph {
    let g = GridGeometry::new(5, 4, CELL, 0, 0).unwrap();
    let a = pose(0, 0, Angle::ZERO);
    let b = pose(0, 3, Angle::ZERO);
    let deg = Angle::from_degrees;
    let scans = vec![
        (
            a,
            vec![
                beam(deg(0.0), Some(400)),
                beam(deg(20.0), Some(420)),
                beam(deg(45.0), Some(300)),
                beam(deg(80.0), Some(300)),
            ],
        ),
        (
            b,
            vec![
                beam(deg(0.0), Some(390)),
                beam(deg(-30.0), Some(330)),
                beam(deg(-70.0), None),
            ],
        ),
        (
            a,
            vec![beam(deg(0.0), Some(380)), beam(deg(45.0), Some(280))],
        ),
    ];
    graph_of(g, 4, &scans, model, prior)
}

#[test]
fn dual_decomposition_and_max_product_find_the_enumerated_map() {
    for (model, prior, step) in [
        (gaussian(1.0, 4.0), Some(0.3), 5.0),
        (gaussian(1.0, 4.0), None, 5.0),
        (ReferenceModel::Pcsm, None, 50.0),
    ] {
        let fg = tiny_loopy(model, prior);
        assert!(fg.n_factors() == 9);
        let exact = enumerate(&fg).unwrap();
        let r = dd::run(
            &fg,
            &DdConfig {
                step_size: step,
                max_iterations: 2000,
                max_seconds: 20.0,
            },
        );
        assert!(
            (r.energy - exact.map_energy).abs() < 1e-9,
            "{model:?} {prior:?}: DD energy {} vs MAP {} ({} iterations, converged {})",
            r.energy,
            exact.map_energy,
            r.iterations,
            r.converged
        );
        assert_eq!(r.labels, exact.map, "{model:?} {prior:?}: DD labels");
        assert!(r.lower_bound <= exact.map_energy + 1e-9);
        let m = bp::run(&fg, BpKind::Max, &exact_bp(), 9);
        let e = fg.energy(&bp::labels_of(&m.beliefs)).total();
        assert!(
            (e - exact.map_energy).abs() < 1e-9,
            "{model:?} {prior:?}: max-product energy {e} vs MAP {}",
            exact.map_energy
        );
    }
}

#[test]
fn explicit_factors_energy_matches_definition() {
    // Two factors over 3 cells: f0 = [0, 1, 2], f1 = [2, 1].
    let fg = FactorGraph::new(
        3,
        &[
            FactorSpec {
                cells: vec![0, 1, 2],
                log_psi: vec![-1.0, -2.0, -3.0],
                log_psi_clear: -4.0,
            },
            FactorSpec {
                cells: vec![2, 1],
                log_psi: vec![-0.5, -0.25],
                log_psi_clear: -8.0,
            },
        ],
        Some(UnaryPrior { p_occupied: 0.25 }),
        vec![],
    )
    .unwrap();
    let e = fg.energy(&[0, 1, 1]);
    assert!((e.nll - (2.0 + 0.5)).abs() < 1e-15);
    assert!((e.prior - (-(0.75f64.ln()) - 2.0 * 0.25f64.ln())).abs() < 1e-12);
    let e = fg.energy(&[0, 0, 0]);
    assert!((e.nll - 12.0).abs() < 1e-15);
    // Enumeration normalises.
    let ex = enumerate(&fg).unwrap();
    let z: f64 = (0..8u8)
        .map(|m| {
            let l = [m & 1, m >> 1 & 1, m >> 2 & 1];
            (-fg.energy(&l).total()).exp()
        })
        .sum();
    assert!((ex.log_z - z.ln()).abs() < 1e-12);
}

#[test]
fn every_method_runs_through_the_eval_entry_point() {
    // A 2-D scene: a room with a wall at x = 15, three poses.
    let g = GridGeometry::new(24, 24, CELL, 0, 0).unwrap();
    let mapper = MapperConfig::new(20 * CELL);
    let scans: Vec<ScanRecord> = [(500, 1200), (600, 600), (900, 1900)]
        .into_iter()
        .map(|(px, py)| {
            let beams = (0..48)
                .map(|i| {
                    let a = Angle((i * 65536 / 48) as u16);
                    let th = a.to_radians();
                    let d = (1500.0 - f64::from(px)) / th.cos();
                    let y = f64::from(py) + d * th.sin();
                    let hit = th.cos() > 0.05 && (400.0..2000.0).contains(&y) && d < 2000.0;
                    beam(a, hit.then(|| d.round() as u32))
                })
                .collect();
            ScanRecord {
                pose: Pose {
                    x_mm: px,
                    y_mm: py,
                    heading: Angle::ZERO,
                },
                beams,
            }
        })
        .collect();
    // The online map initialises Metropolis-Hastings, as in eval-sim.
    let mut mapper_ = host_sim::sim::new_mapper(g, mapper).unwrap();
    for s in &scans {
        mapper_.insert_scan(&s.pose, &s.beams).unwrap();
    }
    let map = mapper_.grid().cells().to_vec();
    let mut cfg = BaselineConfig::default();
    cfg.mh.sweeps = 50;
    cfg.mh.burn_in_sweeps = 10;
    for m in Method::ALL {
        let o = run_method(m.name(), &g, &mapper, &scans, &map, &cfg, 1).unwrap();
        assert_eq!(o.probs.len(), g.len());
        assert!(o.energy.is_finite() && o.nll.is_finite() && o.nll > 0.0);
        assert!(o.trace.len() >= 2, "{}: trace {:?}", m.name(), o.trace);
        // The map is the 0.5 threshold of the output, for marginals and max-marginals alike.
        let thresholded: Vec<u8> = o.probs.iter().map(|&p| u8::from(p > 0.5)).collect();
        assert_eq!(o.labels, thresholded, "{}", m.name());
        if m.is_map() {
            assert!(o.converged || o.iterations > 0);
        }
        if let Some(lb) = o.lower_bound {
            assert!(
                lb <= o.energy + 1e-6,
                "dual bound {lb} above energy {}",
                o.energy
            );
        }
        // The wall (column 15, position uncertain by σ = 3 cells) is occupied, the space in
        // front of it free.
        let band = |x0: usize, x1: usize| {
            let cells: Vec<f64> = (5..19)
                .flat_map(|y| (x0..=x1).map(move |x| y * 24 + x))
                .map(|i| o.probs[i])
                .collect();
            cells.iter().sum::<f64>() / cells.len() as f64
        };
        let (wall, free) = (band(13, 17), band(10, 12));
        assert!(
            wall > 0.15 && free < 0.05,
            "{}: wall band {wall}, free band {free}",
            m.name()
        );
    }
    assert!(run_method("nope", &g, &mapper, &scans, &map, &cfg, 1).is_err());
}
