//! The matcher's tuning harness (issue 39): the relative pose error of drifting odometry and of
//! the robot's tracking on the shared CARMEN logs, fast (no maps scored), with every matcher and
//! odometry setting overridable. The product's evaluation, with the maps' F1, is
//! `host-sim eval-log --odometry-drift SEEDS` ([`host_sim::eval::eval_odometry`]); this uses the
//! same pieces: [`host_sim::sim::track`] and [`host_sim::eval::pose_error`].
//!
//! Command (from the worktree root; `../shared/data/logs` must exist):
//! `CARGO_BUILD_JOBS=1 cargo run --release -p host-sim --example match_eval -- --seeds 1,2,3`
//! (`--json FILE` writes the figures, `--help` lists the settings).
//!
//! `--sim 1,2,3,4,5 --odometry issue39 [--moving]`: instead of the logs, `host-sim firmware`'s
//! simulated runs (σ = 3 cells, or `--sigma-cells S`) tracked with the robot's own settings (`RunConfig::match_config`
//! on its face-band map; `--set` overrides them), a second a run; the pose error of odometry and
//! of the corrected poses. Statistically the firmware's runs, not bit-exact with them (the
//! firmware gets the scans through the LD06 encoding). `--per-scan [--oracle] [--quiet]`: each
//! scan's prediction, match and corrected pose; with `--oracle` every scan is matched against the map
//! made at the true poses, which separates the matcher's own error from the drift it feeds back
//! into its map; `--fresh` (with `--odometry perfect`) also predicts every scan at its true
//! pose: one match's error alone (the summary line gives the usable matches' own error beside
//! the corrected poses': a reset tracker's filter takes nothing of a match).

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Parser;
use host_sim::eval::eval_log::{log_geometry, log_name};
use host_sim::eval::odometry_args::model_named;
use host_sim::eval::pose_error::{position_error, ratio, rpe_all, Rpe};
use host_sim::firmware::odometry::PoseErrors;
use host_sim::sim::carmen::{read_log, ReadOptions};
use host_sim::sim::track::{
    drift, track, with_poses, TrackSettings, VerdictCounts, TRACK_MARGIN_M,
};
use ogm_core::localize::odometry::OdometryModel;
use ogm_core::localize::MatchConfig;
use ogm_core::{Angle, LogOdds, Pose};
use serde::Serialize;

#[derive(Parser, Debug)]
#[command(about = "Odometry vs scan-matched poses on CARMEN logs: relative pose error")]
struct Args {
    /// Logs (files or directories of *.log.gz).
    #[arg(default_value = "../shared/data/logs")]
    logs: Vec<PathBuf>,
    /// Drift seeds.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    seeds: Vec<u64>,
    /// Cell size, mm.
    #[arg(long, default_value_t = 50)]
    cell_mm: u32,
    /// Mapping range cap, m.
    #[arg(long, default_value_t = 20.0)]
    range_cap_m: f64,
    /// Odometry model: `issue39`, `cheap` or `perfect`; the options below override single
    /// parameters.
    #[arg(long, default_value = "cheap")]
    odometry: String,
    /// Odometry translation noise per metre travelled (σ, each axis).
    #[arg(long)]
    trans_noise: Option<f64>,
    /// Odometry rotation noise per radian turned (σ).
    #[arg(long)]
    rot_noise: Option<f64>,
    /// Odometry heading bias, degrees per metre travelled.
    #[arg(long, allow_hyphen_values = true)]
    bias_deg_per_m: Option<f64>,
    /// Odometry turn scale error (fraction).
    #[arg(long, allow_hyphen_values = true)]
    turn_scale: Option<f64>,
    /// Do not match: map on odometry alone.
    #[arg(long)]
    no_match: bool,
    /// Match against a map made with the robot's face band (`RunConfig::ROBOT` as it is).
    #[arg(long)]
    face_band: bool,
    /// Matcher settings, `name=value` (comma-separated): levels, radius, coarse_radius,
    /// coarse_thin, reg_q8, cauchy_q8, prior_rot, prior_trans_q8, iterations, max_range_mm,
    /// min_spacing_mm, budget_reads, min_drop_permille, min_overlap_permille,
    /// max_contradicted_permille, turn_search, min_turn_drop_permille, probe_mm,
    /// hit_offset_mm, max_turn_deg, max_shift_mm, occupied, floor, free.
    #[arg(long, value_delimiter = ',')]
    set: Vec<String>,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Instead of the logs: `host-sim firmware`'s simulated runs of these seeds (a generated
    /// building, the paper's robot, σ = 3 cells), their odometry `--odometry` drifted with the
    /// run's seed, tracked with the robot's own settings (`RunConfig::match_config` of its face
    /// band map; `--set` overrides them): the poses the firmware maps with.
    #[arg(long, value_delimiter = ',')]
    sim: Vec<u64>,
    /// With `--sim`: the robot scans while it drives (`host-sim firmware --moving`: 10 Hz, 456
    /// beams, 0.4 m/s).
    #[arg(long)]
    moving: bool,
    /// With `--sim`: the simulated lidar's range noise σ, cells (default the paper's 3; `host-sim
    /// firmware --sigma-cells`), the robot's settings made for it.
    #[arg(long)]
    sigma_cells: Option<f64>,
    /// With `--sim`: the tracking loop once more, with the mean error per scan; each scan's
    /// prediction and corrected pose against the truth, its verdict and quality unless
    /// `--quiet`.
    #[arg(long)]
    per_scan: bool,
    /// With `--per-scan`: match every scan against the map made at the true poses (what the
    /// matcher does on a map free of the drift it accumulates itself).
    #[arg(long)]
    oracle: bool,
    /// With `--per-scan`: only the mean error.
    #[arg(long)]
    quiet: bool,
    /// With `--oracle`: every scan's prediction is its true pose (the tracker forgets its
    /// correction; run with `--odometry perfect`), so the error is one match's alone, not the
    /// walk of a chain of matches.
    #[arg(long)]
    fresh: bool,
    /// With `--fresh`: predict every scan this far off its true pose instead, `DX:DY:DEG` (mm,
    /// mm, degrees; the signs alternate from scan to scan), to see how much of an error one
    /// match takes out.
    #[arg(long)]
    perturb: Option<String>,
}

fn odometry_model(a: &Args) -> anyhow::Result<OdometryModel> {
    let mut m = if a.odometry == "perfect" {
        OdometryModel::PERFECT
    } else {
        model_named(&a.odometry)?
    };
    if let Some(v) = a.trans_noise {
        m.trans_noise = v;
    }
    if let Some(v) = a.rot_noise {
        m.rot_noise = v;
    }
    if let Some(v) = a.bias_deg_per_m {
        m.bias_rad_per_m = v.to_radians();
    }
    if let Some(v) = a.turn_scale {
        m.turn_scale = v;
    }
    Ok(m)
}

/// The matcher's defaults with `--set name=value` applied.
fn matcher_config(a: &Args) -> anyhow::Result<MatchConfig> {
    apply_settings(a, MatchConfig::default())
}

/// `c` with `--set name=value` applied.
fn apply_settings(a: &Args, mut c: MatchConfig) -> anyhow::Result<MatchConfig> {
    for kv in &a.set {
        let Some((k, v)) = kv.split_once('=') else {
            bail!("--set `{kv}`: expected name=value");
        };
        let n: f64 = v.parse().with_context(|| format!("--set {k}: `{v}`"))?;
        // Saturating casts: a setting out of its type's range is caught by `validate`.
        match k {
            "levels" => c.levels = n as u8,
            "radius" => c.radius = n as u8,
            "coarse_radius" => c.coarse_radius = n as u8,
            "coarse_thin" => c.coarse_thin = n as u8,
            "reg_q8" => c.reg_q8 = n as u16,
            "cauchy_q8" => c.cauchy_q8 = n as u16,
            "prior_rot" => c.prior_rot = n as u16,
            "prior_trans_q8" => c.prior_trans_q8 = n as u16,
            "iterations" => c.iterations = n as u8,
            "max_range_mm" => c.max_range_mm = n as u32,
            "min_spacing_mm" => c.min_spacing_mm = n as u32,
            "budget_reads" => c.budget_reads = n as u32,
            "match_sigma_mm" => c.match_sigma_mm = n as u16,
            "match_sigma_mdeg" => c.match_sigma_mdeg = n as u16,
            "odo_trans_permille" => c.odometry.trans_permille = n as u16,
            "odo_turn_permille" => c.odometry.turn_permille = n as u16,
            "odo_drift_mdeg_per_m" => c.odometry.drift_mdeg_per_m = n as u16,
            "min_drop_permille" => c.min_drop_permille = n as u16,
            "min_overlap_permille" => c.min_overlap_permille = n as u16,
            "max_contradicted_permille" => c.max_contradicted_permille = n as u16,
            "turn_search" => c.turn_search = n as u8,
            "min_turn_drop_permille" => c.min_turn_drop_permille = n as u16,
            "probe_mm" => c.probe_mm = n as u32,
            "hit_offset_mm" => c.hit_offset_mm = n as u16,
            "max_turn_deg" => c.max_turn = Angle::from_degrees(n),
            "max_shift_mm" => c.max_shift_mm = n as u32,
            "occupied" => c.occupied = LogOdds(n as i16),
            "floor" => c.floor = LogOdds(n as i16),
            "free" => c.free = LogOdds(n as i16),
            other => bail!("--set: unknown matcher setting `{other}`"),
        }
    }
    c.validate()
        .map_err(|e| anyhow::anyhow!("matcher settings: {e}"))?;
    Ok(c)
}

#[derive(Clone, Debug, Serialize)]
struct Run {
    log: String,
    seed: u64,
    scans: usize,
    odometry: Vec<Rpe>,
    matched: Vec<Rpe>,
    odometry_position_error_m: (f64, f64),
    matched_position_error_m: (f64, f64),
    verdicts: VerdictCounts,
    ms_per_scan: f64,
}

fn main() -> anyhow::Result<()> {
    let a = Args::parse();
    let model = odometry_model(&a)?;
    if !a.sim.is_empty() {
        return sim_runs(&a, model);
    }
    let settings = TrackSettings {
        matcher: matcher_config(&a)?,
        matching: !a.no_match,
        face_band: a.face_band,
    };
    if a.cell_mm == 0 || !a.range_cap_m.is_finite() || a.range_cap_m <= 0.0 {
        bail!("--cell-mm and --range-cap-m must be positive");
    }
    let files = host_sim::eval::eval_log::collect_logs(&a.logs)?;
    println!("odometry {model:?}\nmatcher {:?}", settings.matcher);
    println!("| log | seed | odometry RPE10 m/° | matched RPE10 | odometry RPE100 | matched RPE100 | ratio t10/t100 | ratio r10/r100 | position error odometry / matched, mean/max m | verdicts T/A/R/U/F/N/W/C | ms/scan |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut runs = Vec::new();
    for f in &files {
        let log = read_log(f, &ReadOptions::default())?;
        let range_mm = ((log.info.max_range_m().min(a.range_cap_m)) * 1000.0).round() as u32;
        let truth: Vec<Pose> = log.scans.iter().map(|s| s.pose).collect();
        for &seed in &a.seeds {
            let odometry = drift(&truth, model, seed);
            let scans = with_poses(&log.scans, &odometry)?;
            let g = log_geometry(
                &scans,
                f64::from(a.cell_mm) / 1000.0,
                range_mm,
                TRACK_MARGIN_M,
            )?;
            let t0 = std::time::Instant::now();
            let t = track(&scans, g, range_mm, &settings)?;
            let r = Run {
                log: log_name(f),
                seed,
                scans: scans.len(),
                odometry: rpe_all(&truth, &odometry),
                matched: rpe_all(&truth, &t.poses),
                odometry_position_error_m: position_error(&truth, &odometry),
                matched_position_error_m: position_error(&truth, &t.poses),
                verdicts: t.verdicts,
                ms_per_scan: t0.elapsed().as_secs_f64() * 1000.0 / scans.len().max(1) as f64,
            };
            let cell = |v: &Rpe| format!("{:.3}/{:.2}", v.trans_m, v.rot_deg);
            let (o, m) = (&r.odometry, &r.matched);
            println!(
                "| {} | {} | {} | {} | {} | {} | {:.2}/{:.2} | {:.2}/{:.2} | {:.2}/{:.2} / {:.2}/{:.2} | {} | {:.2} |",
                r.log,
                seed,
                cell(&o[1]),
                cell(&m[1]),
                cell(&o[2]),
                cell(&m[2]),
                ratio(m[1].trans_m, o[1].trans_m),
                ratio(m[2].trans_m, o[2].trans_m),
                ratio(m[1].rot_deg, o[1].rot_deg),
                ratio(m[2].rot_deg, o[2].rot_deg),
                r.odometry_position_error_m.0,
                r.odometry_position_error_m.1,
                r.matched_position_error_m.0,
                r.matched_position_error_m.1,
                r.verdicts.short(),
                r.ms_per_scan,
            );
            runs.push(r);
        }
    }
    // The bar: matched / odometry at most 0.2 at 10 and 100 scans.
    let over = |k: usize, rot: bool| -> Vec<f64> {
        runs.iter()
            .map(|r| {
                let (m, o) = (&r.matched[k], &r.odometry[k]);
                if rot {
                    ratio(m.rot_deg, o.rot_deg)
                } else {
                    ratio(m.trans_m, o.trans_m)
                }
            })
            .collect()
    };
    for (what, f) in [
        (
            "worst",
            (|v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max)) as fn(&[f64]) -> f64,
        ),
        ("mean", |v: &[f64]| {
            v.iter().sum::<f64>() / v.len().max(1) as f64
        }),
    ] {
        println!(
            "{what} ratio matched/odometry: t10 {:.3} t100 {:.3} r10 {:.3} r100 {:.3}",
            f(&over(1, false)),
            f(&over(2, false)),
            f(&over(1, true)),
            f(&over(2, true)),
        );
    }
    if let Some(p) = &a.json {
        std::fs::write(p, serde_json::to_string_pretty(&runs)?)?;
    }
    Ok(())
}

/// `--sim`: the firmware's simulated runs (`host-sim firmware --seed S [--moving]
/// --odometry-noise MODEL`), tracked as the robot tracks them; position and heading error of
/// odometry and of the corrected poses against the truth.
fn sim_runs(a: &Args, model: OdometryModel) -> anyhow::Result<()> {
    use host_sim::sim::generate::{generate, GenParams};
    use host_sim::sim::{simulate, SimConfig};
    use ogm_core::config::RunConfig;
    let perturb = perturbation(a.perturb.as_deref())?;
    println!("| seed | scans | odometry mean/max m, ° | corrected mean/max m, ° | verdicts T/A/R/U/F/N/W/C | ms/scan |");
    println!("|---|---|---|---|---|---|");
    let mut sums = [0.0f64; 4];
    for &seed in &a.sim {
        let world = generate(
            &GenParams {
                width: 256,
                height: 256,
                ..GenParams::default()
            },
            seed,
        );
        let mut sc = SimConfig::default();
        if a.moving {
            // As `host-sim firmware --moving` sets it up.
            sc.explore = host_sim::sim::explore::ExploreConfig::moving(10.0, 0.4, 0);
            sc.explore.max_stops = SimConfig::default().explore.max_stops * 25;
            sc.lidar.beams = 456;
        }
        if let Some(sigma) = a.sigma_cells {
            sc.lidar.sigma_cells = sigma;
        }
        let sim = simulate(&world, &sc, seed)?;
        let truth: Vec<Pose> = sim.scans.iter().map(|s| s.pose).collect();
        // As `host-sim firmware --odometry-noise` drifts it (integer poses, step by step).
        let arg = host_sim::firmware::odometry::OdometryArg {
            name: "",
            model,
            seed: None,
        };
        let scans = host_sim::firmware::odometry::with_odometry(&sim.scans, &arg, seed);
        let odometry: Vec<Pose> = scans.iter().map(|s| s.pose).collect();
        let range_mm = sim.mapper_config.max_range_mm;
        let sensor = match a.sigma_cells {
            Some(sigma) => RunConfig::ROBOT.with_sensor(sigma, 0.0)?,
            None => RunConfig::ROBOT,
        };
        let robot = sensor
            .with_origin_mm(
                (world.origin_m.0 * 1000.0).round() as i32,
                (world.origin_m.1 * 1000.0).round() as i32,
            )
            .with_max_range_mm(range_mm);
        let robot = RunConfig {
            cell_mm: (world.resolution_m * 1000.0).round() as u32,
            ..robot
        };
        let cfg = robot
            .match_config()
            .context("the robot's correction is off")?;
        let settings = TrackSettings {
            matcher: apply_settings(a, cfg)?,
            matching: !a.no_match,
            face_band: robot.face_band,
        };
        let g = robot.geometry(256, 256)?;
        let t0 = std::time::Instant::now();
        let t = track(&scans, g, range_mm, &settings)?;
        let ms = t0.elapsed().as_secs_f64() * 1000.0 / scans.len().max(1) as f64;
        let err = |poses: &[Pose]| {
            let e = PoseErrors::of(poses, &truth);
            (e.mean_m, e.max_m, e.mean_deg, e.max_deg)
        };
        if a.per_scan {
            per_scan(
                &scans,
                &truth,
                g,
                range_mm,
                &settings,
                (a.oracle, a.quiet, a.fresh),
                perturb,
            )?;
        }
        let (o, m) = (err(&odometry), err(&t.poses));
        println!(
            "| {seed} | {} | {:.2}/{:.2}, {:.1}/{:.1} | {:.3}/{:.3}, {:.2}/{:.2} | {} | {ms:.2} |",
            scans.len(),
            o.0,
            o.1,
            o.2,
            o.3,
            m.0,
            m.1,
            m.2,
            m.3,
            t.verdicts.short()
        );
        for (s, v) in sums.iter_mut().zip([m.0, m.1, m.2, m.3]) {
            *s += v;
        }
    }
    let n = a.sim.len() as f64;
    println!(
        "mean over seeds: corrected position error mean {:.3} max {:.3} m, heading mean {:.2} max {:.2}°",
        sums[0] / n,
        sums[1] / n,
        sums[2] / n,
        sums[3] / n
    );
    Ok(())
}

/// `--perturb DX:DY:DEG` as numbers (zero without it).
fn perturbation(arg: Option<&str>) -> anyhow::Result<(f64, f64, f64)> {
    let Some(arg) = arg else {
        return Ok((0.0, 0.0, 0.0));
    };
    let v: Vec<f64> = arg
        .split(':')
        .map(str::parse)
        .collect::<Result<_, _>>()
        .with_context(|| format!("--perturb {arg}: numbers DX:DY:DEG"))?;
    match v.as_slice() {
        [dx, dy, deg] if v.iter().all(|x| x.is_finite()) => Ok((*dx, *dy, *deg)),
        _ => bail!("--perturb {arg}: three finite numbers DX:DY:DEG"),
    }
}

/// `--per-scan`: the tracking loop of [`track`] once more, printing per scan the verdict and
/// the error of the prediction and of the corrected pose against the truth.
fn per_scan(
    scans: &[host_sim::sim::explore::ScanRecord],
    truth: &[Pose],
    g: ogm_core::GridGeometry,
    range_mm: u32,
    settings: &TrackSettings,
    (oracle, quiet, fresh): (bool, bool, bool),
    (pdx, pdy, pdeg): (f64, f64, f64),
) -> anyhow::Result<()> {
    use ogm_core::localize::{MapView, Tracker};
    use ogm_core::session::{Owned, Session, Sizes};
    let mut session = Session::new(
        host_sim::sim::track::robot_config(&g, range_mm, settings.face_band),
        Owned::<u8>::buffers(&Sizes::grid(g.width(), g.height())),
    )?;
    let mut tracker: Box<Tracker<512>> = Box::new(Tracker::new(settings.matcher));
    tracker.set_matching(settings.matching);
    let e = |p: &Pose, q: &Pose| {
        format!(
            "{:5} {:5} mm {:6.2}°",
            p.x_mm - q.x_mm,
            p.y_mm - q.y_mm,
            f64::from(p.heading.signed_diff(q.heading)) * 360.0 / 65536.0
        )
    };
    let mut corrected = Vec::with_capacity(scans.len());
    // The usable matches themselves (before the filter weighs them) and their scans' truth.
    let (mut matches, mut matched_truth) = (Vec::new(), Vec::new());
    for (k, (s, t)) in scans.iter().zip(truth).enumerate() {
        let map = MapView::new(session.log_odds(), session.geometry())?;
        let mut odometry = s.pose;
        if oracle && fresh {
            // The tracker forgets its correction: the prediction is the pose given here.
            tracker.reset();
            let (sx, sy) = (
                if k % 2 == 0 { 1.0 } else { -1.0 },
                if (k / 2) % 2 == 0 { 1.0 } else { -1.0 },
            );
            odometry = Pose::new(
                t.x_mm + (sx * pdx).round() as i32,
                t.y_mm + (sy * pdy).round() as i32,
                t.heading
                    .wrapping_add(ogm_core::Angle::from_degrees(sx * sy * pdeg)),
            );
        }
        let c = tracker.update(&map, &odometry, &s.beams);
        let q = c.matched.map(|m| m.quality).unwrap_or_default();
        if !quiet {
            println!(
                "  scan {k:2}: predicted {} match {} corrected {} {:?} overlap {} drops {}/{}/{} matched {}/{} contradicted {}",
                e(&c.predicted, t),
                c.matched.map_or_else(|| "-".to_string(), |m| e(&m.pose, t)),
                e(&c.pose, t),
                c.verdict(),
                q.overlap,
                q.drop_weak,
                q.drop_strong,
                q.drop_turn,
                q.matched,
                q.points,
                q.contradicted
            );
        }
        corrected.push(c.pose);
        if let Some(m) = c.matched.filter(|m| m.verdict.is_usable()) {
            matches.push(m.pose);
            matched_truth.push(*t);
        }
        session.insert(if oracle { t } else { &c.pose }, &s.beams)?;
    }
    let (all, raw) = (
        PoseErrors::of(&corrected, truth),
        PoseErrors::of(&matches, &matched_truth),
    );
    println!(
        "  per-scan mean error {:.3} m {:.2}°; the usable matches themselves ({} scans) {:.3} m {:.2}°",
        all.mean_m, all.mean_deg, raw.scans, raw.mean_m, raw.mean_deg
    );
    Ok(())
}
