//! `--odometry-noise MODEL[:SEED]`: drifting wheel odometry on the link instead of the true
//! poses ([`ogm_core::localize::odometry`]), the truth kept for scoring; and how far the poses
//! the robot reports (corrected, [`ogm_core::wire::ScanReport::pose`]) lie from the truth.

use ogm_core::localize::odometry::{wrap, Odometry, OdometryModel, PoseF};
use ogm_core::wire::{MatchVerdict, ScanReport};
use ogm_core::Pose;
use serde::Serialize;

use crate::sim::explore::ScanRecord;

/// `--odometry-noise`: a model and the drift's seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometryArg {
    /// The preset's name.
    pub name: &'static str,
    /// The drift.
    pub model: OdometryModel,
    /// The drift's seed (`None`: the run's `--seed`).
    pub seed: Option<u64>,
}

/// Parses `MODEL[:SEED]` (`issue39`, `cheap`).
pub fn parse_odometry(s: &str) -> Result<OdometryArg, String> {
    let (name, seed) = match s.split_once(':') {
        Some((n, seed)) => (
            n,
            Some(
                seed.parse::<u64>()
                    .map_err(|_| format!("`{s}`: SEED must be a whole number"))?,
            ),
        ),
        None => (s, None),
    };
    let (name, model) = match name {
        "issue39" => ("issue39", OdometryModel::ISSUE_39),
        "cheap" => ("cheap", OdometryModel::CHEAP_ROBOT),
        _ => {
            return Err(format!(
                "`{s}`: MODEL is `issue39` or `cheap` (optionally `:SEED`)"
            ))
        }
    };
    Ok(OdometryArg { name, model, seed })
}

/// `scans` with their poses replaced by what wheel odometry under `arg` reports along them
/// (from the first true pose; `seed` when the argument names none).
pub fn with_odometry(scans: &[ScanRecord], arg: &OdometryArg, seed: u64) -> Vec<ScanRecord> {
    let mut odo = Odometry::new(arg.model, arg.seed.unwrap_or(seed));
    scans
        .iter()
        .map(|s| ScanRecord {
            pose: odo.step(&s.pose),
            beams: s.beams.clone(),
        })
        .collect()
}

/// How far poses lie from the truth, over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PoseErrors {
    /// Scans compared.
    pub scans: usize,
    /// Position error, mean and max, m.
    pub mean_m: f64,
    /// See `mean_m`.
    pub max_m: f64,
    /// Heading error, mean and max, degrees.
    pub mean_deg: f64,
    /// See `mean_deg`.
    pub max_deg: f64,
}

impl PoseErrors {
    /// The errors of `poses` against `truth`, pairwise.
    pub fn of(poses: &[Pose], truth: &[Pose]) -> PoseErrors {
        let mut e = PoseErrors::default();
        for (p, t) in poses.iter().zip(truth) {
            let (p, t) = (PoseF::of(p), PoseF::of(t));
            let d = ((p.x - t.x).powi(2) + (p.y - t.y).powi(2)).sqrt() / 1000.0;
            let a = wrap(p.th - t.th).abs().to_degrees();
            e.scans += 1;
            e.mean_m += d;
            e.mean_deg += a;
            e.max_m = e.max_m.max(d);
            e.max_deg = e.max_deg.max(a);
        }
        if e.scans > 0 {
            e.mean_m /= e.scans as f64;
            e.mean_deg /= e.scans as f64;
        }
        e
    }
}

/// What the robot did with drifting odometry (`--odometry-noise`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct OdometryReport {
    /// The model (`issue39`, `cheap`) and the drift's seed.
    pub model: String,
    /// The drift's seed.
    pub seed: u64,
    /// The odometry sent against the truth.
    pub odometry: PoseErrors,
    /// The poses the robot mapped at (its scan reports) against the truth.
    pub corrected: PoseErrors,
    /// Scans mapped at a corrected pose (trusted or ambiguous verdict).
    pub matched: usize,
    /// Scans where the matcher could not tell (mapped on odometry).
    pub cannot_tell: usize,
}

impl OdometryReport {
    /// The report of a run that sent `sent` (odometry) for `truth`, and got `reports` back (in
    /// scan order).
    pub fn of(
        arg: &OdometryArg,
        seed: u64,
        truth: &[ScanRecord],
        sent: &[ScanRecord],
        reports: &[ScanReport],
    ) -> Self {
        let truth: Vec<Pose> = truth.iter().map(|s| s.pose).collect();
        let sent: Vec<Pose> = sent.iter().map(|s| s.pose).collect();
        let got: Vec<Pose> = reports.iter().map(|r| r.pose).collect();
        let verdicts = reports.iter().map(|r| r.correction.verdict);
        OdometryReport {
            model: arg.name.to_string(),
            seed: arg.seed.unwrap_or(seed),
            odometry: PoseErrors::of(&sent, &truth),
            corrected: PoseErrors::of(&got, &truth),
            matched: verdicts.clone().filter(MatchVerdict::corrected).count(),
            cannot_tell: verdicts.filter(MatchVerdict::cannot_tell).count(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn models_parse_and_bad_ones_say_why() {
        let a = parse_odometry("issue39").unwrap();
        assert_eq!((a.model, a.seed), (OdometryModel::ISSUE_39, None));
        let c = parse_odometry("cheap:7").unwrap();
        assert_eq!((c.model, c.seed), (OdometryModel::CHEAP_ROBOT, Some(7)));
        assert!(parse_odometry("perfect").unwrap_err().contains("MODEL"));
        assert!(parse_odometry("cheap:x").unwrap_err().contains("SEED"));
    }

    #[test]
    fn odometry_drifts_from_the_first_true_pose() {
        let scans: Vec<ScanRecord> = (0..50)
            .map(|i| ScanRecord {
                pose: Pose::new(200 * i, 0, ogm_core::Angle::ZERO),
                beams: Vec::new(),
            })
            .collect();
        let arg = parse_odometry("cheap:3").unwrap();
        let sent = with_odometry(&scans, &arg, 1);
        assert_eq!(sent[0].pose, scans[0].pose);
        let truth: Vec<Pose> = scans.iter().map(|s| s.pose).collect();
        let odo: Vec<Pose> = sent.iter().map(|s| s.pose).collect();
        let e = PoseErrors::of(&odo, &truth);
        // 10 m with a 0.5°/m bias: well off by the end, never wildly.
        assert!(e.max_m > 0.1 && e.max_m < 3.0, "{e:?}");
        assert_eq!(with_odometry(&scans, &arg, 99)[49].pose, sent[49].pose);
    }
}
