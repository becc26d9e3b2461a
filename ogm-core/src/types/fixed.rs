//! Fixed-point log-odds.
//!
//! A cell's belief is stored as log-odds `l = ln(p / (1 - p))` in an `i16` whose least significant
//! bit is [`LSB_NATS`] = ln(4)/1024 ≈ 0.001354 nats. The odd-looking unit is chosen so that the
//! papers' default inverse sensor model (Hähnel: p_occ = 0.8, p_free = 0.2, l = ±ln 4 ≈ ±1.3863) is
//! represented *exactly* as ±1024 LSB: the default mapper then accumulates no rounding error at all,
//! however many scans it integrates. Other models are rounded once, at construction, to the nearest
//! LSB (≤ 0.00068 nats, i.e. ≤ 0.017 % in probability per update; see
//! [`crate::map::sensor_model::InverseSensorModel::effective_probabilities`]).
//!
//! Range: an `i16` spans ±44 nats; the mapper clamps far inside that (see [`Clamp`]), so a
//! saturating add can never wrap.

use crate::error::{Error, Result};

/// Natural-log value of one least significant bit of [`LogOdds`]: ln(4)/1024.
pub const LSB_NATS: f64 = core::f64::consts::LN_2 * 2.0 / 1024.0;

/// A fixed-point log-odds value (`raw` × [`LSB_NATS`] nats).
#[repr(transparent)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LogOdds(pub i16);

impl LogOdds {
    /// p = 0.5.
    pub const ZERO: LogOdds = LogOdds(0);
    /// ln 4 (p = 0.8), Hähnel's occupied increment.
    pub const LN_4: LogOdds = LogOdds(1024);

    /// The raw integer.
    #[inline]
    pub const fn raw(self) -> i16 {
        self.0
    }

    /// Rounds a value in nats to the nearest LSB, saturating at the `i16` range.
    /// Returns [`Error::InvalidProbability`] for NaN.
    pub fn from_nats(nats: f64) -> Result<LogOdds> {
        if nats.is_nan() {
            return Err(Error::InvalidProbability);
        }
        let lsb = libm::round(nats / LSB_NATS);
        // `as` saturates for out-of-range floats (and infinities), which is the documented intent.
        Ok(LogOdds(lsb as i16))
    }

    /// The value in nats.
    #[inline]
    pub fn to_nats(self) -> f64 {
        f64::from(self.0) * LSB_NATS
    }

    /// Log-odds of a probability in the open interval (0, 1), rounded to the nearest LSB.
    pub fn from_probability(p: f64) -> Result<LogOdds> {
        if !(p > 0.0 && p < 1.0) {
            return Err(Error::InvalidProbability);
        }
        LogOdds::from_nats(libm::log(p / (1.0 - p)))
    }

    /// Probability `1 / (1 + e^-l)` in f64 (host-side conversions, tests, I/O).
    pub fn probability(self) -> f64 {
        probability_of_nats(self.to_nats())
    }

    /// Probability in f32 (cheap on a Cortex-M4F's single-precision FPU).
    pub fn probability_f32(self) -> f32 {
        1.0 / (1.0 + libm::expf(-(f32::from(self.0) * LSB_NATS as f32)))
    }

    /// Adds `delta`, saturating at the `i16` range.
    #[inline]
    pub const fn saturating_add(self, delta: LogOdds) -> LogOdds {
        LogOdds(self.0.saturating_add(delta.0))
    }
}

/// `1 / (1 + e^-l)` for a log-odds in nats.
pub fn probability_of_nats(nats: f64) -> f64 {
    1.0 / (1.0 + libm::exp(-nats))
}

/// Bounds every cell's log-odds is kept within.
///
/// The default is ±5120 LSB = ±5·ln 4 ≈ ±6.93 nats, i.e. p ∈ [0.00098, 0.99902]: five consistent
/// Hähnel readings saturate a cell, and five contrary ones bring it back to 0.5. Like OctoMap's
/// clamping this keeps the map revisable (a moved door, a pose error) and bounds how confident a
/// single cell can get, which the Gibbs sampler relies on when it starts from the thresholded
/// map. The bounds are far inside the `i16` range, so `value + increment` never overflows
/// before it is clamped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Clamp {
    min: LogOdds,
    max: LogOdds,
}

impl Clamp {
    /// Bounds with `min < 0 < max`.
    pub const fn new(min: LogOdds, max: LogOdds) -> Result<Clamp> {
        if min.0 < 0 && max.0 > 0 {
            Ok(Clamp { min, max })
        } else {
            Err(Error::InvalidClamp)
        }
    }

    /// Lower bound.
    #[inline]
    pub const fn min(&self) -> LogOdds {
        self.min
    }

    /// Upper bound.
    #[inline]
    pub const fn max(&self) -> LogOdds {
        self.max
    }

    /// The largest magnitude of either bound, in LSB.
    pub const fn span(&self) -> i16 {
        let lo = self.min.0.unsigned_abs();
        let hi = self.max.0.unsigned_abs();
        if lo > hi {
            lo as i16
        } else {
            hi as i16
        }
    }

    /// `value + delta`, clamped to the bounds. Saturates first, so it is total.
    #[inline]
    pub fn apply(&self, value: LogOdds, delta: LogOdds) -> LogOdds {
        let v = value.0.saturating_add(delta.0);
        LogOdds(v.clamp(self.min.0, self.max.0))
    }
}

impl Default for Clamp {
    fn default() -> Self {
        Clamp {
            min: LogOdds(-5120),
            max: LogOdds(5120),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hahnel_is_exact() {
        assert_eq!(LogOdds::from_probability(0.8).unwrap(), LogOdds(1024));
        assert_eq!(LogOdds::from_probability(0.2).unwrap(), LogOdds(-1024));
        assert!((LogOdds(1024).to_nats() - 1.3862943611198906).abs() < 1e-15);
        assert!((LogOdds(1024).probability() - 0.8).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_probabilities() {
        for p in [0.0, 1.0, -0.1, 1.5, f64::NAN, f64::INFINITY] {
            assert_eq!(LogOdds::from_probability(p), Err(Error::InvalidProbability));
        }
        assert_eq!(LogOdds::from_nats(f64::NAN), Err(Error::InvalidProbability));
        assert_eq!(LogOdds::from_nats(1e9).unwrap(), LogOdds(i16::MAX));
        assert_eq!(LogOdds::from_nats(-1e9).unwrap(), LogOdds(i16::MIN));
    }

    #[test]
    fn clamp_saturates_without_wrapping() {
        let c = Clamp::default();
        assert_eq!(c.apply(LogOdds(5000), LogOdds(1024)), LogOdds(5120));
        assert_eq!(c.apply(LogOdds(-5000), LogOdds(-1024)), LogOdds(-5120));
        assert_eq!(c.apply(LogOdds(i16::MAX), LogOdds(i16::MAX)), LogOdds(5120));
        assert_eq!(
            c.apply(LogOdds(i16::MIN), LogOdds(i16::MIN)),
            LogOdds(-5120)
        );
        assert!(Clamp::new(LogOdds(0), LogOdds(5)).is_err());
        assert!(Clamp::new(LogOdds(-5), LogOdds(0)).is_err());
        assert_eq!(c.span(), 5120);
    }

    #[test]
    fn f32_and_f64_probabilities_agree() {
        for raw in (-5120..=5120).step_by(7) {
            let l = LogOdds(raw);
            assert!((f64::from(l.probability_f32()) - l.probability()).abs() < 1e-6);
        }
    }
}
