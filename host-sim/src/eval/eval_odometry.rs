//! `host-sim eval-log --odometry-drift SEEDS | --truth-poses FILE`: maps made on wheel
//! odometry, with and without the robot's scan matching, scored against the benchmark made from
//! the true poses (issue 39).
//!
//! * **Truth and odometry.** With `--odometry-drift`, the log's (SLAM-corrected) poses are the
//!   truth and the odometry is [`crate::sim::track::drift`] of them under `--odometry-model`
//!   (seeded; one run per seed). With `--truth-poses FILE`, the given log's own poses are the
//!   odometry and FILE's poses, scan for scan, are the truth (same number of scans, or an error).
//! * **Matched poses.** The odometry tracked as the robot does ([`crate::sim::track::track`]: its
//!   log-odds map at the robot's settings over the odometry's extent, each scan matched before
//!   it is inserted); `--no-match` skips it.
//! * **Pose error.** The relative pose error ([`crate::eval::pose_error`]) of the odometry and
//!   of the matched poses against the truth at 1, 10 and 100 scans, and matched / odometry.
//! * **Maps.** eval-log's protocol: the benchmark is made from the true poses on their grid;
//!   each experiment's scans are mapped on that grid at the true poses, at the odometry and at
//!   the matched poses, traditionally and by `--methods`, and scored near their own mapped cells.
//!   Cells a drifting run puts outside the benchmark's grid are lost (they would be wrong anyway).
//!
//! Output: the tables on stdout ([`crate::eval::odometry_report::tables`]), `DIR/report.json`
//! ([`OdometryReport`]) per log; with several
//! logs each gets `DIR/<name>/` and `DIR/summary.md` / `summary.json` hold the tables.

use std::path::Path;

use anyhow::{ensure, Context};
use ogm_core::localize::odometry::OdometryModel;
use ogm_core::Pose;

use crate::eval::eval_log::EvalLogArgs;
use crate::eval::log_maps::{
    benchmark, map_experiment, parse_methods, sensor_noise, LogMethod, MethodsConfig,
};
use crate::eval::log_setup::{
    collect_logs, log_geometry, log_name, setup_log, Experiment, LogSetup, MARGIN_M,
};
use crate::eval::odometry_report::{ExperimentF1, OdometryReport, OdometryRun, PosesResult};
use crate::eval::pose_error::{position_error, rpe_all};
use crate::sim::carmen::{read_log, ReadOptions};
use crate::sim::track::{drift, track, with_poses, TrackSettings, TRACK_MARGIN_M};

/// Runs `eval-log` with `--odometry-drift` or `--truth-poses` (`args.odometry` is active).
pub fn run(args: &EvalLogArgs) -> anyhow::Result<()> {
    let logs = collect_logs(&args.log)?;
    let methods = parse_methods(&args.methods)?;
    let experiments = args.experiments();
    let cfg = MethodsConfig::new(&args.map)?;
    ensure!(
        args.odometry.is_active(),
        "give --odometry-drift SEEDS or --truth-poses FILE"
    );
    let o = &args.odometry;
    let model = o.model()?;
    ensure!(
        !args.perturb.is_active(),
        "--odometry-drift / --truth-poses cannot be combined with the perturbation options"
    );
    ensure!(
        o.truth_poses.is_none() || logs.len() == 1,
        "--truth-poses FILE holds the truth of one log; give exactly one --log (got {})",
        logs.len()
    );
    let mut reports = Vec::new();
    for log in &logs {
        let dir = if logs.len() == 1 {
            args.out.clone()
        } else {
            args.out.join(log_name(log))
        };
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("{}: cannot create output directory", dir.display()))?;
        let r = eval_log_odometry(log, args, model, &methods, &cfg, &experiments)
            .with_context(|| format!("evaluating {}", log.display()))?;
        let json = serde_json::to_string_pretty(&r)?;
        std::fs::write(dir.join("report.json"), json + "\n")
            .with_context(|| format!("writing {}", dir.join("report.json").display()))?;
        eprintln!("wrote {}", dir.join("report.json").display());
        reports.push(r);
    }
    let table = crate::eval::odometry_report::tables(&reports);
    println!("\n{table}");
    if logs.len() > 1 {
        crate::eval::eval_log::write_summary(&args.out, &table, &reports)?;
    }
    Ok(())
}

/// The odometry of one run: its drift seed (`None`: the given log's own) and its poses.
type OdometryPoses = (Option<u64>, Vec<Pose>);

/// The truth's setup, where the truth came from, and the odometry runs of one log.
fn truth_and_odometry(
    path: &Path,
    args: &EvalLogArgs,
    model: OdometryModel,
) -> anyhow::Result<(LogSetup, String, Vec<OdometryPoses>)> {
    let setup = setup_log(path, &args.map)?;
    let Some(truth_path) = &args.odometry.truth_poses else {
        let truth: Vec<Pose> = setup.scans.iter().map(|s| s.pose).collect();
        let runs = args
            .odometry
            .odometry_drift
            .iter()
            .map(|&seed| (Some(seed), drift(&truth, model, seed)))
            .collect();
        return Ok((setup, "the log's poses".into(), runs));
    };
    let truth_log = read_log(truth_path, &ReadOptions::default())?;
    ensure!(
        truth_log.scans.len() == setup.scans.len(),
        "--truth-poses {}: {} scans, but {} has {}: the truth needs one pose per scan",
        truth_path.display(),
        truth_log.scans.len(),
        path.display(),
        setup.scans.len()
    );
    let odometry: Vec<Pose> = setup.scans.iter().map(|s| s.pose).collect();
    let truth: Vec<Pose> = truth_log.scans.iter().map(|s| s.pose).collect();
    let scans = with_poses(&setup.scans, &truth)?;
    // The benchmark's grid covers the truth, not the odometry.
    let geometry = log_geometry(
        &scans,
        f64::from(setup.geometry.cell_mm()) / 1000.0,
        setup.mapper.max_range_mm,
        MARGIN_M,
    )?;
    let setup = LogSetup {
        scans,
        geometry,
        ..setup
    };
    Ok((
        setup,
        truth_path.display().to_string(),
        vec![(None, odometry)],
    ))
}

fn eval_log_odometry(
    path: &Path,
    args: &EvalLogArgs,
    model: OdometryModel,
    methods: &[LogMethod],
    cfg: &MethodsConfig,
    experiments: &[u8],
) -> anyhow::Result<OdometryReport> {
    let (setup, truth_source, runs) = truth_and_odometry(path, args, model)?;
    let g = setup.geometry;
    eprintln!(
        "{}: {} scans, {}x{} cells of {} m, mapping range {} m",
        setup.name,
        setup.scans.len(),
        g.width(),
        g.height(),
        f64::from(g.cell_mm()) / 1000.0,
        f64::from(setup.mapper.max_range_mm) / 1000.0
    );
    let (world, _) = benchmark(&setup)?;
    let truth: Vec<Pose> = setup.scans.iter().map(|s| s.pose).collect();
    let maps_at = |poses: &[Pose], label: &str| -> anyhow::Result<Vec<ExperimentF1>> {
        let scans = with_poses(&setup.scans, poses)?;
        // σ from all the scans at these poses, as eval-log takes it.
        let sensor = if cfg.estimate_sigma {
            sensor_noise(&setup, &scans, None)?
        } else {
            None
        };
        let mut out = Vec::new();
        for &id in experiments {
            let sel = Experiment::new(id)?.select(&scans);
            let em = map_experiment(
                &setup,
                &sel,
                sensor.as_ref(),
                methods,
                cfg,
                &format!("{} {label} experiment {id}", setup.name),
            )?;
            let (all, near) = em.score(&world)?;
            out.push(ExperimentF1 {
                experiment: id,
                near_mapped: near.iter().map(|(k, s)| (k.clone(), s.max_f1)).collect(),
                all: all.iter().map(|(k, s)| (k.clone(), s.max_f1)).collect(),
            });
        }
        Ok(out)
    };
    let true_poses = maps_at(&truth, "true poses")?;
    let settings = TrackSettings::default();
    let mut out_runs = Vec::new();
    for (seed, odometry) in runs {
        let tag = seed.map_or("odometry".to_string(), |s| format!("seed {s}"));
        let odo = PosesResult {
            rpe: rpe_all(&truth, &odometry),
            position_error_m: position_error(&truth, &odometry),
            maps: maps_at(&odometry, &format!("{tag} odometry"))?,
        };
        let (matched, verdicts) = if args.odometry.no_match {
            (None, None)
        } else {
            let odo_scans = with_poses(&setup.scans, &odometry)?;
            // The robot's map: over the odometry's extent, with room for the corrections.
            let geometry = log_geometry(
                &odo_scans,
                f64::from(g.cell_mm()) / 1000.0,
                setup.mapper.max_range_mm,
                TRACK_MARGIN_M,
            )?;
            let t = track(&odo_scans, geometry, setup.mapper.max_range_mm, &settings)?;
            eprintln!(
                "{} {tag}: tracked, verdicts {} (trusted/ambiguous/rotation/unconstrained/few/no overlap/window/contradicted)",
                setup.name,
                t.verdicts.short()
            );
            let m = PosesResult {
                rpe: rpe_all(&truth, &t.poses),
                position_error_m: position_error(&truth, &t.poses),
                maps: maps_at(&t.poses, &format!("{tag} matched"))?,
            };
            (Some(m), Some(t.verdicts))
        };
        out_runs.push(OdometryRun {
            seed,
            odometry: odo,
            matched,
            verdicts,
        });
    }
    Ok(OdometryReport {
        log: setup.name.clone(),
        truth: truth_source,
        model: (!args.odometry.odometry_drift.is_empty())
            .then(|| args.odometry.odometry_model.clone()),
        scans: setup.scans.len(),
        true_poses,
        runs: out_runs,
    })
}
