//! `host-sim demo`: the main job. Generates the embedded default world (no files needed), lets
//! the robot explore and map it online with ogm-core, runs the border-conditioned Gibbs sampler
//! (and the other two variants) on the recorded scans, scores every map against ground truth and
//! writes PNGs and `report.json`.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;

use crate::eval::eval_sim::{evaluate_methods, MethodMaps, NEAR_MAPPED_CELLS};
use crate::eval::report::{MapInfo, Report};
use crate::eval::sampling::{run_sampler, SamplingConfig, Variant};
use crate::eval::{progress, render};
use crate::sim::generate;
use crate::sim::{probabilities, simulate, SimConfig};

/// Runs the demo into `out`.
pub fn run(out: &Path, seed: u64, all_samplers: bool) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output directory {}", out.display()))?;
    let world = generate::default_world();
    println!(
        "default world: {}x{} cells of {:.2} m ({:.1} x {:.1} m), {:.1} % occupied",
        world.width,
        world.height,
        world.resolution_m,
        world.width as f64 * world.resolution_m,
        world.height as f64 * world.resolution_m,
        100.0 * world.occupied_fraction()
    );
    let cfg = SimConfig::default();
    let bar = progress::spinner("exploring and mapping online");
    let t0 = Instant::now();
    let run = simulate(&world, &cfg, seed)?;
    let mapping_s = t0.elapsed().as_secs_f64();
    bar.finish_with_message(format!(
        "{} scans mapped online in {:.2} s",
        run.scans.len(),
        mapping_s
    ));

    let mut maps = MethodMaps::new();
    let mut seconds = BTreeMap::new();
    maps.insert("traditional".into(), probabilities(&run.map));
    seconds.insert("traditional".to_string(), mapping_s);
    let scfg = SamplingConfig::default();
    let variants: &[Variant] = if all_samplers {
        &Variant::ALL
    } else {
        // The robot's sampler and the paper's, side by side.
        &[Variant::L9Border, Variant::L9BorderRays]
    };
    let bar = progress::bar(variants.len() as u64, "Gibbs samplers");
    for &v in variants {
        bar.set_message(v.name());
        let o = run_sampler(
            run.geometry,
            &run.mapper_config,
            &run.scans,
            &run.map,
            v,
            &v.configure(&scfg),
            seed,
        )?;
        seconds.insert(v.name().to_string(), o.seconds);
        maps.insert(v.name().into(), o.marginals);
        bar.inc(1);
    }
    bar.finish_with_message("samplers done");

    let (methods, near) = evaluate_methods(&world, &[(maps.clone(), run.observed.clone())])?;
    let (w, h) = (world.width, world.height);
    render::truth_png(out.join("ground_truth.png"), &world)?;
    let mut panels = vec![("ground truth".to_string(), render::truth_image(&world)?)];
    for name in ["traditional", "gibbs_l9_border", "gibbs_l9_border_rays"] {
        let probs = &maps[name];
        let t = methods.get(name).map_or(0.5, |s| s.threshold_at_max_f1);
        // What no measurement reached is drawn unknown; the error map scores every estimate.
        let shown = render::unknown_where_unobserved(probs, &run.observed);
        render::probability_png(out.join(format!("{name}_probability.png")), &shown, w, h)?;
        render::threshold_png(out.join(format!("{name}_thresholded.png")), &shown, w, h, t)?;
        render::comparison_png(out.join(format!("{name}_errors.png")), probs, &world, t)?;
        panels.push((name.to_string(), render::probability_image(&shown, w, h)?));
    }
    render::side_by_side_png(out.join("comparison.png"), &panels)?;

    let report = Report {
        methods,
        methods_near_mapped: near,
        restricted_radius_cells: NEAR_MAPPED_CELLS,
        datasets: 1,
        maps: vec![MapInfo {
            name: "default".into(),
            width: w,
            height: h,
            resolution_m: world.resolution_m,
            runs: 1,
            mean_scans: run.scans.len() as f64,
        }],
        settings: serde_json::json!({
            "sim": cfg, "seed": seed, "sampler": scfg,
            "mapper": format!("{:?}", run.mapper_config),
        }),
        seconds,
    };
    report.write(&out.join("report.json"))?;
    println!("\n{}", report.table());
    println!(
        "ground truth | traditional | robot's sampler | paper's sampler: {}",
        out.join("comparison.png").display()
    );
    println!("wrote {}", out.display());
    Ok(())
}
