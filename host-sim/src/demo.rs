//! `host-sim demo`: the main job. Generates the embedded default world (no files needed), lets
//! the robot explore and map it online with ogm-core, scores the maps against ground truth and
//! writes PNGs and `report.json`.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;

use crate::eval::{evaluate_methods, MethodMaps};
use crate::report::{MapInfo, Report};
use crate::sim::{probabilities, simulate, SimConfig};
use crate::{progress, render, world};

/// Runs the demo into `out`.
pub fn run(out: &Path, seed: u64) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output directory {}", out.display()))?;
    let world = world::generate::default_world();
    println!(
        "default world: {}x{} cells of {:.2} m ({:.1} x {:.1} m)",
        world.width,
        world.height,
        world.resolution_m,
        world.width as f64 * world.resolution_m,
        world.height as f64 * world.resolution_m
    );
    let cfg = SimConfig::default();
    let bar = progress::spinner("exploring and mapping");
    let t0 = Instant::now();
    let run = simulate(&world, &cfg, seed)?;
    let mapping_s = t0.elapsed().as_secs_f64();
    bar.finish_with_message(format!("{} scans in {:.2} s", run.scans.len(), mapping_s));

    let traditional = probabilities(&run.map);
    let mut maps = MethodMaps::new();
    maps.insert("traditional".into(), traditional.clone());
    let (methods, near) = evaluate_methods(&world, &[(maps, run.observed.clone())])?;

    let t = methods
        .get("traditional")
        .map(|s| s.threshold_at_max_f1)
        .unwrap_or(0.5);
    render::truth_png(out.join("ground_truth.png"), &world)?;
    render::probability_png(
        out.join("traditional_probability.png"),
        &traditional,
        world.width,
        world.height,
    )?;
    render::threshold_png(
        out.join("traditional_thresholded.png"),
        &traditional,
        world.width,
        world.height,
        t,
    )?;
    render::comparison_png(out.join("traditional_errors.png"), &traditional, &world, t)?;

    let mut seconds = BTreeMap::new();
    seconds.insert("traditional".to_string(), mapping_s);
    let report = Report {
        methods,
        methods_near_mapped: near,
        restricted_radius_cells: crate::eval::NEAR_MAPPED_CELLS,
        datasets: 1,
        maps: vec![MapInfo {
            name: "default".into(),
            width: world.width,
            height: world.height,
            resolution_m: world.resolution_m,
            runs: 1,
            mean_scans: run.scans.len() as f64,
        }],
        settings: serde_json::json!({ "sim": cfg, "seed": seed, "mapper": format!("{:?}", run.mapper_config) }),
        seconds,
    };
    report.write(&out.join("report.json"))?;
    println!("\n{}", report.table());
    println!("wrote {}", out.display());
    Ok(())
}
