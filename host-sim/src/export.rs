//! `host-sim export`: any map the tools produce as a ROS map_server map — a YAML (`image`,
//! `resolution`, `origin`, `negate: 0`, `occupied_thresh: 0.65`, `free_thresh: 0.196`,
//! `mode: trinary`), a trinary P5 PGM (0 occupied, 254 free, 205 unknown) and the same grey
//! levels as PNG — through the field tools' writer ([`ogm_field::export::export_world`]).
//!
//! The one command that serves two of host-sim's users: `--stream` is the robot user's
//! ([`ogm_field::export::world_from_stream`]), the other sources are the researcher's (`--log`
//! maps a log with the evaluation's methods). So it sits at the top, above both.
//!
//! Sources (exactly one):
//! * `--log FILE [--experiment 0..3] [--method NAME]`: maps a CARMEN log like `eval-log` and
//!   exports the `benchmark` (its trinary ground truth, exactly), `traditional` or any sampler's
//!   or baseline's map; experiment 0 is all of the log's data. With `--match` the log's poses are
//!   wheel odometry: the robot's scan matcher corrects them ([`crate::sim::track`]) before the
//!   log is mapped, and the matched trajectory goes to `<out>.poses.csv` (`map.yaml` →
//!   `map.poses.csv`: `scan,x_m,y_m,theta_rad`, one row per scan, in the log's frame).
//! * `--probability-png FILE`: a probability image the tools write (`demo`'s
//!   `*_probability.png`, `eval-log`'s `expN_<method>.png`; grey = 255·(1 − p)), or one panel of a
//!   side-by-side strip (`eval-sim`'s per-map PNG, `comparison.png`) with `--panel I --panels N`.
//!   The image has no scale: give `--resolution` (default 0.05 m) and `--origin`.
//! * `--world FILE`: a ground-truth map (PNG / PGM / ROS YAML), re-exported as is.
//! * `--stream FILE [--layer marginals|log-odds]`: a captured map stream of the robot (the bytes
//!   its host link sent, complete or cut off anywhere): the grid size comes from its `Hello`,
//!   the cell size and origin from its `Configured` (or `--resolution` / `--origin` if the
//!   capture has none), and every tile in it is applied in order, so the latest state of each
//!   tile wins. Cells whose log-odds is 0 (never measured) are unknown in both layers; cells
//!   whose marginal tile is not in the capture yet take their log-odds probability (where the
//!   robot's estimates start).
//!
//! Probability maps become trinary with `--occupied-thresh` (default 0.65) and `--free-thresh`
//! (default 0.196); p = 0.5 exactly (no data) is always unknown.

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};

use ogm_field::export::{export_world, world_from_stream};
use ogm_field::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use ogm_field::world::{load_world, probabilities_to_world, World};

use ogm_core::localize::odometry::PoseF;
use ogm_core::Pose;

use crate::eval::eval_log::{
    benchmark_truth, log_geometry, map_scans, parse_methods, run_log_method, setup_log, Experiment,
    LogMapArgs, LogSetup, MethodsConfig, BENCHMARK_THRESHOLD, MARGIN_M,
};
use crate::eval::render::SIDE_BY_SIDE_GAP_PX;
use crate::sim::probabilities;
use crate::sim::track::{track, with_poses, TrackSettings, TRACK_MARGIN_M};

/// `host-sim export` options.
#[derive(clap::Args, Clone, Debug)]
pub struct ExportArgs {
    /// Output ROS map YAML (`.yaml`); the `.pgm` and `.png` are written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Source: a CARMEN log to map.
    #[arg(long, group = "source")]
    pub log: Option<PathBuf>,
    /// Source: a probability PNG written by the tools.
    #[arg(long, group = "source")]
    pub probability_png: Option<PathBuf>,
    /// Source: a ground-truth map (PNG, PGM or ROS YAML).
    #[arg(long, group = "source")]
    pub world: Option<PathBuf>,
    /// With --log: the data (0 = all of it, 1..3 = the experiments of Table III).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub experiment: u8,
    /// With --log: `benchmark`, `traditional`, or a sampler or baseline name.
    #[arg(long, default_value = "traditional")]
    pub method: String,
    /// With --log: take the log's poses as wheel odometry and correct them with the robot's scan
    /// matcher before mapping (issue 39); the matched trajectory is written beside the map as
    /// `<out>.poses.csv` (`scan,x_m,y_m,theta_rad`, one row per scan, the log's frame).
    #[arg(long = "match", requires = "log")]
    pub match_poses: bool,
    /// With --log: grid, range and method settings.
    #[command(flatten)]
    pub map: LogMapArgs,
    /// Source: a captured map stream from the robot (e.g. `firmware/target/qemu/uart1.out`).
    #[arg(long, group = "source")]
    pub stream: Option<PathBuf>,
    /// With --stream: `marginals` (the sampler's map, the robot's product) or `log-odds` (the
    /// traditional map).
    #[arg(long, default_value = "marginals")]
    pub layer: String,
    /// With --probability-png (or a --stream without its config): metres per pixel.
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// With --probability-png (or a --stream without its config): world position (m) of the
    /// lower-left corner, `X,Y`.
    #[arg(long, default_value = "0,0", allow_hyphen_values = true)]
    pub origin: String,
    /// With --probability-png: take panel I (from 0) of a side-by-side strip of --panels maps.
    #[arg(long, requires = "panels")]
    pub panel: Option<u32>,
    /// With --panel: the number of maps in the strip.
    #[arg(long, requires = "panel")]
    pub panels: Option<u32>,
    /// A probability at or above this is occupied.
    #[arg(long, default_value_t = DEFAULT_OCCUPIED_THRESH)]
    pub occupied_thresh: f64,
    /// A probability at or below this is free.
    #[arg(long, default_value_t = DEFAULT_FREE_THRESH)]
    pub free_thresh: f64,
}

/// Probabilities from a grey probability image (grey = 255·(1 − p), top row first) as grid
/// rows (row 0 at the bottom), optionally one panel of a side-by-side strip.
pub fn probabilities_from_png(
    path: &Path,
    panel: Option<(u32, u32)>,
) -> anyhow::Result<(Vec<f64>, usize, usize)> {
    let img = image::open(path)
        .with_context(|| format!("{}: cannot read image", path.display()))?
        .to_luma8();
    let (w, h) = img.dimensions();
    let (x0, pw) = match panel {
        None => (0, w),
        Some((i, n)) => {
            ensure!(n >= 1 && i < n, "--panel {i} of --panels {n}: out of range");
            let gaps = (n - 1) * SIDE_BY_SIDE_GAP_PX;
            ensure!(
                w > gaps && (w - gaps) % n == 0,
                "{}: {w} px wide is not {n} equal panels with {SIDE_BY_SIDE_GAP_PX} px gaps",
                path.display()
            );
            let pw = (w - gaps) / n;
            (i * (pw + SIDE_BY_SIDE_GAP_PX), pw)
        }
    };
    let (pw, ph) = (pw as usize, h as usize);
    let mut probs = Vec::with_capacity(pw * ph);
    for y in 0..ph {
        let r = (ph - 1 - y) as u32;
        for x in 0..pw {
            let g = img.get_pixel(x0 + x as u32, r)[0];
            probs.push(1.0 - f64::from(g) / 255.0);
        }
    }
    Ok((probs, pw, ph))
}

fn parse_origin(s: &str) -> anyhow::Result<(f64, f64)> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [x, y] = parts.as_slice() else {
        bail!("--origin `{s}`: expected X,Y in metres");
    };
    let x: f64 = x.parse().with_context(|| format!("--origin x `{x}`"))?;
    let y: f64 = y.parse().with_context(|| format!("--origin y `{y}`"))?;
    ensure!(x.is_finite() && y.is_finite(), "--origin must be finite");
    Ok((x, y))
}

/// Runs `host-sim export`.
pub fn run(a: &ExportArgs) -> anyhow::Result<()> {
    ensure!(
        !a.match_poses || a.log.is_some(),
        "--match corrects a log's poses: give --log FILE"
    );
    ensure!(
        (0.0..=1.0).contains(&a.free_thresh)
            && (0.0..=1.0).contains(&a.occupied_thresh)
            && a.free_thresh < a.occupied_thresh,
        "need 0 <= --free-thresh < --occupied-thresh <= 1"
    );
    let world = if let Some(log) = &a.log {
        world_from_log(log, a)?
    } else if let Some(png) = &a.probability_png {
        ensure!(
            a.resolution.is_finite() && a.resolution > 0.0,
            "--resolution must be positive"
        );
        let (probs, w, h) = probabilities_from_png(png, a.panel.zip(a.panels))?;
        probabilities_to_world(
            &probs,
            w,
            h,
            a.resolution,
            parse_origin(&a.origin)?,
            a.occupied_thresh,
            a.free_thresh,
        )
    } else if let Some(path) = &a.world {
        load_world(path, None)?
    } else if let Some(path) = &a.stream {
        world_from_stream(path, &a.layer, a.occupied_thresh, a.free_thresh, || {
            Ok((a.resolution, parse_origin(&a.origin)?))
        })?
    } else {
        bail!("give one source: --log, --probability-png, --world or --stream");
    };
    let c = world.counts();
    for p in export_world(&a.out, &world)? {
        println!("wrote {}", p.display());
    }
    println!(
        "{}x{} cells of {} m, origin ({}, {}): {} occupied, {} free, {} unknown",
        world.width,
        world.height,
        world.resolution_m,
        world.origin_m.0,
        world.origin_m.1,
        c.occupied,
        c.free,
        c.unknown
    );
    Ok(())
}

/// Tracks `setup`'s poses as odometry ([`crate::sim::track`]); the setup at the matched poses
/// (its grid over them) and the matched poses.
fn matched_setup(setup: LogSetup) -> anyhow::Result<(LogSetup, Vec<Pose>)> {
    let cell_m = f64::from(setup.geometry.cell_mm()) / 1000.0;
    let range = setup.mapper.max_range_mm;
    let robot_map = log_geometry(&setup.scans, cell_m, range, TRACK_MARGIN_M)?;
    let t = track(&setup.scans, robot_map, range, &TrackSettings::default())?;
    println!(
        "{}: {} scans matched: {} used, verdicts {} (trusted/ambiguous/rotation/unconstrained/few/no overlap/window/contradicted)",
        setup.name,
        setup.scans.len(),
        t.verdicts.usable(),
        t.verdicts.short()
    );
    let scans = with_poses(&setup.scans, &t.poses)?;
    let geometry = log_geometry(&scans, cell_m, range, MARGIN_M)?;
    Ok((
        LogSetup {
            scans,
            geometry,
            ..setup
        },
        t.poses,
    ))
}

/// Writes `poses` as `scan,x_m,y_m,theta_rad`.
pub fn write_poses_csv(path: &Path, poses: &[Pose]) -> anyhow::Result<()> {
    let mut s = String::from("scan,x_m,y_m,theta_rad\n");
    for (i, p) in poses.iter().enumerate() {
        let th = PoseF::of(p).th;
        s.push_str(&format!(
            "{i},{:.3},{:.3},{th:.6}\n",
            f64::from(p.x_mm) / 1000.0,
            f64::from(p.y_mm) / 1000.0
        ));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create directory", dir.display()))?;
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

fn world_from_log(log: &Path, a: &ExportArgs) -> anyhow::Result<World> {
    let mut setup = setup_log(log, &a.map)?;
    if a.match_poses {
        let (matched, poses) = matched_setup(setup)?;
        let csv = a.out.with_extension("poses.csv");
        write_poses_csv(&csv, &poses)?;
        println!("wrote {}", csv.display());
        setup = matched;
    }
    let g = setup.geometry;
    let (w, h) = (usize::from(g.width()), usize::from(g.height()));
    let res = f64::from(g.cell_mm()) / 1000.0;
    let origin = (
        f64::from(g.origin_mm().0) / 1000.0,
        f64::from(g.origin_mm().1) / 1000.0,
    );
    if a.method == "benchmark" {
        ensure!(
            a.experiment == 0,
            "--method benchmark uses all the data; drop --experiment"
        );
        let m = map_scans(g, setup.mapper, &setup.scans)?;
        let cells = benchmark_truth(&probabilities(&m.map), &m.observed, BENCHMARK_THRESHOLD);
        return Ok(World {
            width: w,
            height: h,
            resolution_m: res,
            origin_m: origin,
            cells,
        });
    }
    let scans = Experiment::new(a.experiment)?.select(&setup.scans);
    let t = map_scans(g, setup.mapper, &scans)?;
    let probs = if a.method == "traditional" {
        probabilities(&t.map)
    } else {
        let methods = parse_methods(&a.method)?;
        let [m] = methods.as_slice() else {
            bail!("--method: give one method");
        };
        let cfg = MethodsConfig::new(&a.map)?;
        let probs = run_log_method(*m, &setup, &scans, &t.map, &cfg, &mut None)?.probs;
        // What no measurement reached stays unknown in the exported map.
        crate::eval::render::unknown_where_unobserved(&probs, &t.observed)
    };
    Ok(probabilities_to_world(
        &probs,
        w,
        h,
        res,
        origin,
        a.occupied_thresh,
        a.free_thresh,
    ))
}
