//! Runs `ogm_core::sampler::gibbs` on a recorded dataset, with host-sized (or firmware-sized) buffers:
//! the paper's Table I/II variants and the robot's own sampler. `gibbs_l9_border` is always the
//! firmware's default mode (`RunConfig::robot`: per-cell evidence, the evidence's configuration
//! as a candidate, averaged draws); `gibbs_l9_border_rays` is the paper's (the forward model
//! over every stored ray, sample counts), `gibbs_l9_border_hybrid` the robot's sampler with
//! the rays still in the store plus the evidence of what it dropped; `gibbs_l9_border_mean` the
//! robot's sampler read out as the mean of every counted sweep instead of its moving average. `gibbs_l25` (Table I's
//! "L = 25, data-driven prior") does not fit `ogm_core::sampler::gibbs`'s 16-bit patch words and runs on
//! the host-only sampler of [`crate::l25`] instead.

use std::time::Instant;

use anyhow::anyhow;
use ogm_core::config::{DataTerm, Estimator};
use ogm_core::map::sensor_model::InverseSensorModel;
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::gibbs::{
    block_words, BorderPrior, Buffers, ConstantCellPrior, Gibbs, LocalRay, NeighbourPrior,
    PatchPrior, SamplerConfig, UnconditionedPrior,
};
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::wire::{SamplerReport, StoreReport};
use ogm_core::{GridGeometry, LogOdds, MapperConfig};
use serde::{Deserialize, Serialize};

use crate::explore::ScanRecord;

/// Which sampler.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Variant {
    /// L = 1 with the constant data-driven prior p(m_k) (rays).
    L1,
    /// L = 1 conditioned on the 8 neighbours (rays; Table I's "L = 1, data-driven prior with
    /// border").
    L1Border,
    /// L = 9 with the unconditioned data-driven prior (rays).
    L9,
    /// L = 9 conditioned on the 16-cell border: the robot's sampler (the firmware's default).
    L9Border,
    /// L = 9 + border, the paper's sampler: rays, sample counts.
    L9BorderRays,
    /// The robot's sampler with the hybrid data term (stored rays + evidence of dropped ones).
    L9BorderHybrid,
    /// The robot's sampler ([`Variant::L9Border`]: evidence, the same chain), its marginals
    /// read out as the mean of every counted sweep (sample counts, like the paper's samplers)
    /// instead of the robot's short moving average, which an online robot needs (its evidence
    /// changes, and its estimates are bytes) but which keeps only the last ~8 draws of a cell.
    L9BorderMean,
    /// L = 25 (5 × 5 patches) with the unconditioned data-driven prior (rays; Table I's "L = 25,
    /// data-driven prior"): the host-only [`crate::l25::L25Sampler`].
    L25,
}

impl Variant {
    /// The paper's Table II columns, then the robot's sampler and its other data terms, then
    /// Table I's L = 25.
    pub const ALL: [Variant; 8] = [
        Variant::L1,
        Variant::L1Border,
        Variant::L9,
        Variant::L9Border,
        Variant::L9BorderRays,
        Variant::L9BorderHybrid,
        Variant::L9BorderMean,
        Variant::L25,
    ];

    /// The method name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Variant::L1 => "gibbs_l1",
            Variant::L1Border => "gibbs_l1_border",
            Variant::L9 => "gibbs_l9",
            Variant::L9Border => "gibbs_l9_border",
            Variant::L9BorderRays => "gibbs_l9_border_rays",
            Variant::L9BorderHybrid => "gibbs_l9_border_hybrid",
            Variant::L9BorderMean => "gibbs_l9_border_mean",
            Variant::L25 => "gibbs_l25",
        }
    }

    /// Cells per patch.
    pub fn cells(self) -> u32 {
        match self {
            Variant::L1 | Variant::L1Border => 1,
            Variant::L25 => crate::l25::CELLS,
            Variant::L9
            | Variant::L9Border
            | Variant::L9BorderRays
            | Variant::L9BorderHybrid
            | Variant::L9BorderMean => 9,
        }
    }

    /// `cfg` with this variant's data term and estimator: the robot's (`RunConfig::robot`,
    /// free evidence and the evidence map's free update matched to `cfg.sigma_cells`) for
    /// [`Variant::L9Border`] and [`Variant::L9BorderHybrid`] ([`Variant::L9BorderMean`]: the
    /// robot's with sample counts), the paper's (rays, sample counts) for the others (for
    /// [`Variant::L25`] only the rays are implemented).
    pub fn configure(self, cfg: &SamplingConfig) -> SamplingConfig {
        match self {
            Variant::L9Border | Variant::L9BorderHybrid | Variant::L9BorderMean => {
                // The robot's settings at this data set's σ: the face band, or the split free
                // update and the 1/σ evidence gain.
                let robot = ogm_core::config::RunConfig::robot(
                    (0, 0),
                    1,
                    0,
                    ogm_core::config::Budget::Fixed { updates: 0 },
                )
                .with_noise_matched(cfg.sigma_cells);
                SamplingConfig {
                    data: if self == Variant::L9BorderHybrid {
                        DataTerm::Hybrid
                    } else {
                        DataTerm::Evidence
                    },
                    evidence_gain_q8: robot.evidence_gain_q8,
                    evidence_free_q8: robot.evidence_free_q8,
                    free_update_q8: robot.free_update_q8,
                    face_band: robot.face_band,
                    data_candidate: robot.data_candidate,
                    estimator: if self == Variant::L9BorderMean {
                        Estimator::Counts
                    } else {
                        robot.estimator
                    },
                    hot_share: robot.hot_share,
                    ..*cfg
                }
            }
            _ => SamplingConfig {
                data: DataTerm::Rays,
                data_candidate: false,
                estimator: Estimator::Counts,
                hot_share: 0,
                ..*cfg
            },
        }
    }
}

/// Buffer sizes: `None` = large enough for everything (the host's unbounded configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Bounds {
    /// Stored rays.
    pub rays: Option<usize>,
    /// Stored scans.
    pub scans: Option<usize>,
    /// Rays per tile visit.
    pub local: Option<usize>,
    /// Marginal counters are `u8` (firmware) instead of `u32`.
    pub u8_counts: bool,
}

/// Sampler settings for an evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SamplingConfig {
    /// Sweeps discarded before marginals are counted.
    pub burn_in: u32,
    /// Sweeps counted.
    pub sweeps: u32,
    /// Candidates per patch.
    pub max_candidates: u8,
    /// Forward model σ, cells.
    pub sigma_cells: f64,
    /// Forward model outlier weight.
    pub outlier_weight: f64,
    /// p_randPatch.
    pub p_rand_patch: f32,
    /// Log2 of the tile edge.
    pub tile_shift: u8,
    /// Sweeps of a tile per visit.
    pub visit_sweeps: u8,
    /// Blocks per side of the tile-visit ray index.
    pub block_grid: u8,
    /// Initial sample: occupied iff the online log-odds exceeds this (raw LSB).
    pub init_threshold: i16,
    /// Buffer bounds.
    pub bounds: Bounds,
    /// The measurement term.
    pub data: DataTerm,
    /// Evidence gain, Q8.
    pub evidence_gain_q8: u16,
    /// Relative scale of free evidence, Q8.
    pub evidence_free_q8: u16,
    /// Scale of the free update of the map the evidence term reads, Q8 (256: the dataset's
    /// own log-odds map; otherwise the scans are mapped again with the scaled model, as the
    /// robot's mapper does).
    pub free_update_q8: u16,
    /// The robot's mapper uses the face band of σ = `sigma_cells` for the map the evidence term
    /// reads (`RunConfig::face_band`; the scans are mapped again with it).
    #[serde(default)]
    pub face_band: bool,
    /// Offer the evidence's configuration as a candidate.
    pub data_candidate: bool,
    /// Marginal estimator.
    pub estimator: Estimator,
    /// Change-driven share of tile visits, of 256.
    pub hot_share: u8,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        SamplingConfig {
            burn_in: 20,
            sweeps: 100,
            max_candidates: 16,
            sigma_cells: 3.0,
            outlier_weight: 0.01,
            p_rand_patch: 0.001,
            tile_shift: 4,
            visit_sweeps: 16,
            block_grid: 16,
            init_threshold: -1,
            bounds: Bounds::default(),
            data: DataTerm::Rays,
            evidence_gain_q8: 256,
            evidence_free_q8: 256,
            free_update_q8: 256,
            face_band: false,
            data_candidate: false,
            estimator: Estimator::Counts,
            hot_share: 0,
        }
    }
}

impl SamplingConfig {
    /// The inverse model of the map the evidence term reads: `mapper`'s with the free update
    /// scaled by `free_update_q8` and, with `face_band`, the band of σ = `sigma_cells`.
    pub fn evidence_model(
        &self,
        geometry: &GridGeometry,
        mapper: &MapperConfig,
    ) -> anyhow::Result<InverseSensorModel> {
        let q8 = self.free_update_q8;
        let model = mapper
            .model
            .with_free_scale(q8)
            .map_err(|e| anyhow!("free update scale {q8}: {e}"))?;
        if !self.face_band {
            return Ok(model);
        }
        let sigma_mm = (self.sigma_cells * f64::from(geometry.cell_mm())).round();
        anyhow::ensure!(
            sigma_mm >= 1.0 && sigma_mm < f64::from(u32::MAX),
            "face band: σ = {} cells is not a whole number of mm ≥ 1",
            self.sigma_cells
        );
        let band = InverseSensorModel::hahnel_face_band(sigma_mm as u32)
            .map_err(|e| anyhow!("face band: {e}"))?;
        band.with_free_scale(q8)
            .map_err(|e| anyhow!("free update scale {q8}: {e}"))
    }
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

/// A sampler set up on a dataset (rays stored, sample initialised), ready to sweep.
pub struct Prepared {
    inner: Box<dyn Sweeper>,
}

trait Sweeper {
    fn sweeps(&mut self, n: u32);
    fn marginals(&self) -> Vec<f64>;
    fn stats(&self) -> SamplerReport;
    fn store_stats(&self) -> StoreReport;
}

pub(crate) type Store = RayStore<Vec<StoredScan>, Vec<StoredRay>>;

struct Session<P, N: ogm_core::sampler::gibbs::Count> {
    store: Store,
    map: Vec<LogOdds>,
    gibbs: Gibbs<P, Vec<u32>, Vec<N>, Vec<LocalRay>, Vec<u32>, N>,
    sweep: u32,
}

impl<P: PatchPrior, N: ogm_core::sampler::gibbs::Count> Sweeper for Session<P, N> {
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

impl Sweeper for crate::l25::L25Sampler {
    fn sweeps(&mut self, n: u32) {
        crate::l25::L25Sampler::sweeps(self, n);
    }
    fn marginals(&self) -> Vec<f64> {
        crate::l25::L25Sampler::marginals(self)
    }
    fn stats(&self) -> SamplerReport {
        crate::l25::L25Sampler::stats(self)
    }
    fn store_stats(&self) -> StoreReport {
        crate::l25::L25Sampler::store_stats(self)
    }
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
                session(geometry, mapper, scans, map, prior, cfg, seed)?
            }
            Variant::L1Border => session(geometry, mapper, scans, map, NeighbourPrior, cfg, seed)?,
            Variant::L9 => session(geometry, mapper, scans, map, UnconditionedPrior, cfg, seed)?,
            Variant::L9Border
            | Variant::L9BorderRays
            | Variant::L9BorderHybrid
            | Variant::L9BorderMean => session(
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
                Box::new(crate::l25::L25Sampler::new(
                    geometry, mapper, scans, map, cfg, seed,
                )?)
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

/// The scans mapped again with `model` instead of `mapper`'s: the log-odds map the robot's
/// mapper keeps (`RunConfig::mapper_config`, [`SamplingConfig::evidence_model`]).
pub fn evidence_map(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    model: InverseSensorModel,
) -> anyhow::Result<Vec<LogOdds>> {
    let config = MapperConfig { model, ..*mapper };
    let mut m = crate::sim::new_mapper(geometry, config)?;
    for s in scans {
        m.insert_scan(&s.pose, &s.beams)
            .map_err(|e| anyhow!("mapping: {e}"))?;
    }
    Ok(m.grid().cells().to_vec())
}

fn session<P: PatchPrior + 'static>(
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

/// A dataset's rays in a store of `cfg.bounds`' capacities (all of them when unbounded), and the
/// forward model of `cfg`'s σ and outlier weight over the mapper's range: what every sampler
/// variant that reads rays starts from.
pub(crate) fn rays_and_model(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    cfg: &SamplingConfig,
) -> anyhow::Result<(Store, ForwardModel)> {
    let total_rays: usize = scans.iter().map(|s| s.beams.len()).sum();
    let b = cfg.bounds;
    let mut store = RayStore::new(
        geometry,
        mapper.max_range_mm,
        mapper.min_range_mm,
        vec![StoredScan::default(); b.scans.unwrap_or(scans.len()).max(1)],
        vec![StoredRay::default(); b.rays.unwrap_or(total_rays).max(1)],
    )
    .map_err(|e| anyhow!("ray store: {e}"))?;
    for s in scans {
        store.add_scan(&s.pose, &s.beams);
    }
    let fm = ForwardModel::gaussian(
        cfg.sigma_cells,
        cfg.outlier_weight,
        f64::from(mapper.max_range_mm) / f64::from(geometry.cell_mm()),
    )
    .map_err(|e| anyhow!("forward model: {e}"))?;
    Ok((store, fm))
}

fn build<P: PatchPrior, N: ogm_core::sampler::gibbs::Count>(
    geometry: GridGeometry,
    mapper: &MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
    prior: P,
    cfg: &SamplingConfig,
    seed: u64,
) -> anyhow::Result<Session<P, N>> {
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
    Ok(Session {
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
        let (g, mapper, scans, map) = crate::l25::tests::wall_dataset();
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
