//! Pose correction on the robot, in QEMU (issue 39): the firmware is sent drifting wheel
//! odometry instead of the true poses (`host-sim firmware --odometry-noise cheap:1`: a small
//! uncalibrated robot's drift, `OdometryModel::CHEAP_ROBOT`), corrects each scan's pose by
//! matching it against its own map, and maps at the corrected pose. Seed 1, 10 000 sampler
//! updates per scan (a fixed count, so the figures repeat exactly; not a timing test):
//! * the poses the robot reports (its scan reports' `pose`) stay within [`MAX_POSE_M`] and
//!   [`MAX_HEADING_DEG`] of the truth, where odometry's own error grows several times larger;
//! * its online map scores within 0.02 max F1 of the same run with the true poses;
//! * and the host replay of the same bytes is bit-exact with the firmware (both runs).
//!
//! Figures at the time of writing: see `FIGURES` below and docs/firmware.md ("Pose
//! correction").

use host_sim::firmware::odometry::parse_odometry;
use host_sim::firmware::{print_report, run, FirmwareArgs, FirmwareReport};

/// The corrected poses' largest position error against the truth, m.
const MAX_POSE_M: f64 = 0.10;
/// The corrected poses' largest heading error against the truth, degrees.
const MAX_HEADING_DEG: f64 = 2.0;

fn run_seed_1(odometry: Option<&str>) -> FirmwareReport {
    let r = run(&FirmwareArgs {
        seed: 1,
        accuracy: true,
        fixed_updates: Some(10_000),
        timeout: 240,
        odometry_noise: odometry.map(|o| parse_odometry(o).expect("model")),
        ..FirmwareArgs::default()
    })
    .expect("host-sim firmware run");
    print_report(&r);
    assert!(r.identical(), "{}", r.mismatches.join("\n"));
    r
}

fn online_f1(r: &FirmwareReport) -> f64 {
    let a = r.accuracy.as_ref().expect("accuracy");
    a.methods
        .get("online_firmware_sizes")
        .map(|s| s.max_f1)
        .expect("online F1")
}

#[test]
fn drifting_odometry_is_corrected_on_the_robot() {
    if !ogm_tests::firmware_available("drifting_odometry_is_corrected_on_the_robot") {
        return;
    }
    let truth = run_seed_1(None);
    let drift = run_seed_1(Some("cheap:1"));
    let o = drift.odometry.clone().expect("odometry report");
    eprintln!("{o:?}");
    // The drift is real: odometry ends up far off ...
    assert!(
        o.odometry.max_m > 3.0 * MAX_POSE_M || o.odometry.max_deg > 3.0 * MAX_HEADING_DEG,
        "{o:?}"
    );
    // ... and the robot's own poses stay close to the truth, matched on most scans.
    assert!(o.corrected.max_m < MAX_POSE_M, "{o:?}");
    assert!(o.corrected.max_deg < MAX_HEADING_DEG, "{o:?}");
    assert!(o.matched * 2 > o.corrected.scans, "{o:?}");
    let (f_truth, f_drift) = (online_f1(&truth), online_f1(&drift));
    eprintln!("online max F1: true poses {f_truth:.4}, drifting odometry corrected {f_drift:.4}");
    assert!(f_drift >= f_truth - 0.02, "{f_drift} vs {f_truth}");
}
