//! Issue 38's diagnosis: the robot's online sampler against `eval-log`'s offline chain on one
//! log, cell by cell (docs/results.md, "The online sampler", "On the logs").
//!
//! ```sh
//! cargo run --release -p host-sim --example online_vs_offline            # fhw, experiment 1
//! STREAM=out/win-fhw cargo run --release -p host-sim --example online_vs_offline
//! ```
//!
//! Offline: `eval-log --methods gibbs_l9_border --range-cap 3`'s maps (defaults otherwise).
//! Online: without `STREAM`, a `Session` with the same robot settings on `eval-log`'s whole
//! grid (no window), `U` updates after every scan (`POST` more after the last; `BATCH=1`: reset
//! on the final map first, the offline protocol); with `STREAM=DIR`, the stitched stream of a
//! `host-sim firmware --log … --range-cap 3000 --out DIR` run (its cells are `eval-log`'s,
//! `report.json`'s `offset_cells`). Other settings: `LOG`, `EXP`, `CAP` (m), `SEED`, `HOT`
//! (`hot_share`), `ESTIMATOR` (`counts` or `SHIFT,MAX_SHIFT`), `SWAP` (`never`, `unobserved`,
//! `observed`: score the online map with the offline marginals in those cells).
//!
//! Prints both F1 near mapped, then the scored cells by observed / unobserved and truth: how
//! many each map calls occupied at 0.5, the mean estimates, and where the unobserved ones lie.
use std::path::Path;

use anyhow::Context;
use host_sim::eval::log_maps::{benchmark, map_experiment, sensor_noise, LogMethod, MethodsConfig};
use host_sim::eval::log_setup::{setup_log, Experiment, LogMapArgs};
use host_sim::eval::metrics::PrAccumulator;
use host_sim::eval::sampling::Variant;
use ogm_core::config::{Estimator, PoseCorrection, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::GridGeometry;
use ogm_field::stream::{BuildingMap, DeviceEvent, StreamDecoder};
use ogm_field::world::Truth;

fn env<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

/// An estimate nothing has moved yet (an unknown cell's ½ in a byte): never sampled.
const UNSAMPLED: u32 = 128;

fn main() -> anyhow::Result<()> {
    let log: String = env("LOG", "../shared/data/logs/fhw-corrected.log.gz".into());
    let a = LogMapArgs {
        range_cap: env("CAP", 3.0),
        ..LogMapArgs::default()
    };
    let setup = setup_log(Path::new(&log), &a)?;
    let scans = Experiment::new(env("EXP", 1))?.select(&setup.scans);
    let (world, bench) = benchmark(&setup)?;
    let sensor = sensor_noise(&setup, &setup.scans, Some(&bench.map))?;
    let em = map_experiment(
        &setup,
        &scans,
        sensor.as_ref(),
        &[LogMethod::Sampler(Variant::L9Border)],
        &MethodsConfig::new(&a)?,
        "offline",
    )?;
    let (_, near_scores) = em.score(&world)?;
    for (k, s) in &near_scores {
        println!("offline {k}: F1 near {:.4}", s.max_f1);
    }
    let (off, lo) = (&em.maps["gibbs_l9_border"], &em.mapped.map);
    let g = setup.geometry;
    // The online map: estimates, and the byte each came from.
    let (mut on, counts) = match std::env::var("STREAM") {
        Ok(dir) => from_stream(Path::new(&dir), &g)?,
        Err(_) => {
            let (sigma, tau) = em.cfg.sampling.sensor();
            let mut cfg = RunConfig::ROBOT
                .with_sensor(sigma, tau)?
                .with_correction(PoseCorrection::Off)
                .with_origin_mm(g.origin_mm().0, g.origin_mm().1)
                .with_max_range_mm(setup.mapper.max_range_mm)
                .with_seed(env("SEED", 1));
            cfg.min_range_mm = setup.mapper.min_range_mm;
            cfg.hot_share = env("HOT", cfg.hot_share);
            match env("ESTIMATOR", String::new()).as_str() {
                "" => {}
                "counts" => cfg.estimator = Estimator::Counts,
                s => {
                    let (a, b) = s.split_once(',').context("ESTIMATOR: counts or S,MAX")?;
                    cfg.estimator = Estimator::Average {
                        shift: a.parse()?,
                        max_shift: b.parse()?,
                        reset_on_change: true,
                        rao_blackwell: false,
                    };
                }
            }
            let sizes = Sizes {
                width: g.width(),
                height: g.height(),
                rays: 1,
                scans: 1,
                local: 128,
            };
            let mut s = Session::new(cfg, Owned::<u8>::buffers(&sizes))?;
            let (u, batch) = (env("U", 2000u32), env("BATCH", 0u8) != 0);
            for sc in &scans {
                s.insert(&sc.pose, &sc.beams)?;
                if !batch {
                    s.step(u);
                }
            }
            if batch {
                s.reset()?;
            }
            let mut post = env("POST", 0u32);
            while post > 0 {
                post -= s.step(post.min(100_000));
            }
            anyhow::ensure!(s.log_odds() == &lo[..], "the session's log-odds differ");
            println!("{:?}", s.sampler_report());
            let on = (0..g.len()).map(|i| s.marginal(i).map_or(0.5, f64::from));
            (
                on.collect(),
                (0..g.len()).map(|i| s.gibbs().count(i)).collect(),
            )
        }
    };
    let swap = env("SWAP", String::new());
    for i in 0..g.len() {
        let observed = lo[i].0 != 0;
        let take = match swap.as_str() {
            "never" => !observed && counts[i] == UNSAMPLED,
            "unobserved" => !observed,
            "observed" => observed,
            _ => false,
        };
        if take {
            on[i] = off[i];
        }
    }
    let mut acc = PrAccumulator::new();
    acc.add(&on, &world.cells, Some(&em.near))?;
    println!("online: F1 near {:.4}", acc.summary().max_f1);
    // [observed][truth occupied]: cells, called occupied by log-odds / offline / online, the
    // estimates' sums, unsampled online.
    let mut t = [[([0u64; 4], [0f64; 2], 0u64); 2]; 2];
    for i in 0..g.len() {
        let occ = match world.cells[i] {
            Truth::Occupied => 1,
            Truth::Free => 0,
            Truth::Unknown => continue,
        };
        if !em.near[i] {
            continue;
        }
        let (n, p, unsampled) = &mut t[usize::from(lo[i].0 != 0)][occ];
        n[0] += 1;
        n[1] += u64::from(lo[i].0 > 0);
        n[2] += u64::from(off[i] > 0.5);
        n[3] += u64::from(on[i] > 0.5);
        p[0] += off[i];
        p[1] += on[i];
        *unsampled += u64::from(lo[i].0 == 0 && counts[i] == UNSAMPLED);
    }
    for (obs, row) in t.iter().enumerate() {
        for (occ, (n, p, unsampled)) in row.iter().enumerate() {
            let k = n[0].max(1) as f64;
            println!(
                "observed {obs} truth occupied {occ}: {} cells; occupied: log-odds {} offline {} \
                 online {}; mean p offline {:.3} online {:.3}; never sampled online {unsampled}",
                n[0],
                n[1],
                n[2],
                n[3],
                p[0] / k,
                p[1] / k
            );
        }
    }
    Ok(())
}

/// The stitched stream of a `host-sim firmware --log … --out dir` run on `g`'s cells: estimates
/// (½ where no estimate arrived) and bytes (`u32::MAX` there).
fn from_stream(dir: &Path, g: &GridGeometry) -> anyhow::Result<(Vec<f64>, Vec<u32>)> {
    let bytes = std::fs::read(dir.join("stream.bin"))?;
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json"))?)?;
    let offset = |k: usize| report["offset_cells"][k].as_i64().context("offset_cells");
    let off = (offset(0)?, offset(1)?);
    let events: Vec<DeviceEvent> = StreamDecoder::new()
        .push(&bytes)
        .into_iter()
        .filter_map(Result::ok)
        .collect();
    let hello = events
        .iter()
        .find_map(|e| match e {
            DeviceEvent::Hello(h) => Some(h.clone()),
            _ => None,
        })
        .context("no Hello in the stream")?;
    let r = BuildingMap::stitch(&hello, &events).render();
    let (w, h) = (r.map.width as i64, r.map.height as i64);
    let gw = i64::from(g.width());
    let mut on = vec![0.5; g.len()];
    let mut counts = vec![u32::MAX; g.len()];
    for (i, (p, c)) in on.iter_mut().zip(&mut counts).enumerate() {
        let (bx, by) = (i as i64 % gw, i as i64 / gw);
        let (x, y) = (bx - off.0 - r.x0, by - off.1 - r.y0);
        if (0..w).contains(&x) && (0..h).contains(&y) {
            let j = (y * w + x) as usize;
            if r.have_counts[j] {
                *c = u32::from(r.map.counts[j]);
                *p = f64::from(*c) / 255.0;
            }
        }
    }
    Ok((on, counts))
}
