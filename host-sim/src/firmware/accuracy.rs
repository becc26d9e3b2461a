//! `--accuracy`: what the firmware's bounds cost, scored against ground truth like `eval-sim`.

use std::collections::BTreeMap;

use anyhow::anyhow;
use ogm_core::config::RunConfig;
use ogm_core::session::Sizes;
use ogm_field::world::World;
use ogm_firmware::sizes::MPS2_AN386 as FW;
use ogm_firmware::{Fed, Work};

use super::args::FirmwareArgs;
use super::replay::{marginals, replay, FIRMWARE_SIZES};
use super::report::{Accuracy, AnytimePoint};
use super::setup::{firmware_world, sim_config};
use crate::sim::simulate;

/// The accuracy cost of the firmware's bounds: the eval-sim sampler (`crate::eval::sampling`,
/// offline: the online map, then 20 burn-in + 100 counted sweeps) with the firmware's
/// compile-time buffer sizes next to unbounded host buffers, on `args.runs` generated worlds
/// (the first is `world`, already simulated), pooled and scored against ground truth. After a
/// QEMU run (`online`: its input and update counts) the online replay is scored the same way,
/// with firmware sizes and unbounded.
pub(super) fn accuracy(
    args: &FirmwareArgs,
    config: &RunConfig,
    world: &World,
    sim: &crate::sim::SimRun,
    scans: &[crate::sim::explore::ScanRecord],
    online: Option<Online<'_>>,
) -> anyhow::Result<Accuracy> {
    use crate::eval::eval_sim::NEAR_MAPPED_CELLS;
    use crate::eval::metrics::{mask_within, PrAccumulator};
    use crate::eval::sampling::{run_sampler, SamplingConfig, Variant};

    let mut all: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut near: BTreeMap<String, PrAccumulator> = BTreeMap::new();
    let mut acc = Accuracy {
        runs: args.runs.max(1),
        scans: Vec::new(),
        methods: BTreeMap::new(),
        methods_near_mapped: BTreeMap::new(),
        local_overflow_firmware: 0,
        local_overflow_unbounded: 0,
        tile_visits: 0,
        thinnings: 0,
        anytime: Vec::new(),
    };
    // The robot's sampler, offline.
    let host_cfg = SamplingConfig {
        data: config.data,
        evidence_gain_q8: config.evidence_gain_q8,
        evidence_free_q8: config.evidence_free_q8,
        free_update_q8: config.free_update_q8,
        face_band: config.face_band,
        sigma_cells: f64::from(config.sigma_milli_cells) / 1000.0,
        data_candidate: config.data_candidate,
        estimator: config.estimator,
        hot_share: config.hot_share,
        max_candidates: config.max_candidates,
        ..SamplingConfig::default()
    };
    let fw_cfg = crate::eval::eval_sim::with_firmware_bounds(host_cfg);
    for run in 0..acc.runs {
        let (w, s);
        let (world, sim, scans) = if run == 0 {
            (world, sim, scans)
        } else {
            w = firmware_world(&FirmwareArgs {
                seed: args.seed + u64::from(run),
                ..args.clone()
            })?;
            s = simulate(&w, &sim_config(args), args.seed + u64::from(run))?;
            (&w, &s, s.scans.as_slice())
        };
        acc.scans.push(scans.len());
        let mask = mask_within(&sim.observed, world.width, world.height, NEAR_MAPPED_CELLS);
        let mut score = |name: &str, probs: &[f64]| -> anyhow::Result<()> {
            all.entry(name.into())
                .or_default()
                .add(probs, &world.cells, None)?;
            near.entry(name.into())
                .or_default()
                .add(probs, &world.cells, Some(&mask))?;
            Ok(())
        };
        let seed = args.seed + u64::from(run);
        let trad: Vec<f64> = sim.map.iter().map(|l| l.probability()).collect();
        score("traditional", &trad)?;
        // The robot's own log-odds map (its mapper matched to the noise): the sampler is
        // measured against both.
        if config.free_update_q8 != 256 || config.face_band {
            let model = config
                .mapper_config()
                .map_err(|e| anyhow!("settings: {e}"))?
                .model;
            let own = crate::eval::sampling::evidence_map(
                sim.geometry,
                &sim.mapper_config,
                scans,
                model,
            )?;
            let own: Vec<f64> = own.iter().map(|l| l.probability()).collect();
            score("traditional_noise_matched", &own)?;
        }
        for (name, cfg) in [
            ("offline_firmware_sizes", &fw_cfg),
            ("offline_unbounded", &host_cfg),
        ] {
            let o = run_sampler(
                sim.geometry,
                &sim.mapper_config,
                scans,
                &sim.map,
                Variant::L9Border,
                cfg,
                seed,
            )?;
            // Unobserved cells unknown, as in every map the robot streams.
            let m: Vec<f64> = o
                .marginals
                .iter()
                .zip(&sim.observed)
                .map(|(&p, &seen)| if seen { p } else { 0.5 })
                .collect();
            score(name, &m)?;
            if cfg.bounds.rays.is_some() {
                acc.local_overflow_firmware += o.stats.local_overflow;
                acc.tile_visits += o.stats.tile_visits;
                acc.thinnings += o.store.thinnings;
            } else {
                acc.local_overflow_unbounded += o.stats.local_overflow;
            }
        }
        if let (0, Some(online)) = (run, online) {
            let get = |w: Work| match w {
                Work::Scan(seq) => online.scan_updates.get(seq as usize).copied(),
                Work::Idle(seq) => online.idle_updates.get(seq as usize).copied(),
            };
            let total_rays: usize = scans.iter().map(|s| s.beams.len()).sum();
            let unbounded = Sizes {
                rays: total_rays.max(1),
                scans: scans.len().max(1),
                local: total_rays.clamp(1, 1 << 16),
                ..FIRMWARE_SIZES
            };
            let (gw, ww, wh) = (usize::from(FW.width), world.width, world.height);
            let crop = |v: &[f64]| -> Vec<f64> {
                (0..wh)
                    .flat_map(|y| (0..ww).map(move |x| y * gw + x))
                    .map(|i| v[i])
                    .collect()
            };
            let f1 = |v: &[f64]| -> anyhow::Result<f64> {
                let mut a = PrAccumulator::default();
                a.add(&crop(v), &world.cells, None)?;
                Ok(a.summary().max_f1)
            };
            let last = scans.len().saturating_sub(1) as u32;
            let every = (scans.len() / 200).max(1) as u32;
            let mut end_of_scans: Option<Vec<f64>> = None;
            let mut idle_maps: Vec<Vec<f64>> = Vec::new();
            let mut failure: Option<anyhow::Error> = None;
            let configured = replay::<u8, _>(
                online.input,
                &[],
                FIRMWARE_SIZES,
                get,
                |fed, m| {
                    let r = (|| -> anyhow::Result<()> {
                        match fed {
                            Fed::Scan(seq) => {
                                if seq % every == 0 || seq == last {
                                    let lo: Vec<f64> =
                                        m.log_odds().iter().map(|l| l.probability()).collect();
                                    acc.anytime.push(AnytimePoint {
                                        scans: seq + 1,
                                        online: f1(&marginals(m))?,
                                        log_odds: f1(&lo)?,
                                    });
                                }
                                if seq == last {
                                    end_of_scans = Some(marginals(m));
                                }
                            }
                            Fed::Idle(_) => idle_maps.push(marginals(m)),
                            _ => {}
                        }
                        Ok(())
                    })();
                    if let (Err(e), None) = (r, &failure) {
                        failure = Some(e);
                    }
                },
                |m, _| m.is_some(),
            )?;
            if let Some(e) = failure {
                return Err(e);
            }
            let unbounded_map = replay::<u32, _>(
                online.input,
                &[],
                unbounded,
                get,
                |_, _| {},
                |m, _| m.map(marginals),
            )?;
            if let (true, Some(online_map)) = (configured, &end_of_scans) {
                score("online_firmware_sizes", &crop(online_map))?;
            }
            if let Some(u) = unbounded_map {
                // Unbounded buffers and u32 estimates, at the end of the run (idle included).
                score("online_unbounded", &crop(&u))?;
            }
            for (secs, m) in online.idle_marks.iter().zip(&idle_maps) {
                score(&format!("online_idle_{secs}s"), &crop(m))?;
            }
        }
    }
    acc.methods = all.iter().map(|(k, v)| (k.clone(), v.summary())).collect();
    acc.methods_near_mapped = near.iter().map(|(k, v)| (k.clone(), v.summary())).collect();
    Ok(acc)
}

/// What the online replay needs: the robot's input and the sampler work it reported.
#[derive(Clone, Copy, Debug)]
pub(super) struct Online<'a> {
    pub(super) input: &'a [u8],
    pub(super) scan_updates: &'a [u32],
    pub(super) idle_updates: &'a [u32],
    /// Cumulative idle seconds at the end of each idle period.
    pub(super) idle_marks: &'a [f64],
}
