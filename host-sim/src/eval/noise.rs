//! The range sensor's noise, estimated from the data itself rather than hand-set: the forward
//! model's σ and outlier rate, and through σ the weight of free evidence
//! (`ogm_core::config::noise::free_evidence_q8`).
//!
//! For every hit of a sample of the scans, look along the beam within ±[`WINDOW_CELLS`] of the
//! measured range for the cell the log-odds map (built from the same scans) believes most
//! occupied; the residual is the measured range minus that cell's distance along the beam.
//! Walls are where many beams agree, so the residuals of a sensor with Gaussian noise σ spread
//! like N(0, σ²) plus the half-cell quantisation; outliers (glass, people, beams grazing a
//! corner) land anywhere. σ = 1.4826 · MAD of the residuals (robust to those outliers), minus
//! the quantisation in quadrature; the outlier rate is the share of hits more than 3σ from the
//! median or with no occupied cell in the window.
//!
//! The robot's settings read a calibrated pair instead ([`NoiseEstimate::sensor`]): σ from a
//! Gaussian + uniform mixture fitted to the residuals ([`mixture`]: the MAD is its start; the MAD
//! itself reads too high under noise or outliers, e.g. 1.45 for a true 1.0), and τ, the share
//! of hits that support no surface near their end: the unmatched ones plus the mixture's
//! uniform share of the rest. τ is not the sensor's outlier rate: on sparse data (few scans see
//! a given wall) most of it is hits no other scan corroborates, which dilute a wall's evidence
//! just the same.

use ogm_core::{Beam, GridGeometry, LogOdds, Pose, Range};
use serde::{Deserialize, Serialize};

use crate::sim::explore::ScanRecord;

/// Half-width of the search window along a beam, cells.
pub const WINDOW_CELLS: f64 = 12.0;

/// At most this many hits are examined (scans are sampled evenly).
pub const MAX_HITS: usize = 200_000;

/// The estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NoiseEstimate {
    /// Range noise standard deviation, cells.
    pub sigma_cells: f64,
    /// Share of hits that are outliers.
    pub outlier_rate: f64,
    /// Hits examined.
    pub hits: usize,
    /// σ (cells) of the Gaussian + uniform mixture fitted to the matched residuals
    /// ([`mixture`]): calibrated past the MAD's 50 % breakdown.
    #[serde(default)]
    pub sigma_mixture: f64,
    /// The mixture's uniform share among the matched hits.
    #[serde(default)]
    pub outlier_mixture: f64,
    /// Share of the examined hits with no occupied cell in the window (mostly sparse data: no
    /// other scan saw that surface); `outlier_rate` counts them too.
    #[serde(default)]
    pub unmatched: f64,
    /// Hits the sensor's σ was estimated from when it came from more scans than these
    /// ([`estimate_with_sensor`]: all the log's); 0 when from these scans.
    #[serde(default)]
    pub sensor_hits: usize,
}

impl NoiseEstimate {
    /// What the robot's settings read (`RunConfig::with_sensor`): the mixture's σ (at least
    /// [`MIN_SIGMA_CELLS`]) and τ = unmatched + (1 − unmatched)·ε, the share of hits that
    /// support no surface near their end.
    pub fn sensor(&self) -> (f64, f64) {
        let tau = self.unmatched + (1.0 - self.unmatched) * self.outlier_mixture;
        (
            self.sigma_mixture.max(MIN_SIGMA_CELLS),
            if tau.is_finite() {
                tau.clamp(0.0, 1.0)
            } else {
                0.0
            },
        )
    }
}

/// The smallest σ (cells) an estimate hands on: below it a cell is far wider than the noise
/// and every setting is the textbook one anyway.
pub const MIN_SIGMA_CELLS: f64 = 0.25;

/// Fits `(1 − ε)·N(μ, σ² + q) + ε·U(−W, W)` (`q` the search's quantisation variance, W =
/// [`WINDOW_CELLS`]) to `residuals` (sorted) by EM from the robust start (their median, `sigma0`,
/// ε = 0.1); returns `(σ, ε)`. The uniform term takes the outliers the MAD cannot ignore once
/// they are many (its breakdown is 50 %), so σ stays the Gaussian's.
pub fn mixture(residuals: &[f64], sigma0: f64, quant: f64) -> (f64, f64) {
    let (var, eps) = fit(residuals, sigma0 * sigma0 + quant, quant, true);
    ((var - quant).max(0.0).sqrt().max(0.05), eps)
}

/// The uniform share ε of the same mixture with σ held at `sigma` (μ and ε fitted).
pub fn mixture_share(residuals: &[f64], sigma: f64, quant: f64) -> f64 {
    fit(residuals, sigma * sigma + quant, quant, false).1
}

/// EM for the mixture from variance `var0` (fitted too if `fit_var`); returns `(variance, ε)`.
fn fit(residuals: &[f64], var0: f64, quant: f64, fit_var: bool) -> (f64, f64) {
    let Some(&mid) = residuals.get(residuals.len() / 2) else {
        return (var0, 0.0);
    };
    let n = residuals.len() as f64;
    let (mut mu, mut var, mut eps) = (mid, var0, 0.1f64);
    let u = 1.0 / (2.0 * WINDOW_CELLS);
    // The Gaussian's responsibility for residual `r`.
    let resp = |r: f64, mu: f64, var: f64, eps: f64| {
        let g = (1.0 - eps) * (-(r - mu).powi(2) / (2.0 * var)).exp()
            / (2.0 * std::f64::consts::PI * var).sqrt();
        g / (g + eps * u)
    };
    for _ in 0..200 {
        let (mut sw, mut swr) = (0.0, 0.0);
        for &r in residuals {
            let w = resp(r, mu, var, eps);
            sw += w;
            swr += w * r;
        }
        if sw <= 0.0 {
            break;
        }
        let mu1 = swr / sw;
        let var1 = if fit_var {
            let swr2: f64 = residuals
                .iter()
                .map(|&r| resp(r, mu, var, eps) * (r - mu1).powi(2))
                .sum();
            (swr2 / sw).max(quant + 1e-4)
        } else {
            var
        };
        let eps1 = (1.0 - sw / n).clamp(1e-4, 0.999);
        // With σ held, μ must settle too.
        let done = (var1 - var).abs() < 1e-6
            && (eps1 - eps).abs() < 1e-6
            && (fit_var || (mu1 - mu).abs() < 1e-6);
        (mu, var, eps) = (mu1, var1, eps1);
        if done {
            break;
        }
    }
    (var, eps)
}

/// The median of sorted absolute deviations that come in half-cell steps (the search's), read
/// as grouped data: the step holding the middle value is spread evenly over its ±¼-cell bin
/// (the first, 0, over [0, ¼]) and the median interpolated in it. Without this the MAD, and σ
/// with it, jumps between 0.5, 1, 1.5 ... cells (σ 0.67, 1.45, 2.20 ...): "a little more noise
/// than the shared logs" read as twice theirs.
fn grouped_median(dev: &[f64]) -> f64 {
    let n = dev.len();
    let Some(&m) = dev.get(n / 2) else {
        return 0.0;
    };
    let below = dev.partition_point(|&d| d < m - 0.125);
    let upto = dev.partition_point(|&d| d <= m + 0.125);
    let in_bin = upto.saturating_sub(below).max(1) as f64;
    let (lo, width) = if m < 0.125 {
        (0.0, 0.25)
    } else {
        (m - 0.25, 0.5)
    };
    lo + width * ((n as f64 / 2.0 - below as f64) / in_bin).clamp(0.0, 1.0)
}

/// Estimates the noise of the scans `scans` from `map`, their log-odds map over `g` built with
/// `mapper` (whose occupied increment is taken back out of each beam's own end cell); `None` if
/// fewer than 100 hits have an occupied cell near them.
pub fn estimate(
    g: &GridGeometry,
    mapper: &ogm_core::MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
) -> Option<NoiseEstimate> {
    let (residuals, missing) = residuals(g, mapper, scans, map);
    if residuals.len() < 100 {
        return None;
    }
    let median = residuals[residuals.len() / 2];
    let mut dev: Vec<f64> = residuals.iter().map(|r| (r - median).abs()).collect();
    dev.sort_by(f64::total_cmp);
    let mad = grouped_median(&dev);
    let sigma = ((1.4826 * mad).powi(2) - QUANT).max(0.0).sqrt().max(0.05);
    let (sigma_mixture, outlier_mixture) = mixture(&residuals, sigma, QUANT);
    Some(NoiseEstimate {
        sigma_cells: sigma,
        sigma_mixture,
        ..shares(&residuals, missing, sigma, outlier_mixture)
    })
}

/// The noise of `scans` (a selection, e.g. an experiment's every 10th scan) with the sensor's σ
/// taken from `sensor`, an estimate over all the scans the sensor produced: σ is the sensor's,
/// while how many hits support a surface (the unmatched share, the mixture's uniform share ε,
/// refitted with σ held) is this selection's. A selection of a few dozen scans sees most walls
/// once, and its own mixture fit then reads anything from a third to twice the sensor's σ (from
/// 0.9 to 3.5 cells on three perturbations of one log with the same added noise), while the
/// whole log's reads it within a few percent. `None` only if no hit was examined.
pub fn estimate_with_sensor(
    g: &GridGeometry,
    mapper: &ogm_core::MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    sensor: &NoiseEstimate,
) -> Option<NoiseEstimate> {
    let (residuals, missing) = residuals(g, mapper, scans, map);
    if residuals.is_empty() && missing == 0 {
        return None;
    }
    // Too few matched hits to fit ε: the sensor's.
    let eps = if residuals.len() < 100 {
        sensor.outlier_mixture
    } else {
        mixture_share(&residuals, sensor.sigma_mixture, QUANT)
    };
    Some(NoiseEstimate {
        sigma_cells: sensor.sigma_cells,
        sigma_mixture: sensor.sigma_mixture,
        sensor_hits: sensor.hits,
        ..shares(&residuals, missing, sensor.sigma_cells, eps)
    })
}

/// The search quantises a residual to half a cell (uniform: variance 1/48), and a wall cell is
/// one cell deep (uniform over it: 1/12).
const QUANT: f64 = 1.0 / 48.0 + 1.0 / 12.0;

/// The shares of an estimate (σ left 0): outliers by the 3σ rule, the mixture's `eps`, unmatched.
fn shares(residuals: &[f64], missing: usize, sigma: f64, eps: f64) -> NoiseEstimate {
    let median = residuals.get(residuals.len() / 2).copied().unwrap_or(0.0);
    let far = residuals
        .iter()
        .filter(|r| (*r - median).abs() > 3.0 * sigma.max(0.5))
        .count();
    let n = (residuals.len() + missing).max(1);
    NoiseEstimate {
        outlier_rate: (far + missing) as f64 / n as f64,
        hits: residuals.len() + missing,
        outlier_mixture: eps,
        unmatched: missing as f64 / n as f64,
        ..NoiseEstimate::default()
    }
}

/// The residuals (sorted) of a sample of at most [`MAX_HITS`] hits of `scans`, and how many
/// sampled hits had no occupied cell in the window.
fn residuals(
    g: &GridGeometry,
    mapper: &ogm_core::MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
) -> (Vec<f64>, usize) {
    let occ_increment = i32::from(mapper.model.occ_increment().raw());
    let cell = f64::from(g.cell_mm());
    let hits_total: usize = scans
        .iter()
        .map(|s| {
            s.beams
                .iter()
                .filter(|b| matches!(b.range, Range::Hit(_)))
                .count()
        })
        .sum();
    let stride = hits_total.div_ceil(MAX_HITS).max(1);
    let mut residuals = Vec::new();
    let mut missing = 0usize;
    let mut k = 0usize;
    for s in scans {
        for b in &s.beams {
            let Range::Hit(mm) = b.range else { continue };
            k += 1;
            if k % stride != 0 {
                continue;
            }
            match residual(g, map, occ_increment, &s.pose, b, f64::from(mm) / cell) {
                Some(r) => residuals.push(r),
                None => missing += 1,
            }
        }
    }
    residuals.sort_by(f64::total_cmp);
    (residuals, missing)
}

/// Measured range (cells) minus the distance of the most occupied cell within the window.
fn residual(
    g: &GridGeometry,
    map: &[LogOdds],
    occ_increment: i32,
    pose: &Pose,
    b: &Beam,
    z: f64,
) -> Option<f64> {
    let cell = f64::from(g.cell_mm());
    let (ox, oy) = (
        f64::from(g.origin_mm().0) / cell,
        f64::from(g.origin_mm().1) / cell,
    );
    let (px, py) = (
        f64::from(pose.x_mm) / cell - ox,
        f64::from(pose.y_mm) / cell - oy,
    );
    let th = pose.heading.wrapping_add(b.angle).to_radians();
    let (c, s) = (th.cos(), th.sin());
    let (w, h) = (i64::from(g.width()), i64::from(g.height()));
    let mut best: Option<(i32, f64)> = None;
    let end = ((px + z * c).floor() as i64, (py + z * s).floor() as i64);
    let mut t = (z - WINDOW_CELLS).max(0.5);
    while t <= z + WINDOW_CELLS {
        let (x, y) = ((px + t * c).floor() as i64, (py + t * s).floor() as i64);
        if (0..w).contains(&x) && (0..h).contains(&y) {
            let mut l = i32::from(map[(y * w + x) as usize].raw());
            if (x, y) == end {
                // Leave this beam's own hit out: it would pull the estimate to itself.
                l -= occ_increment;
            }
            // Most occupied; on ties the one nearest the measurement.
            let better = match best {
                None => l > 0,
                Some((bl, bt)) => l > bl || (l == bl && (t - z).abs() < (bt - z).abs()),
            };
            if better {
                best = Some((l, t));
            }
        }
        t += 0.5;
    }
    best.map(|(_, t)| z - t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimConfig};

    /// A 200 × 200-cell simulated building (seed 3).
    fn test_world() -> ogm_field::world::World {
        crate::sim::generate::generate(
            &crate::sim::generate::GenParams {
                width: 200,
                height: 200,
                ..Default::default()
            },
            3,
        )
    }

    #[test]
    fn recovers_the_simulated_lidars_noise() {
        let world = test_world();
        for sigma in [0.5, 1.5, 3.0] {
            let mut cfg = SimConfig::default();
            cfg.lidar.sigma_cells = sigma;
            let run = simulate(&world, &cfg, 3).unwrap();
            let e = estimate(&run.geometry, &run.mapper_config, &run.scans, &run.map).unwrap();
            eprintln!("σ = {sigma}: estimated {e:?}");
            assert!(
                (e.sigma_cells - sigma).abs() < 0.35 * sigma + 0.3,
                "σ = {sigma}: estimated {e:?}"
            );
            // The same bound: below a cell both read the simulator's own discretisation too
            // (0.92 for σ = 0.5).
            assert!(
                (e.sigma_mixture - sigma).abs() < 0.35 * sigma + 0.3,
                "σ = {sigma}: estimated {e:?}"
            );
        }
    }

    /// The mixture recovers σ and the uniform share where the MAD is pulled up by outliers.
    #[test]
    fn mixture_separates_noise_from_outliers() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal, Uniform};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let uniform = Uniform::new(-WINDOW_CELLS, WINDOW_CELLS).unwrap();
        for (sigma, eps) in [(0.5, 0.1), (1.0, 0.4), (2.0, 0.6)] {
            let mut r: Vec<f64> = (0..20_000)
                .map(|k| {
                    if f64::from(k % 100) < eps * 100.0 {
                        uniform.sample(&mut rng)
                    } else {
                        sigma * normal.sample(&mut rng)
                    }
                })
                .collect();
            r.sort_by(f64::total_cmp);
            let mad = {
                let mut d: Vec<f64> = r.iter().map(|x| x.abs()).collect();
                d.sort_by(f64::total_cmp);
                d[d.len() / 2] * 1.4826
            };
            let (s, e) = mixture(&r, mad, 0.0);
            assert!(
                (s - sigma).abs() < 0.05 * sigma,
                "σ {sigma}: {s} (MAD {mad})"
            );
            assert!((e - eps).abs() < 0.02, "ε {eps}: {e}");
        }
        assert_eq!(mixture(&[], 0.7, 0.1), (0.7, 0.0));
    }

    /// With σ held at the truth, the refit recovers the uniform share alone.
    #[test]
    fn mixture_share_fits_the_outliers_at_a_given_sigma() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal, Uniform};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
        let normal = Normal::new(0.3, 1.5).unwrap();
        let uniform = Uniform::new(-WINDOW_CELLS, WINDOW_CELLS).unwrap();
        let mut r: Vec<f64> = (0..20_000)
            .map(|k| {
                if k % 10 < 6 {
                    uniform.sample(&mut rng)
                } else {
                    normal.sample(&mut rng)
                }
            })
            .collect();
        r.sort_by(f64::total_cmp);
        let eps = mixture_share(&r, 1.5, 0.0);
        assert!((eps - 0.6).abs() < 0.02, "ε 0.6: {eps}");
        // A σ far too small takes most of the Gaussian's hits for outliers.
        assert!(mixture_share(&r, 0.3, 0.0) > 0.7);
        assert_eq!(mixture_share(&[], 1.0, 0.1), 0.0);
    }

    /// A selection of a few scans takes σ from the sensor's estimate and its shares from itself.
    #[test]
    fn a_selection_takes_the_sensors_sigma() {
        let world = test_world();
        let mut cfg = SimConfig::default();
        cfg.lidar.sigma_cells = 1.5;
        let run = simulate(&world, &cfg, 3).unwrap();
        let all = estimate(&run.geometry, &run.mapper_config, &run.scans, &run.map).unwrap();
        let few: Vec<ScanRecord> = run.scans.iter().step_by(10).cloned().collect();
        let map = crate::eval::log_setup::map_scans(run.geometry, run.mapper_config, &few)
            .unwrap()
            .map;
        let e = estimate_with_sensor(&run.geometry, &run.mapper_config, &few, &map, &all).unwrap();
        assert_eq!(
            (e.sigma_cells, e.sigma_mixture, e.sensor_hits),
            (all.sigma_cells, all.sigma_mixture, all.hits)
        );
        assert!(e.hits > 0 && e.hits < all.hits, "{e:?} {all:?}");
        // Fewer scans corroborate each other less.
        assert!(e.unmatched >= all.unmatched, "{e:?} {all:?}");
        assert!((0.0..=1.0).contains(&e.outlier_mixture));
    }

    /// The grouped median interpolates within the half-cell step that holds the middle value.
    #[test]
    fn grouped_median_is_not_quantised() {
        // 60 % zeros, 40 % half-cells: the plain median is 0, the grouped one 5/6 of ¼.
        let mut d = vec![0.0; 60];
        d.extend([0.5; 40]);
        assert!((grouped_median(&d) - 0.25 * 50.0 / 60.0).abs() < 1e-12);
        // A third each of 0, ½ and 1: the middle step is ½, read as its bin [¼, ¾] halfway.
        let mut d = vec![0.0; 30];
        d.extend([0.5; 30]);
        d.extend([1.0; 30]);
        assert!((grouped_median(&d) - 0.5).abs() < 1e-12);
        assert_eq!(grouped_median(&[]), 0.0);
    }

    #[test]
    fn tau_joins_unmatched_and_outliers() {
        let e = NoiseEstimate {
            sigma_mixture: 0.1,
            outlier_mixture: 0.2,
            unmatched: 0.5,
            ..NoiseEstimate::default()
        };
        let (s, t) = e.sensor();
        assert_eq!(s, MIN_SIGMA_CELLS);
        assert!((t - 0.6).abs() < 1e-12);
    }
}
