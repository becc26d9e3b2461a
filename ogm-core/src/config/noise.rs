//! Settings matched to the range sensor's noise: how the robot's mapper and sampler weigh free
//! and occupied evidence for a sensor whose range noise is σ cells.

/// The scale of free evidence (Q8) that matches a range sensor with Gaussian noise of `sigma`
/// cells: the Hähnel inverse model frees every cell a beam passes and hits the cell it ends in,
/// so at a wall's face a noisy beam passes the face cell with probability
/// `1 − Φ(½/σ)` and ends in it with probability `2Φ(½/σ) − 1`. Free evidence scaled by their
/// ratio (at most 1) makes the face cell's expected evidence neutral instead of free: 0.31 for
/// the simulation's σ = 3 cells, 1 for any sensor with σ ≤ 1.1 cells (every real lidar at 5 cm).
pub fn free_evidence_q8(sigma: f64) -> u16 {
    if sigma.is_nan() || sigma <= 0.0 || sigma.is_infinite() {
        return 256;
    }
    let x = 0.5 / (sigma * core::f64::consts::SQRT_2);
    let (hit, pass) = (libm::erf(x), 0.5 * libm::erfc(x));
    let ratio = if pass > 0.0 {
        (hit / pass).min(1.0)
    } else {
        1.0
    };
    libm::round(ratio * 256.0) as u16
}

/// Whether the robot's mapper uses the face band
/// ([`crate::map::sensor_model::InverseModelKind::FaceBand`]) for a sensor with range noise `sigma`
/// (cells): exactly where the textbook model's face cell reads free in expectation, i.e.
/// [`free_evidence_q8`] < 256 (σ above about 1.1 cells; never for a real lidar at 5 cm). There
/// the band replaces the free scaling: on the simulated maps (σ = 3 cells, `eval-sim`, 26
/// datasets) the robot's sampler scores max F1 0.961 on the band's map against 0.950 with the
/// split free update (docs/results.md, "Face band"). Below it a cell is wider than the noise
/// and the end cell is where the surface is.
pub fn face_band_for(sigma: f64) -> bool {
    free_evidence_q8(sigma) < 256
}

/// The free scale (Q8) the robot applies twice, once to the mapper's free update (before the
/// clamp) and once to the evidence term (after it): the square root of
/// [`free_evidence_q8`]'s ratio, so that the two together scale free evidence by that ratio.
///
/// Why split it: with dense data a wall's face cell is passed by noisy beams more often than
/// it is hit, so under the textbook free update it clamps *free*, like the room in front of
/// it, and no scale applied afterwards can tell the two apart (a 2 000-scan mission under
/// σ = 3 cells lost to the log-odds map itself: docs/results.md). Scaling only the update
/// instead changes the signs of sparse evidence (one hit against three passes), and short
/// runs lose 0.03 of max F1. Half of the correction in each place keeps both (same page,
/// "Noise-matched free update"). 256 for every sensor with σ ≤ 1.1 cells: the textbook model.
pub fn noise_matched_free_q8(sigma: f64) -> u16 {
    let ratio = f64::from(free_evidence_q8(sigma)) / 256.0;
    (libm::round(libm::sqrt(ratio) * 256.0) as u16).clamp(1, 256)
}

/// The evidence gain (Q8) matched to the sensor's range noise `sigma` (cells): 512 (2×) at
/// the simulation's σ = 3 cells, growing as 1/σ up to [`MAX_GAIN_Q8`] (at σ ≤ 0.375 cells),
/// never below 256 (the log-odds themselves). Why 1/σ: a noisy hit's support spreads over
/// about σ cells, so the log-odds of a precise sensor say proportionally more about each cell,
/// and where they are strong the data must win over the prior. Measured (docs/results.md,
/// "Noise-matched evidence gain"): on eval-sim (σ = 3) 512 beats 1 024 and 2 048; on the real
/// logs (σ estimated at 0.67 cells) the law's 2 293 meets all fifteen eval-log targets where
/// 512 met ten, and every gain from 2 048 up scores the same.
pub fn noise_matched_gain_q8(sigma: f64) -> u16 {
    if sigma.is_nan() || sigma <= 0.0 || sigma.is_infinite() {
        return 512;
    }
    libm::round(512.0 * 3.0 / sigma).clamp(256.0, f64::from(MAX_GAIN_Q8)) as u16
}

/// Largest evidence gain (Q8, both [`crate::sampler::gibbs::SamplerConfig::evidence_gain_q8`] and the
/// free scale): 16×, so `log-odds × gain` fits an `i32` (2^15 · 2^12).
pub const MAX_GAIN_Q8: u16 = 4096;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_scale_follows_the_noise() {
        assert_eq!(free_evidence_q8(3.0), 78);
        assert_eq!(free_evidence_q8(0.5), 256);
        assert_eq!(free_evidence_q8(0.9), 256);
        assert!(free_evidence_q8(10.0) < 30);
        assert_eq!(free_evidence_q8(f64::NAN), 256);
        assert_eq!(free_evidence_q8(-1.0), 256);
    }

    #[test]
    fn the_split_scale_squares_to_the_ratio() {
        assert_eq!(noise_matched_free_q8(3.0), 141);
        assert_eq!(noise_matched_free_q8(0.5), 256);
        assert_eq!(noise_matched_free_q8(f64::NAN), 256);
        for sigma in [1.2, 2.0, 3.0, 5.0, 10.0, 100.0] {
            let q = f64::from(noise_matched_free_q8(sigma)) / 256.0;
            let r = f64::from(free_evidence_q8(sigma)) / 256.0;
            assert!((q * q - r).abs() < 0.01, "σ {sigma}: {q}² vs {r}");
            assert!(noise_matched_free_q8(sigma) >= 1);
        }
    }

    #[test]
    fn the_evidence_gain_grows_as_the_noise_shrinks() {
        assert_eq!(noise_matched_gain_q8(3.0), 512);
        assert_eq!(noise_matched_gain_q8(1.5), 1024);
        assert_eq!(noise_matched_gain_q8(0.1), MAX_GAIN_Q8);
        assert_eq!(noise_matched_gain_q8(100.0), 256);
        assert_eq!(noise_matched_gain_q8(f64::NAN), 512);
        assert_eq!(noise_matched_gain_q8(0.0), 512);
        let gains: Vec<u16> = [0.3, 0.67, 1.0, 2.0, 3.0, 6.0, 12.0]
            .map(noise_matched_gain_q8)
            .to_vec();
        assert!(gains.windows(2).all(|w| w[0] >= w[1]), "{gains:?}");
    }
}
