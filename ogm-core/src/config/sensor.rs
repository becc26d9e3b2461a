//! The robot's settings for a range sensor of given noise, as continuous functions of it:
//! [`RunConfig::with_sensor`] (σ and the share of hits that carry no evidence, both estimated
//! from the robot's own data by the host) and the helpers it is made of.
//!
//! One model at every σ, no switch: the face band's width grows from 0 (the textbook end cell,
//! where a cell is wider than the noise) to σ itself at the paper's σ = 3 cells, and the
//! evidence gain falls smoothly as σ grows. The previous law ([`RunConfig::with_noise_matched`])
//! switched the band on at σ ≈ 1.1 cells and the gain from 1 396 to 256 with it, which cost
//! real data with a little more noise than the shared logs' up to 0.08 of max F1
//! (docs/results.md, "Robustness").

use super::noise::MAX_GAIN_Q8;
use super::RunConfig;
use crate::error::{Error, Result};

/// The σ (cells) from which the face band takes the sensor's whole σ and no far edge: the
/// simulated LD06's, where the band was measured (docs/results.md, "Face band") and the
/// firmware's default runs ([`RunConfig::ROBOT`]).
pub const FULL_BAND_SIGMA: f64 = 3.0;

/// Largest share of hits without evidence [`RunConfig::with_sensor`] corrects for: beyond it
/// the gain would pass 10× what the hits alone say.
pub const MAX_OUTLIER_SHARE: f64 = 0.9;

/// The textbook model's face ratio r(σ) = P(a reading ends in a wall's face cell) / P(it passes
/// it) for Gaussian range noise of `sigma` cells (`free_evidence_q8` is its clamp at 1, in
/// Q8): above 1 the face cell reads occupied in expectation, below 1 free. 1.08 at σ = 1.1,
/// 0.74 at 1.45, 0.49 at 2, 0.31 at 3. Infinite for σ not positive and finite.
pub fn face_ratio(sigma: f64) -> f64 {
    if !(sigma.is_finite() && sigma > 0.0) {
        return f64::INFINITY;
    }
    let x = 0.5 / (sigma * core::f64::consts::SQRT_2);
    let (hit, pass) = (libm::erf(x), 0.5 * libm::erfc(x));
    if pass > 0.0 {
        hit / pass
    } else {
        f64::INFINITY
    }
}

/// The face band's share of the sensor's σ, w(σ) = (1 − r(σ)) / (1 − r(3)) clamped to [0, 1]
/// (r = [`face_ratio`]): how wrong-signed the textbook face cell is, relative to the simulated
/// LD06's. 0 wherever the textbook face cell reads occupied in expectation (σ ≤ 1.07 cells),
/// 1 from [`FULL_BAND_SIGMA`] on, continuous and increasing in between.
pub fn band_share(sigma: f64) -> f64 {
    let r = face_ratio(sigma);
    if !r.is_finite() {
        return 0.0;
    }
    ((1.0 - r) / (1.0 - face_ratio(FULL_BAND_SIGMA))).clamp(0.0, 1.0)
}

/// The face band's σ (cells) for a sensor of range noise `sigma` cells: w(σ)·σ
/// ([`band_share`]). 0 (no band: the textbook model) up to 1.07 cells, 0.54 at 1.45, 1.47
/// at 2, σ itself from 3 on; increasing and continuous.
pub fn band_sigma(sigma: f64) -> f64 {
    let w = band_share(sigma);
    if w > 0.0 {
        w * sigma
    } else {
        0.0
    }
}

/// The far edge's share (Q8) of the face band of a sensor of range noise `sigma` cells:
/// 256·(1 − w(σ)) ([`band_share`]; `InverseSensorModel::with_far_edge`). A band narrower than
/// a cell must be evaluated at the cells' far edges to become the textbook model in its limit
/// (at the sample point it gives the reading's cell only Φ(1.5) of the occupied update and a
/// wall's face reads free: −0.03…−0.07 of max F1 at σ ≈ 1.3 on the shared logs); a band of
/// several cells is right at the sample point (on the simulated maps, whose faces lie on cell
/// boundaries, the full far edge costs 0.013-0.019 at σ = 3). 0 from [`FULL_BAND_SIGMA`] on.
pub fn far_edge_q8(sigma: f64) -> u16 {
    libm::round(256.0 * (1.0 - band_share(sigma))).clamp(0.0, 256.0) as u16
}

/// The evidence gain (Q8) for a sensor of range noise `sigma` cells: 256·(3/σ)^{3/2}, clamped
/// to 256 ..= [`MAX_GAIN_Q8`]: 256 at the simulated LD06's σ = 3 (the firmware's default),
/// ≈ 2 400 at σ = 0.67. Why it falls with σ: a noisy hit's support spreads over about σ cells,
/// so each cell's log-odds say less, and where they are strong the data must win over the
/// prior. Why 3/2 and not the earlier 1 (on the simulation only): the real logs with added
/// noise want gains of 1 024-2 048 at σ = 2-3 while the simulation wants 256-512 at 3; the
/// exponent is the simplest law that keeps σ = 3 at 256 and the shared logs' σ ≈ 0.5-0.8
/// above 2 048, where every gain scores the same (docs/results.md).
pub fn sensor_gain_q8(sigma: f64) -> u16 {
    if !(sigma.is_finite() && sigma > 0.0) {
        return 256;
    }
    let g = 256.0 * libm::pow(FULL_BAND_SIGMA / sigma, 1.5);
    libm::round(g.clamp(256.0, f64::from(MAX_GAIN_Q8))) as u16
}

impl RunConfig {
    /// These settings with the robot's mapper and evidence for a range sensor whose noise is
    /// `sigma_cells` (Gaussian σ, cells) and of whose hits a share `outlier_share` (0 ..= 1)
    /// supports no surface near its end (outliers, and hits no other scan corroborates), both
    /// as the host estimates them from the robot's data. Continuous in both, no switch:
    ///
    /// * the face band of σ_b = [`band_sigma`] (none below 1.07 cells: the textbook end cell),
    ///   `sigma_milli_cells` holding σ_b where there is a band (the evidence data term reads no
    ///   forward model), else σ; its far edge is [`RunConfig::band_far_edge_q8`];
    /// * the textbook free update in the mapper and the evidence (the band handles faces);
    /// * the evidence gain [`sensor_gain_q8`] / (1 − min(τ, [`MAX_OUTLIER_SHARE`])),
    ///   clamped to [`MAX_GAIN_Q8`]: a wall's evidence accrues from the hits that land on it,
    ///   so when a share τ of the hits carries none its evidence relative to the prior is
    ///   diluted by 1 − τ, and the gain restores it.
    ///
    /// At σ = 3 cells and τ = 0: exactly [`RunConfig::ROBOT`] (tested). Everything else is kept.
    /// [`Error::InvalidModel`] if `sigma_cells` is not positive and finite or `outlier_share` not
    /// within 0 ..= 1.
    pub fn with_sensor(self, sigma_cells: f64, outlier_share: f64) -> Result<Self> {
        let valid =
            sigma_cells.is_finite() && sigma_cells > 0.0 && (0.0..=1.0).contains(&outlier_share);
        if !valid {
            return Err(Error::InvalidModel);
        }
        let tau = outlier_share.min(MAX_OUTLIER_SHARE);
        let gain = f64::from(sensor_gain_q8(sigma_cells)) / (1.0 - tau);
        let gain = libm::round(gain.min(f64::from(MAX_GAIN_Q8))) as u16;
        let band = band_sigma(sigma_cells);
        // A band under 1 mm has no cell to spread over: the textbook model it tends to.
        let face_band = band * f64::from(self.cell_mm) >= 1.0;
        let s = if face_band { band } else { sigma_cells };
        Ok(RunConfig {
            sigma_milli_cells: libm::round((s * 1000.0).clamp(1.0, 1e9)) as u32,
            face_band,
            free_update_q8: 256,
            evidence_free_q8: 256,
            evidence_gain_q8: gain,
            ..self
        })
    }

    /// The far edge's share (Q8, `InverseSensorModel::with_far_edge`) of these settings' face
    /// band: that of the sensor whose band [`RunConfig::with_sensor`] makes σ_b =
    /// `sigma_milli_cells` wide ([`far_edge_q8`] of the σ whose [`band_sigma`] is σ_b; σ_b
    /// grows with σ, so there is one). All of the half step for a band of σ_b → 0, none from
    /// [`FULL_BAND_SIGMA`] on (the firmware's default), continuous in between; 0 without a band.
    pub fn band_far_edge_q8(&self) -> u16 {
        let sigma_b = f64::from(self.sigma_milli_cells) / 1000.0;
        if !self.face_band || sigma_b >= FULL_BAND_SIGMA {
            return 0;
        }
        // Bisection on [1, 3]: band_sigma is 0 at 1 and 3 at 3, increasing in between.
        let (mut lo, mut hi) = (1.0f64, FULL_BAND_SIGMA);
        for _ in 0..48 {
            let mid = 0.5 * (lo + hi);
            if band_sigma(mid) < sigma_b {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        far_edge_q8(0.5 * (lo + hi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Budget;

    fn base() -> RunConfig {
        RunConfig::ROBOT
            .with_max_range_mm(3750)
            .with_seed(7)
            .with_budget(Budget::Fixed { updates: 100 })
    }

    #[test]
    fn the_robot_at_the_paper_sigma() {
        let robot = RunConfig::ROBOT
            .with_max_range_mm(3750)
            .with_seed(7)
            .with_budget(Budget::Fixed { updates: 100 });
        assert_eq!(base().with_sensor(3.0, 0.0), Ok(robot));
        assert_eq!(robot.band_far_edge_q8(), 0);
        // Any starting point: only the sensor's fields change.
        let paper = RunConfig::PAPER
            .with_max_range_mm(3750)
            .with_seed(7)
            .with_budget(Budget::Fixed { updates: 100 });
        let p = paper.with_sensor(3.0, 0.0).unwrap();
        assert_eq!((p.data, p.estimator), (paper.data, paper.estimator));
        assert!(p.face_band);
    }

    #[test]
    fn no_step_in_sigma() {
        // Across the old switch at ~1.1 cells and everywhere else, a step of 0.01 cell moves
        // the gain by at most ~2.5 % (1.5·0.01/σ at σ ≥ 0.6) and the band's σ and far edge by
        // a little: no jump.
        let band = |c: &RunConfig| {
            if c.face_band {
                i64::from(c.sigma_milli_cells)
            } else {
                0
            }
        };
        let mut last = base().with_sensor(0.6, 0.0).unwrap();
        for i in 61..=800 {
            let sigma = f64::from(i) / 100.0;
            let c = base().with_sensor(sigma, 0.0).unwrap();
            let (g0, g1) = (
                i32::from(last.evidence_gain_q8),
                i32::from(c.evidence_gain_q8),
            );
            assert!(
                g1 <= g0 && g0 - g1 <= (g0 / 40).max(2),
                "σ {sigma}: {g0} → {g1}"
            );
            assert!(band(&c) >= band(&last), "σ {sigma}: band shrinks");
            assert!(band(&c) - band(&last) <= 45, "σ {sigma}: band jumps");
            // Where the band starts (σ_b = 1 mm) the far edge starts at nearly all of it: a band
            // that narrow with its far edge is the textbook model it replaces.
            let (f0, f1) = (last.band_far_edge_q8(), c.band_far_edge_q8());
            if last.face_band {
                assert!(f0.abs_diff(f1) <= 8, "σ {sigma}: far edge {f0} → {f1}");
            } else if c.face_band {
                assert!(f1 >= 240, "σ {sigma}: the band starts with far edge {f1}");
            }
            assert_eq!((c.free_update_q8, c.evidence_free_q8), (256, 256));
            last = c;
        }
        // The band's ends: none (the textbook model) up to 1.07 cells, σ itself from 3 on.
        assert!(!base().with_sensor(1.0, 0.0).unwrap().face_band);
        assert_eq!(band_sigma(5.0), 5.0);
        assert_eq!(band_sigma(0.5), 0.0);
        // The far edge: all of it where the band starts, none from 3 cells on.
        assert_eq!(far_edge_q8(1.0), 256);
        assert_eq!(far_edge_q8(3.0), 0);
        let narrow = base().with_sensor(1.2, 0.0).unwrap();
        assert!(narrow.face_band && narrow.band_far_edge_q8() > 200);
    }

    #[test]
    fn the_far_edge_follows_the_band_it_was_made_for() {
        for sigma in [1.2, 1.3, 1.5, 2.0, 2.5, 2.9] {
            let c = base().with_sensor(sigma, 0.2).unwrap();
            assert!(
                c.band_far_edge_q8().abs_diff(far_edge_q8(sigma)) <= 1,
                "σ {sigma}: {} vs {}",
                c.band_far_edge_q8(),
                far_edge_q8(sigma)
            );
        }
        let no_band = base().with_sensor(0.7, 0.0).unwrap();
        assert_eq!(no_band.band_far_edge_q8(), 0);
    }

    #[test]
    fn outliers_raise_the_gain() {
        let g = |tau| base().with_sensor(3.0, tau).unwrap().evidence_gain_q8;
        assert_eq!(g(0.5), 512);
        assert_eq!(g(0.75), 1024);
        // Capped at 90 %, and at the largest gain.
        assert_eq!(g(1.0), g(0.9));
        assert_eq!(
            base().with_sensor(0.2, 0.9).unwrap().evidence_gain_q8,
            MAX_GAIN_Q8
        );
        // Unchanged otherwise.
        let a = base().with_sensor(1.5, 0.0).unwrap();
        let b = base().with_sensor(1.5, 0.3).unwrap();
        assert_eq!(a.sigma_milli_cells, b.sigma_milli_cells);
        assert!(b.evidence_gain_q8 > a.evidence_gain_q8);
    }

    #[test]
    fn bad_input_is_an_error() {
        for (s, t) in [
            (0.0, 0.0),
            (-1.0, 0.0),
            (f64::NAN, 0.0),
            (f64::INFINITY, 0.0),
            (1.0, -0.1),
            (1.0, 1.5),
            (1.0, f64::NAN),
        ] {
            assert_eq!(
                base().with_sensor(s, t),
                Err(Error::InvalidModel),
                "{s} {t}"
            );
        }
        assert_eq!(sensor_gain_q8(f64::NAN), 256);
        assert_eq!(band_sigma(f64::NAN), 0.0);
        assert!(face_ratio(-1.0).is_infinite());
    }

    #[test]
    fn the_law_at_a_few_points() {
        assert!((face_ratio(3.0) - 0.31).abs() < 0.01);
        assert!((face_ratio(1.1) - 1.08).abs() < 0.01);
        assert!((band_sigma(2.0) - 1.47).abs() < 0.01);
        assert_eq!(sensor_gain_q8(3.0), 256);
        assert_eq!(sensor_gain_q8(0.3), MAX_GAIN_Q8);
        assert!((2350..2450).contains(&sensor_gain_q8(0.67)));
    }
}
