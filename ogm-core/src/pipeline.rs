//! The mapping loop's one step, shared by the firmware and the host simulator.
//!
//! `read scan → look up pose → (sort, for the cone model) → insert`. The firmware calls it with
//! its UART-backed sensor; `host-sim` with its synthetic lidar. Same function, same results.

use crate::geometry::Pose;
use crate::hal::{PoseSource, RangeSensor, ScanBuf};
use crate::mapper::{Mapper, ScanStats};
use crate::sensor_model::InverseModelKind;

/// Why a pipeline step failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PipelineError<SE, PE> {
    /// The range sensor failed.
    Sensor(SE),
    /// The pose source failed.
    Pose(PE),
    /// The mapper rejected the scan.
    Map(crate::Error),
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
