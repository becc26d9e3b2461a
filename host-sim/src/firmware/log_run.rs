//! `host-sim firmware --log FILE [--experiment N] --out DIR`: a real laser log through the
//! firmware in QEMU ([`super::log`] encodes it), checked bit-exact against the host replay, and
//! what the robot mapped written out and scored like `eval-log`.
//!
//! The robot's grid is its board's (256 × 256 cells of 5 cm on the QEMU board), centred on the
//! log's first pose and aligned with `eval-log`'s grid of the same log, so its cells are
//! `eval-log`'s cells. With `--window-margin CELLS` the grid is a rolling window
//! (`RunConfig::window_margin_cells`) and the host stitches the building from the stream
//! (`ogm_field::stream::BuildingMap`); without it the robot maps the grid around its start.
//! Every figure is over the cells the stitched stream covers, against the benchmark made from
//! all of the log's scans at the same mapping range (`--range-cap`, as `eval-log --range-cap`;
//! the `coverage` says how much of the benchmark's mapped cells that is). Rays beyond the window
//! are clipped by the robot's mapper (counted in its `Window` reports).
//!
//! `DIR/map.yaml` (+ `.pgm`, `.png`: map_server conventions, unknown cells unknown) is the
//! robot's sampler map as `export --stream` makes it from the captured stream, `DIR/map-log-odds.yaml`
//! its log-odds map; `DIR/report.json` the run's report, the encoding and the scores;
//! `DIR/stream.bin`, `input.bin`, `lidar.bin` the bytes.

use std::path::Path;

use anyhow::{ensure, Context};
use ogm_core::config::{Budget, RunConfig};
use ogm_core::GridGeometry;
use ogm_field::stream::{counts_of_one, stream_probabilities, BuildingMap, DeviceEvent, MapLayer};
use ogm_field::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use ogm_field::world::{Truth, World};
use serde::Serialize;

use super::args::FirmwareArgs;
use super::groups::{decode_captured, Groups};
use super::log::{firmware_scan, log_config, log_input, mount_heading, LogEncoding};
use super::online::run_input_online;
use super::replay::FIRMWARE_SIZES;
use super::report::FirmwareReport;
use super::run::run_input;
use crate::eval::eval_log::{
    benchmark_truth, map_scans, setup_log, Experiment, LogMapArgs, BENCHMARK_THRESHOLD,
    NEAR_MAPPED_CELLS,
};
use crate::eval::log_maps::{experiment_noise, sensor_noise};
use crate::eval::metrics::{mask_within, PrAccumulator, Summary};
use crate::sim::probabilities;

/// `DIR/report.json` of a `--log` run.
#[derive(Clone, Debug, Serialize)]
pub struct LogRunReport {
    /// The log as given.
    pub log: String,
    /// The experiment (Table III: 1 = every 2nd beam, 2 = every 2nd pose and beam, 3 = every
    /// 10th pose and 2nd beam; 0 = every scan and beam).
    pub experiment: u8,
    /// How the scans were sent.
    pub encoding: LogEncoding,
    /// The sensor the settings were made for (σ cells, τ), estimated from the experiment's
    /// data as `eval-log` does; `None`: too few hits, the robot's defaults.
    pub sensor: Option<(f64, f64)>,
    /// The settings the robot ran with.
    pub config: RunConfig,
    /// The robot's grid (its window, with `--window-margin`), cells wide and tall.
    pub grid: (u16, u16),
    /// Offset of the robot's first grid in `eval-log`'s grid, cells.
    pub offset_cells: (i64, i64),
    /// The stitched map, cells wide and tall (the grid itself without a window).
    pub stitched: (usize, usize),
    /// The robot's last `Window` report (with `--window-margin`).
    pub window: Option<ogm_core::wire::WindowReport>,
    /// Whether the host sent stored tiles back (with `--window-margin`, unless `--no-restore`).
    pub restore: bool,
    /// The mapper's reach in cells (`Session::window_reach_cells`): the margin the window needs
    /// to equal an unbounded map.
    pub reach_cells: u32,
    /// Regions the robot came back to, as the stitching saw them.
    pub revisits: ogm_field::stream::Revisits,
    /// The stitched log-odds against an unbounded host map of the same scans (with a window):
    /// cells that differ, and cells the unbounded map knows.
    pub unbounded: Option<(usize, usize)>,
    /// Share of the benchmark's mapped cells that the robot's grid covers.
    pub coverage: f64,
    /// F1 near mapped (`eval-log`'s protocol) of the robot's log-odds map (`traditional`) and
    /// its sampler map (`gibbs_l9_border`), over the robot's grid.
    pub near_mapped: Vec<(String, Summary)>,
    /// The run: QEMU against the replay.
    pub firmware: FirmwareReport,
}

/// Runs `path` through the firmware (see the module docs).
pub fn run_log(args: &FirmwareArgs, path: &Path, experiment: u8) -> anyhow::Result<LogRunReport> {
    let out = args
        .out
        .as_ref()
        .context("--log needs --out DIR (the map and the report go there)")?;
    // The cap is the protocol's: the benchmark, eval-log's maps and the robot all map up to it.
    let map_args = match args.range_cap {
        0 => LogMapArgs::default(),
        cap => LogMapArgs {
            range_cap: f64::from(cap) / 1000.0,
            ..LogMapArgs::default()
        },
    };
    let setup = setup_log(path, &map_args)?;
    let exp = Experiment::new(experiment)?;
    let mut scans = exp.select(&setup.scans);
    if let Some(n) = args.max_scans {
        scans.truncate(n);
    }
    ensure!(!scans.is_empty(), "{}: no scans to send", path.display());
    let g = setup.geometry;
    let fw = FIRMWARE_SIZES;
    let cell = i64::from(g.cell_mm());
    // The robot's grid, centred on the first pose, on eval-log's lattice.
    let p0 = scans[0].pose;
    let offset = |o: i32, p: i32, n: u16| {
        ((i64::from(p) - i64::from(o)).div_euclid(cell)) - i64::from(n) / 2
    };
    let off = (
        offset(g.origin_mm().0, p0.x_mm, fw.width),
        offset(g.origin_mm().1, p0.y_mm, fw.height),
    );
    let origin = |o: i32, k: i64| i32::try_from(i64::from(o) + k * cell);
    let (ox, oy) = (
        origin(g.origin_mm().0, off.0).context("the log lies too far from its origin")?,
        origin(g.origin_mm().1, off.1).context("the log lies too far from its origin")?,
    );
    let budget = match args.fixed_updates {
        Some(updates) => Budget::Fixed { updates },
        None => Budget::Time {
            period_us: args.period_us,
            max_updates: args.max_updates,
        },
    };
    // The benchmark's map: all of the log's scans (σ is estimated from it, and the robot's maps
    // are scored against it).
    let bench = map_scans(g, setup.mapper, &setup.scans)?;
    // The robot's settings made for this log's sensor, as eval-log's robot mode makes them (σ
    // from all the log's scans, the shares of unsupported hits from the experiment's), on the
    // robot's grid.
    let sensor = experiment_noise(
        &setup,
        &scans,
        &map_scans(g, setup.mapper, &scans)?.map,
        sensor_noise(&setup, &setup.scans, Some(&bench.map))?.as_ref(),
    )
    .map(|n| n.sensor());
    let robot = match sensor {
        Some((sigma, tau)) => RunConfig::ROBOT.with_sensor(sigma, tau)?,
        None => RunConfig::ROBOT,
    };
    // A log's poses are SLAM-corrected: sent as they are they need no correction, as the
    // simulator's true poses (`--correction match` matches them all the same).
    let robot = robot.with_correction(
        args.correction
            .map_or(ogm_core::config::PoseCorrection::Off, |c| c.setting()),
    );
    let base = robot
        .with_origin_mm(ox, oy)
        .with_max_range_mm(setup.mapper.max_range_mm)
        .with_seed(args.seed)
        .with_budget(budget);
    // A host that sends tiles back answers every shift: the robot holds the turn that shifted
    // until then, so a step of any length maps onto the tiles it comes back to.
    let restore = args.window_margin > 0 && !args.no_restore;
    let config = log_config(
        RunConfig {
            tiles_per_scan: args.tiles_per_scan,
            count_tiles_per_scan: args.count_tiles_per_scan,
            ..base
                .with_window_margin_cells(args.window_margin)
                .with_window_hold(restore)
        },
        mount_heading(&scans),
    );
    let (input, encoding) = log_input(&scans, &config)?;
    eprintln!(
        "{}: {} scans (experiment {experiment}) as LD06 turns, lidar mounted at {}°; \
         {} padding points, {} inexact angles, {} clipped ranges; settings for σ, τ = {:?}",
        setup.name,
        scans.len(),
        encoding.mount_deg,
        encoding.padding_points,
        encoding.inexact_angles,
        encoding.clipped_ranges,
        sensor
    );
    let (firmware, stream, link) = if args.window_margin > 0 {
        run_input_online(args, &config, &input, restore)?
    } else {
        let (f, s) = run_input(args, &config, &input)?;
        (f, s, [&input.link[..], &input.finish[..]].concat())
    };
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create output directory", out.display()))?;
    std::fs::write(out.join("stream.bin"), &stream)?;
    std::fs::write(out.join("input.bin"), &link)?;
    std::fs::write(out.join("lidar.bin"), &input.lidar)?;
    // The robot's maps, as its stream carries them.
    let fallback = || Ok((f64::from(config.cell_mm) / 1000.0, (0.0, 0.0)));
    for (layer, name) in [("marginals", "map"), ("log-odds", "map-log-odds")] {
        let world = ogm_field::export::world_from_stream(
            &out.join("stream.bin"),
            layer,
            DEFAULT_OCCUPIED_THRESH,
            DEFAULT_FREE_THRESH,
            fallback,
        )?;
        ogm_field::export::export_world(&out.join(format!("{name}.yaml")), &world)?;
    }
    // What the robot mapped, stitched from its stream as `export --stream` stitches it.
    let (events, _) = decode_captured(&stream);
    let groups = Groups::of(&events);
    let hello = groups
        .hello
        .as_ref()
        .context("no Hello in the robot's stream")?;
    let building = BuildingMap::stitch(hello, &events);
    let samples = events
        .iter()
        .rev()
        .find_map(|e| match e {
            DeviceEvent::Sampler(s) => Some(s.samples),
            _ => None,
        })
        .unwrap_or(0);
    let render = building.render();
    let reach_cells = ogm_core::Session::new(config, ogm_core::session::Owned::<u8>::buffers(&fw))
        .map_or(0, |s| s.window_reach_cells());
    let unbounded = match args.window_margin {
        0 => None,
        _ => Some(unbounded_differ(&config, &scans, &render)?),
    };
    let one = counts_of_one(Some(&config), Some(hello), samples);
    let probs = |layer| stream_probabilities(&render.map, &render.have_counts, one, layer);
    let (w, h) = (render.map.width, render.map.height);
    let at = (off.0 + render.x0, off.1 + render.y0);
    // The sampler's map is scored as eval-log scores its samplers: its estimate in every cell
    // the robot streamed one for, including cells no ray reached (the prior's inference).
    let (near_mapped, coverage) = score(
        &setup,
        &bench,
        &probs(MapLayer::LogOdds),
        &probs(MapLayer::Estimates),
        (w, h),
        at,
    )?;
    let report = LogRunReport {
        log: path.display().to_string(),
        experiment,
        encoding,
        sensor,
        config,
        grid: (fw.width, fw.height),
        offset_cells: off,
        stitched: (w, h),
        window: building.window().copied(),
        restore,
        reach_cells,
        revisits: building.revisits().clone(),
        unbounded,
        coverage,
        near_mapped,
        firmware,
    };
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    Ok(report)
}

/// Cells of the stitched log-odds `r` (building cell (0, 0) at `config`'s origin) that differ
/// from an unbounded host map of the same scans as the firmware read them, and the cells that
/// map knows. Its grid covers every pose and the range around it.
fn unbounded_differ(
    config: &RunConfig,
    scans: &[crate::sim::explore::ScanRecord],
    r: &ogm_field::stream::BuildingRender,
) -> anyhow::Result<(usize, usize)> {
    let cell = i64::from(config.cell_mm.max(1));
    let reach = i64::from(config.max_range_mm) / cell + 8;
    let cells = |v: i32, o: i32| (i64::from(v) - i64::from(o)).div_euclid(cell);
    let xs = scans.iter().map(|s| cells(s.pose.x_mm, config.origin_x_mm));
    let ys = scans.iter().map(|s| cells(s.pose.y_mm, config.origin_y_mm));
    let (x0, x1) = (
        xs.clone().min().unwrap_or(0) - reach,
        xs.max().unwrap_or(0) + reach,
    );
    let (y0, y1) = (
        ys.clone().min().unwrap_or(0) - reach,
        ys.max().unwrap_or(0) + reach,
    );
    let (w, h) = (
        u16::try_from(x1 - x0 + 1).context("the log is too wide for one host grid")?,
        u16::try_from(y1 - y0 + 1).context("the log is too tall for one host grid")?,
    );
    let origin = |o: i32, c: i64| i32::try_from(i64::from(o) + c * cell);
    let mut host = ogm_core::Session::new(
        config.with_window_margin_cells(0).with_origin_mm(
            origin(config.origin_x_mm, x0)?,
            origin(config.origin_y_mm, y0)?,
        ),
        ogm_core::session::Owned::<u8>::buffers(&ogm_core::Sizes::grid(w, h)),
    )
    .map_err(|e| anyhow::anyhow!("the unbounded host map: {e:?}"))?;
    for s in scans {
        let (pose, beams) = firmware_scan(s, config.mount.heading);
        host.insert(&pose, &beams)
            .map_err(|e| anyhow::anyhow!("the unbounded host map: {e:?}"))?;
    }
    let (rw, rh) = (r.map.width as i64, r.map.height as i64);
    let (mut differ, mut known) = (0, 0);
    for (i, l) in host.log_odds().iter().enumerate() {
        let (bx, by) = (
            x0 + (i % usize::from(w)) as i64,
            y0 + (i / usize::from(w)) as i64,
        );
        let (x, y) = (bx - r.x0, by - r.y0);
        let got = if (0..rw).contains(&x) && (0..rh).contains(&y) {
            r.map.log_odds[(y * rw + x) as usize]
        } else {
            0
        };
        known += usize::from(l.0 != 0);
        differ += usize::from(got != l.0);
    }
    // A stitched cell known outside the host's grid differs too.
    for (i, &l) in r.map.log_odds.iter().enumerate() {
        let (bx, by) = (r.x0 + i as i64 % rw, r.y0 + i as i64 / rw);
        let inside = (x0..x0 + i64::from(w)).contains(&bx) && (y0..y0 + i64::from(h)).contains(&by);
        differ += usize::from(l != 0 && !inside);
    }
    Ok((differ, known))
}

/// F1 near mapped of the robot's maps (`traditional`: its log-odds, `gibbs_l9_border`: its
/// sampler's marginals) against the log's benchmark (`bench`: the map of all of `setup`'s scans)
/// over the stitched map (`w × h` cells at `off` in the benchmark's grid), and the share of the
/// benchmark's mapped cells it covers.
fn score(
    setup: &crate::eval::eval_log::LogSetup,
    bench: &crate::eval::log_setup::Mapped,
    log_odds: &[f64],
    sampler: &[f64],
    (w, h): (usize, usize),
    off: (i64, i64),
) -> anyhow::Result<(Vec<(String, Summary)>, f64)> {
    let g: GridGeometry = setup.geometry;
    let truth = benchmark_truth(
        &probabilities(&bench.map),
        &bench.observed,
        BENCHMARK_THRESHOLD,
    );
    let (gw, gh) = (i64::from(g.width()), i64::from(g.height()));
    let mut crop = vec![Truth::Unknown; w * h];
    let mut covered = 0usize;
    for y in 0..h {
        for x in 0..w {
            let (bx, by) = (x as i64 + off.0, y as i64 + off.1);
            if (0..gw).contains(&bx) && (0..gh).contains(&by) {
                let i = (by * gw + bx) as usize;
                crop[y * w + x] = truth[i];
                covered += usize::from(bench.observed[i]);
            }
        }
    }
    let mapped = bench.observed.iter().filter(|&&o| o).count().max(1);
    let observed: Vec<bool> = log_odds.iter().map(|p| *p != 0.5).collect();
    let near = mask_within(&observed, w, h, NEAR_MAPPED_CELLS);
    let world = World {
        width: w,
        height: h,
        resolution_m: f64::from(g.cell_mm()) / 1000.0,
        origin_m: (0.0, 0.0),
        cells: crop,
    };
    let mut out = Vec::new();
    for (name, probs) in [("traditional", log_odds), ("gibbs_l9_border", sampler)] {
        let mut a = PrAccumulator::new();
        a.add(probs, &world.cells, Some(&near))?;
        out.push((name.to_string(), a.summary()));
    }
    Ok((out, covered as f64 / mapped as f64))
}
