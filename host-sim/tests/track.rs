//! Issue 39 on the host: the relative pose error, tracking a drifting run with the robot's
//! matcher, `export --log --match` and `eval-log --truth-poses` — on simulated runs, so no
//! `../shared` is needed (the one real-log test says SKIPPED without it).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use host_sim::eval::eval_log::log_geometry;
use host_sim::eval::pose_error::{position_error, rpe, rpe_all, rpe_f};
use host_sim::sim::explore::{ExploreConfig, ScanRecord};
use host_sim::sim::generate::default_world;
use host_sim::sim::lidar::LidarConfig;
use host_sim::sim::track::{drift, track, with_poses, TrackSettings, TRACK_MARGIN_M};
use host_sim::sim::{simulate, SimConfig};
use ogm_core::localize::odometry::{OdometryModel, PoseF};
use ogm_core::{Angle, Pose, Range};

/// Lidar range of the simulated runs, cells of 5 cm.
const RANGE_CELLS: f64 = 160.0;

/// A robot driving through the demo's building at 0.4 m/s, scanning at 10 Hz (an LD06) with a
/// 360-beam lidar of σ = 1 cell: `scans` scans at their true poses.
fn simulated_run(scans: usize, seed: u64) -> Vec<ScanRecord> {
    let cfg = SimConfig {
        lidar: LidarConfig {
            beams: 360,
            max_range_cells: RANGE_CELLS,
            sigma_cells: 1.0,
        },
        explore: ExploreConfig::moving(10.0, 0.4, scans),
    };
    let mut run = simulate(&default_world(), &cfg, seed).unwrap().scans;
    run.truncate(scans);
    assert_eq!(run.len(), scans);
    run
}

fn range_mm() -> u32 {
    (RANGE_CELLS * 50.0) as u32
}

// ---------------------------------------------------------------------------------------------
// Relative pose error.

/// Straight along x, `step` mm per scan.
fn straight(n: usize, step: i32) -> Vec<Pose> {
    (0..n)
        .map(|i| Pose::new(i as i32 * step, 0, Angle::ZERO))
        .collect()
}

#[test]
fn rpe_of_a_scale_error_is_the_scale_times_the_distance() {
    // Odometry reporting 110 mm for every true 100 mm: Δ scans apart it is 10·Δ mm off.
    let truth = straight(250, 100);
    let odo = straight(250, 110);
    let r = rpe_all(&truth, &odo);
    for (r, delta) in r.iter().zip([1usize, 10, 100]) {
        assert_eq!(r.delta, delta);
        assert_eq!(r.pairs, 250 - delta);
        assert!((r.trans_m - 0.01 * delta as f64).abs() < 1e-9, "{r:?}");
        assert!((r.max_trans_m - 0.01 * delta as f64).abs() < 1e-9, "{r:?}");
        assert_eq!(r.rot_deg, 0.0);
    }
    // The same error anywhere along the run, so the mean is the error; the absolute error grows.
    let (mean, max) = position_error(&truth, &odo);
    assert!((max - 0.01 * 249.0).abs() < 1e-9 && mean < max);
    // No error, no RPE; a run not longer than Δ has no pairs.
    assert_eq!(rpe(&truth, &truth, 10).trans_m, 0.0);
    assert_eq!(rpe(&truth[..5], &odo[..5], 10).pairs, 0);
    assert_eq!(rpe(&truth[..5], &odo[..5], 10).trans_m, 0.0);
}

#[test]
fn rpe_of_a_constant_heading_drift_is_known() {
    // Every step 100 mm straight ahead; the estimate turns ε each step while moving the same.
    let eps = 0.2f64.to_radians();
    let n = 300;
    let mut truth = vec![PoseF::default()];
    let mut est = vec![PoseF::default()];
    for _ in 1..n {
        let step = PoseF {
            x: 100.0,
            y: 0.0,
            th: 0.0,
        };
        truth.push(truth.last().unwrap().compose(&step));
        est.push(est.last().unwrap().compose(&PoseF { th: eps, ..step }));
    }
    for delta in [1usize, 10, 100] {
        let r = rpe_f(&truth, &est, delta);
        // Rotation: Δ·ε. Translation: the estimate's chord over Δ steps (the first step straight,
        // then turning ε per step: Σ_{k<Δ} 100·(cos kε, sin kε)) against 100·Δ straight.
        let (mut x, mut y) = (0.0, 0.0);
        for k in 0..delta {
            x += 100.0 * (k as f64 * eps).cos();
            y += 100.0 * (k as f64 * eps).sin();
        }
        let want = (x - 100.0 * delta as f64).hypot(y) / 1000.0;
        assert!(
            (r.rot_deg - (delta as f64 * eps).to_degrees()).abs() < 1e-9,
            "Δ{delta}: {r:?}"
        );
        assert!(
            (r.trans_m - want).abs() < 1e-9,
            "Δ{delta}: {r:?} want {want}"
        );
    }
    // At 100 scans that is 20° and ~1.74 m (mostly sideways: ε·100·Σk ≈ 1.73 m).
    let r = rpe_f(&truth, &est, 100);
    assert!(
        (r.rot_deg - 20.0).abs() < 1e-9 && r.trans_m > 1.7 && r.trans_m < 1.8,
        "{r:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Tracking.

#[test]
fn tracking_reduces_the_error_of_a_drifting_run() {
    let run = simulated_run(400, 3);
    let truth: Vec<Pose> = run.iter().map(|s| s.pose).collect();
    let odometry = drift(&truth, OdometryModel::CHEAP_ROBOT, 1);
    let scans = with_poses(&run, &odometry).unwrap();
    let g = log_geometry(&scans, 0.05, range_mm(), TRACK_MARGIN_M).unwrap();
    let t = track(&scans, g, range_mm(), &TrackSettings::default()).unwrap();
    assert_eq!(t.poses.len(), run.len());
    let (o, m) = (rpe_all(&truth, &odometry), rpe_all(&truth, &t.poses));
    let v = t.verdicts;
    eprintln!("odometry {o:?}\nmatched {m:?}\nverdicts {v:?}");
    assert_eq!(
        v.no_overlap
            + v.usable()
            + v.too_few_points
            + v.unconstrained
            + v.out_of_window
            + v.contradicted
            + v.unmatched,
        run.len()
    );
    assert!(v.trusted > run.len() * 3 / 4, "{v:?}");
    // The drift the odometry accumulates, the matcher takes out. Measured (seed 3, odometry
    // seed 1): 100 scans (4 m) 0.046 m / 0.63° against odometry's 0.217 m / 7.4°; 10 scans
    // 0.28° against 1.62°. Asserted with margin: at most 30 % of odometry's at 100 scans, half
    // of its rotation at 10. Not the translation at 10 scans: over 40 cm this odometry is off by
    // 8 mm, below what a match at 5 cm cells resolves (matched 12 mm).
    assert!(o[1].rot_deg > 0.0 && o[2].trans_m > 0.0 && o[2].rot_deg > 0.0);
    assert!(
        m[1].rot_deg < 0.5 * o[1].rot_deg,
        "{:?} vs {:?}",
        m[1],
        o[1]
    );
    assert!(
        m[2].trans_m < 0.3 * o[2].trans_m,
        "{:?} vs {:?}",
        m[2],
        o[2]
    );
    assert!(
        m[2].rot_deg < 0.3 * o[2].rot_deg,
        "{:?} vs {:?}",
        m[2],
        o[2]
    );
    let (pe_o, pe_m) = (
        position_error(&truth, &odometry),
        position_error(&truth, &t.poses),
    );
    assert!(
        pe_m.1 < pe_o.1,
        "position error {pe_m:?} vs odometry {pe_o:?}"
    );
    // Matching off: the odometry as it is (to the tracker's integer rounding).
    let off = TrackSettings {
        matching: false,
        ..TrackSettings::default()
    };
    let t = track(&scans, g, range_mm(), &off).unwrap();
    assert_eq!(t.verdicts.unmatched, run.len());
    assert!(position_error(&odometry, &t.poses).1 < 0.01);
}

#[test]
fn drift_is_seeded_and_starts_at_the_truth() {
    let truth: Vec<Pose> = simulated_run(50, 2).iter().map(|s| s.pose).collect();
    let a = drift(&truth, OdometryModel::ISSUE_39, 5);
    assert_eq!(a, drift(&truth, OdometryModel::ISSUE_39, 5));
    assert_ne!(a, drift(&truth, OdometryModel::ISSUE_39, 6));
    assert_eq!(a[0], truth[0]);
    assert_eq!(drift(&truth, OdometryModel::PERFECT, 5), truth);
}

// ---------------------------------------------------------------------------------------------
// The commands, on a simulated run written as a CARMEN log.

/// Writes `scans` as a CARMEN log of 360° `ROBOTLASER1` lines (no-returns at the range).
fn write_log(path: &Path, scans: &[ScanRecord]) {
    let mut f = std::fs::File::create(path).unwrap();
    let max_m = f64::from(range_mm()) / 1000.0;
    for s in scans {
        let n = s.beams.len();
        let res = std::f64::consts::TAU / n as f64;
        let start = s.beams[0].angle.to_radians();
        let mut line = format!(
            "ROBOTLASER1 0 {start} {} {res} {max_m} 0.01 0 {n}",
            res * n as f64
        );
        for b in &s.beams {
            let r = match b.range {
                Range::Hit(mm) => f64::from(mm) / 1000.0,
                _ => max_m,
            };
            line.push_str(&format!(" {r:.3}"));
        }
        let (x, y) = (
            f64::from(s.pose.x_mm) / 1000.0,
            f64::from(s.pose.y_mm) / 1000.0,
        );
        let th = s.pose.heading.to_radians();
        line.push_str(&format!(
            " 0 {x} {y} {th} {x} {y} {th} 0 0 0 0 0 0.0 sim 0.0"
        ));
        writeln!(f, "{line}").unwrap();
    }
}

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

fn run(cmd: &mut Command) -> (bool, String) {
    let out = cmd.output().unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

fn drifted_log(dir: &Path, scans: usize) -> (PathBuf, Vec<ScanRecord>) {
    let truth = simulated_run(scans, 4);
    let poses: Vec<Pose> = truth.iter().map(|s| s.pose).collect();
    let odo = with_poses(&truth, &drift(&poses, OdometryModel::CHEAP_ROBOT, 2)).unwrap();
    let path = dir.join("odometry.log");
    write_log(&path, &odo);
    (path, truth)
}

#[test]
fn export_match_writes_the_matched_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let (log, truth) = drifted_log(dir.path(), 120);
    let out = dir.path().join("map.yaml");
    let (ok, text) = run(host_sim()
        .args(["export", "--log"])
        .arg(&log)
        .arg("--match")
        .arg("--out")
        .arg(&out));
    assert!(ok, "{text}");
    assert!(out.exists() && dir.path().join("map.pgm").exists());
    let csv = std::fs::read_to_string(dir.path().join("map.poses.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("scan,x_m,y_m,theta_rad"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), truth.len());
    let mut matched = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 4);
        assert_eq!(r[0], i as f64);
        assert!(r[3].abs() <= std::f64::consts::PI + 1e-9);
        matched.push(Pose::new(
            (r[1] * 1000.0).round() as i32,
            (r[2] * 1000.0).round() as i32,
            Angle::from_radians(r[3]),
        ));
    }
    // The log's frame: the trajectory starts where the log does and stays near the truth.
    let poses: Vec<Pose> = truth.iter().map(|s| s.pose).collect();
    let odo = drift(&poses, OdometryModel::CHEAP_ROBOT, 2);
    let (m, o) = (
        position_error(&poses, &matched),
        position_error(&poses, &odo),
    );
    assert!(m.1 < o.1, "matched {m:?} vs odometry {o:?}");
    // Bad input: --match needs a log.
    let (ok, text) = run(host_sim()
        .args(["export", "--world"])
        .arg(&out)
        .arg("--match")
        .arg("--out")
        .arg(dir.path().join("x.yaml")));
    assert!(!ok && text.contains("--log"), "{text}");
}

#[test]
fn truth_poses_must_match_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let (log, truth) = drifted_log(dir.path(), 60);
    let short = dir.path().join("truth.log");
    write_log(&short, &truth[..40]);
    let (ok, text) = run(host_sim()
        .args([
            "eval-log",
            "--methods",
            "none",
            "--experiment",
            "1",
            "--log",
        ])
        .arg(&log)
        .arg("--truth-poses")
        .arg(&short)
        .arg("--out")
        .arg(dir.path().join("out")));
    assert!(!ok, "{text}");
    assert!(text.contains("40 scans") && text.contains("60"), "{text}");
    // With the right truth it runs and reports both trajectories.
    let full = dir.path().join("truth-full.log");
    write_log(&full, &truth);
    let (ok, text) = run(host_sim()
        .args([
            "eval-log",
            "--methods",
            "none",
            "--experiment",
            "1",
            "--log",
        ])
        .arg(&log)
        .arg("--truth-poses")
        .arg(&full)
        .arg("--out")
        .arg(dir.path().join("out")));
    assert!(ok, "{text}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/report.json")).unwrap())
            .unwrap();
    let runs = r["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 1);
    let odo10 = runs[0]["odometry"]["rpe"][1]["trans_m"].as_f64().unwrap();
    let m10 = runs[0]["matched"]["rpe"][1]["trans_m"].as_f64().unwrap();
    // 2.4 m of driving: too short for the matcher to beat odometry (that is the test above); here
    // the report's shape: both errors, and a verdict per scan.
    assert!(odo10 > 0.0 && m10.is_finite(), "{odo10} {m10}");
    let v = runs[0]["verdicts"].as_object().unwrap();
    assert_eq!(v.values().map(|n| n.as_u64().unwrap()).sum::<u64>(), 60);
    assert!(
        r["true_poses"][0]["near_mapped"]["traditional"]
            .as_f64()
            .unwrap()
            > 0.5
    );
    assert!(text.contains("true poses"), "{text}");
    // --no-match alone is an error.
    let (ok, text) = run(host_sim()
        .args(["eval-log", "--methods", "none", "--no-match", "--log"])
        .arg(&log)
        .arg("--out")
        .arg(dir.path().join("o2")));
    assert!(!ok && text.contains("--no-match"), "{text}");
}

// ---------------------------------------------------------------------------------------------
// The shared logs (skipped without ../shared).

fn shared_logs() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/logs");
    p.is_dir().then_some(p)
}

#[test]
fn tracking_a_shared_log_takes_out_the_drift() {
    let Some(dir) = shared_logs() else {
        eprintln!("SKIPPED: ../shared/data/logs not found");
        return;
    };
    use host_sim::sim::carmen::{read_log, ReadOptions};
    // The two logs where the 100-scan bar holds on every seed (docs/results.md, "Odometry and
    // scan matching on real logs"): measured with the cheap robot's odometry, seed 1,
    // freiburg-101 0.014 / 0.007 and seattle 0.026 / 0.029 (translation / rotation ratio).
    for name in ["freiburg-101", "seattle"] {
        let log = read_log(
            &dir.join(format!("{name}-corrected.log.gz")),
            &ReadOptions::default(),
        )
        .unwrap();
        let range = (log.info.max_range_m().min(20.0) * 1000.0) as u32;
        let truth: Vec<Pose> = log.scans.iter().map(|s| s.pose).collect();
        let odometry = drift(&truth, OdometryModel::CHEAP_ROBOT, 1);
        let scans = with_poses(&log.scans, &odometry).unwrap();
        let g = log_geometry(&scans, 0.05, range, TRACK_MARGIN_M).unwrap();
        let t = track(&scans, g, range, &TrackSettings::default()).unwrap();
        let (o, m) = (rpe_all(&truth, &odometry), rpe_all(&truth, &t.poses));
        let (rt, rr) = (m[2].trans_m / o[2].trans_m, m[2].rot_deg / o[2].rot_deg);
        eprintln!(
            "{name}: 100-scan ratio {rt:.3} / {rr:.3}, verdicts {}",
            t.verdicts.short()
        );
        assert!(rt < 0.1 && rr < 0.1, "{name}: {rt} {rr}");
    }
}
