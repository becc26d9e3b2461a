//! Pose correction on the robot, in QEMU (issue 39): the firmware is sent drifting wheel
//! odometry instead of the true poses (`host-sim firmware --odometry-noise issue39`: issue 39's
//! model, `OdometryModel::ISSUE_39`), corrects each scan's pose by matching it against its own
//! map, and maps at the corrected pose. Seed 5 (33 scans of a generated building, stops ~2 m
//! apart), 10 000 sampler updates per scan (a fixed count, so the figures repeat exactly; not a
//! timing test). Three runs: the true poses, the odometry with correction off, and with it on.
//! * every run's host replay is bit-exact with the firmware;
//! * the poses the robot reports (its scan reports' `pose`) are closer to the truth than the
//!   odometry it was sent: the largest error at most 40 % of odometry's, the mean at most 45 %
//!   (18 % and 28 % at the time of writing);
//! * at least 70 % of the scans are matched (27 of 32; stops ~2 m apart, so on some scans the
//!   matcher cannot tell and the filter keeps odometry's prediction);
//! * its online map beats the odometry-only map by at least 0.10 max F1 (0.7554 against 0.5687)
//!   and lies within 0.15 of the true-pose map's (0.8714).
//!
//! Not (yet) asserted: issue 39's bar of 0.02 F1 from the true-pose run. At the time of writing
//! (`host-sim firmware --seed 5 --accuracy --fixed-updates 10000 [--odometry-noise issue39
//! [--correction off]]`) the figures are printed by this test and listed in docs/firmware.md
//! ("Pose correction"): the matcher on the robot's thick face-band map with the simulator's
//! σ = 3-cell lidar does not get that close yet.

use host_sim::firmware::odometry::parse_odometry;
use host_sim::firmware::{print_report, run, CorrectionArg, FirmwareArgs, FirmwareReport};

fn run_seed_5(odometry: bool, correction: CorrectionArg) -> FirmwareReport {
    let r = run(&FirmwareArgs {
        seed: 5,
        accuracy: true,
        fixed_updates: Some(10_000),
        timeout: 240,
        odometry_noise: odometry.then(|| parse_odometry("issue39").expect("model")),
        correction: Some(correction),
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
    let truth = run_seed_5(false, CorrectionArg::Off);
    let off = run_seed_5(true, CorrectionArg::Off);
    let on = run_seed_5(true, CorrectionArg::Match);
    let o = on.odometry.clone().expect("odometry report");
    eprintln!("{o:?}");
    // Correction off maps at the odometry it was sent.
    let o_off = off.odometry.clone().expect("odometry report");
    assert_eq!(o_off.corrected, o_off.odometry);
    // On, the robot's poses are closer to the truth.
    assert!(o.odometry.max_m > 0.5, "the drift is real: {o:?}");
    assert!(o.corrected.max_m <= 0.4 * o.odometry.max_m, "{o:?}");
    assert!(o.corrected.mean_m <= 0.45 * o.odometry.mean_m, "{o:?}");
    // At least 70 % of the scans matched (27 of 32 at the time of writing).
    assert!(o.matched * 10 >= o.corrected.scans * 7, "{o:?}");
    let (f_truth, f_off, f_on) = (online_f1(&truth), online_f1(&off), online_f1(&on));
    eprintln!(
        "online max F1: true poses {f_truth:.4}, odometry {f_off:.4}, odometry corrected {f_on:.4}"
    );
    assert!(f_on >= f_off + 0.10, "{f_on} vs {f_off}");
    assert!(f_on >= f_truth - 0.15, "{f_on} vs {f_truth}");
}
