//! Pose correction through the session (issue 39): `Session::insert` takes odometry, matches
//! the scan against the session's own map, inserts at the corrected pose and says so
//! (`Inserted::correction`, the wire's `CorrectionReport`). Drifting odometry is corrected;
//! bad input (a lidar that sees nothing, an odometry jump, a single wall) is reported as what
//! the matcher cannot tell, and the robot keeps mapping on odometry.

use ogm_core::config::{Budget, OdometryNoise, PoseCorrection, PoseInput, RunConfig};
use ogm_core::localize::fuse::SUSPECT_SCANS;
use ogm_core::localize::odometry::{wrap, PoseF};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::MatchVerdict;
use ogm_core::{Angle, Beam, Pose, Range};

mod common;
use common::{pose_of, Seg};

/// A 5 × 4 m room centred on the origin, with a pillar, a cabinet and a partition, so that no
/// direction and no rotation is left open.
fn room() -> Vec<Seg> {
    vec![
        (-2500.0, -2000.0, 2500.0, -2000.0),
        (2500.0, -2000.0, 2500.0, 2000.0),
        (2500.0, 2000.0, -2500.0, 2000.0),
        (-2500.0, 2000.0, -2500.0, -2000.0),
        (800.0, 500.0, 1100.0, 500.0),
        (1100.0, 500.0, 1100.0, 800.0),
        (1100.0, 800.0, 800.0, 800.0),
        (800.0, 800.0, 800.0, 500.0),
        (-1800.0, -2000.0, -1800.0, -1500.0),
        (-1800.0, -1500.0, -1000.0, -1500.0),
        (-1000.0, -1500.0, -1000.0, -2000.0),
        (-300.0, 2000.0, -300.0, 1000.0),
    ]
}

/// The session tests' lidar: 360 beams, 6 m.
fn scan(world: &[Seg], pose: (f64, f64, f64)) -> Vec<Beam> {
    common::scan(world, pose, 360, 6000.0)
}

/// Position (mm) and heading (degrees) error of `p` against `truth`.
fn err(p: &Pose, truth: (f64, f64, f64)) -> (f64, f64) {
    let q = PoseF::of(p);
    (
        (q.x - truth.0).hypot(q.y - truth.1),
        wrap(q.th - truth.2).abs().to_degrees(),
    )
}

fn session(correction: PoseCorrection, poses: PoseInput) -> Session<Owned<u8>> {
    session_with(config(correction, poses))
}

fn config(correction: PoseCorrection, poses: PoseInput) -> RunConfig {
    RunConfig::ROBOT
        .with_origin_mm(-3200, -3200)
        .with_max_range_mm(6000)
        .with_budget(Budget::Fixed { updates: 0 })
        .with_poses(poses)
        .with_correction(correction)
}

fn session_with(config: RunConfig) -> Session<Owned<u8>> {
    Session::new(config, Owned::<u8>::buffers(&Sizes::grid(128, 128))).unwrap()
}

/// The true path: 40 scans, 40 mm and 0.8° apart, from (−1500, −700) heading 0.
fn path() -> Vec<(f64, f64, f64)> {
    (0..40)
        .map(|i| {
            let i = f64::from(i);
            (
                -1500.0 + 40.0 * i,
                -700.0 + 15.0 * i,
                (0.8 * i).to_radians(),
            )
        })
        .collect()
}

/// Odometry along `truth`: every step reported 4 % too long and turned 0.6° too far left.
fn drifting(truth: &[(f64, f64, f64)]) -> Vec<Pose> {
    let t: Vec<PoseF> = truth.iter().map(|&(x, y, th)| PoseF { x, y, th }).collect();
    let mut odo = t[0];
    let mut out = vec![odo.pose()];
    for w in t.windows(2) {
        let mut d = w[0].between(&w[1]);
        d.x *= 1.04;
        d.y *= 1.04;
        d.th += 0.6f64.to_radians();
        odo = odo.compose(&d);
        out.push(odo.pose());
    }
    out
}

#[test]
fn drifting_odometry_is_corrected_and_reported() {
    let (world, truth) = (room(), path());
    let odo = drifting(&truth);
    // The robot is told how bad its odometry is (`RunConfig::odometry`): 4 % of the distance,
    // 0.6° per 43 mm step.
    let mut on = session_with(
        config(PoseCorrection::Match, PoseInput::Link).with_odometry_noise(OdometryNoise {
            trans_permille: 40,
            turn_permille: 50,
            drift_mdeg_per_m: 14_000,
        }),
    );
    let mut off = session(PoseCorrection::Off, PoseInput::Link);
    let (mut worst_on, mut worst_off) = ((0.0f64, 0.0f64), (0.0f64, 0.0f64));
    for (t, o) in truth.iter().zip(&odo) {
        let beams = scan(&world, *t);
        let a = on.insert(o, &beams).unwrap();
        let c = a.correction;
        assert_eq!(c.odometry, *o);
        let report = on.correction_report(&c);
        assert!(!report.without_odometry);
        let (d, h) = err(&c.pose, *t);
        worst_on = (worst_on.0.max(d), worst_on.1.max(h));
        let b = off.insert(o, &beams).unwrap();
        assert_eq!(b.correction.pose, *o, "correction off: the pose as it came");
        assert_eq!(
            off.correction_report(&b.correction).verdict,
            MatchVerdict::Off
        );
        let (d, h) = err(o, *t);
        worst_off = (worst_off.0.max(d), worst_off.1.max(h));
    }
    // Odometry ends ~0.5 m and 23° off; the corrected poses stay within 8 cm and 2.5° (the
    // filter weighs each step's 0.6° of odometry against a match it trusts to 0.8°, this
    // σ = 3-cell sensor's, so it lags the drift by a fraction of both).
    assert!(worst_off.0 > 300.0 && worst_off.1 > 20.0, "{worst_off:?}");
    assert!(worst_on.0 < 80.0 && worst_on.1 < 2.5, "{worst_on:?}");
    // The correction map ← odometry is what the last scan used.
    let (last_odo, last_pose) = on.last_correction().unwrap();
    assert_eq!(last_odo, *odo.last().unwrap());
    assert!(err(&last_pose, *truth.last().unwrap()).0 < 80.0);
}

#[test]
fn without_odometry_the_robot_tracks_itself_and_says_so() {
    let (world, truth) = (room(), path());
    let mut s = session(PoseCorrection::Match, PoseInput::Fixed);
    // No odometry: every scan comes with the first pose.
    let fixed = pose_of(truth[0]);
    let mut worst = (0.0f64, 0.0f64);
    for t in &truth {
        let c = s.insert(&fixed, &scan(&world, *t)).unwrap().correction;
        assert!(s.correction_report(&c).without_odometry);
        let (d, h) = err(&c.pose, *t);
        worst = (worst.0.max(d), worst.1.max(h));
    }
    // The robot moved 1.6 m and turned 31°; it knows where it is within 5 cm and 1.5° (the
    // second scan, matched against one scan's map, is not trusted and stays where the first
    // was: one step, 43 mm, off).
    assert!(worst.0 < 50.0 && worst.1 < 1.5, "{worst:?}");
}

/// A session that has mapped the room from three scans at the truth.
fn mapped() -> (Session<Owned<u8>>, (f64, f64, f64)) {
    let world = room();
    let mut s = session(PoseCorrection::Match, PoseInput::Link);
    let at = (-500.0, -300.0, 0.3);
    for dx in [0.0, 20.0, 40.0] {
        let p = (at.0 + dx, at.1, at.2);
        s.insert(&pose_of(p), &scan(&world, p)).unwrap();
    }
    (s, (at.0 + 60.0, at.1, at.2))
}

#[test]
fn a_lidar_that_sees_nothing_maps_on_odometry() {
    let (mut s, next) = mapped();
    let blind: Vec<Beam> = (0..360)
        .map(|i| Beam {
            angle: Angle::from_centidegrees(100 * i),
            range: Range::NoReturn,
        })
        .collect();
    let a = s.insert(&pose_of(next), &blind).unwrap();
    let c = a.correction;
    assert_eq!(s.correction_report(&c).verdict, MatchVerdict::TooFewPoints);
    assert!(s.correction_report(&c).verdict.cannot_tell());
    assert_eq!(c.pose, c.predicted, "mapped at the odometry prediction");
    assert!(a.stats.cells_freed > 0, "and still mapped: {:?}", a.stats);
}

#[test]
fn an_odometry_jump_is_not_trusted_and_maps_near_odometry() {
    let (mut s, next) = mapped();
    // Odometry says the robot jumped 1.2 m; the scan is from where it really is.
    let jumped = pose_of((next.0 + 1200.0, next.1 + 300.0, next.2));
    let beams = scan(&room(), next);
    let a = s.insert(&jumped, &beams).unwrap();
    let c = a.correction;
    let v = s.correction_report(&c).verdict;
    // Not trusted; at most one direction corrected, and not by much: the scan is mapped
    // (nearly) where odometry put it.
    assert!(
        !matches!(v, MatchVerdict::Trusted | MatchVerdict::Off),
        "{v:?}"
    );
    let moved =
        f64::from(c.pose.x_mm - c.predicted.x_mm).hypot(f64::from(c.pose.y_mm - c.predicted.y_mm));
    assert!(moved < 100.0, "{c:?}");
    assert!(a.stats.cells_hit > 0);
}

#[test]
fn a_single_wall_leaves_its_direction_to_odometry() {
    // A 30 m wall along x: the match can only say how far the robot is from it.
    let wall = [(-20_000.0, 1000.0, 20_000.0, 1000.0)];
    let mut s = session(PoseCorrection::Match, PoseInput::Link);
    let mut p = (-1500.0, 0.0, 0.0);
    for _ in 0..3 {
        s.insert(&pose_of(p), &scan(&wall, p)).unwrap();
        p.0 += 30.0;
    }
    // Odometry slips 80 mm along the wall and 150 mm across it: more than one step of odometry
    // or the match's own noise explains. Odometry's step was the sharper source, so the first
    // such matches are taken for the match's fault and the scans stay on odometry; when the
    // disagreement persists, the filter takes the match across the wall.
    let odo = pose_of((p.0 + 80.0, p.1 + 150.0, p.2));
    for _ in 0..SUSPECT_SCANS {
        let c = s.correct(&odo, &scan(&wall, p));
        assert_eq!(c.pose, c.predicted, "{c:?}");
    }
    let taken = s.correct(&odo, &scan(&wall, p));
    let c = s.insert(&odo, &scan(&wall, p)).unwrap().correction;
    assert_eq!(c, taken);
    let v = s.correction_report(&c).verdict;
    match v {
        MatchVerdict::Ambiguous { .. } => {
            // Along the wall odometry's; across it corrected (half way or more: the prior on
            // the prediction holds the rest).
            assert!((c.pose.x_mm - c.predicted.x_mm).abs() < 20, "{c:?}");
            let across = |q: &Pose| (f64::from(q.y_mm) - p.1).abs();
            assert!(across(&c.pose) * 2.0 <= across(&c.predicted), "{c:?}");
        }
        other => {
            assert!(other.cannot_tell(), "{other:?}");
            assert_eq!(c.pose, c.predicted);
        }
    }
    assert!(
        !matches!(v, MatchVerdict::Trusted | MatchVerdict::Off),
        "{v:?}"
    );
}

/// With a rolling window the caller corrects first (the shift follows the corrected pose) and
/// the insert of the same odometry pose uses that correction.
#[test]
fn correct_then_insert_uses_one_match() {
    let (mut s, next) = mapped();
    // Off by more than the match's noise (29 mm, 0.8° at this σ), persistently (odometry
    // slipped), so after the scans the filter holds on odometry it takes most of the match.
    let odo = pose_of((next.0 + 100.0, next.1 - 70.0, next.2 + 0.05));
    let beams = scan(&room(), next);
    for _ in 0..SUSPECT_SCANS {
        let held = s.correct(&odo, &beams);
        assert_eq!(held.pose, held.predicted, "{held:?}");
    }
    let first = s.correct(&odo, &beams);
    let a = s.insert(&odo, &beams).unwrap();
    assert_eq!(a.correction, first);
    assert!(
        err(&first.pose, next).0 * 2.0 < err(&first.predicted, next).0,
        "{first:?}"
    );
}
