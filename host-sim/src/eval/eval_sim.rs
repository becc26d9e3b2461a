//! `host-sim eval-sim`: simulated datasets on ground-truth maps, pooled metrics per method
//! (the protocol of the paper's Table II: ≈500×500-cell worlds, F = 75 cells, σ = 3 cells,
//! sparse scans at stops).

use ogm_firmware::sizes::MPS2_AN386 as FW;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use ogm_field::world::{load_world, World};
use serde::{Deserialize, Serialize};

use crate::eval::metrics::{mask_within, PrAccumulator, Summary};
use crate::eval::report::{MapInfo, Report};
use crate::eval::sampling::{run_sampler, Bounds, SamplingConfig, Variant};
use crate::eval::{progress, render};
use crate::sim::{probabilities, simulate, SimConfig};

/// Radius (cells) of the "near a mapped cell" restriction (the paper's hardware metric).
pub const NEAR_MAPPED_CELLS: f64 = 10.0;

/// The canonical cell size (the prior's): evaluation worlds are labelled with it.
pub const EVAL_RESOLUTION_M: f64 = 0.05;

/// Side (cells) larger evaluation maps are cropped to, like the paper's 500×500 worlds.
pub const EVAL_CELLS: usize = 500;

/// Probability maps per method for one dataset.
pub type MethodMaps = BTreeMap<String, Vec<f64>>;

/// Pools per-method metrics over datasets: `(maps, mapped)` pairs on the same `world`.
/// Returns (all cells, cells near mapped cells).
pub fn evaluate_methods(
    world: &World,
    datasets: &[(MethodMaps, Vec<bool>)],
) -> anyhow::Result<(BTreeMap<String, Summary>, BTreeMap<String, Summary>)> {
    let mut acc = Pooled::default();
    for (maps, mapped) in datasets {
        acc.add(world, maps, mapped)?;
    }
    Ok((acc.summaries(false), acc.summaries(true)))
}

/// Per-method accumulators over all cells and over cells near mapped cells.
#[derive(Default)]
struct Pooled {
    all: BTreeMap<String, PrAccumulator>,
    near: BTreeMap<String, PrAccumulator>,
}

impl Pooled {
    fn add(&mut self, world: &World, maps: &MethodMaps, mapped: &[bool]) -> anyhow::Result<()> {
        let mask = mask_within(mapped, world.width, world.height, NEAR_MAPPED_CELLS);
        for (name, probs) in maps {
            self.all
                .entry(name.clone())
                .or_default()
                .add(probs, &world.cells, None)?;
            self.near
                .entry(name.clone())
                .or_default()
                .add(probs, &world.cells, Some(&mask))?;
        }
        Ok(())
    }

    fn summaries(&self, near: bool) -> BTreeMap<String, Summary> {
        let acc = if near { &self.near } else { &self.all };
        acc.iter().map(|(k, v)| (k.clone(), v.summary())).collect()
    }
}

/// Expands directories into the map files inside them (sorted), keeps files as given.
pub fn collect_maps(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    collect_files(paths, "map files (.png, .pgm, .yaml)", |f| {
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
}

/// Expands command-line paths: a file is taken as it is (it must exist), a directory gives its
/// files that `wanted` accepts, sorted (none is an error naming the directory and `what`).
pub fn collect_files(
    paths: &[PathBuf],
    what: &str,
    wanted: impl Fn(&Path) -> bool,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("{}: cannot read directory", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| wanted(f))
                .collect();
            files.sort();
            if files.is_empty() {
                bail!("{}: no {what} in directory", p.display());
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

/// Loads an evaluation world. A ROS YAML whose image is missing falls back (with a warning) to an
/// image of the same stem beside it. The protocol is defined in cells (F = 75, σ = 3, ≈500×500
/// worlds), so one map pixel is one cell, labelled with the canonical 0.05 m (Player/Stage
/// bitmaps are 2.5–4.5 cm per pixel); a map wider or taller than [`EVAL_CELLS`] + 20 % is cropped
/// to the [`EVAL_CELLS`]-square window (or strip) holding the most wall cells (occupied cells
/// next to free ones), searched on a 25-cell stride — deterministic, and it keeps the building
/// rather than empty margins or open halls.
/// Finally every free region not connected to the largest one becomes occupied: Player/Stage
/// draws solid obstacles as outlines, and a region no robot can enter or see into is solid for
/// the simulator (and unknowable to any mapper), so scoring it as free would only measure that.
pub fn load_eval_world(path: &Path) -> anyhow::Result<World> {
    let world = match load_world(path, None) {
        Ok(w) => w,
        Err(e @ ogm_field::world::MapError::ImageMissing { .. }) => {
            let alt = ["pgm", "png"]
                .iter()
                .map(|x| path.with_extension(x))
                .find(|p| p.exists());
            match alt {
                Some(alt) => {
                    eprintln!("warning: {e}; using {} instead", alt.display());
                    load_world(&alt, None)?
                }
                None => return Err(e.into()),
            }
        }
        Err(e) => return Err(e.into()),
    };
    let limit = EVAL_CELLS + EVAL_CELLS / 5;
    let mut w = if world.width > limit || world.height > limit {
        let (cw, ch) = (world.width.min(EVAL_CELLS), world.height.min(EVAL_CELLS));
        let (x, y) = densest_window(&world, cw, ch);
        world.crop(x, y, cw, ch)
    } else {
        world
    };
    w.resolution_m = EVAL_RESOLUTION_M;
    w.origin_m = (0.0, 0.0);
    fill_enclosed(&mut w);
    Ok(w)
}

/// Marks every free cell outside the largest 4-connected free region occupied.
pub fn fill_enclosed(w: &mut World) {
    let comps = w.free_components();
    let Some(largest) = comps
        .sizes
        .iter()
        .enumerate()
        .max_by_key(|(_, s)| **s)
        .map(|(i, _)| i as u32)
    else {
        return;
    };
    for (c, l) in w.cells.iter_mut().zip(&comps.labels) {
        if *c == ogm_field::world::Truth::Free && *l != largest {
            *c = ogm_field::world::Truth::Occupied;
        }
    }
}

/// Lower-left corner of the `cw × ch` window with the most wall cells (25-cell stride).
fn densest_window(world: &World, cw: usize, ch: usize) -> (usize, usize) {
    use ogm_field::world::Truth;
    let (w, h) = (world.width, world.height);
    let wall = |x: usize, y: usize| {
        world.cells[y * w + x] == Truth::Occupied
            && [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .any(|(dx, dy)| world.get(x as i64 + dx, y as i64 + dy) == Some(Truth::Free))
    };
    let mut sat = vec![0u64; (w + 1) * (h + 1)];
    for y in 0..h {
        for x in 0..w {
            let free = u64::from(wall(x, y));
            sat[(y + 1) * (w + 1) + x + 1] =
                free + sat[y * (w + 1) + x + 1] + sat[(y + 1) * (w + 1) + x] - sat[y * (w + 1) + x];
        }
    }
    let count = |x: usize, y: usize| {
        sat[(y + ch) * (w + 1) + x + cw] + sat[y * (w + 1) + x]
            - sat[y * (w + 1) + x + cw]
            - sat[(y + ch) * (w + 1) + x]
    };
    let mut best = (0, 0, 0);
    for y in (0..=h - ch).step_by(25) {
        for x in (0..=w - cw).step_by(25) {
            let c = count(x, y);
            if c > best.0 {
                best = (c, x, y);
            }
        }
    }
    (best.1, best.2)
}

/// Settings of an evaluation run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalConfig {
    /// Datasets per map.
    pub runs: u32,
    /// First seed.
    pub seed: u64,
    /// Sampler variants to run besides traditional OGM.
    pub variants: Vec<Variant>,
    /// Simulation.
    pub sim: SimConfig,
    /// Samplers.
    pub sampling: SamplingConfig,
    /// Baseline methods (`mh`, `mh_heatmap`, `bp_sum`, `bp_max`, `dd`) to run besides the samplers.
    #[serde(default)]
    pub baselines: Vec<crate::eval::baselines::Method>,
    /// Their settings (forward model, cell prior, budgets); also defines the energy reported for
    /// every method.
    #[serde(default)]
    pub baseline: crate::eval::baselines::BaselineConfig,
}

/// Runs `eval-sim`.
pub fn run_sim(maps: &[PathBuf], out: &Path, cfg: &EvalConfig) -> anyhow::Result<()> {
    anyhow::ensure!(cfg.runs > 0, "--runs must be at least 1");
    let files = collect_maps(maps)?;
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create output directory", out.display()))?;
    let mut pooled = Pooled::default();
    // Per map too, so a reader can see where each method wins or loses.
    let mut per_map: BTreeMap<String, Pooled> = BTreeMap::new();
    let mut infos = Vec::new();
    let mut seconds: BTreeMap<String, f64> = BTreeMap::new();
    let mut per_sweep: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut skipped = Vec::new();
    let mut energies = crate::eval::baselines::EnergyTable::default();
    let bar = progress::bar(
        files.len() as u64 * u64::from(cfg.runs),
        "simulated datasets",
    );
    for (j, file) in files.iter().enumerate() {
        let world = match load_eval_world(file) {
            Ok(w) => w,
            Err(e) => {
                bar.println(format!("skipping {}: {e:#}", file.display()));
                skipped.push(serde_json::json!({ "map": file.display().to_string(), "error": format!("{e:#}") }));
                bar.inc(u64::from(cfg.runs));
                continue;
            }
        };
        let name = file
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("map")
            .to_string();
        let mut scans = 0usize;
        for i in 0..cfg.runs {
            bar.set_message(format!("{name} run {}", i + 1));
            let s = cfg.seed + 1000 * j as u64 + u64::from(i);
            let t0 = Instant::now();
            let run = simulate(&world, &cfg.sim, s)
                .with_context(|| format!("simulating on {}", file.display()))?;
            *seconds.entry("traditional".into()).or_default() += t0.elapsed().as_secs_f64();
            scans += run.scans.len();
            let mut m = MethodMaps::new();
            m.insert("traditional".into(), probabilities(&run.map));
            let mut timed = Vec::new();
            for &v in &cfg.variants {
                let o = run_sampler(
                    run.geometry,
                    &run.mapper_config,
                    &run.scans,
                    &run.map,
                    v,
                    &v.configure(&cfg.sampling),
                    s,
                )?;
                *seconds.entry(v.name().into()).or_default() += o.seconds;
                timed.push((v.name().to_string(), o.seconds));
                per_sweep
                    .entry(v.name().into())
                    .or_default()
                    .push(o.seconds_per_sweep);
                m.insert(v.name().into(), o.marginals);
            }
            // The baselines, and the energy of every method's map, on one shared factor graph.
            let graph = crate::eval::baselines::build_graph(
                &run.geometry,
                &run.mapper_config,
                &run.scans,
                &cfg.baseline,
            )?;
            let mut traces = Vec::new();
            for &b in &cfg.baselines {
                bar.set_message(format!("{name} run {}: {}", i + 1, b.name()));
                let o =
                    crate::eval::baselines::run_on_graph(b, &graph, &run.map, &cfg.baseline, s)?;
                energies.add_run(&name, b.name(), &o);
                *seconds.entry(b.name().into()).or_default() += o.seconds;
                traces.push((b.name().to_string(), o.trace));
                m.insert(b.name().into(), o.probs);
            }
            for (k, probs) in &m {
                energies.add(&name, k, graph.energy_of_probs(probs));
            }
            if i == 0 && !traces.is_empty() {
                // Dhiman et al.'s Fig. 3: energy against time; the samplers as end points.
                let e = |k: &str| m.get(k).map(|p| graph.energy_of_probs(p).total());
                let points: Vec<(String, f64, f64)> = std::iter::once(("traditional".into(), 0.0))
                    .chain(timed)
                    .filter_map(|(k, t)| e(&k).map(|e| (k, t, e)))
                    .collect();
                crate::eval::baselines::plot::energy_vs_time_svg(
                    out.join(format!("energy_{name}.svg")),
                    &format!("Energy vs time, {name}"),
                    &traces,
                    &points,
                )?;
            }
            pooled.add(&world, &m, &run.observed)?;
            per_map
                .entry(name.clone())
                .or_default()
                .add(&world, &m, &run.observed)?;
            if i == 0 {
                // One picture per map: ground truth, then every method's probability map.
                let mut panels = vec![("ground truth".to_string(), render::truth_image(&world)?)];
                for (k, probs) in &m {
                    let shown = render::unknown_where_unobserved(probs, &run.observed);
                    panels.push((
                        k.clone(),
                        render::probability_image(&shown, world.width, world.height)?,
                    ));
                }
                render::side_by_side_png(out.join(format!("{name}.png")), &panels)?;
            }
            bar.inc(1);
        }
        infos.push(MapInfo {
            name,
            width: world.width,
            height: world.height,
            resolution_m: world.resolution_m,
            runs: cfg.runs,
            mean_scans: scans as f64 / f64::from(cfg.runs),
        });
    }
    bar.finish();
    if infos.is_empty() {
        // One line naming the file and the problem (the progress bar's messages are not shown
        // when stderr is not a terminal).
        let first = skipped
            .first()
            .and_then(|s| s["error"].as_str())
            .unwrap_or("no map files")
            .to_string();
        match skipped.len() {
            0 | 1 => bail!("no map could be loaded: {first}"),
            n => bail!("no map could be loaded: {first} (and {} more)", n - 1),
        }
    }
    let curves: Vec<(String, Vec<crate::eval::metrics::PrPoint>)> = pooled
        .all
        .iter()
        .map(|(k, v)| (k.clone(), v.curve()))
        .collect();
    render::pr_curve_svg(
        out.join("pr_curve.svg"),
        &curves,
        "Precision-recall, simulated datasets",
    )?;
    render::f1_vs_threshold_svg(
        out.join("f1_vs_threshold.svg"),
        &curves,
        "F1 vs threshold, simulated datasets",
    )?;
    let mean_per_sweep: BTreeMap<String, f64> = per_sweep
        .iter()
        .map(|(k, v)| (k.clone(), v.iter().sum::<f64>() / v.len().max(1) as f64))
        .collect();
    let datasets = infos.iter().map(|m| m.runs as usize).sum();
    let report = Report {
        methods: pooled.summaries(false),
        methods_near_mapped: pooled.summaries(true),
        restricted_radius_cells: NEAR_MAPPED_CELLS,
        datasets,
        maps: infos,
        settings: serde_json::json!({
            "eval": cfg, "eval_cells": EVAL_CELLS,
            "seconds_per_map_sample": mean_per_sweep, "skipped": skipped,
            "max_f1_per_map": per_map.iter().map(|(k, p)| {
                (k.clone(), p.summaries(false).into_iter().map(|(m, s)| (m, s.max_f1)).collect::<BTreeMap<_, _>>())
            }).collect::<BTreeMap<_, _>>(),
            "energy": energies.to_json(),
        }),
        seconds,
    };
    report.write(&out.join("report.json"))?;
    println!("\n{}", report.table());
    println!("{}", energies.table());
    for (k, v) in &mean_per_sweep {
        println!(
            "{k}: {:.1} ms per map sample (K/L patch updates)",
            v * 1000.0
        );
    }
    println!("wrote {}", out.join("report.json").display());
    Ok(())
}

/// The firmware's sampler buffers, from `ogm_firmware::sizes::MPS2_AN386` (ray store rays and
/// scans, the per-tile ray list, `u8` marginal counts): for `eval-sim --firmware-bounds`.
/// [`with_firmware_bounds`] also sets the firmware's block grid.
pub fn firmware_bounds() -> Bounds {
    Bounds {
        rays: Some(FW.rays),
        scans: Some(FW.scans),
        local: Some(FW.local_rays),
        u8_counts: true,
    }
}

/// `cfg` as the firmware runs it: [`firmware_bounds`] and the firmware's tile-visit block grid
/// (`ogm_core::sampler::gibbs::DEFAULT_BLOCK_GRID`, which sizes its block bitsets).
pub fn with_firmware_bounds(cfg: SamplingConfig) -> SamplingConfig {
    SamplingConfig {
        bounds: firmware_bounds(),
        block_grid: ogm_core::sampler::gibbs::DEFAULT_BLOCK_GRID,
        ..cfg
    }
}
