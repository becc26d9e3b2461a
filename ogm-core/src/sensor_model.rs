//! Inverse sensor models: what one range reading says about the cells it touches.
//!
//! Two models, both updating `l ← clamp(l + l_inv − l₀)`:
//! * [`InverseModelKind::Beam`] — the papers' model (Merali & Barfoot, after Hähnel): cells the
//!   beam passes through before its end cell get `l_free`, the end cell gets `l_occ`, nothing else
//!   changes. The default is Hähnel's p_free = 0.2, p_occ = 0.8 (l = ∓1.3863), exact in our
//!   fixed point (see [`crate::fixed`]).
//! * [`InverseModelKind::Cone`] — the α/β model of the lecture (Probabilistic Robotics §9.2): a
//!   cell is updated from the beam closest to it in heading; it is occupied if it lies within α/2
//!   of a real return, free if it is nearer than the return, and untouched if it is more than β/2
//!   off the beam or beyond `min(r_max, r_k + α/2)`.

use crate::angle::Angle;
use crate::error::{Error, Result};
use crate::fixed::{probability_of_nats, LogOdds};

/// Which geometry of update a model uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum InverseModelKind {
    /// Ray model: free along the ray, occupied at its end cell.
    Beam,
    /// The lecture's cone model.
    Cone {
        /// Obstacle thickness α in mm.
        alpha_mm: u32,
        /// Beam opening angle β.
        beta: Angle,
    },
}

/// An inverse sensor model with its log-odds increments (already relative to the prior l₀).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InverseSensorModel {
    kind: InverseModelKind,
    occ: LogOdds,
    free: LogOdds,
    /// The increments in nats as requested, `(occupied, free)`; `None` when they are exactly
    /// the fixed-point ones (Hähnel's ±ln 4 = ±1024 LSB and its free scalings by `q8 / 256`), so
    /// a model built from integers alone needs no floating point (the firmware's flash).
    nominal: Option<(f64, f64)>,
}

impl Default for InverseSensorModel {
    fn default() -> Self {
        InverseSensorModel::hahnel()
    }
}

impl InverseSensorModel {
    /// Hähnel's p_occ = 0.8, p_free = 0.2 with a 0.5 prior, the papers' "traditional OGM".
    pub const fn hahnel() -> Self {
        InverseSensorModel {
            kind: InverseModelKind::Beam,
            occ: LogOdds::LN_4,
            free: LogOdds(-LogOdds::LN_4.0),
            nominal: None,
        }
    }

    /// [`Self::hahnel`] with its free update scaled by `q8 / 256`, in integers alone (no
    /// floating point reaches the firmware's flash): equal to
    /// `hahnel().with_free_scale(q8)`, errors included.
    pub const fn hahnel_free_scaled(q8: u16) -> Result<Self> {
        if q8 == 0 || q8 > 256 {
            return Err(Error::InvalidModel);
        }
        let m = Self::hahnel();
        // −1024 · q8 / 256 = −4 · q8: exact, in [−1024, −4].
        Ok(InverseSensorModel {
            free: LogOdds(m.free.0 / 256 * q8 as i16),
            ..m
        })
    }

    /// A ray model with the given occupied/free probabilities and cell prior.
    /// Requires `p_free < prior < p_occ`, all in (0, 1).
    pub fn beam(p_occ: f64, p_free: f64, prior: f64) -> Result<Self> {
        Self::with_kind(InverseModelKind::Beam, p_occ, p_free, prior)
    }

    /// The lecture's α/β cone model. Requires `p_free < prior < p_occ`, `alpha_mm > 0`, and a
    /// non-zero `beta`.
    pub fn cone(p_occ: f64, p_free: f64, prior: f64, alpha_mm: u32, beta: Angle) -> Result<Self> {
        if alpha_mm == 0 || beta.0 == 0 {
            return Err(Error::InvalidModel);
        }
        Self::with_kind(
            InverseModelKind::Cone { alpha_mm, beta },
            p_occ,
            p_free,
            prior,
        )
    }

    fn with_kind(kind: InverseModelKind, p_occ: f64, p_free: f64, prior: f64) -> Result<Self> {
        let logit = |p: f64| -> Result<f64> {
            if !(p > 0.0 && p < 1.0) {
                return Err(Error::InvalidProbability);
            }
            Ok(libm::log(p / (1.0 - p)))
        };
        let l0 = logit(prior)?;
        let nominal_occ = logit(p_occ)? - l0;
        let nominal_free = logit(p_free)? - l0;
        let occ = LogOdds::from_nats(nominal_occ)?;
        let free = LogOdds::from_nats(nominal_free)?;
        if occ.0 <= 0 || free.0 >= 0 {
            return Err(Error::InvalidModel);
        }
        Ok(InverseSensorModel {
            kind,
            occ,
            free,
            nominal: Some((nominal_occ, nominal_free)),
        })
    }

    /// This model with its free update scaled by `q8 / 256` (1 ≤ `q8` ≤ 256; otherwise
    /// [`Error::InvalidModel`]): the inverse model matched to a noisy range sensor, whose
    /// beams pass a wall's face cell more often than they end in it
    /// ([`crate::gibbs::noise_matched_free_q8`]). 256 leaves the model as it is.
    pub fn with_free_scale(self, q8: u16) -> Result<Self> {
        if q8 == 0 || q8 > 256 {
            return Err(Error::InvalidModel);
        }
        if q8 == 256 {
            return Ok(self);
        }
        let scaled = i32::from(self.free.0) * i32::from(q8);
        let (free, nominal) = match self.nominal {
            // Exact in integers (Hähnel's −1024 LSB: every q8), and the nominal stays exact.
            // |scaled / 256| < |free| (q8 < 256 here), so it fits an i16.
            None if scaled % 256 == 0 => (LogOdds((scaled / 256) as i16), None),
            _ => {
                let (occ, free) = self.nominal_increments();
                let nominal_free = free * f64::from(q8) / 256.0;
                (LogOdds::from_nats(nominal_free)?, Some((occ, nominal_free)))
            }
        };
        // A scale of at least 1/256 keeps a free increment of at least 4 LSB away from zero.
        if free.0 >= 0 {
            return Err(Error::InvalidModel);
        }
        Ok(InverseSensorModel {
            free,
            nominal,
            ..self
        })
    }

    /// The update geometry.
    pub const fn kind(&self) -> InverseModelKind {
        self.kind
    }

    /// Fixed-point increment for an occupied cell (`l_occ − l₀`, rounded to the LSB).
    pub const fn occ_increment(&self) -> LogOdds {
        self.occ
    }

    /// Fixed-point increment for a free cell (`l_free − l₀`, rounded to the LSB).
    pub const fn free_increment(&self) -> LogOdds {
        self.free
    }

    /// The increments in nats as requested, before rounding: `(occupied, free)`.
    pub fn nominal_increments(&self) -> (f64, f64) {
        self.nominal.unwrap_or_else(|| self.effective_increments())
    }

    /// The increments in nats the fixed-point mapper actually applies: `(occupied, free)`.
    pub fn effective_increments(&self) -> (f64, f64) {
        (self.occ.to_nats(), self.free.to_nats())
    }

    /// The (p_occ, p_free) the fixed-point increments correspond to at a 0.5 prior. For the
    /// default model these are exactly (0.8, 0.2); otherwise each differs from the request by at
    /// most half an LSB in log-odds (≤ 0.00017 in probability).
    pub fn effective_probabilities(&self) -> (f64, f64) {
        let (o, f) = self.effective_increments();
        (probability_of_nats(o), probability_of_nats(f))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_scale_scales_only_the_free_update() {
        let m = InverseSensorModel::hahnel();
        assert_eq!(m.with_free_scale(256), Ok(m));
        let half = m.with_free_scale(128).unwrap();
        assert_eq!(half.occ_increment(), LogOdds(1024));
        assert_eq!(half.free_increment(), LogOdds(-512));
        let q = m.with_free_scale(141).unwrap();
        assert_eq!(q.free_increment(), LogOdds(-564));
        assert!(
            (q.nominal_increments().1 + 2.0 * core::f64::consts::LN_2 * 141.0 / 256.0).abs()
                < 1e-12
        );
        assert_eq!(m.with_free_scale(0), Err(Error::InvalidModel));
        assert_eq!(m.with_free_scale(257), Err(Error::InvalidModel));
        assert!(m.with_free_scale(1).unwrap().free_increment().0 < 0);
    }

    /// The integer path (Hähnel's model, no floating point) against the float reference:
    /// the rounded scaled nominal, for every scale; and a model whose increments are not
    /// exact LSB multiples still takes the float path.
    #[test]
    fn free_scale_in_integers_matches_the_float_reference() {
        let m = InverseSensorModel::hahnel();
        for q8 in 1..=256u16 {
            let nats = -2.0 * core::f64::consts::LN_2 * f64::from(q8) / 256.0;
            let s = m.with_free_scale(q8).unwrap();
            assert_eq!(
                s.free_increment(),
                LogOdds::from_nats(nats).unwrap(),
                "q8 {q8}"
            );
            assert!((s.nominal_increments().1 - nats).abs() < 1e-12, "q8 {q8}");
            assert_eq!(s.occ_increment(), LogOdds(1024));
            assert_eq!(InverseSensorModel::hahnel_free_scaled(q8), Ok(s), "q8 {q8}");
        }
        for q8 in [0, 257, u16::MAX] {
            assert_eq!(
                InverseSensorModel::hahnel_free_scaled(q8),
                m.with_free_scale(q8)
            );
        }
        let b = InverseSensorModel::beam(0.7, 0.4, 0.5).unwrap();
        let s = b.with_free_scale(100).unwrap();
        let nats = b.nominal_increments().1 * 100.0 / 256.0;
        assert_eq!(s.free_increment(), LogOdds::from_nats(nats).unwrap());
        assert!((s.nominal_increments().1 - nats).abs() < 1e-15);
    }

    #[test]
    fn hahnel_default() {
        let m = InverseSensorModel::default();
        assert_eq!(m.occ_increment(), LogOdds(1024));
        assert_eq!(m.free_increment(), LogOdds(-1024));
        let (po, pf) = m.effective_probabilities();
        assert!((po - 0.8).abs() < 1e-12 && (pf - 0.2).abs() < 1e-12);
        let same = InverseSensorModel::beam(0.8, 0.2, 0.5).unwrap();
        assert_eq!(same.occ_increment(), m.occ_increment());
        assert_eq!(same.free_increment(), m.free_increment());
    }

    #[test]
    fn rounding_is_within_half_an_lsb() {
        let m = InverseSensorModel::beam(0.7, 0.4, 0.5).unwrap();
        let (no, nf) = m.nominal_increments();
        let (eo, ef) = m.effective_increments();
        assert!((no - eo).abs() <= crate::fixed::LSB_NATS / 2.0);
        assert!((nf - ef).abs() <= crate::fixed::LSB_NATS / 2.0);
    }

    #[test]
    fn rejects_inconsistent_parameters() {
        assert_eq!(
            InverseSensorModel::beam(0.4, 0.2, 0.5),
            Err(Error::InvalidModel)
        );
        assert_eq!(
            InverseSensorModel::beam(0.8, 0.6, 0.5),
            Err(Error::InvalidModel)
        );
        assert_eq!(
            InverseSensorModel::beam(1.0, 0.2, 0.5),
            Err(Error::InvalidProbability)
        );
        assert_eq!(
            InverseSensorModel::beam(0.8, 0.2, f64::NAN),
            Err(Error::InvalidProbability)
        );
        assert_eq!(
            InverseSensorModel::cone(0.8, 0.2, 0.5, 0, Angle(100)),
            Err(Error::InvalidModel)
        );
        assert_eq!(
            InverseSensorModel::cone(0.8, 0.2, 0.5, 10, Angle(0)),
            Err(Error::InvalidModel)
        );
    }
}
