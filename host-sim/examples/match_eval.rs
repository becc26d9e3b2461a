//! The matcher's tuning harness (issue 39): the relative pose error of drifting odometry and of
//! the robot's tracking on the shared CARMEN logs, fast (no maps scored), with every matcher and
//! odometry setting overridable. The product's evaluation, with the maps' F1, is
//! `host-sim eval-log --odometry-drift SEEDS` ([`host_sim::eval::eval_odometry`]); this uses the
//! same pieces: [`host_sim::sim::track`] and [`host_sim::eval::pose_error`].
//!
//! Command (from the worktree root; `../shared/data/logs` must exist):
//! `CARGO_BUILD_JOBS=1 cargo run --release -p host-sim --example match_eval -- --seeds 1,2,3`
//! (`--json FILE` writes the figures, `--help` lists the settings).

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Parser;
use host_sim::eval::eval_log::{log_geometry, log_name};
use host_sim::eval::odometry_args::model_named;
use host_sim::eval::pose_error::{position_error, ratio, rpe_all, Rpe};
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
    /// max_contradicted_permille, turn_search, max_turn_deg, max_shift_mm, occupied, floor, free.
    #[arg(long, value_delimiter = ',')]
    set: Vec<String>,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
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
    let mut c = MatchConfig::default();
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
            "min_drop_permille" => c.min_drop_permille = n as u16,
            "min_overlap_permille" => c.min_overlap_permille = n as u16,
            "max_contradicted_permille" => c.max_contradicted_permille = n as u16,
            "turn_search" => c.turn_search = n as u8,
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
