//! A blocking mapping step for host tools: `read scan → look up pose → (sort, for the cone
//! model) → insert` into a bare [`Mapper`], through the [`RangeSensor`] and [`PoseSource`]
//! traits (see [`crate::lidar::source`] for why the robot does not use them).
//!
//! To be removed when host-sim moves to `Session::insert` (its `eval_log.rs` and `sim.rs` are
//! the only callers); nothing in ogm-core or the firmware uses it.
// TODO(issue 36): remove after host-sim migrates.

use crate::lidar::source::{PoseSource, RangeSensor};
use crate::map::mapper::{Mapper, ScanStats};
use crate::map::sensor_model::InverseModelKind;
use crate::types::geometry::Pose;
use crate::types::scan::ScanBuf;

/// Why a pipeline step failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PipelineError<SE, PE> {
    /// The range sensor failed.
    Sensor(SE),
    /// The pose source failed.
    Pose(PE),
    /// The mapper rejected the scan.
    Map(crate::Error),
}

impl<SE: core::fmt::Display, PE: core::fmt::Display> core::fmt::Display for PipelineError<SE, PE> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PipelineError::Sensor(e) => write!(f, "range sensor: {e}"),
            PipelineError::Pose(e) => write!(f, "pose source: {e}"),
            PipelineError::Map(e) => write!(f, "mapper: {e}"),
        }
    }
}

impl<SE, PE> From<crate::Error> for PipelineError<SE, PE> {
    fn from(e: crate::Error) -> Self {
        PipelineError::Map(e)
    }
}

/// The outcome of one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport {
    /// Pose the scan was inserted at.
    pub pose: Pose,
    /// Beams read from the sensor (including any dropped for lack of buffer space).
    pub beams_read: u32,
    /// Beams the scan buffer had no room for.
    pub beams_overflowed: u32,
    /// What the mapper did.
    pub stats: ScanStats,
}

/// Reads one scan and its pose and integrates it.
// TODO(issue 36): remove after host-sim migrates (to `Session::insert`).
pub fn map_next_scan<R, P, S, M, const N: usize>(
    sensor: &mut R,
    poses: &mut P,
    scan: &mut ScanBuf<N>,
    mapper: &mut Mapper<S, M>,
) -> Result<StepReport, PipelineError<R::Error, P::Error>>
where
    R: RangeSensor,
    P: PoseSource,
    S: AsRef<[crate::LogOdds]> + AsMut<[crate::LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
{
    sensor.read_scan(scan).map_err(PipelineError::Sensor)?;
    let pose = poses.current_pose().map_err(PipelineError::Pose)?;
    if matches!(mapper.config().model.kind(), InverseModelKind::Cone { .. }) {
        scan.sort_by_angle();
    }
    let stats = mapper
        .insert_scan(&pose, scan.beams())
        .map_err(PipelineError::Map)?;
    Ok(StepReport {
        pose,
        beams_read: (scan.beams().len() as u32).saturating_add(scan.overflow()),
        beams_overflowed: scan.overflow(),
        stats,
    })
}
