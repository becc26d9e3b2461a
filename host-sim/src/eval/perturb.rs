//! Seeded perturbations of a recorded log (`eval-log --add-noise-cells / --add-outliers /
//! --thin / --perturb-seed`): what a noisier or sparser sensor, or a busier building, would
//! have recorded along the same poses. The benchmark of `eval-log` is still made from the
//! unperturbed log; only the experiments read the perturbed scans.
//!
//! Applied to each scan in this order:
//! 1. **Thinning** (`thin = K`): keep every K-th beam (the first, the (K+1)-th, ...).
//! 2. **Range noise** (`noise_cells = S`): every hit's range gets N(0, (S · cell)²) added
//!    (at least 1 mm; a reading pushed to or past the sensor's range stays a hit there, which
//!    the mapper treats as a no-return up to its range, as it does a real far reading).
//! 3. **Outliers** (`outliers = P`): each hit is, with probability P, replaced by an outlier
//!    drawn from this mix (the kinds a lidar in a building sees):
//!    * [`SHORT_SHARE`] (80 %): **short** — something between the sensor and the wall (people,
//!      chairs, clutter): uniform between [`MIN_OUTLIER_MM`] and the true range;
//!    * [`FAR_SHARE`] (10 %): **far** — the beam went through (glass, an open door) and hit
//!      something further: uniform between the true range and the sensor's maximum range;
//!    * the rest (10 %): **no return** — glass or a black surface that returns nothing.
//!
//! No-return beams are left as they are (noise and outliers are drawn for hits only). Every
//! draw comes from one `Xoshiro256PlusPlus` stream seeded with `seed` and walked scan by scan,
//! beam by beam: the same seed and log give the same perturbed scans, and a scan is perturbed
//! the same way whichever experiment later selects it.

use ogm_core::{Beam, Range};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use crate::sim::explore::ScanRecord;

/// Share of outliers that are short readings (people, clutter).
pub const SHORT_SHARE: f64 = 0.8;
/// Share of outliers that are readings past the true surface (glass, open doors).
pub const FAR_SHARE: f64 = 0.1;
/// Share of outliers that are no-returns (glass, black surfaces).
pub const NO_RETURN_SHARE: f64 = 1.0 - SHORT_SHARE - FAR_SHARE;
/// Nearest a short outlier reads, mm.
pub const MIN_OUTLIER_MM: u32 = 100;

/// `eval-log`'s perturbation options.
#[derive(clap::Args, Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PerturbArgs {
    /// Add Gaussian range noise of this standard deviation (cells) to every hit of the
    /// experiments' scans (the benchmark is made from the unperturbed log).
    #[arg(long, default_value_t = 0.0)]
    pub add_noise_cells: f64,
    /// Replace this fraction (0..1) of the experiments' hits by outliers: 80 % short (uniform
    /// between 0.1 m and the true range), 10 % past the surface (uniform up to the sensor's
    /// range), 10 % no-returns.
    #[arg(long, default_value_t = 0.0)]
    pub add_outliers: f64,
    /// Keep every K-th beam of the experiments' scans (1 = all).
    #[arg(long, default_value_t = 1)]
    pub thin: usize,
    /// Seed of the perturbation.
    #[arg(long, default_value_t = 1)]
    pub perturb_seed: u64,
}

impl PerturbArgs {
    /// Whether these options change anything.
    pub fn is_active(&self) -> bool {
        self.add_noise_cells > 0.0 || self.add_outliers > 0.0 || self.thin > 1
    }

    /// Checks the ranges of the options.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.add_noise_cells.is_finite() && (0.0..=1000.0).contains(&self.add_noise_cells),
            "--add-noise-cells must be a number of cells from 0 to 1000, not {}",
            self.add_noise_cells
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.add_outliers),
            "--add-outliers must be a fraction from 0 to 1, not {}",
            self.add_outliers
        );
        anyhow::ensure!(
            self.thin >= 1,
            "--thin must be 1 or more, not {}",
            self.thin
        );
        Ok(())
    }
}

/// What a perturbation did (for the report).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PerturbStats {
    /// The options.
    pub args: PerturbArgs,
    /// Beams kept after thinning.
    pub beams: usize,
    /// Hits among them (before outliers).
    pub hits: usize,
    /// Hits replaced by short outliers.
    pub short: usize,
    /// Hits replaced by far outliers.
    pub far: usize,
    /// Hits replaced by no-returns.
    pub no_return: usize,
}

/// `scans` perturbed by `args` on a grid of `cell_mm` cells for a sensor of range
/// `max_range_mm` (see the module docs).
pub fn perturb(
    scans: &[ScanRecord],
    args: &PerturbArgs,
    cell_mm: u32,
    max_range_mm: u32,
) -> (Vec<ScanRecord>, PerturbStats) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(args.perturb_seed);
    let sd = args.add_noise_cells.max(0.0) * f64::from(cell_mm);
    let noise = Normal::new(0.0, sd).ok();
    let p = args.add_outliers.clamp(0.0, 1.0);
    let mut st = PerturbStats {
        args: *args,
        ..PerturbStats::default()
    };
    let out = scans
        .iter()
        .map(|s| {
            let beams: Vec<Beam> = s
                .beams
                .iter()
                .step_by(args.thin.max(1))
                .map(|b| {
                    st.beams += 1;
                    let Range::Hit(mm) = b.range else { return *b };
                    st.hits += 1;
                    let mut r = f64::from(mm);
                    if let (Some(n), true) = (&noise, sd > 0.0) {
                        r += n.sample(&mut rng);
                    }
                    let mut range = Range::Hit(r.round().clamp(1.0, f64::from(u32::MAX)) as u32);
                    if p > 0.0 && rng.random::<f64>() < p {
                        let u: f64 = rng.random();
                        let v: f64 = rng.random();
                        let truth = f64::from(mm);
                        range = if u < SHORT_SHARE {
                            st.short += 1;
                            let lo = f64::from(MIN_OUTLIER_MM).min(truth);
                            Range::Hit((lo + v * (truth - lo)).round().max(1.0) as u32)
                        } else if u < SHORT_SHARE + FAR_SHARE {
                            st.far += 1;
                            let hi = f64::from(max_range_mm).max(truth);
                            Range::Hit((truth + v * (hi - truth)).round().max(1.0) as u32)
                        } else {
                            st.no_return += 1;
                            Range::NoReturn
                        };
                    }
                    Beam {
                        angle: b.angle,
                        range,
                    }
                })
                .collect();
            ScanRecord {
                pose: s.pose,
                beams,
            }
        })
        .collect();
    (out, st)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::{Angle, Pose};

    fn log(scans: usize, beams: usize) -> Vec<ScanRecord> {
        (0..scans)
            .map(|i| ScanRecord {
                pose: Pose {
                    x_mm: i as i32 * 10,
                    y_mm: 0,
                    heading: Angle(0),
                },
                beams: (0..beams)
                    .map(|k| Beam {
                        angle: Angle((k * 100) as u16),
                        range: if k % 10 == 9 {
                            Range::NoReturn
                        } else {
                            Range::Hit(5000)
                        },
                    })
                    .collect(),
            })
            .collect()
    }

    fn args(noise: f64, outliers: f64, thin: usize, seed: u64) -> PerturbArgs {
        PerturbArgs {
            add_noise_cells: noise,
            add_outliers: outliers,
            thin,
            perturb_seed: seed,
        }
    }

    #[test]
    fn nothing_asked_nothing_changed() {
        let l = log(20, 50);
        let (p, st) = perturb(&l, &PerturbArgs::default(), 50, 20_000);
        assert_eq!(p, l);
        assert_eq!(st.short + st.far + st.no_return, 0);
        assert!(!PerturbArgs::default().is_active());
    }

    #[test]
    fn deterministic_for_a_seed_and_different_across_seeds() {
        let l = log(50, 100);
        let a = args(1.5, 0.3, 1, 7);
        assert_eq!(perturb(&l, &a, 50, 20_000), perturb(&l, &a, 50, 20_000));
        let b = args(1.5, 0.3, 1, 8);
        assert_ne!(perturb(&l, &a, 50, 20_000).0, perturb(&l, &b, 50, 20_000).0);
    }

    #[test]
    fn noise_has_the_asked_spread() {
        let l = log(200, 100);
        let (p, st) = perturb(&l, &args(2.0, 0.0, 1, 3), 50, 20_000);
        let r: Vec<f64> = p
            .iter()
            .flat_map(|s| &s.beams)
            .filter_map(|b| match b.range {
                Range::Hit(mm) => Some(f64::from(mm) - 5000.0),
                Range::NoReturn => None,
            })
            .collect();
        assert_eq!(r.len(), st.hits);
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let sd = (r.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
        assert!(mean.abs() < 2.0, "mean {mean}");
        assert!(
            (sd - 100.0).abs() < 3.0,
            "sd {sd} mm, asked 2 cells of 50 mm"
        );
    }

    #[test]
    fn outliers_at_the_asked_rate_and_mix() {
        let l = log(400, 100);
        for rate in [0.2, 0.6] {
            let (p, st) = perturb(&l, &args(0.0, rate, 1, 11), 50, 20_000);
            let n = st.hits as f64;
            let got = (st.short + st.far + st.no_return) as f64 / n;
            assert!((got - rate).abs() < 0.01, "rate {got} for {rate}");
            let out = (st.short + st.far + st.no_return) as f64;
            assert!((st.short as f64 / out - SHORT_SHARE).abs() < 0.02);
            assert!((st.far as f64 / out - FAR_SHARE).abs() < 0.02);
            // Short ones before the surface, far ones past it, within the sensor's range.
            let (mut short, mut far, mut none) = (0, 0, 0);
            for (s, o) in p.iter().zip(&l) {
                for (b, t) in s.beams.iter().zip(&o.beams) {
                    match (b.range, t.range) {
                        (Range::Hit(m), Range::Hit(_)) if m < 5000 => {
                            assert!(m >= MIN_OUTLIER_MM);
                            short += 1;
                        }
                        (Range::Hit(m), Range::Hit(_)) if m > 5000 => {
                            assert!(m <= 20_000);
                            far += 1;
                        }
                        (Range::NoReturn, Range::Hit(_)) => none += 1,
                        _ => {}
                    }
                }
            }
            // Exactly 5000 only if a draw hit it: at most a handful.
            assert!((short as i64 - st.short as i64).abs() <= 2);
            assert!((far as i64 - st.far as i64).abs() <= 2);
            assert_eq!(none, st.no_return);
        }
    }

    #[test]
    fn bad_options_are_errors() {
        assert!(args(0.0, 0.0, 1, 1).validate().is_ok());
        assert!(args(3.0, 1.0, 4, 1).validate().is_ok());
        for bad in [
            args(-1.0, 0.0, 1, 1),
            args(f64::NAN, 0.0, 1, 1),
            args(f64::INFINITY, 0.0, 1, 1),
            args(0.0, 1.5, 1, 1),
            args(0.0, -0.1, 1, 1),
            args(0.0, f64::NAN, 1, 1),
            args(0.0, 0.0, 0, 1),
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.starts_with("--"), "{e}");
        }
    }

    #[test]
    fn thinning_keeps_every_kth_beam() {
        let l = log(3, 100);
        let (p, st) = perturb(&l, &args(0.0, 0.0, 3, 1), 50, 20_000);
        assert_eq!(st.beams, 3 * 34);
        for (s, o) in p.iter().zip(&l) {
            let want: Vec<Beam> = o.beams.iter().step_by(3).copied().collect();
            assert_eq!(s.beams, want);
        }
    }
}
