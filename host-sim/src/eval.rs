//! `host-sim eval-sim`: simulated datasets on ground-truth maps, pooled metrics per method.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};

use crate::metrics::{mask_within, PrAccumulator, Summary};
use crate::report::{MapInfo, Report};
use crate::sim::{probabilities, simulate, SimConfig};
use crate::world::{load::load_world, World};
use crate::{progress, render};

/// Radius (cells) of the "near a mapped cell" restriction (the paper's hardware metric).
pub const NEAR_MAPPED_CELLS: f64 = 10.0;

/// Cell size every evaluation world is resampled to (the prior's canonical cell size).
pub const EVAL_RESOLUTION_M: f64 = 0.05;

/// Probability maps per method for one dataset.
pub type MethodMaps = BTreeMap<String, Vec<f64>>;

/// Pools per-method metrics over datasets: `(maps, mapped)` pairs on the same `world`.
/// Returns (all cells, cells near mapped cells).
pub fn evaluate_methods(
    world: &World,
    datasets: &[(MethodMaps, Vec<bool>)],
) -> anyhow::Result<(BTreeMap<String, Summary>, BTreeMap<String, Summary>)> {
    let mut all: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut near: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    accumulate(world, datasets, &mut all, &mut near)?;
    Ok((summaries(&all), summaries(&near)))
}

fn accumulate(
    world: &World,
    datasets: &[(MethodMaps, Vec<bool>)],
    all: &mut BTreeMap<String, PrAccumulator>,
    near: &mut BTreeMap<String, PrAccumulator>,
) -> anyhow::Result<()> {
    for (maps, mapped) in datasets {
        let mask = mask_within(mapped, world.width, world.height, NEAR_MAPPED_CELLS);
        for (name, probs) in maps {
            all.entry(name.clone())
                .or_default()
                .add(probs, &world.cells, None)?;
            near.entry(name.clone())
                .or_default()
                .add(probs, &world.cells, Some(&mask))?;
        }
    }
    Ok(())
}

fn summaries(acc: &BTreeMap<String, PrAccumulator>) -> BTreeMap<String, Summary> {
    acc.iter().map(|(k, v)| (k.clone(), v.summary())).collect()
}

/// Expands directories into the map files inside them (sorted), keeps files as given.
pub fn collect_maps(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("reading directory {}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| {
                    let ext = f
                        .extension()
                        .and_then(|e| e.to_str())
                        .unwrap_or("")
                        .to_ascii_lowercase();
                    // A YAML describes its image; don't load the image twice.
                    match ext.as_str() {
                        "yaml" | "yml" => true,
                        "png" | "pgm" => {
                            !f.with_extension("yaml").exists() && !f.with_extension("yml").exists()
                        }
                        _ => false,
                    }
                })
                .collect();
            files.sort();
            if files.is_empty() {
                bail!(
                    "{}: no map files (.png, .pgm, .yaml) in directory",
                    p.display()
                );
            }
            out.extend(files);
        } else if p.exists() {
            out.push(p.clone());
        } else {
            bail!("{}: no such file or directory", p.display());
        }
    }
    Ok(out)
}

/// Runs `eval-sim`.
pub fn run_sim(maps: &[PathBuf], runs: u32, out: &Path, seed: u64) -> anyhow::Result<()> {
    anyhow::ensure!(runs > 0, "--runs must be at least 1");
    let files = collect_maps(maps)?;
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output directory {}", out.display()))?;
    let cfg = SimConfig::default();
    let mut all: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut near: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut infos = Vec::new();
    let mut seconds: BTreeMap<String, f64> = BTreeMap::new();
    let bar = progress::bar(files.len() as u64 * u64::from(runs), "simulated datasets");
    for (j, file) in files.iter().enumerate() {
        let world = load_world(file, None)?.resample(EVAL_RESOLUTION_M);
        let name = file
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("map")
            .to_string();
        let mut scans = 0usize;
        for i in 0..runs {
            bar.set_message(format!("{name} run {}", i + 1));
            let s = seed + 1000 * j as u64 + u64::from(i);
            let t0 = Instant::now();
            let run = simulate(&world, &cfg, s)
                .with_context(|| format!("simulating on {}", file.display()))?;
            *seconds.entry("traditional".into()).or_default() += t0.elapsed().as_secs_f64();
            scans += run.scans.len();
            let mut m = MethodMaps::new();
            m.insert("traditional".into(), probabilities(&run.map));
            accumulate(&world, &[(m, run.observed.clone())], &mut all, &mut near)?;
            bar.inc(1);
        }
        infos.push(MapInfo {
            name,
            width: world.width,
            height: world.height,
            resolution_m: world.resolution_m,
            runs,
            mean_scans: scans as f64 / f64::from(runs),
        });
    }
    bar.finish();
    let curves: Vec<(String, Vec<crate::metrics::PrPoint>)> =
        all.iter().map(|(k, v)| (k.clone(), v.curve())).collect();
    render::pr_curve_svg(
        out.join("pr_curve.svg"),
        &curves,
        "Precision-recall, simulated datasets",
    )?;
    let report = Report {
        methods: summaries(&all),
        methods_near_mapped: summaries(&near),
        restricted_radius_cells: NEAR_MAPPED_CELLS,
        datasets: files.len() * runs as usize,
        maps: infos,
        settings: serde_json::json!({ "sim": cfg, "seed": seed, "resolution_m": EVAL_RESOLUTION_M }),
        seconds,
    };
    report.write(&out.join("report.json"))?;
    println!("\n{}", report.table());
    println!("wrote {}", out.join("report.json").display());
    Ok(())
}
