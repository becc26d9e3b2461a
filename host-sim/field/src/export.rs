//! `host-sim export --stream`: a captured map stream of the robot (the bytes its host link sent,
//! complete or cut off anywhere) as a ROS map_server map. The grid size comes from its `Hello`,
//! the cell size and origin from its `Configured` (or the caller's fallback if the capture has
//! none), and every tile in it is applied in order, so the latest state of each tile wins.
//! Tiles carry building tile coordinates ([`BuildingMap`]): a rolling window's stream gives the
//! whole building (its origin the settings' origin moved by the tiles left of or below the
//! robot's first grid); a fixed grid's gives exactly that grid.
//! Cells whose log-odds is 0 (never measured) are unknown in both layers; cells whose marginal
//! tile is not in the capture yet take their log-odds probability (where the robot's estimates
//! start). [`export_world`] is the writer every map export goes through (`listen` saves with
//! it too).

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};

use crate::stream::{
    counts_of_one, decode_file, stream_probabilities, BuildingMap, DeviceEvent, MapLayer,
};
use crate::world::{probabilities_to_world, write_png, write_ros_map, World};

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

/// The map a captured stream carries (see the [module docs](self)): `layer_name` is `marginals` or
/// `log-odds`; probabilities become trinary with `occupied_thresh` and `free_thresh`;
/// `fallback` gives the cell size (m) and origin (m) when the capture has no `Configured`.
pub fn world_from_stream(
    path: &Path,
    layer_name: &str,
    occupied_thresh: f64,
    free_thresh: f64,
    fallback: impl FnOnce() -> anyhow::Result<(f64, (f64, f64))>,
) -> anyhow::Result<World> {
    let marginals = match layer_name {
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
    // A bad tile is counted by the map and skipped.
    let building = BuildingMap::stitch(&hello, &events);
    let (mut config, mut samples) = (None, 0u32);
    for e in &events {
        match e {
            DeviceEvent::Configured(c) => config = Some(*c),
            DeviceEvent::Sampler(r) => samples = r.samples,
            _ => {}
        }
    }
    if building.tiles_bad_size() > 0 {
        eprintln!(
            "warning: {}: {} tiles had the wrong size and were skipped",
            path.display(),
            building.tiles_bad_size()
        );
    }
    if building.tiles_refused() > 0 {
        eprintln!(
            "warning: {}: {} tiles lay too far away (the building is capped at {} cells) and were skipped",
            path.display(),
            building.tiles_refused(),
            crate::stream::MAX_BUILDING_CELLS
        );
    }
    ensure!(
        building.tiles_applied() > 0,
        "{}: no map tile in the stream ({} frames): nothing to export",
        path.display(),
        events.len()
    );
    let render = building.render();
    let map = &render.map;
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
            fallback()?
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
    let origin = render.origin_m(resolution, origin);
    let probs = stream_probabilities(
        map,
        &render.have_counts,
        counts_of_one(config.as_ref(), Some(&hello), samples),
        layer,
    );
    println!(
        "{}: {} tiles applied, {}x{} cells, layer {}",
        path.display(),
        map.tiles,
        map.width,
        map.height,
        layer_name
    );
    if let Some(win) = building.window() {
        println!(
            "{}: rolling window: {} building tiles stitched, {} shifts, {} tiles out, {} beams clipped",
            path.display(),
            building.building_tiles(),
            win.shifts,
            win.tiles_out,
            win.beams_clipped
        );
    }
    Ok(probabilities_to_world(
        &probs,
        map.width,
        map.height,
        resolution,
        origin,
        occupied_thresh,
        free_thresh,
    ))
}
