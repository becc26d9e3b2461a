//! A seeded wheel-odometry model for simulators and evaluations: turns a sequence of true poses
//! into the poses a differential-drive robot's wheel odometry would report (issue 39).
//!
//! It lives in ogm-core (not host-sim) so that every user draws the same drift from the same seed
//! — the simulator that feeds the firmware, the log evaluation, and the tests of `ogm-core` and
//! of the `tests` crate — and because it is `no_std` and deterministic (`libm`, no platform
//! floating-point library), so a seed means the same odometry on every machine. The firmware never
//! calls it (it receives odometry), so none of it is linked there.
//!
//! ## Model (per step between two consecutive true poses)
//! Let the true motion, in the frame of the previous true pose, be `(dx, dy)` over a distance
//! `d = |(dx, dy)|`, and the turn `dθ`. Odometry reports
//! * `dx' = s·dx + N(0, (σ_t·d)²)`, `dy' = s·dy + N(0, (σ_t·d)²)` — the translation, scaled by the
//!   distance scale error `s = 1 + dist_scale` (mean wheel diameter wrong: UMBmark's `E_s`) with
//!   noise proportional to the distance (slip, encoder quantisation);
//! * `dθ' = (1 + turn_scale)·dθ + bias·d + N(0, (σ_r·|dθ|)² + (σ_rt·d)²)` — the turn, scaled by the
//!   wheelbase error (`E_b`: the effective track is not the nominal one), a heading bias per metre
//!   travelled (`E_d`: unequal wheel diameters make a robot driving "straight" turn), noise
//!   proportional to the turn, and noise proportional to the distance (a wheel slipping on a
//!   straight run turns the robot);
//!
//! and integrates the reported steps from the first true pose. Noise is Gaussian (splitmix64 +
//! Box–Muller), four draws per step whatever the parameters, so the same seed gives the same
//! draws under any settings.
//!
//! ## Presets
//! * [`OdometryModel::ISSUE_39`] — the issue's "mild" model: σ_t 1 %, σ_r 2 %, bias 0.11°/m.
//! * [`OdometryModel::CHEAP_ROBOT`] — what a small, uncalibrated differential-drive robot with
//!   hobby encoders does (the figures and their sources are on the constant).
//!
//! Both are far below what particle filters assume for safety (ROS/Nav2 AMCL's defaults are 0.2
//! for each of its four noise factors, `alpha1..4`), so neither flatters odometry.

use crate::types::angle::Angle;
use crate::types::geometry::Pose;

/// The parameters of the drift (see the module docs for the equations).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometryModel {
    /// σ of each translation component per metre travelled (fraction of the distance).
    pub trans_noise: f64,
    /// σ of the turn per radian turned (fraction of the turn).
    pub rot_noise: f64,
    /// σ of the turn per metre travelled, radians per metre.
    pub rot_noise_per_m: f64,
    /// Heading bias, radians per metre travelled (positive: turns left).
    pub bias_rad_per_m: f64,
    /// Systematic turn scale error (0.02: reports 2 % more turn than the robot made).
    pub turn_scale: f64,
    /// Systematic distance scale error (0.01: reports 1 % more distance).
    pub dist_scale: f64,
}

impl OdometryModel {
    /// Issue 39's model: translation noise 1 % of the distance, rotation noise 2 % of the turn,
    /// a heading bias of 0.11° per metre; no scale errors.
    pub const ISSUE_39: OdometryModel = OdometryModel {
        trans_noise: 0.01,
        rot_noise: 0.02,
        rot_noise_per_m: 0.0,
        bias_rad_per_m: 0.11 * core::f64::consts::PI / 180.0,
        turn_scale: 0.0,
        dist_scale: 0.0,
    };

    /// A small uncalibrated differential-drive robot (wheelbase ~0.2 m, hobby encoders,
    /// rubber tyres; the robots this project targets):
    /// * heading bias 0.5°/m: a wheel-diameter ratio `E_d` of 1.002 (0.2 %, well within the
    ///   tolerance of moulded tyres and of a load on one side) on a 0.23 m track turns the robot
    ///   by `(E_d − 1)/b` ≈ 0.0087 rad ≈ 0.5° per metre (Borenstein & Feng 1996, UMBmark: the
    ///   uncalibrated robots they measured had `E_d` and `E_b` errors of this order and more);
    /// * turn scale 2 %: the effective track lies somewhere across the tyres' contact patches,
    ///   ±5 mm of a 0.23 m track is ±2 % (`E_b`);
    /// * distance scale 1 % (`E_s`: tyre compression, nominal wheel diameter);
    /// * noise: 2 % of the distance per axis, 5 % of the turn, 0.2° per metre (slip on floor
    ///   joints, carpet edges, encoder quantisation at ~1 mm per tick).
    pub const CHEAP_ROBOT: OdometryModel = OdometryModel {
        trans_noise: 0.02,
        rot_noise: 0.05,
        rot_noise_per_m: 0.2 * core::f64::consts::PI / 180.0,
        bias_rad_per_m: 0.5 * core::f64::consts::PI / 180.0,
        turn_scale: 0.02,
        dist_scale: 0.01,
    };

    /// No drift at all: odometry equals the truth.
    pub const PERFECT: OdometryModel = OdometryModel {
        trans_noise: 0.0,
        rot_noise: 0.0,
        rot_noise_per_m: 0.0,
        bias_rad_per_m: 0.0,
        turn_scale: 0.0,
        dist_scale: 0.0,
    };
}

/// A pose in millimetres and radians (the model's own state: integrating rounded poses would add
/// a rounding error per step).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseF {
    /// x, mm.
    pub x: f64,
    /// y, mm.
    pub y: f64,
    /// Heading, radians in (−π, π].
    pub th: f64,
}

impl PoseF {
    /// The pose of an integer [`Pose`].
    pub fn of(p: &Pose) -> PoseF {
        PoseF {
            x: f64::from(p.x_mm),
            y: f64::from(p.y_mm),
            th: wrap(p.heading.to_radians()),
        }
    }

    /// The nearest integer [`Pose`] (positions saturate at the `i32` range).
    pub fn pose(&self) -> Pose {
        let r = |v: f64| libm::round(v).clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        Pose::new(r(self.x), r(self.y), Angle::from_radians(self.th))
    }

    /// `self ⊕ d`: the motion `d` (in this pose's frame) applied to this pose.
    pub fn compose(&self, d: &PoseF) -> PoseF {
        let (s, c) = (libm::sin(self.th), libm::cos(self.th));
        PoseF {
            x: self.x + c * d.x - s * d.y,
            y: self.y + s * d.x + c * d.y,
            th: wrap(self.th + d.th),
        }
    }

    /// `self⁻¹ ⊕ other`: the motion from this pose to `other`, in this pose's frame.
    pub fn between(&self, other: &PoseF) -> PoseF {
        let (s, c) = (libm::sin(self.th), libm::cos(self.th));
        let (dx, dy) = (other.x - self.x, other.y - self.y);
        PoseF {
            x: c * dx + s * dy,
            y: -s * dx + c * dy,
            th: wrap(other.th - self.th),
        }
    }
}

/// An angle wrapped into (−π, π].
pub fn wrap(a: f64) -> f64 {
    let t = core::f64::consts::TAU;
    a - t * libm::floor((a + core::f64::consts::PI) / t)
}

/// Simulated wheel odometry: feed it the true poses in order, get the odometry poses.
#[derive(Clone, Debug)]
pub struct Odometry {
    model: OdometryModel,
    rng: u64,
    /// The last true pose seen and the odometry pose reported for it.
    last: Option<(PoseF, PoseF)>,
}

impl Odometry {
    /// Odometry drifting by `model`, its noise drawn from `seed`.
    pub fn new(model: OdometryModel, seed: u64) -> Self {
        Odometry {
            model,
            rng: seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x39,
            last: None,
        }
    }

    /// The model.
    pub fn model(&self) -> &OdometryModel {
        &self.model
    }

    /// The odometry pose for the next true pose (the first is reported as it is).
    pub fn step(&mut self, truth: &Pose) -> Pose {
        self.step_f(&PoseF::of(truth)).pose()
    }

    /// [`Odometry::step`] in millimetres and radians, without rounding.
    pub fn step_f(&mut self, truth: &PoseF) -> PoseF {
        let out = match self.last {
            None => *truth,
            Some((prev_truth, prev_odo)) => {
                let d = prev_truth.between(truth);
                let dist = libm::hypot(d.x, d.y) / 1000.0; // m
                let m = self.model;
                let (n1, n2, n3, n4) = (self.normal(), self.normal(), self.normal(), self.normal());
                let s = 1.0 + m.dist_scale;
                let noisy = PoseF {
                    x: s * d.x + m.trans_noise * dist * 1000.0 * n1,
                    y: s * d.y + m.trans_noise * dist * 1000.0 * n2,
                    th: (1.0 + m.turn_scale) * d.th
                        + m.bias_rad_per_m * dist
                        + m.rot_noise * libm::fabs(d.th) * n3
                        + m.rot_noise_per_m * dist * n4,
                };
                prev_odo.compose(&noisy)
            }
        };
        self.last = Some((*truth, out));
        out
    }

    /// splitmix64.
    fn next_u64(&mut self) -> u64 {
        self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1).
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller, one of the pair).
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        libm::sqrt(-2.0 * libm::log(u)) * libm::cos(core::f64::consts::TAU * v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_path() -> [PoseF; 9] {
        let q = core::f64::consts::FRAC_PI_2;
        [
            PoseF {
                x: 0.0,
                y: 0.0,
                th: 0.0,
            },
            PoseF {
                x: 2000.0,
                y: 0.0,
                th: 0.0,
            },
            PoseF {
                x: 2000.0,
                y: 0.0,
                th: q,
            },
            PoseF {
                x: 2000.0,
                y: 2000.0,
                th: q,
            },
            PoseF {
                x: 2000.0,
                y: 2000.0,
                th: 2.0 * q,
            },
            PoseF {
                x: 0.0,
                y: 2000.0,
                th: 2.0 * q,
            },
            PoseF {
                x: 0.0,
                y: 2000.0,
                th: -q,
            },
            PoseF {
                x: 0.0,
                y: 0.0,
                th: -q,
            },
            PoseF {
                x: 0.0,
                y: 0.0,
                th: 0.0,
            },
        ]
    }

    #[test]
    fn perfect_model_reports_the_truth() {
        let mut o = Odometry::new(OdometryModel::PERFECT, 7);
        for t in square_path() {
            let r = o.step_f(&t);
            assert!(
                (r.x - t.x).abs() < 1e-6 && (r.y - t.y).abs() < 1e-6,
                "{r:?} {t:?}"
            );
            assert!(wrap(r.th - t.th).abs() < 1e-9);
        }
    }

    #[test]
    fn bias_turns_a_straight_run() {
        let model = OdometryModel {
            bias_rad_per_m: 0.01,
            ..OdometryModel::PERFECT
        };
        let mut o = Odometry::new(model, 1);
        o.step_f(&PoseF::default());
        let r = o.step_f(&PoseF {
            x: 3000.0,
            ..PoseF::default()
        });
        assert!((r.th - 0.03).abs() < 1e-12, "{r:?}");
        // The translation itself is reported exactly (no noise, no scale).
        assert!((r.x - 3000.0).abs() < 1e-9 && r.y.abs() < 1e-9);
    }

    #[test]
    fn same_seed_same_drift_other_seed_other_drift() {
        let run = |seed| {
            let mut o = Odometry::new(OdometryModel::CHEAP_ROBOT, seed);
            square_path().map(|t| o.step_f(&t))
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
        // The cheap robot ends the 8 m square well away from where it started.
        let end = run(3)[8];
        assert!(libm::hypot(end.x, end.y) > 20.0, "{end:?}");
    }
}
