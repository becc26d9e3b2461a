//! Fusing odometry and matches: a Kalman filter on the corrected pose (issue 39).
//!
//! A match is not a pose's truth: against a 5 cm grid it is off by a location-dependent bias of
//! a few centimetres and a few tenths of a degree (walls quantised to cells), which successive
//! scans share. Taken as is, scan after scan, those biases add up as a walk through the robot's
//! own map. Wheel odometry is the opposite: over one step of a few centimetres it is off by
//! well under a millimetre, but its error grows without bound. So the tracker keeps the
//! uncertainty of its corrected pose ([`Uncertainty`]: translation 2 × 2 and heading, mm² and
//! rad²), grows it by each odometry step ([`Uncertainty::predict`], the model of
//! [`crate::localize::odometry`] taken as noise: σ per metre travelled, per radian turned, a
//! heading drift per metre), and moves the prediction towards a usable match only as far as the
//! two uncertainties say ([`Uncertainty::fuse`], the Kalman gain `K = P (P + R)⁻¹`), the match's
//! `R` being [`MatchConfig::match_sigma_mm`] and [`MatchConfig::match_sigma_mdeg`]. Along the
//! axis an ambiguous match leaves open (a corridor), `R` is practically infinite (and stretched
//! along the weakest axis of any match by how little score a move along it loses); for the
//! heading of a match that cannot tell it, the heading stays the prediction's.
//!
//! A match outside the χ² gate is blamed on whichever source was less precise over the last
//! step. If odometry's own variance over it was above the match's (a long or turning step, or a
//! robot whose settings call its odometry poor), odometry slipped: `P` is widened until the
//! innovation is one σ and the match is taken nearly whole. If odometry was the sharper, the
//! match is the likelier culprit (a young map's bias, a look-alike wall) and is ignored, until
//! [`SUSPECT_SCANS`] such matches in a row say odometry did slip after all. Taking every outlier
//! whole let single matches walk a robot with exact heading odometry, told so, 1.3° off on
//! average while driving (docs/firmware.md, "Pose correction").
//!
//! Translation and heading are filtered separately (no cross-covariance); the heading's effect
//! on the translation over a step (`d² · σ_θ²`) is added to the translation's variance. This is
//! `f32` (the Cortex-M4F has it in hardware, and IEEE arithmetic without fused operations is the
//! same on the host, so replays stay bit-exact): a handful of operations per scan, on values
//! that need range more than resolution.

use crate::localize::{MatchConfig, MatchResult, Verdict};
use crate::types::angle::{Angle, FULL_TURN};
use crate::types::geometry::Pose;

/// Radians per [`Angle`] unit.
const RAD_PER_UNIT: f32 = core::f32::consts::TAU / FULL_TURN as f32;

/// 2³⁰: [`Angle::cos_sin_q30`]'s one.
const Q30: f32 = (1u32 << 30) as f32;

/// The variance of a direction a match does not constrain, mm² (ten thousand times the
/// largest variance a prediction can have, [`MAX_VAR_MM2`]: its gain stays below 10⁻⁴).
const OPEN: f32 = 1e16;

/// Variances never fall below these (mm², rad²): one millimetre, a thousandth of a degree, so
/// a long stand-still cannot make the filter deaf to every later match.
const MIN_VAR_MM2: f32 = 1.0;
const MIN_VAR_RAD2: f32 = 3.0e-10;

/// Added per scan whatever the motion (mm², rad²: 0.5 mm, 0.005°): a robot standing still
/// with its pose a little off the map settles onto the map over a few seconds of scans
/// (~60 scans) instead of never.
const STEP_VAR_MM2: f32 = 0.25;
const STEP_VAR_RAD2: f32 = 7.6e-9;

/// [`Uncertainty::odometry_scale`] at most (odometry's σ ten times its settings').
pub const MAX_ODOMETRY_SCALE: f32 = 100.0;
/// How fast [`Uncertainty::odometry_scale`] follows the innovations (per match).
const ODOMETRY_LEARN: f32 = 0.05;

/// χ² of an innovation the model explains 99 times in 100 (2 and 1 degrees of freedom);
/// beyond it the prediction's variance is widened until the innovation is one σ.
const GATE_TRANS: f32 = 9.21;
const GATE_TURN: f32 = 6.63;

/// Out-of-gate matches ignored in a row, at most, while odometry's step is the sharper
/// source: after that many the next is taken (odometry did slip). Four scans are 0.4 s at an
/// LD06's 10 Hz (4 to 8 did the same on the simulated drives, 1 and 2 less well).
pub const SUSPECT_SCANS: u8 = 4;

/// Variances never exceed these (mm², rad²): a kilometre, a full turn, so that `f32` never
/// overflows whatever the odometry did.
const MAX_VAR_MM2: f32 = 1e12;
const MAX_VAR_RAD2: f32 = 40.0;

/// The uncertainty of the corrected pose: translation covariance (world frame, mm²) and heading
/// variance (rad²).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Uncertainty {
    /// Variance of x, mm².
    pub xx: f32,
    /// Covariance of x and y, mm².
    pub xy: f32,
    /// Variance of y, mm².
    pub yy: f32,
    /// Variance of the heading, rad².
    pub tt: f32,
    /// How much worse than [`MatchConfig`]'s model odometry has turned out (a factor on its
    /// variances, 1..=[`MAX_ODOMETRY_SCALE`]): learnt from the innovations.
    pub odometry_scale: f32,
    /// Odometry's own variance over the last step, translation per axis (mm²), before the
    /// heading's swing and the per-scan floor: what an out-of-gate match is weighed against.
    pub step_xx: f32,
    /// The same for the heading (rad²).
    pub step_tt: f32,
    /// Out-of-gate matches ignored in a row so far ([`SUSPECT_SCANS`]).
    pub ignored: u8,
}

impl Uncertainty {
    /// Exactly known (the first scan defines the map's frame).
    pub const ZERO: Uncertainty = Uncertainty {
        xx: 0.0,
        xy: 0.0,
        yy: 0.0,
        tt: 0.0,
        odometry_scale: 1.0,
        // No step yet: nothing says odometry is the sharper source.
        step_xx: MAX_VAR_MM2,
        step_tt: MAX_VAR_RAD2,
        ignored: 0,
    };

    /// σ of the position along its worst direction, mm (the larger eigenvalue's root).
    pub fn sigma_mm(&self) -> f32 {
        let half = 0.5 * (self.xx + self.yy);
        let d = 0.5 * (self.xx - self.yy);
        libm::sqrtf(half + libm::sqrtf(d * d + self.xy * self.xy)).max(0.0)
    }

    /// σ of the heading, degrees.
    pub fn sigma_deg(&self) -> f32 {
        libm::sqrtf(self.tt.max(0.0)) * (180.0 / core::f32::consts::PI)
    }

    /// Grows by one odometry step `step` (the motion in the last pose's frame): the model's
    /// noise per metre travelled and per radian turned, and what the heading's uncertainty does
    /// to the step's translation.
    pub fn predict(&mut self, step: &Pose, cfg: &MatchConfig) {
        let d = libm::sqrtf(
            (step.x_mm as f32) * (step.x_mm as f32) + (step.y_mm as f32) * (step.y_mm as f32),
        );
        let turn = f32::from(step.heading.signed_diff(Angle::ZERO)).abs() * RAD_PER_UNIT;
        let d_m = d / 1000.0;
        let st = f32::from(cfg.odometry.trans_permille) / 1000.0 * d;
        let sr = f32::from(cfg.odometry.turn_permille) / 1000.0 * turn;
        let sd = f32::from(cfg.odometry.drift_mdeg_per_m) / 1000.0
            * (core::f32::consts::PI / 180.0)
            * d_m;
        // The heading's uncertainty before the step swings the step's translation.
        let swing = d * d * self.tt;
        let k = clamp_var(self.odometry_scale, 1.0, MAX_ODOMETRY_SCALE);
        self.step_xx = k * st * st;
        self.step_tt = k * (sr * sr + sd * sd);
        self.xx += self.step_xx + swing + STEP_VAR_MM2;
        self.yy += self.step_xx + swing + STEP_VAR_MM2;
        self.tt += self.step_tt + STEP_VAR_RAD2;
        self.clamp();
    }

    /// Moves `predicted` towards the match `matched` as far as the gain says, and shrinks the
    /// uncertainty; returns the fused pose. `verdict` says which parts the match constrains
    /// (only usable verdicts are fused; others return `predicted` unchanged). With
    /// [`MatchConfig::match_sigma_mm`] 0 the match is taken as it is.
    pub fn fuse(&mut self, m: &MatchResult, cfg: &MatchConfig) -> Pose {
        let (predicted, matched, verdict) = (&m.predicted, &m.pose, &m.verdict);
        if !verdict.is_usable() {
            return *predicted;
        }
        if cfg.match_sigma_mm == 0 {
            *self = Uncertainty::ZERO;
            return *matched;
        }
        let r = f32::from(cfg.match_sigma_mm);
        let r2 = (r * r).max(MIN_VAR_MM2);
        let rt = f32::from(cfg.match_sigma_mdeg) / 1000.0 * (core::f32::consts::PI / 180.0);
        let rt2 = (rt * rt).max(MIN_VAR_RAD2);
        // The heading's innovation (angle units, and radians) and its χ²; none for a match that
        // cannot tell the heading.
        let e = f32::from(matched.heading.signed_diff(predicted.heading));
        let er = e * RAD_PER_UNIT;
        let fuse_heading = !matches!(verdict, Verdict::AmbiguousRotation);
        let d2_turn = if fuse_heading {
            er * er / (self.tt + rt2)
        } else {
            0.0
        };
        // R = r² I, stretched along the weakest direction by how much less score a move along
        // it loses than one along the strongest (the score's curvature is the information), and
        // open along the axis of a match that cannot tell it (a corridor, a single wall).
        let q = &m.quality;
        let stretch = if matches!(verdict, Verdict::Ambiguous { .. }) {
            OPEN
        } else {
            clamp_var(
                r2 * (f32::from(q.drop_strong) / f32::from(q.drop_weak.max(1)) - 1.0),
                0.0,
                OPEN,
            )
        };
        // The integer table (no f64, no libm's sin/cos on the board).
        let axis = match verdict {
            Verdict::Ambiguous { weak_axis } => *weak_axis,
            _ => q.weak_axis,
        };
        let (c, s) = axis.cos_sin_q30();
        let (c, s) = (c as f32 / Q30, s as f32 / Q30);
        let ex = (i64::from(matched.x_mm) - i64::from(predicted.x_mm)) as f32;
        let ey = (i64::from(matched.y_mm) - i64::from(predicted.y_mm)) as f32;
        // In the frame of the weak axis `u = (c, s)` and its normal `n = (−s, c)` R is diagonal
        // (r², r² + stretch): no f32 cancellation however large the stretch (in the world frame
        // the products of an open axis cancel to noise unless it is x or y).
        let (pnn, pnu, puu) = (
            s * s * self.xx - 2.0 * c * s * self.xy + c * c * self.yy,
            -s * c * self.xx + (c * c - s * s) * self.xy + c * s * self.yy,
            c * c * self.xx + 2.0 * c * s * self.xy + s * s * self.yy,
        );
        let (en, eu) = (-s * ex + c * ey, c * ex + s * ey);
        let (rn, ru) = (r2, r2 + stretch);
        // An innovation the model cannot explain is ignored while odometry's last step was the
        // sharper source (`ignore_outlier`); otherwise odometry slipped, or is worse than its
        // settings say, and it widens P until it is a one-σ innovation (P ← f P + (f − 1) r² I,
        // f = d²: S grows by f where the match constrains it, not along a stretched axis), so
        // the match is taken nearly whole: without this the filter would follow such odometry
        // for many scans. Within the gate the two are averaged.
        let d2 = mahalanobis2(en, eu, pnn + rn, pnu, puu + ru);
        if self.ignore_outlier(d2 > GATE_TRANS || d2_turn > GATE_TURN, r2, rt2) {
            return *predicted;
        }
        self.learn(d2 / 2.0);
        let (mut pnn, mut pnu, mut puu) = (pnn, pnu, puu);
        if d2 > GATE_TRANS {
            let f = d2;
            pnn = f * pnn + (f - 1.0) * r2;
            pnu *= f;
            puu = f * puu + (f - 1.0) * r2;
        }
        // S = P + R, K = P S⁻¹, in the (n, u) frame.
        let (snn, snu, suu) = (pnn + rn, pnu, puu + ru);
        let det = snn * suu - snu * snu;
        let (mut gn, mut gu) = (0.0f32, 0.0f32);
        if det.is_finite() && det > 0.0 {
            let (inn, inu, iuu) = (suu / det, -snu / det, snn / det);
            let knn = pnn * inn + pnu * inu;
            let knu = pnn * inu + pnu * iuu;
            let kun = pnu * inn + puu * inu;
            let kuu = pnu * inu + puu * iuu;
            gn = knn * en + knu * eu;
            gu = kun * en + kuu * eu;
            // P ← (I − K) P, symmetrised.
            let qnn = (1.0 - knn) * pnn - knu * pnu;
            let qnu = (1.0 - knn) * pnu - knu * puu;
            let qun = -kun * pnn + (1.0 - kuu) * pnu;
            let quu = -kun * pnu + (1.0 - kuu) * puu;
            pnn = qnn;
            pnu = 0.5 * (qnu + qun);
            puu = quu;
        }
        // Back to the world frame: P = [n u] P' [n u]ᵀ, g = n gn + u gu.
        self.xx = s * s * pnn - 2.0 * s * c * pnu + c * c * puu;
        self.xy = -s * c * pnn + (c * c - s * s) * pnu + s * c * puu;
        self.yy = c * c * pnn + 2.0 * s * c * pnu + s * s * puu;
        self.clamp();
        let (gx, gy) = (-s * gn + c * gu, c * gn + s * gu);
        let mut heading = predicted.heading;
        if fuse_heading {
            self.learn(d2_turn);
            if d2_turn > GATE_TURN {
                let f = d2_turn;
                self.tt = clamp_var(f * self.tt + (f - 1.0) * rt2, MIN_VAR_RAD2, MAX_VAR_RAD2);
            }
            let k = self.tt / (self.tt + rt2);
            heading = predicted
                .heading
                .wrapping_add(Angle(libm::roundf(k * e) as i16 as u16));
            self.tt *= 1.0 - k;
        }
        self.clamp();
        Pose {
            x_mm: round_add(predicted.x_mm, gx),
            y_mm: round_add(predicted.y_mm, gy),
            heading,
        }
    }

    /// Whether to ignore a match that is `outside` the gate (module docs): yes while
    /// odometry's last step was sharper than the match (`r2`, `rt2`) in translation and heading
    /// and fewer than [`SUSPECT_SCANS`] were ignored in a row. A match inside the gate, or one
    /// odometry's step cannot outdo, ends the run.
    fn ignore_outlier(&mut self, outside: bool, r2: f32, rt2: f32) -> bool {
        if outside && self.step_xx < r2 && self.step_tt < rt2 {
            if self.ignored < SUSPECT_SCANS {
                self.ignored += 1;
                return true;
            }
        } else {
            self.ignored = 0;
        }
        false
    }

    /// Adapts [`Uncertainty::odometry_scale`] to one normalised innovation `nis` (χ² per
    /// degree of freedom: 1 on average when the model is right): innovations larger than the
    /// model explains say odometry is worse than its settings, smaller ones that it is not.
    fn learn(&mut self, nis: f32) {
        let nis = if nis.is_finite() {
            clamp_var(nis, 0.0, 5.0)
        } else {
            5.0
        };
        let k = self.odometry_scale * (1.0 + ODOMETRY_LEARN * (nis - 1.0));
        self.odometry_scale = clamp_var(k, 1.0, MAX_ODOMETRY_SCALE);
    }

    /// Keeps every variance in range (and a NaN out: it becomes the floor).
    fn clamp(&mut self) {
        self.xx = clamp_var(self.xx, MIN_VAR_MM2, MAX_VAR_MM2);
        self.yy = clamp_var(self.yy, MIN_VAR_MM2, MAX_VAR_MM2);
        let lim = libm::sqrtf(self.xx * self.yy);
        self.xy = if self.xy.is_finite() {
            self.xy.max(-lim).min(lim)
        } else {
            0.0
        };
        self.tt = clamp_var(self.tt, MIN_VAR_RAD2, MAX_VAR_RAD2);
        self.odometry_scale = clamp_var(self.odometry_scale, 1.0, MAX_ODOMETRY_SCALE);
    }
}

/// `v` within `lo..=hi`; NaN becomes `hi` (not knowing is the uncertain side).
fn clamp_var(v: f32, lo: f32, hi: f32) -> f32 {
    // `max`/`min`, not `f32::clamp`: that asserts its bounds and formats them on failure,
    // which would link float formatting (~20 KiB) into the firmware.
    if v.is_nan() {
        hi
    } else {
        v.max(lo).min(hi)
    }
}

/// `eᵀ S⁻¹ e` for the symmetric `S = [sxx sxy; sxy syy]` (0 if `S` is singular).
fn mahalanobis2(ex: f32, ey: f32, sxx: f32, sxy: f32, syy: f32) -> f32 {
    let det = sxx * syy - sxy * sxy;
    if !(det.is_finite() && det > 0.0) {
        return 0.0;
    }
    let d2 = (syy * ex * ex - 2.0 * sxy * ex * ey + sxx * ey * ey) / det;
    if d2.is_finite() {
        d2
    } else {
        0.0
    }
}

/// `a + round(g)`, saturating (a non-finite `g` adds nothing).
fn round_add(a: i32, g: f32) -> i32 {
    if !g.is_finite() {
        return a;
    }
    // `as` saturates (and `g` is finite here).
    let g = libm::roundf(g) as i64;
    i64::from(a)
        .saturating_add(g)
        .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::OdometryNoise;
    use crate::localize::{Quality, Work};

    fn result(predicted: Pose, pose: Pose, verdict: Verdict) -> MatchResult {
        MatchResult {
            pose,
            predicted,
            verdict,
            quality: Quality {
                drop_weak: 300,
                drop_strong: 300,
                ..Quality::default()
            },
            work: Work::default(),
        }
    }

    fn cfg() -> MatchConfig {
        MatchConfig {
            match_sigma_mm: 20,
            match_sigma_mdeg: 500,
            ..MatchConfig::default()
        }
    }

    /// P = R of [`cfg`]: 20 mm per axis and 0.5°, all of it from the last odometry step.
    fn as_uncertain_as_the_match() -> Uncertainty {
        let tt = (0.5f32.to_radians()).powi(2);
        Uncertainty {
            xx: 400.0,
            xy: 0.0,
            yy: 400.0,
            tt,
            step_xx: 400.0,
            step_tt: tt,
            ..Uncertainty::ZERO
        }
    }

    #[test]
    fn equal_uncertainties_meet_half_way() {
        let c = cfg();
        // P = R: 20 mm per axis and 0.5°.
        let mut u = as_uncertain_as_the_match();
        let tt = u.tt;
        let p = Pose::new(1000, 2000, Angle(100));
        let m = Pose::new(1060, 1960, Angle(300));
        let f = u.fuse(&result(p, m, Verdict::Trusted), &c);
        assert_eq!((f.x_mm, f.y_mm, f.heading), (1030, 1980, Angle(200)));
        assert!((u.xx - 200.0).abs() < 0.5 && u.xy.abs() < 1e-3, "{u:?}");
        assert!((u.tt - tt / 2.0).abs() < tt * 1e-3);
    }

    #[test]
    fn an_exact_prediction_ignores_the_match_and_an_uncertain_one_takes_it() {
        let c = cfg();
        let p = Pose::new(0, 0, Angle::ZERO);
        // Within what the match's own σ explains.
        let m = Pose::new(20, -15, Angle(50));
        let mut exact = Uncertainty::ZERO;
        let f = exact.fuse(&result(p, m, Verdict::Trusted), &c);
        assert!(
            f.x_mm.abs() <= 1 && f.y_mm.abs() <= 1 && f.heading.0 <= 1,
            "{f:?}"
        );
        let m = Pose::new(80, -60, Angle(500));
        let mut lost = Uncertainty {
            xx: 1e8,
            xy: 0.0,
            yy: 1e8,
            tt: 1.0,
            ..Uncertainty::ZERO
        };
        let f = lost.fuse(&result(p, m, Verdict::Trusted), &c);
        assert_eq!((f.x_mm, f.y_mm, f.heading), (80, -60, Angle(500)));
        assert!(lost.sigma_mm() < 20.5, "{}", lost.sigma_mm());
    }

    #[test]
    fn a_corridor_corrects_across_it_only_and_unusable_matches_change_nothing() {
        let c = cfg();
        let p = Pose::new(0, 0, Angle::ZERO);
        let m = Pose::new(300, 40, Angle(200));
        let big = Uncertainty {
            xx: 400.0,
            xy: 0.0,
            yy: 400.0,
            tt: 0.1,
            ..Uncertainty::ZERO
        };
        // The corridor runs along x (moving along it loses 1 ‰ of the score, across it 600 ‰):
        // x stays about the prediction's, y and the heading meet the match half way or more.
        let mut corridor = result(
            p,
            m,
            Verdict::Ambiguous {
                weak_axis: Angle::ZERO,
            },
        );
        corridor.quality.drop_weak = 1;
        corridor.quality.drop_strong = 600;
        let mut u = big;
        let f = u.fuse(&corridor, &c);
        assert!(f.x_mm.abs() <= 1 && (f.y_mm - 20).abs() <= 1, "{f:?}");
        assert!((i32::from(f.heading.signed_diff(Angle(200)))).abs() <= 1);
        assert!(u.xx > 399.0 && (u.yy - 200.0).abs() < 1.0, "{u:?}");
        // A match that cannot tell the rotation keeps the heading.
        let mut u = big;
        let near = Pose::new(30, 40, Angle(200));
        let f = u.fuse(&result(p, near, Verdict::AmbiguousRotation), &c);
        assert_eq!(f.heading, Angle::ZERO);
        assert_eq!((f.x_mm, f.y_mm), (15, 20));
        for v in [
            Verdict::TooFewPoints,
            Verdict::NoOverlap,
            Verdict::OutOfWindow,
            Verdict::Contradicted,
            Verdict::Unconstrained,
        ] {
            let mut u = big;
            assert_eq!(u.fuse(&result(p, m, v), &c), p);
            assert_eq!(u, big);
        }
    }

    #[test]
    fn a_diagonal_corridor_corrects_across_it_only() {
        // Any weak axis, not only x or y: the open direction gets (almost) nothing, the
        // normal half of the innovation (P = R), whatever the angle.
        let c = cfg();
        let p = Pose::new(0, 0, Angle::ZERO);
        for deg in [5.6f64, 22.5, 34.0, 45.0, 61.0, 123.0, 200.0] {
            let a = Angle::from_degrees(deg);
            let (cu, su) = (deg.to_radians().cos(), deg.to_radians().sin());
            // 40 mm across the corridor and 300 mm along it.
            let (along, across) = (300.0, 40.0);
            let m = Pose::new(
                (along * cu - across * su).round() as i32,
                (along * su + across * cu).round() as i32,
                Angle::ZERO,
            );
            let mut u = as_uncertain_as_the_match();
            let f = u.fuse(&result(p, m, Verdict::Ambiguous { weak_axis: a }), &c);
            let (fx, fy) = (f64::from(f.x_mm), f64::from(f.y_mm));
            let got_along = fx * cu + fy * su;
            let got_across = -fx * su + fy * cu;
            assert!(got_along.abs() < 2.0, "{deg}°: {f:?}");
            assert!((got_across - 20.0).abs() < 2.0, "{deg}°: {f:?}");
            for v in [u.xx, u.xy, u.yy] {
                assert!(v.is_finite(), "{deg}°: {u:?}");
            }
        }
    }

    #[test]
    fn an_innovation_the_model_cannot_explain_widens_the_prediction() {
        let c = cfg();
        let p = Pose::new(0, 0, Angle::ZERO);
        // P = R (20 mm, 0.5°), but the match is 300 mm and 5° away: odometry slipped.
        let mut u = as_uncertain_as_the_match();
        let m = Pose::new(300, 0, Angle::from_degrees(5.0));
        let f = u.fuse(&result(p, m, Verdict::Trusted), &c);
        // Without the widening half way (150 mm, 2.5°); with it most of the way.
        assert!(f.x_mm > 250 && f.y_mm == 0, "{f:?}");
        let deg = f64::from(f.heading.signed_diff(Angle::ZERO)) * 360.0 / 65536.0;
        assert!(deg > 4.0, "{deg}");
    }

    #[test]
    fn an_outlier_against_sharper_odometry_is_ignored_until_it_persists() {
        let c = cfg();
        let p = Pose::new(0, 0, Angle::ZERO);
        // After a short straight step of good odometry (its own σ 1 mm and 0.01°, far below
        // the match's 20 mm and 0.5°) the pose is known to 2 mm and 0.05°.
        let sharp = Uncertainty {
            xx: 4.0,
            yy: 4.0,
            tt: (0.05f32.to_radians()).powi(2),
            step_xx: 1.0,
            step_tt: (0.01f32.to_radians()).powi(2),
            ..Uncertainty::ZERO
        };
        let outlier = result(
            p,
            Pose::new(300, 0, Angle::from_degrees(5.0)),
            Verdict::Trusted,
        );
        let mut u = sharp;
        for i in 0..SUSPECT_SCANS {
            assert_eq!(u.fuse(&outlier, &c), p, "match {i} is ignored");
            assert_eq!(u.ignored, i + 1);
        }
        // The next in a row: odometry did slip, and the match is taken most of the way.
        let f = u.fuse(&outlier, &c);
        assert!(f.x_mm > 250, "{f:?}");
        // A match within the gate ends the run: the next outlier is ignored again.
        let mut u = sharp;
        assert_eq!(u.fuse(&outlier, &c), p);
        u.fuse(
            &result(p, Pose::new(1, 0, Angle::ZERO), Verdict::Trusted),
            &c,
        );
        assert_eq!(u.ignored, 0);
        assert_eq!(u.fuse(&outlier, &c), p);
        // Odometry no sharper than the match (a long step of the cheap robot's odometry): the
        // outlier is odometry's slip and is taken at once.
        let mut u = Uncertainty::ZERO;
        u.predict(&Pose::new(2000, 0, Angle::from_degrees(90.0)), &c);
        assert!(u.step_xx > 400.0 && u.step_tt > (0.5f32.to_radians()).powi(2));
        assert!(u.fuse(&outlier, &c).x_mm > 250);
        assert_eq!(u.ignored, 0);
    }

    #[test]
    fn odometry_steps_grow_the_uncertainty_with_distance_and_turn() {
        let c = cfg();
        let mut u = Uncertainty::ZERO;
        u.predict(&Pose::new(0, 0, Angle::ZERO), &c);
        let still = u;
        u.predict(&Pose::new(1000, 0, Angle::ZERO), &c);
        // 1 m: 2 % per axis (20 mm), 0.5° of drift.
        assert!((u.xx - still.xx - 400.0).abs() < 1.0, "{u:?}");
        assert!((u.sigma_deg() - 0.5).abs() < 0.01, "{}", u.sigma_deg());
        let before = u;
        u.predict(&Pose::new(0, 0, Angle::QUARTER), &c);
        // A quarter turn: 5 % of it, 4.5°, on top.
        let want = (before.tt + (0.05 * core::f32::consts::FRAC_PI_2).powi(2)).sqrt();
        assert!((u.tt.sqrt() - want).abs() < 1e-4);
        // Driving on, the heading's uncertainty swings the translation.
        let before = u;
        u.predict(&Pose::new(1000, 0, Angle::ZERO), &c);
        assert!(u.xx - before.xx > 400.0 + 1e6 * before.tt * 0.99);
    }

    #[test]
    fn absurd_input_stays_finite() {
        let c = MatchConfig {
            match_sigma_mm: u16::MAX,
            match_sigma_mdeg: u16::MAX,
            odometry: OdometryNoise {
                trans_permille: u16::MAX,
                turn_permille: u16::MAX,
                drift_mdeg_per_m: u16::MAX,
            },
            ..MatchConfig::default()
        };
        let mut u = Uncertainty::ZERO;
        for _ in 0..100 {
            u.predict(&Pose::new(i32::MAX, i32::MIN, Angle::HALF), &c);
        }
        let p = Pose::new(i32::MIN, i32::MAX, Angle::ZERO);
        let m = Pose::new(i32::MAX, i32::MIN, Angle::HALF);
        let _ = u.fuse(&result(p, m, Verdict::Trusted), &c);
        for v in [u.xx, u.xy, u.yy, u.tt, u.odometry_scale] {
            assert!(v.is_finite(), "{u:?}");
        }
        let mut nan = Uncertainty {
            xx: f32::NAN,
            xy: f32::NAN,
            yy: f32::INFINITY,
            tt: f32::NAN,
            ..Uncertainty::ZERO
        };
        nan.predict(&Pose::new(10, 0, Angle::ZERO), &c);
        assert!(
            nan.xx.is_finite() && nan.xy.is_finite() && nan.tt.is_finite(),
            "{nan:?}"
        );
    }
}
