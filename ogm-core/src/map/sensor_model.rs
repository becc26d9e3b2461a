//! Inverse sensor models: what one range reading says about the cells it touches.
//!
//! Two models, both updating `l ← clamp(l + l_inv − l₀)`:
//! * [`InverseModelKind::Beam`] — the papers' model (Merali & Barfoot, after Hähnel): cells the
//!   beam passes through before its end cell get `l_free`, the end cell gets `l_occ`, nothing else
//!   changes. The default is Hähnel's p_free = 0.2, p_occ = 0.8 (l = ∓1.3863), exact in our
//!   fixed point (see [`crate::types::fixed`]).
//! * [`InverseModelKind::FaceBand`] — the beam model for a sensor whose range noise σ spans
//!   several cells: a reading says the surface lies within σ of it, not in its end cell. Cells
//!   more than [`FACE_BAND_REACH_EIGHTHS`]/8 σ before the reading are free as in the beam model;
//!   the cells of the band from there to as far *beyond* the reading are updated by
//!   `Φ(t)·l_occ + (1 − Φ(t))·l_free`, where `t` is the cell's distance past the reading in σ and
//!   `Φ(t)` the probability that the surface lies before the cell (behind a face the cells are
//!   wall). The textbook model instead frees a wall's face cell whenever a noisy reading lands
//!   behind it, which under σ = 3 cells is more often than it lands in it, so its log-odds map
//!   draws faces cells too deep; the band's expected evidence changes sign at the face itself
//!   (docs/results.md, "Face band"). A band narrower than a few cells is evaluated part of the
//!   way towards each cell's far edge ([`InverseSensorModel::with_far_edge`]), so that as σ → 0
//!   it becomes the beam model exactly.
//! * [`InverseModelKind::Cone`] — the α/β model of the lecture (Probabilistic Robotics §9.2): a
//!   cell is updated from the beam closest to it in heading; it is occupied if it lies within α/2
//!   of a real return, free if it is nearer than the return, and untouched if it is more than β/2
//!   off the beam or beyond `min(r_max, r_k + α/2)`.

use crate::error::{Error, Result};
use crate::types::angle::Angle;
use crate::types::fixed::{probability_of_nats, LogOdds};

/// Which geometry of update a model uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum InverseModelKind {
    /// Ray model: free along the ray, occupied at its end cell.
    Beam,
    /// The ray model with the noise-aware band around each reading (module docs).
    FaceBand {
        /// The sensor's range noise σ in mm (≥ 1).
        sigma_mm: u32,
    },
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
    /// With [`InverseModelKind::FaceBand`], the share (Q8, 0 ..= 256) of half a ray step by
    /// which each band cell's offset is taken past the ray's sample point, towards the cell's
    /// far edge ([`Self::with_far_edge`]); 0 for every other kind.
    far_edge_q8: u16,
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
            far_edge_q8: 0,
        }
    }

    /// [`Self::hahnel`] with its free update scaled by `q8 / 256`, in integers alone (no
    /// floating point reaches the firmware's flash): equal to
    /// Hähnel's increments with the face band of a sensor whose range noise is `sigma_mm`
    /// ([`InverseModelKind::FaceBand`]); [`Error::InvalidModel`] if it is 0.
    pub const fn hahnel_face_band(sigma_mm: u32) -> Result<Self> {
        Self::hahnel().with_face_band(sigma_mm)
    }

    /// This model's increments with the face band of a sensor whose range noise is `sigma_mm`
    /// ([`InverseModelKind::FaceBand`], replacing the kind); [`Error::InvalidModel`] if it is
    /// 0.
    pub const fn with_face_band(self, sigma_mm: u32) -> Result<Self> {
        if sigma_mm == 0 {
            return Err(Error::InvalidModel);
        }
        Ok(InverseSensorModel {
            kind: InverseModelKind::FaceBand { sigma_mm },
            far_edge_q8: 0,
            ..self
        })
    }

    /// This face band ([`InverseModelKind::FaceBand`]) with each cell's offset past the reading
    /// taken `q8`/256 of half a ray step further on, towards the cell's far edge (and Φ of it
    /// past the band's reach, where only this shift gets: up to
    /// [`FACE_BAND_FAR_EIGHTHS`]). Why: the band evaluates Φ at each cell's sample point (about
    /// its centre along the ray), so a band narrower than a cell gives the reading's cell only
    /// Φ(1.5)·l_occ and frees a wall's face cell that noisy readings pass about as often as they
    /// hit it; at the far edge Φ is the chance that the surface lies before the ray leaves the
    /// cell, and a band of σ → 0 hits the reading's cell with the whole `l_occ`: the beam model.
    /// A wide band (σ of several cells) is right at the sample point
    /// ([`crate::config::RunConfig::band_far_edge_q8`] weighs the two). 0 is the band as it was;
    /// [`Error::InvalidModel`] for `q8` > 256 or a model without a face band.
    pub const fn with_far_edge(self, q8: u16) -> Result<Self> {
        if q8 > 256 || !matches!(self.kind, InverseModelKind::FaceBand { .. }) {
            return Err(Error::InvalidModel);
        }
        Ok(InverseSensorModel {
            far_edge_q8: q8,
            ..self
        })
    }

    /// The face band's far-edge share, Q8 ([`Self::with_far_edge`]; 0 without a band).
    pub const fn far_edge_q8(&self) -> u16 {
        self.far_edge_q8
    }

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
            far_edge_q8: 0,
        })
    }

    /// This model with its free update scaled by `q8 / 256` (1 ≤ `q8` ≤ 256; otherwise
    /// [`Error::InvalidModel`]): the inverse model matched to a noisy range sensor, whose
    /// beams pass a wall's face cell more often than they end in it
    /// ([`crate::config::noise::noise_matched_free_q8`]). 256 leaves the model as it is.
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

/// Half-width of [`InverseModelKind::FaceBand`]'s band, in eighths of σ: 1.5 σ on each side of
/// the reading. Chosen on the simulated maps (σ = 3 cells, `eval-sim`): 1.25 / 1.5 / 1.75 σ gave
/// max F1 0.9591 / 0.9612 / 0.9610 (docs/results.md, "Face band").
pub const FACE_BAND_REACH_EIGHTHS: u8 = 12;

/// How far past the reading, in eighths of σ, a face band cell's offset can lie: the band's
/// reach [`FACE_BAND_REACH_EIGHTHS`] plus the far edge's half step
/// ([`InverseSensorModel::with_far_edge`]; a step is at most 32 eighths, the mapper's cap).
/// Offsets before the reading stay clamped at −[`FACE_BAND_REACH_EIGHTHS`].
pub const FACE_BAND_FAR_EIGHTHS: u8 = FACE_BAND_REACH_EIGHTHS + 16;

/// `Φ(q / 8)` in Q15 for `q = 0 ..=` [`FACE_BAND_FAR_EIGHTHS`]: the standard normal
/// distribution function, `round(32768 · ½ erfc(−q / (8√2)))` (generated with Python's
/// `math.erfc`; the f64 reference mapper computes it with `libm::erfc` and `reference` tests
/// the two agree). `Φ(−t) = 1 − Φ(t)`. Entries past [`FACE_BAND_REACH_EIGHTHS`] are read only
/// with a far edge.
pub const PHI_EIGHTHS_Q15: [u16; FACE_BAND_FAR_EIGHTHS as usize + 1] = [
    16384, 18014, 19618, 21174, 22658, 24052, 25342, 26516, 27569, 28499, 29306, 29997, 30579,
    31061, 31455, 31772, 32023, 32218, 32367, 32480, 32565, 32626, 32670, 32702, 32724, 32739,
    32749, 32756, 32760,
];

/// `Φ(t8 / 8)` in Q15 for `−`[`FACE_BAND_REACH_EIGHTHS`]` ≤ t8 ≤ `[`FACE_BAND_FAR_EIGHTHS`]
/// (clamped there).
pub fn phi_eighths_q15(t8: i8) -> u16 {
    let far = if t8 >= 0 {
        FACE_BAND_FAR_EIGHTHS
    } else {
        FACE_BAND_REACH_EIGHTHS
    };
    let q = usize::from(t8.unsigned_abs()).min(usize::from(far));
    let p = PHI_EIGHTHS_Q15.get(q).copied().unwrap_or(1 << 15);
    if t8 >= 0 {
        p
    } else {
        (1 << 15) - p
    }
}

/// The face band's update of a cell `t8` eighths of σ past the reading, from the increments
/// `occ` and `free` (LSB): `Φ·occ + (1 − Φ)·free`, rounded to nearest.
pub fn face_band_delta(occ: i32, free: i32, t8: i8) -> i32 {
    let phi = i64::from(phi_eighths_q15(t8));
    let v = phi * i64::from(occ) + ((1 << 15) - phi) * i64::from(free);
    // |v| ≤ 2^15 · 2^16: the quotient fits an i32.
    ((v + (1 << 14)) >> 15) as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn face_band_table_is_the_normal_distribution() {
        for (q, &p) in PHI_EIGHTHS_Q15.iter().enumerate() {
            let exact = 0.5 * libm::erfc(-(q as f64) / 8.0 / core::f64::consts::SQRT_2);
            assert!(
                (f64::from(p) / 32768.0 - exact).abs() < 1.0 / 32768.0,
                "q {q}"
            );
        }
        // Symmetric, monotone, and the band's ends are nearly the plain updates.
        let (occ, free) = (1024, -1024);
        assert_eq!(face_band_delta(occ, free, 0), 0);
        for t in -12i8..12 {
            assert!(face_band_delta(occ, free, t) < face_band_delta(occ, free, t + 1));
            assert_eq!(
                face_band_delta(occ, free, t),
                -face_band_delta(occ, free, -t)
            );
        }
        assert_eq!(face_band_delta(occ, free, 12), 887);
        assert_eq!(face_band_delta(occ, free, -12), -887);
        assert_eq!(face_band_delta(occ, free, -100), -887);
        // Past the reach (only a far edge's shift gets there): Φ itself, up to 3.5 σ.
        for t in 12i8..28 {
            assert!(face_band_delta(occ, free, t) <= face_band_delta(occ, free, t + 1));
        }
        assert_eq!(face_band_delta(occ, free, 20), 1011);
        assert_eq!(face_band_delta(occ, free, 28), 1024);
        assert_eq!(face_band_delta(occ, free, 100), 1024);
        assert!(InverseSensorModel::hahnel_face_band(0).is_err());
    }

    #[test]
    fn far_edge_only_on_a_face_band() {
        let band = InverseSensorModel::hahnel_face_band(150).unwrap();
        assert_eq!(band.far_edge_q8(), 0);
        let far = band.with_far_edge(256).unwrap();
        assert_eq!(far.far_edge_q8(), 256);
        assert_eq!(far.kind(), band.kind());
        assert_eq!(band.with_far_edge(257), Err(Error::InvalidModel));
        assert_eq!(
            InverseSensorModel::hahnel().with_far_edge(10),
            Err(Error::InvalidModel)
        );
        // A new band width starts without it.
        assert_eq!(far.with_face_band(100).unwrap().far_edge_q8(), 0);
    }

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
        assert!((no - eo).abs() <= crate::types::fixed::LSB_NATS / 2.0);
        assert!((nf - ef).abs() <= crate::types::fixed::LSB_NATS / 2.0);
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
