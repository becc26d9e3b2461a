//! What every sampler starts from on a recorded dataset: its rays in a ray store with the
//! forward model (`rays_and_model`), and the log-odds map the evidence term reads
//! ([`evidence_map`]).

use anyhow::anyhow;
use ogm_core::map::sensor_model::InverseSensorModel;
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::{GridGeometry, LogOdds, MapperConfig};

use super::config::SamplingConfig;
use crate::sim::explore::ScanRecord;

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

pub(crate) type Store = RayStore<Vec<StoredScan>, Vec<StoredRay>>;

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
