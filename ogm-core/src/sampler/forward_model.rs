//! Forward sensor models p(z | f): how likely a reading is given the first occupied cell `f` on
//! its ray. The Gibbs sampler evaluates them in fixed point (log-likelihoods in the same LSB as
//! [`crate::LogOdds`], ln(4)/1024 nats), from tables built once at construction with `libm` —
//! identical on the host and the Cortex-M4, because both run the same pure-Rust `libm` and IEEE
//! soft/hard float for the few operations involved.
//!
//! Distances are in 1/16 cells; the tables hold quarter-cell steps and are interpolated linearly
//! (error < 0.001 nats for σ = 3). A ray's reading is either a hit at distance `z` or "no return"
//! (nothing within the maximum range `F`).
//!
//! * [`ForwardModel::gaussian`] (Merali & Barfoot, Eq. 1: p(z|f) = N(f, σ²), σ = 3 cells), mixed
//!   with a small uniform component `w/F` so one outlier cannot veto a map (the mixture keeps
//!   every likelihood non-zero, which Gibbs sampling needs for ergodicity anyway). A no-return
//!   reading has likelihood `(1−w)·P(f + noise ≥ F) + w/F`: it is explained by "no occupied cell
//!   before max range".
//! * [`ForwardModel::pcsm`] — Dhiman et al.'s piecewise-constant model (Eq. 26): log-likelihood
//!   0 if the first occupied cell is the measured cell, −900 if the ray is free through it, −1000
//!   if something occupied comes earlier (energies in nats).

use crate::error::{Error, Result};
use crate::types::fixed::LSB_NATS;

/// Entries of each table: distances 0 ..= 255 quarter cells (64 cells); beyond is the floor.
pub const TABLE_LEN: usize = 256;

/// A log-likelihood in [`crate::types::fixed::LSB_NATS`] units (≤ 0).
pub type LogLik = i32;

#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Kind {
    Gaussian,
    Pcsm,
}

/// A forward sensor model in fixed point.
#[derive(Clone, Debug, PartialEq)]
pub struct ForwardModel {
    kind: Kind,
    /// Gaussian: log p(hit at z | f) by |z − f| in quarter cells.
    hit: [LogLik; TABLE_LEN],
    /// Gaussian: log p(no return | f) by (F − f) in quarter cells (f before max range).
    no_return: [LogLik; TABLE_LEN],
    /// log p(hit | no occupied cell within range), and the value beyond the hit table.
    floor: LogLik,
    /// log p(no return | no occupied cell within range).
    no_return_clear: LogLik,
    /// Parameters, for reports and the f64 reference.
    sigma_cells: f64,
    outlier_weight: f64,
    max_range_cells: f64,
}

fn to_lsb(nats: f64) -> LogLik {
    let v = libm::round(nats / LSB_NATS);
    if v < f64::from(i32::MIN / 4) {
        i32::MIN / 4
    } else {
        v as i32
    }
}

/// Linear interpolation in a quarter-cell table at `q16` (1/16 cells); `beyond` past its end.
#[inline]
fn interpolate(table: &[LogLik; TABLE_LEN], q16: u32, beyond: LogLik) -> LogLik {
    let i = (q16 >> 2) as usize;
    let frac = (q16 & 3) as i32;
    match (table.get(i), table.get(i + 1)) {
        (Some(&a), Some(&b)) => a + (((b - a) * frac + 2) >> 2),
        (Some(&a), None) => a,
        _ => beyond,
    }
}

/// Standard normal upper tail 1 − Φ(x), via erfc.
fn upper_tail(x: f64) -> f64 {
    0.5 * libm::erfc(x / core::f64::consts::SQRT_2)
}

impl ForwardModel {
    /// Gaussian noise σ (cells) mixed with a uniform outlier weight `w` over a sensor of maximum
    /// range `max_range_cells`. The paper's setting is σ = 3, F = 75; `w` = 0.01 is our default.
    pub fn gaussian(sigma_cells: f64, outlier_weight: f64, max_range_cells: f64) -> Result<Self> {
        let valid = sigma_cells > 0.0
            && sigma_cells.is_finite()
            && 0.0 < outlier_weight
            && outlier_weight < 1.0
            && max_range_cells >= 1.0
            && max_range_cells.is_finite();
        if !valid {
            return Err(Error::InvalidModel);
        }
        let (s, w, f) = (sigma_cells, outlier_weight, max_range_cells);
        let uniform = w / f;
        let mut hit = [0; TABLE_LEN];
        let mut no_return = [0; TABLE_LEN];
        for (i, (h, n)) in hit.iter_mut().zip(no_return.iter_mut()).enumerate() {
            let d = i as f64 / 4.0;
            let gauss =
                libm::exp(-d * d / (2.0 * s * s)) / (s * libm::sqrt(2.0 * core::f64::consts::PI));
            *h = to_lsb(libm::log((1.0 - w) * gauss + uniform));
            *n = to_lsb(libm::log((1.0 - w) * upper_tail(d / s) + uniform));
        }
        Ok(ForwardModel {
            kind: Kind::Gaussian,
            hit,
            no_return,
            floor: to_lsb(libm::log(uniform)),
            no_return_clear: to_lsb(libm::log(1.0 - w + uniform)),
            sigma_cells,
            outlier_weight,
            max_range_cells,
        })
    }

    /// The paper's default: σ = 3 cells, F = 75 cells, 1 % outliers.
    pub fn paper_default() -> Self {
        match Self::gaussian(3.0, 0.01, 75.0) {
            Ok(m) => m,
            // Unreachable: the parameters are valid constants.
            Err(_) => Self::pcsm(),
        }
    }

    /// Dhiman et al.'s piecewise-constant sensor model (Eq. 26).
    pub fn pcsm() -> Self {
        ForwardModel {
            kind: Kind::Pcsm,
            hit: [0; TABLE_LEN],
            no_return: [0; TABLE_LEN],
            floor: to_lsb(-900.0),
            no_return_clear: 0,
            sigma_cells: 0.0,
            outlier_weight: 0.0,
            max_range_cells: 0.0,
        }
    }

    /// Whether this is the piecewise-constant model.
    pub fn is_pcsm(&self) -> bool {
        self.kind == Kind::Pcsm
    }

    /// (σ, w, F) of the Gaussian model (zeros for PCSM).
    pub fn parameters(&self) -> (f64, f64, f64) {
        (self.sigma_cells, self.outlier_weight, self.max_range_cells)
    }

    /// log p(hit at z | first occupied cell f) where `z_minus_f_q16` = (z − f) in 1/16 cells.
    #[inline]
    pub fn hit(&self, z_minus_f_q16: i32) -> LogLik {
        match self.kind {
            Kind::Gaussian => interpolate(&self.hit, z_minus_f_q16.unsigned_abs(), self.floor),
            // The measured cell is "the" first occupied one if they are within half a cell.
            Kind::Pcsm => {
                if z_minus_f_q16.abs() <= 8 {
                    0
                } else if z_minus_f_q16 > 0 {
                    to_lsb(-1000.0)
                } else {
                    to_lsb(-900.0)
                }
            }
        }
    }

    /// log p(hit | no occupied cell within range).
    #[inline]
    pub fn hit_clear(&self) -> LogLik {
        self.floor
    }

    /// log p(no return | f) where `range_minus_f_q16` = (F − f) in 1/16 cells (≥ 0).
    #[inline]
    pub fn no_return(&self, range_minus_f_q16: i32) -> LogLik {
        match self.kind {
            Kind::Gaussian => interpolate(
                &self.no_return,
                range_minus_f_q16.max(0).unsigned_abs(),
                self.floor,
            ),
            Kind::Pcsm => to_lsb(-1000.0),
        }
    }

    /// log p(no return | no occupied cell within range).
    #[inline]
    pub fn no_return_clear(&self) -> LogLik {
        self.no_return_clear
    }

    /// Eq. 1's factor of one ray: log p(z | f) for a ray of `steps` steps of `step_q12` cells
    /// (Q12, ≤ √2) whose measured range is `z_q4` (1/16 steps; [`crate::sampler::ray_store::NONE`]: no
    /// return) and whose first occupied step in the map it is scored against is `f` (`NONE`:
    /// none). Steps and ranges are below 2^15 (a ray never leaves the grid's ≤ 2^15 columns),
    /// so every product fits an i32.
    #[inline]
    pub fn ray(&self, z_q4: u16, step_q12: u16, steps: u16, f: u16) -> LogLik {
        use crate::sampler::ray_store::NONE;
        let k = i32::from(step_q12);
        if z_q4 == NONE {
            if f == NONE {
                return self.no_return_clear();
            }
            // (F − f) steps → 1/16 cells: × step (Q12) × 16 / 4096.
            return self.no_return(((i32::from(steps) - i32::from(f)) * k + 128) >> 8);
        }
        if f == NONE {
            return self.hit_clear();
        }
        // (z − f) in 1/16 steps → 1/16 cells: × step (Q12) / 4096, rounded to nearest (an
        // arithmetic shift: |d| < 2^20 and k < 2^13, so the product fits an i32).
        let d = i32::from(z_q4) - 16 * i32::from(f);
        self.hit((d * k + 2048) >> 12)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_table_matches_f64() {
        let m = ForwardModel::gaussian(3.0, 0.01, 75.0).unwrap();
        for q in [0i32, 1, 5, 12, 40, 100, -7, -100, 333] {
            let d = f64::from(q) / 16.0;
            let p = 0.99 * (-(d * d) / 18.0).exp() / (3.0 * (2.0 * std::f64::consts::PI).sqrt())
                + 0.01 / 75.0;
            // Table rounding (½ LSB) + interpolation (h²/8σ² ≈ 0.0009 nats ≈ 0.65 LSB).
            assert!(
                (f64::from(m.hit(q)) * LSB_NATS - p.ln()).abs() <= 2.0 * LSB_NATS,
                "q = {q}"
            );
        }
        assert_eq!(m.hit(10_000), m.hit_clear());
        // Beyond ~6σ the Gaussian is negligible and the outlier floor dominates.
        assert!((f64::from(m.hit(4 * 255)) * LSB_NATS - (0.01f64 / 75.0).ln()).abs() < 1e-3);
        // A no-return reading is likely if the first occupied cell is at/after max range,
        // unlikely if it is well inside.
        assert!(m.no_return(0) > m.no_return(16 * 9));
        assert!(m.no_return_clear() > m.no_return(0));
        assert!(
            (f64::from(m.no_return(0)) * LSB_NATS - (0.99f64 * 0.5 + 0.01 / 75.0).ln()).abs()
                <= LSB_NATS
        );
    }

    #[test]
    fn pcsm_levels() {
        let m = ForwardModel::pcsm();
        assert_eq!(m.hit(4), 0);
        assert!(m.hit(48) < m.hit(-48));
        assert_eq!(m.hit(-48), m.hit_clear());
        assert_eq!(m.no_return_clear(), 0);
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(ForwardModel::gaussian(0.0, 0.01, 75.0).is_err());
        assert!(ForwardModel::gaussian(3.0, 0.0, 75.0).is_err());
        assert!(ForwardModel::gaussian(3.0, 0.01, f64::NAN).is_err());
    }
}
