//! How far an estimated trajectory is from the truth: the relative pose error of Kümmerle et
//! al. 2009 ("On measuring the accuracy of SLAM algorithms"), and the absolute position error.
//!
//! The relative pose error at Δ scans compares, for every pair (i, i + Δ), the motion the
//! estimate says the robot made with the motion it made: `e = (tᵢ⁻¹ ∘ tᵢ₊Δ)⁻¹ ∘ (eᵢ⁻¹ ∘ eᵢ₊Δ)`;
//! its translation (m) and rotation (°) are averaged over the pairs. Unlike the absolute error
//! it does not depend on where along the run an error happened (one bad heading early makes
//! every later absolute position wrong, but only the pairs spanning it), and Δ picks the scale:
//! 1 scan is the step's own error, 10 and 100 the drift over a room and over a corridor.

use ogm_core::localize::odometry::PoseF;
use ogm_core::Pose;
use serde::{Deserialize, Serialize};

/// The scan distances reported: 1, 10 and 100 scans apart.
pub const RPE_DELTAS: [usize; 3] = [1, 10, 100];

/// The relative pose error at one scan distance.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Rpe {
    /// Scans apart.
    pub delta: usize,
    /// Mean translation error, m.
    pub trans_m: f64,
    /// Mean rotation error, degrees.
    pub rot_deg: f64,
    /// Largest translation error, m.
    pub max_trans_m: f64,
    /// Pairs averaged (0: the run is not longer than `delta`, and the errors are 0).
    pub pairs: usize,
}

/// The relative pose error of `estimate` against `truth` at `delta` scans (pairs up to the
/// shorter of the two).
pub fn rpe(truth: &[Pose], estimate: &[Pose], delta: usize) -> Rpe {
    let t: Vec<PoseF> = truth.iter().map(PoseF::of).collect();
    let e: Vec<PoseF> = estimate.iter().map(PoseF::of).collect();
    rpe_f(&t, &e, delta)
}

/// [`rpe`] on poses in millimetres and radians.
pub fn rpe_f(truth: &[PoseF], estimate: &[PoseF], delta: usize) -> Rpe {
    let mut r = Rpe {
        delta,
        ..Rpe::default()
    };
    let n = truth.len().min(estimate.len());
    if delta == 0 {
        return r;
    }
    for i in 0..n.saturating_sub(delta) {
        let moved = truth[i].between(&truth[i + delta]);
        let said = estimate[i].between(&estimate[i + delta]);
        let err = moved.between(&said);
        let d = err.x.hypot(err.y) / 1000.0;
        r.trans_m += d;
        r.rot_deg += err.th.abs().to_degrees();
        r.max_trans_m = r.max_trans_m.max(d);
        r.pairs += 1;
    }
    if r.pairs > 0 {
        r.trans_m /= r.pairs as f64;
        r.rot_deg /= r.pairs as f64;
    }
    r
}

/// [`rpe`] at each of [`RPE_DELTAS`].
pub fn rpe_all(truth: &[Pose], estimate: &[Pose]) -> Vec<Rpe> {
    RPE_DELTAS
        .iter()
        .map(|&d| rpe(truth, estimate, d))
        .collect()
}

/// The absolute position error, m: mean and largest over the scans.
pub fn position_error(truth: &[Pose], estimate: &[Pose]) -> (f64, f64) {
    let d: Vec<f64> = truth
        .iter()
        .zip(estimate)
        .map(|(t, e)| {
            (f64::from(t.x_mm) - f64::from(e.x_mm)).hypot(f64::from(t.y_mm) - f64::from(e.y_mm))
                / 1000.0
        })
        .collect();
    let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
    (mean, d.iter().copied().fold(0.0, f64::max))
}

/// `a / b`, or NaN when `b` is 0 (a run without odometry error has no ratio).
pub fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        f64::NAN
    }
}
