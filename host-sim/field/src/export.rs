//! `host-sim export --stream`: a captured map stream of the robot (the bytes its host link sent,
//! complete or cut off anywhere) as a ROS map_server map. The grid size comes from its `Hello`,
//! the cell size and origin from its `Configured` (or the caller's fallback if the capture has
//! none), and every tile in it is applied in order, so the latest state of each tile wins.
//! Cells whose log-odds is 0 (never measured) are unknown in both layers; cells whose marginal
//! tile is not in the capture yet take their log-odds probability (where the robot's estimates
//! start). [`export_world`] is the writer every map export goes through (`listen` saves with
//! it too).

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};

use crate::stream::{
    counts_of_one, decode_file, stream_probabilities, DeviceEvent, MapLayer, StreamedMap,
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
        layer_name
    );
    Ok(probabilities_to_world(
        &probs,
        w,
        h,
        resolution,
        origin,
        occupied_thresh,
        free_thresh,
    ))
}
