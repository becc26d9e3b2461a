//! The Gibbs sampler against the exact posterior (1-D, by enumeration) and against the f64
//! reference sampler (2-D).

use ogm_core::map::mapper::marks_len;
use ogm_core::reference::{ReferenceGibbs, ReferenceModel};
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::gibbs::{
    block_words, Buffers, ConstantCellPrior, Gibbs, LocalRay, PatchCandidate, PatchPrior,
    SamplerConfig,
};
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::types::fixed::LSB_NATS;
use ogm_core::{
    Angle, Beam, CellCoord, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose, Range,
};

type Store = RayStore<Vec<StoredScan>, Vec<StoredRay>>;
type Sampler<P> = Gibbs<P, Vec<u32>, Vec<u32>, Vec<LocalRay>, Vec<u32>, u32>;

const CELL: u32 = 100;

fn store(g: GridGeometry, max_range_mm: u32) -> Store {
    RayStore::new(
        g,
        max_range_mm,
        0,
        vec![StoredScan::default(); 256],
        vec![StoredRay::default(); 8192],
    )
    .unwrap()
}

fn sampler<P: PatchPrior>(
    g: GridGeometry,
    prior: P,
    fm: ForwardModel,
    cfg: SamplerConfig,
) -> Sampler<P> {
    let buf = Buffers {
        sample: vec![0; g.len().div_ceil(32)],
        counts: vec![0; g.len()],
        local: vec![LocalRay::default(); 4096],
        blocks: vec![0; block_words(4096, SamplerConfig::default().block_grid)],
    };
    Gibbs::new(g, prior, fm, cfg, buf).unwrap()
}

fn kl(p: f64, q: f64) -> f64 {
    let q = q.clamp(1e-4, 1.0 - 1e-4);
    let t = |a: f64, b: f64| if a <= 0.0 { 0.0 } else { a * (a / b).ln() };
    t(p, q) + t(1.0 - p, 1.0 - q)
}

/// The 1-D problem: robot at cell 0 looking along +x at a wall at cell 10; K = 16 cells,
/// F = 15 cells, σ = 2 cells, eight readings (as in merali-barfoot-mcmc-gibbs-ogm Fig. 2, scaled
/// to K ≤ 20 so enumeration is exact).
const K: usize = 16;
const READINGS: [f64; 8] = [9.6, 10.4, 11.1, 8.7, 10.0, 12.2, 9.3, 10.8];

fn one_d() -> (GridGeometry, Store, ForwardModel) {
    let g = GridGeometry::new(K as u16, 1, CELL, 0, 0).unwrap();
    let mut st = store(g, 15 * CELL);
    let pose = Pose {
        x_mm: 50,
        y_mm: 50,
        heading: Angle::ZERO,
    };
    for z in READINGS {
        st.add_scan(
            &pose,
            &[Beam {
                angle: Angle::ZERO,
                range: Range::Hit((z * f64::from(CELL)).round() as u32),
            }],
        );
    }
    (g, st, ForwardModel::gaussian(2.0, 0.01, 15.0).unwrap())
}

/// Exact marginals by enumerating all 2^K maps with the sampler's own fixed-point model.
fn exact_marginals(st: &Store, fm: &ForwardModel, log_free: f64, log_occ: f64) -> Vec<f64> {
    let rays: Vec<(u16, u64)> = st
        .rays()
        .iter()
        .map(|r| {
            let scan = st.scans()[0];
            (r.z_q4, st.ray_geometry(&scan.pose, r.angle).ray.steps())
        })
        .collect();
    let mut logp = vec![0f64; 1 << K];
    for (m, lp) in logp.iter_mut().enumerate() {
        let occ = m.count_ones() as f64;
        let mut l = occ * log_occ + (K as f64 - occ) * log_free;
        for &(z_q4, n) in &rays {
            // Horizontal rays: one step = one cell; the first occupied cell within the far end.
            let f = (0..=n.min(K as u64 - 1)).find(|&i| m & (1 << i) != 0);
            let ll = match f {
                None => fm.hit_clear(),
                Some(f) => {
                    let d = i64::from(z_q4) - 16 * f as i64;
                    fm.hit(d as i32)
                }
            };
            l += f64::from(ll) * LSB_NATS;
        }
        *lp = l;
    }
    let max = logp.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let z: f64 = logp.iter().map(|l| (l - max).exp()).sum();
    (0..K)
        .map(|k| {
            logp.iter()
                .enumerate()
                .filter(|(m, _)| m & (1 << k) != 0)
                .map(|(_, l)| (l - max).exp())
                .sum::<f64>()
                / z
        })
        .collect()
}

#[test]
fn l1_sampler_converges_to_the_exact_1d_posterior() {
    let (g, mut st, fm) = one_d();
    let prior = ConstantCellPrior::new(0.3).unwrap();
    let cfg = SamplerConfig {
        burn_in_sweeps: 0,
        p_rand_patch: 0.0,
        seed: 7,
        ..SamplerConfig::default()
    };
    let mut s = sampler(g, prior, fm.clone(), cfg);
    s.reset(&[LogOdds::ZERO; K], &mut st).unwrap();
    let lsb = |p: f64| f64::from(LogOdds::from_nats(p.ln()).unwrap().0) * LSB_NATS;
    let exact = exact_marginals(&st, &fm, lsb(0.7), lsb(0.3));
    // The wall region is uncertain, the cells before it are free, behind it at the prior.
    assert!(
        exact[3] < 0.01 && exact[10] > 0.3 && (exact[15] - 0.3).abs() < 0.05,
        "{exact:?}"
    );
    let mut kls = Vec::new();
    let mut done = 0u32;
    for sweeps in [30u32, 300, 3000, 30000] {
        s.step(&mut st, &[LogOdds::ZERO; K], (sweeps - done) * K as u32);
        done = sweeps;
        let total: f64 = (0..K)
            .map(|k| kl(exact[k], f64::from(s.marginal(k).unwrap())))
            .sum();
        kls.push(total);
    }
    eprintln!("summed KL after 30/300/3000/30000 sweeps: {kls:?}");
    assert!(kls[3] <= 0.01, "KL {kls:?}");
    assert!(
        kls[0] > kls[2] && kls[1] > kls[3],
        "KL should decrease: {kls:?}"
    );
}

/// A small synthetic L = 9 prior: four shapes with fixed log-priors regardless of the border.
struct ShapesPrior;
impl PatchPrior for ShapesPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        2
    }
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize {
        // Border-dependent order/weights so the border path is exercised too.
        let bias = if border.count_ones() > 8 { 600 } else { -600 };
        let c = [
            PatchCandidate {
                config: 0,
                log_prior: -200,
            },
            PatchCandidate {
                config: 0x1FF,
                log_prior: -2000 + bias,
            },
            PatchCandidate {
                config: 0b000_111_000,
                log_prior: -900,
            },
            PatchCandidate {
                config: 0b010_010_010,
                log_prior: -1100,
            },
        ];
        let n = out.len().min(4);
        out[..n].copy_from_slice(&c[..n]);
        n
    }
}

/// A 2-D scene: a 24×24 room with a wall segment, scanned sparsely from three poses.
fn two_d() -> (GridGeometry, Store, Vec<LogOdds>) {
    let g = GridGeometry::new(24, 24, CELL, 0, 0).unwrap();
    let max = 20 * CELL;
    let mut st = store(g, max);
    let grid = LogOddsGrid::new(g, vec![LogOdds::ZERO; g.len()]).unwrap();
    let mut mapper =
        Mapper::new(grid, vec![0; marks_len(g.len())], MapperConfig::new(max)).unwrap();
    // Wall: x = 15..17 (cells), y = 4..20; readings are distances to x = 1500 mm.
    for (px, py) in [(500, 1200), (600, 600), (900, 1900)] {
        let pose = Pose {
            x_mm: px,
            y_mm: py,
            heading: Angle::ZERO,
        };
        let beams: Vec<Beam> = (0..48)
            .map(|i| {
                let a = Angle((i * 65536 / 48) as u16);
                let th = a.to_radians();
                let range = if th.cos() > 0.05 {
                    let d = (1500.0 - f64::from(px)) / th.cos();
                    let y = f64::from(py) + d * th.sin();
                    if (400.0..2000.0).contains(&y) && d < f64::from(max) {
                        Range::Hit(d.round() as u32)
                    } else {
                        Range::NoReturn
                    }
                } else {
                    Range::NoReturn
                };
                Beam { angle: a, range }
            })
            .collect();
        mapper.insert_scan(&pose, &beams).unwrap();
        st.add_scan(&pose, &beams);
    }
    (g, st, mapper.grid().cells().to_vec())
}

#[test]
fn fixed_point_conditional_matches_f64_reference() {
    let (g, mut st, map) = two_d();
    let fm = ForwardModel::gaussian(3.0, 0.01, 20.0).unwrap();
    let model = ReferenceModel::Gaussian {
        sigma: 3.0,
        w: 0.01,
        max_range: 20.0,
    };
    let mut worst = 0f64;
    for seed in 0..6u64 {
        let cfg = SamplerConfig {
            seed,
            ..SamplerConfig::default()
        };
        let mut s = sampler(g, ShapesPrior, fm.clone(), cfg);
        s.reset(&map, &mut st).unwrap();
        s.step(&mut st, &map, 500 * (seed as u32 + 1)); // wander to a random state
                                                        // The reference starts from the fixed sampler's current sample.
        let state: Vec<LogOdds> = (0..g.len())
            .map(|i| LogOdds(if s.occupied(i) { 1 } else { -1 }))
            .collect();
        let (mut sample, mut counts) = (vec![0u8; g.len()], vec![0u64; g.len()]);
        let mut r = ReferenceGibbs::new(
            g,
            ShapesPrior,
            model,
            0.0,
            &state,
            LogOdds::ZERO,
            &mut sample,
            &mut counts,
            1,
        )
        .unwrap();
        for cy in 2..22 {
            for cx in 2..22 {
                let c = CellCoord { x: cx, y: cy };
                let (mut a, mut b) = ([(0u16, 0f64); 16], [(0u16, 0f64); 16]);
                let na = s.conditional(&mut st, &map, c, &mut a);
                let nb = r.conditional(&st, c, &mut b);
                assert_eq!(na, nb);
                for (x, y) in a[..na].iter().zip(&b[..nb]) {
                    assert_eq!(x.0, y.0);
                    worst = worst.max((x.1 - y.1).abs());
                }
            }
        }
    }
    eprintln!("worst conditional probability difference: {worst:.5}");
    // Quarter-cell distance quantisation and Q16 weights: stated tolerance 0.02.
    assert!(worst < 0.02, "worst {worst}");
}

#[test]
fn fixed_point_marginals_match_f64_reference_sampler() {
    let (g, mut st, map) = two_d();
    let fm = ForwardModel::gaussian(3.0, 0.01, 20.0).unwrap();
    let model = ReferenceModel::Gaussian {
        sigma: 3.0,
        w: 0.01,
        max_range: 20.0,
    };
    let cfg = SamplerConfig {
        seed: 3,
        burn_in_sweeps: 20,
        ..SamplerConfig::default()
    };
    let mut s = sampler(g, ShapesPrior, fm, cfg);
    s.reset(&map, &mut st).unwrap();
    let sweep = (g.len() as u32).div_ceil(9);
    s.step(&mut st, &map, sweep * 1020);
    let (mut sample, mut counts) = (vec![0u8; g.len()], vec![0u64; g.len()]);
    let mut r = ReferenceGibbs::new(
        g,
        ShapesPrior,
        model,
        0.001,
        &map,
        cfg.init_threshold, // both chains start from the same thresholded map
        &mut sample,
        &mut counts,
        9,
    )
    .unwrap();
    for i in 0..1020 {
        r.sweep(&st, i >= 20);
    }
    let mut sum = 0.0;
    let mut worst = 0f64;
    for i in 0..g.len() {
        let d = (f64::from(s.marginal(i).unwrap()) - r.marginal(i).unwrap()).abs();
        sum += d;
        worst = worst.max(d);
    }
    let mean = sum / g.len() as f64;
    eprintln!("marginals: mean |Δ| {mean:.4}, worst {worst:.4}");
    assert!(mean < 0.02 && worst < 0.15, "mean {mean} worst {worst}");
}
