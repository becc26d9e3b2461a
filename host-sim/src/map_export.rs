//! `host-sim export`: any map the tools produce as a ROS map_server map — a YAML (`image`,
//! `resolution`, `origin`, `negate: 0`, `occupied_thresh: 0.65`, `free_thresh: 0.196`,
//! `mode: trinary`), a trinary P5 PGM (0 occupied, 254 free, 205 unknown) and the same grey
//! levels as PNG — through [`crate::world::export`].
//!
//! Sources (exactly one):
//! * `--log FILE [--experiment 0..3] [--method NAME]`: maps a CARMEN log like `eval-log` and
//!   exports the `benchmark` (its trinary ground truth, exactly), `traditional` or any sampler's
//!   or baseline's map; experiment 0 is all of the log's data.
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

use crate::eval_log::{
    benchmark_truth, map_scans, parse_methods, run_log_method, setup_log, Experiment, LogMapArgs,
    MethodsConfig, BENCHMARK_THRESHOLD,
};
use crate::link::{HelloInfo, StreamedMap};
use crate::render::SIDE_BY_SIDE_GAP_PX;
use crate::sim::probabilities;
use crate::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use crate::world::{load_world, probabilities_to_world, write_png, write_ros_map, World};

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

/// Writes `world` as `<out>.yaml` + `<out>.pgm` (ROS map_server) and `<out>.png`; returns the
/// paths written.
pub fn export_world(out: &Path, world: &World) -> anyhow::Result<Vec<PathBuf>> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create directory", dir.display()))?;
    }
    let pgm = write_ros_map(out, world)?;
    let png = out.with_extension("png");
    write_png(&png, world)?;
    Ok(vec![out.to_path_buf(), pgm, png])
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
        world_from_stream(path, a)?
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

/// The map a captured stream carries (see the [module docs](self)).
fn world_from_stream(path: &Path, a: &ExportArgs) -> anyhow::Result<World> {
    use crate::link::{decode_file, DeviceEvent};
    let marginals = match a.layer.as_str() {
        "marginals" => true,
        "log-odds" => false,
        other => bail!("--layer {other}: expected marginals or log-odds"),
    };
    let events = decode_file(path)?;
    let hello = events
        .iter()
        .find_map(|e| match e {
            DeviceEvent::Hello(h) => Some(h.clone()),
            _ => None,
        })
        .with_context(|| {
            format!(
                "{}: no Hello in the stream (the grid size is in it): capture from the robot's boot",
                path.display()
            )
        })?;
    let (w, h) = (usize::from(hello.width), usize::from(hello.height));
    ensure!(
        w > 0 && h > 0 && hello.tile_edge > 0,
        "{}: Hello gives an empty grid",
        path.display()
    );
    let mut map = StreamedMap::new(w, h, usize::from(hello.tile_edge));
    let (mut config, mut samples, mut bad_tiles) = (None, 0u32, 0usize);
    // Cells whose marginal tile has arrived (the robot streams those round robin, so a short
    // or cut-off capture may lack some).
    let mut have_counts = vec![false; w * h];
    for e in &events {
        match e {
            DeviceEvent::Configured(c) => config = Some(*c),
            DeviceEvent::Sampler(r) => samples = r.samples,
            DeviceEvent::Tile(t) => match map.apply(t) {
                Err(_) => bad_tiles += 1,
                Ok(rect) if t.layer == ogm_core::wire::Layer::Counts => {
                    for c in rect.cells() {
                        if let Some(x) = have_counts.get_mut(c) {
                            *x = true;
                        }
                    }
                }
                Ok(_) => {}
            },
            _ => {}
        }
    }
    ensure!(
        map.tiles > 0,
        "{}: no map tile in the stream ({} frames): nothing to export",
        path.display(),
        events.len()
    );
    if bad_tiles > 0 {
        eprintln!(
            "warning: {}: {bad_tiles} tiles did not fit the grid and were skipped",
            path.display()
        );
    }
    let (resolution, origin) = match &config {
        Some(c) => (
            f64::from(c.cell_mm) / 1000.0,
            (
                f64::from(c.origin_x_mm) / 1000.0,
                f64::from(c.origin_y_mm) / 1000.0,
            ),
        ),
        None => {
            eprintln!(
                "warning: {}: no Configured in the stream; using --resolution and --origin",
                path.display()
            );
            (a.resolution, parse_origin(&a.origin)?)
        }
    };
    ensure!(
        resolution.is_finite() && resolution > 0.0,
        "{}: cell size must be positive",
        path.display()
    );
    let layer = if marginals {
        MapLayer::Marginals
    } else {
        MapLayer::LogOdds
    };
    let probs = stream_probabilities(
        &map,
        &have_counts,
        counts_of_one(config.as_ref(), Some(&hello), samples),
        layer,
    );
    println!(
        "{}: {} tiles applied, {}x{} cells, layer {}",
        path.display(),
        map.tiles,
        w,
        h,
        a.layer
    );
    Ok(probabilities_to_world(
        &probs,
        w,
        h,
        resolution,
        origin,
        a.occupied_thresh,
        a.free_thresh,
    ))
}

fn world_from_log(log: &Path, a: &ExportArgs) -> anyhow::Result<World> {
    let setup = setup_log(log, &a.map)?;
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
        crate::render::unknown_where_unobserved(&probs, &t.observed)
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

/// Which map to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapLayer {
    /// The sampler's marginals (cells whose marginal tile has not arrived take their log-odds
    /// probability).
    Marginals,
    /// The log-odds map.
    LogOdds,
}

/// Per-cell probabilities of a streamed map, as `host-sim export --stream` computes them:
/// log-odds 0 (never measured) is 0.5 (unknown) in both layers; with [`MapLayer::Marginals`] a
/// cell whose marginal tile arrived (`have_counts`) is `count / counts_of_one` (capped at 1),
/// any other its log-odds probability.
pub fn stream_probabilities(
    map: &StreamedMap,
    have_counts: &[bool],
    counts_of_one: u32,
    layer: MapLayer,
) -> Vec<f64> {
    (0..map.width * map.height)
        .map(|i| {
            let l = map.log_odds.get(i).copied().unwrap_or(0);
            if l == 0 {
                return 0.5;
            }
            if layer == MapLayer::Marginals && have_counts.get(i) == Some(&true) {
                let c = map.counts.get(i).copied().unwrap_or(0);
                (f64::from(c) / f64::from(counts_of_one.max(1))).min(1.0)
            } else {
                ogm_core::LogOdds(l).probability()
            }
        })
        .collect()
}

/// The count that means p = 1: the last `Sampler` report's `samples` under the paper's
/// estimator (`Estimator::Counts`), else the robot's `count_max` (255 without a `Hello`).
pub fn counts_of_one(
    config: Option<&ogm_core::config::RunConfig>,
    hello: Option<&HelloInfo>,
    samples: u32,
) -> u32 {
    match config.map(|c| c.estimator) {
        Some(ogm_core::config::Estimator::Counts) => samples,
        _ => hello.map_or(255, |h| h.count_max),
    }
}
