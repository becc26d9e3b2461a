//! The simulator the researcher and the firmware developer share: one simulated dataset — a
//! world ([`generate`] builds them; the type is `ogm_field::world::World`), a robot exploring it
//! ([`mod@explore`]), the synthetic lidar ([`lidar`]), and the online fixed-point mapper
//! ([`insert_scan`]); and real recorded scans, CARMEN logs ([`carmen`]), in the same form
//! ([`explore::ScanRecord`]); [`track`] tracks a run's odometry with the robot's scan matcher. The firmware maps the same scans through its own lidar parser:
//! `host-sim firmware` sends them as LD06 packets with pose frames (see
//! `ogm_core::lidar::source` for why that byte stream is the one seam).

pub mod boxes;
pub mod carmen;
pub mod explore;
pub mod generate;
pub mod lidar;
pub mod track;

use anyhow::{anyhow, ensure, Context};
use ogm_core::map::mapper::marks_len;
use ogm_core::map::sensor_model::InverseModelKind;
use ogm_core::{
    GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose, ScanBuf, ScanStats,
};
use ogm_field::world::World;

use crate::sim::explore::{explore, ExploreConfig, ScanRecord};
use crate::sim::lidar::{LidarConfig, SimLidar};

/// Largest scan the simulator produces (beams per revolution).
pub const MAX_BEAMS: usize = 4096;

/// Simulation settings.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimConfig {
    /// The lidar.
    pub lidar: LidarConfig,
    /// The robot.
    pub explore: ExploreConfig,
}

/// The grid geometry matching a world (same size, resolution, origin).
pub fn geometry_of(world: &World) -> anyhow::Result<GridGeometry> {
    let w = u16::try_from(world.width)
        .map_err(|_| anyhow!("world is {} cells wide; at most 65535", world.width))?;
    let h = u16::try_from(world.height)
        .map_err(|_| anyhow!("world is {} cells tall; at most 65535", world.height))?;
    let cell_mm = (world.resolution_m * 1000.0).round();
    ensure!(
        cell_mm >= 1.0,
        "world resolution {} m is below 1 mm",
        world.resolution_m
    );
    ensure!(
        (cell_mm / 1000.0 - world.resolution_m).abs() < 1e-9,
        "world resolution {} m is not a whole number of millimetres; resample it first",
        world.resolution_m
    );
    let ox = (world.origin_m.0 * 1000.0).round() as i32;
    let oy = (world.origin_m.1 * 1000.0).round() as i32;
    GridGeometry::new(w, h, cell_mm as u32, ox, oy).map_err(|e| anyhow!("{e}"))
}

/// The mapper configuration used for a world and lidar (Hähnel model, lidar max range).
pub fn mapper_config(world: &World, lidar: &LidarConfig) -> MapperConfig {
    let max_mm = (lidar.max_range_cells * world.resolution_m * 1000.0).round() as u32;
    MapperConfig::new(max_mm.max(1))
}

/// A fresh host mapper for a geometry.
pub fn new_mapper(
    geometry: GridGeometry,
    config: MapperConfig,
) -> anyhow::Result<Mapper<Vec<LogOdds>, Vec<u32>>> {
    let grid = LogOddsGrid::new(geometry, vec![LogOdds::ZERO; geometry.len()])
        .map_err(|e| anyhow!("{e}"))?;
    Mapper::new(grid, vec![0; marks_len(geometry.len())], config).map_err(|e| anyhow!("{e}"))
}

/// Integrates one scan taken at `pose` into a host mapper (known-pose mapping, as in the
/// papers); the cone model needs its beams in angle order, so `scan` is sorted for it.
pub fn insert_scan<const N: usize>(
    mapper: &mut Mapper<Vec<LogOdds>, Vec<u32>>,
    pose: &Pose,
    scan: &mut ScanBuf<N>,
) -> anyhow::Result<ScanStats> {
    if matches!(mapper.config().model.kind(), InverseModelKind::Cone { .. }) {
        scan.sort_by_angle();
    }
    mapper
        .insert_scan(pose, scan.beams())
        .map_err(|e| anyhow!("mapping failed: {e}"))
}

/// The outcome of one simulated run.
pub struct SimRun {
    /// Recorded scans (pose + beams), in order.
    pub scans: Vec<ScanRecord>,
    /// The online (traditional) log-odds map after all scans.
    pub map: Vec<LogOdds>,
    /// Cells some measurement updated (the paper's "mapped" cells).
    pub observed: Vec<bool>,
    /// Grid geometry of `map`.
    pub geometry: GridGeometry,
    /// Mapper configuration used.
    pub mapper_config: MapperConfig,
}

/// Explores `world` and maps it online; returns the dataset and the traditional map.
pub fn simulate(world: &World, cfg: &SimConfig, seed: u64) -> anyhow::Result<SimRun> {
    let geometry = geometry_of(world)?;
    let mapper_config = mapper_config(world, &cfg.lidar);
    let mut mapper = new_mapper(geometry, mapper_config)?;
    // Separate streams for the lidar noise and the exploration choices.
    let mut lidar = SimLidar::new(
        world,
        cfg.lidar,
        seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5EED,
    )?;
    let mut buf: Box<ScanBuf<MAX_BEAMS>> = Box::default();
    let mut observed = vec![false; geometry.len()];
    let mut marks = vec![0u32; marks_len(geometry.len())];
    let scans = explore(world, &cfg.explore, seed, |pose| {
        lidar.pose = *pose;
        lidar.read_scan(&mut *buf);
        insert_scan(&mut mapper, pose, &mut *buf)?;
        mark_observed(
            &geometry,
            &mapper_config,
            pose,
            buf.beams(),
            &mut marks,
            &mut observed,
        )?;
        Ok((buf.beams().to_vec(), observed.clone()))
    })
    .context("exploring the world")?;
    Ok(SimRun {
        scans,
        map: mapper.grid().cells().to_vec(),
        observed,
        geometry,
        mapper_config,
    })
}

/// Marks the cells a scan updates (through the mapper's own classification) in `observed`.
pub fn mark_observed(
    geometry: &GridGeometry,
    config: &MapperConfig,
    pose: &Pose,
    beams: &[ogm_core::Beam],
    marks: &mut [u32],
    observed: &mut [bool],
) -> anyhow::Result<()> {
    ogm_core::map::mapper::classify_scan(geometry, config, pose, beams, marks, |i, _| {
        if let Some(o) = observed.get_mut(i) {
            *o = true;
        }
    })
    .map(|_| ())
    .map_err(|e| anyhow!("{e}"))
}

/// Occupancy probabilities of a log-odds map.
pub fn probabilities(map: &[LogOdds]) -> Vec<f64> {
    map.iter().map(|l| l.probability()).collect()
}
