//! Running a sampler on a recorded dataset: [`run_sampler`] (burn-in, then counted sweeps) over
//! a [`Prepared`] sampler of any [`Variant`].

use std::time::Instant;

use anyhow::anyhow;
use ogm_core::config::{DataTerm, Estimator};
use ogm_core::sampler::gibbs::{
    block_words, BorderPrior, Buffers, ConstantCellPrior, Gibbs, LocalRay, NeighbourPrior,
    PatchPrior, SamplerConfig, UnconditionedPrior,
};
use ogm_core::wire::{SamplerReport, StoreReport};
use ogm_core::{GridGeometry, LogOdds, MapperConfig};

use super::config::SamplingConfig;
use super::dataset::{evidence_map, rays_and_model, Store};
use super::l25::L25Sampler;
use super::variant::Variant;
use crate::sim::explore::ScanRecord;

/// Runs `variant` on a dataset whose online log-odds map is `map`: burn-in, then `cfg.sweeps`
/// counted sweeps.
pub fn run_sampler(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    variant: Variant,
    cfg: &SamplingConfig,
    seed: u64,
) -> anyhow::Result<SamplerOutput> {
    let mut p = Prepared::new(geometry, mapper, scans, map, variant, cfg, seed)?;
    let t0 = Instant::now();
    p.sweeps(cfg.burn_in + cfg.sweeps);
    let seconds = t0.elapsed().as_secs_f64();
    Ok(SamplerOutput {
        marginals: p.marginals(),
        stats: p.stats(),
        store: p.store_stats(),
        seconds,
        seconds_per_sweep: seconds / f64::from((cfg.burn_in + cfg.sweeps).max(1)),
    })
}

/// What a sampler run produced.
#[derive(Clone, Debug)]
pub struct SamplerOutput {
    /// Marginal p(occupied) per cell.
    pub marginals: Vec<f64>,
    /// The sampler's counters.
    pub stats: SamplerReport,
    /// The ray store's counters.
    pub store: StoreReport,
    /// Wall-clock seconds of sampling (burn-in + sweeps), excluding setup.
    pub seconds: f64,
    /// Seconds per map sample (K/L patch updates).
    pub seconds_per_sweep: f64,
}

/// A sampler set up on a dataset (rays stored, sample initialised), ready to sweep.
pub struct Prepared {
    inner: Box<dyn Sweeper>,
}

impl Prepared {
    /// Stores the dataset's rays and initialises `variant` from the thresholded `map`.
    pub fn new(
        geometry: GridGeometry,
        mapper: &MapperConfig,
        scans: &[ScanRecord],
        map: &[LogOdds],
        variant: Variant,
        cfg: &SamplingConfig,
        seed: u64,
    ) -> anyhow::Result<Prepared> {
        let remapped;
        let map = if (cfg.free_update_q8 != 256 || cfg.face_band) && cfg.data != DataTerm::Rays {
            let model = cfg.evidence_model(&geometry, mapper)?;
            remapped = evidence_map(geometry, mapper, scans, model)?;
            &remapped[..]
        } else {
            map
        };
        let inner: Box<dyn Sweeper> = match variant {
            Variant::L1 => {
                let p = ogm_core::sampler::prior::occupancy_prior().p_occupied();
                let prior =
                    ConstantCellPrior::new(p).map_err(|e| anyhow!("cell prior {p}: {e}"))?;
                offline_sampler(geometry, mapper, scans, map, prior, cfg, seed)?
            }
            Variant::L1Border => {
                offline_sampler(geometry, mapper, scans, map, NeighbourPrior, cfg, seed)?
            }
            Variant::L9 => {
                offline_sampler(geometry, mapper, scans, map, UnconditionedPrior, cfg, seed)?
            }
            Variant::L9Border
            | Variant::L9BorderRays
            | Variant::L9BorderHybrid
            | Variant::L9BorderMean => offline_sampler(
                geometry,
                mapper,
                scans,
                map,
                BorderPrior::default(),
                cfg,
                seed,
            )?,
            Variant::L25 => {
                anyhow::ensure!(
                    cfg.data == DataTerm::Rays && cfg.estimator == Estimator::Counts,
                    "gibbs_l25 implements only the rays and sample counts"
                );
                Box::new(L25Sampler::new(geometry, mapper, scans, map, cfg, seed)?)
            }
        };
        Ok(Prepared { inner })
    }

    /// Runs `n` sweeps (K/L patch updates each).
    pub fn sweeps(&mut self, n: u32) {
        self.inner.sweeps(n);
    }

    /// Current marginal estimates (0.5 before the first counted sweep).
    pub fn marginals(&self) -> Vec<f64> {
        self.inner.marginals()
    }

    /// The sampler's counters.
    pub fn stats(&self) -> SamplerReport {
        self.inner.stats()
    }

    /// The ray store's counters.
    pub fn store_stats(&self) -> StoreReport {
        self.inner.store_stats()
    }
}

trait Sweeper {
    fn sweeps(&mut self, n: u32);
    fn marginals(&self) -> Vec<f64>;
    fn stats(&self) -> SamplerReport;
    fn store_stats(&self) -> StoreReport;
}

/// A sampler on a complete dataset: every ray stored up front, the sample initialised from the
/// final log-odds map (`Gibbs::reset`), swept `sweep` patch updates at a time, with any patch
/// prior and counter type.
///
/// Not `ogm_core::session::Session`, which it resembles: that is the robot's online engine —
/// the border prior only, buffers and forward model from a `RunConfig`, scans mapped as they
/// arrive with the sample seeded cell by cell — so it can run neither the paper's other
/// variants nor this batch protocol, and its maps differ from this one's (the evaluation's
/// figures are this protocol's).
struct OfflineSampler<P, N: ogm_core::sampler::gibbs::Count> {
    store: Store,
    map: Vec<LogOdds>,
    gibbs: Gibbs<P, Vec<u32>, Vec<N>, Vec<LocalRay>, Vec<u32>, N>,
    sweep: u32,
}

impl<P: PatchPrior, N: ogm_core::sampler::gibbs::Count> Sweeper for OfflineSampler<P, N> {
    fn sweeps(&mut self, n: u32) {
        for _ in 0..n {
            self.gibbs.step(&mut self.store, &self.map, self.sweep);
        }
    }

    fn marginals(&self) -> Vec<f64> {
        (0..self.gibbs.geometry().len())
            .map(|i| self.gibbs.marginal(i).map_or(0.5, f64::from))
            .collect()
    }

    fn stats(&self) -> SamplerReport {
        self.gibbs.stats()
    }

    fn store_stats(&self) -> StoreReport {
        self.store.stats()
    }
}

impl Sweeper for L25Sampler {
    fn sweeps(&mut self, n: u32) {
        L25Sampler::sweeps(self, n);
    }

    fn marginals(&self) -> Vec<f64> {
        L25Sampler::marginals(self)
    }

    fn stats(&self) -> SamplerReport {
        L25Sampler::stats(self)
    }

    fn store_stats(&self) -> StoreReport {
        L25Sampler::store_stats(self)
    }
}

fn offline_sampler<P: PatchPrior + 'static>(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    prior: P,
    cfg: &SamplingConfig,
    seed: u64,
) -> anyhow::Result<Box<dyn Sweeper>> {
    Ok(if cfg.bounds.u8_counts {
        Box::new(build::<P, u8>(
            geometry, mapper, scans, map, prior, cfg, seed,
        )?)
    } else {
        Box::new(build::<P, u32>(
            geometry, mapper, scans, map, prior, cfg, seed,
        )?)
    })
}

fn build<P: PatchPrior, N: ogm_core::sampler::gibbs::Count>(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    prior: P,
    cfg: &SamplingConfig,
    seed: u64,
) -> anyhow::Result<OfflineSampler<P, N>> {
    let (mut store, fm) = rays_and_model(geometry, mapper, scans, cfg)?;
    let cells_per_patch = u32::from(prior.size()) * u32::from(prior.size());
    let sc = SamplerConfig {
        p_rand_patch: cfg.p_rand_patch,
        burn_in_sweeps: cfg.burn_in,
        max_candidates: cfg.max_candidates,
        init_threshold: LogOdds(cfg.init_threshold),
        tile_shift: cfg.tile_shift,
        visit_sweeps: cfg.visit_sweeps,
        block_grid: cfg.block_grid,
        seed,
        data: cfg.data,
        evidence_gain_q8: cfg.evidence_gain_q8,
        evidence_free_q8: cfg.evidence_free_q8,
        data_candidate: cfg.data_candidate,
        floor_log_prior: ogm_core::sampler::gibbs::FLOOR_LOG_PRIOR,
        estimator: cfg.estimator,
        hot_share: cfg.hot_share,
    };
    let total_rays: usize = scans.iter().map(|s| s.beams.len()).sum();
    let local = cfg.bounds.local.unwrap_or(total_rays.clamp(1, 1 << 16));
    let buf = Buffers {
        sample: vec![0u32; geometry.len().div_ceil(32)],
        counts: vec![N::default(); geometry.len()],
        local: vec![LocalRay::default(); local],
        blocks: vec![0u32; block_words(local, cfg.block_grid)],
    };
    let mut gibbs =
        Gibbs::new(geometry, prior, fm, sc, buf).map_err(|e| anyhow!("sampler: {e}"))?;
    gibbs
        .reset(map, &mut store)
        .map_err(|e| anyhow!("sampler reset: {e}"))?;
    let sweep = (geometry.len() as u32).div_ceil(cells_per_patch);
    Ok(OfflineSampler {
        store,
        map: map.to_vec(),
        gibbs,
        sweep,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mean_read_out_runs_the_robots_chain() {
        let (g, mapper, scans, map) = super::super::l25::tests::wall_dataset();
        let cfg = SamplingConfig {
            burn_in: 5,
            sweeps: 40,
            ..SamplingConfig::default()
        };
        let run =
            |v: Variant| run_sampler(g, &mapper, &scans, &map, v, &v.configure(&cfg), 7).unwrap();
        let (robot, mean) = (run(Variant::L9Border), run(Variant::L9BorderMean));
        // The same draws, patch for patch (what each update did is counted the same)…
        assert_eq!(robot.stats, mean.stats);
        assert!(robot.stats.changed > 0, "{:?}", robot.stats);
        // …read out differently (the robot's moving average vs the mean of the sweeps), into
        // maps that agree on most cells' side of 0.5.
        assert_ne!(robot.marginals, mean.marginals);
        let agree = robot
            .marginals
            .iter()
            .zip(&mean.marginals)
            .filter(|(a, b)| (**a > 0.5) == (**b > 0.5))
            .count();
        assert!(agree * 10 >= robot.marginals.len() * 9, "{agree}");
    }
}
