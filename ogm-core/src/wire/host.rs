//! Host → device: [`HostMsg`].

use serde::{Deserialize, Serialize};

use crate::config::RunConfig;
use crate::types::geometry::Pose;

use super::{Layer, RestoreData};

/// Host → device.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HostMsg {
    /// Settings; must come first, exactly once.
    Config(RunConfig),
    /// The LD06 points that follow, up to the matching [`HostMsg::ScanEnd`], are one scan taken
    /// at `pose` (known-pose mapping).
    ScanStart {
        /// Scan number (the host counts from 0).
        seq: u32,
        /// Where the scan was taken.
        pose: Pose,
    },
    /// End of scan `seq`; the host sent `points` LD06 points (fewer arrived = some were lost).
    ScanEnd {
        /// Scan number.
        seq: u32,
        /// Points sent.
        points: u32,
    },
    /// No more scans: stream the final map and stop.
    Finish,
    /// Sample for `period_us` of board time with no scan coming (the robot stands still), then
    /// report ([`DeviceMsg::Idle`]). `seq` numbers the idle periods so that a repeated frame is
    /// not a second period.
    ///
    /// [`DeviceMsg::Idle`]: super::DeviceMsg::Idle
    Idle {
        /// Idle period number.
        seq: u32,
        /// Board time to sample for, µs.
        period_us: u32,
    },
    /// Where the robot was at `t_us` (µs of the lidar's clock: the LD06 timestamps, unwrapped
    /// by the device from the first packet it read; each [`ScanReport::t_us`] gives a host that
    /// clock). Poses come in time order, at their own rate; lidar packets are placed by
    /// interpolating between the two around their time ([`crate::lidar::turn`]).
    ///
    /// [`ScanReport::t_us`]: super::ScanReport::t_us
    Pose {
        /// Time, µs of the lidar clock.
        t_us: u64,
        /// The robot's pose (not the lidar's: [`RunConfig::mount`] is applied on the device).
        pose: Pose,
    },
    /// Rows `row ..` of building tile (`tx`, `ty`)'s `layer` (`LogOdds` or `Counts`), a
    /// stored tile sent back as the rolling window comes over it again (version 6, appended:
    /// the older variants keep their indices). A part carries
    /// [`super::restore_rows_per_part`] rows; the device checks it
    /// ([`super::check_restore_part`]), assembles the tile and restores it once every part of
    /// both layers has arrived ([`crate::session::TileRestore`]).
    Restore {
        /// Building tile column.
        tx: i32,
        /// Building tile row.
        ty: i32,
        /// `LogOdds` or `Counts`.
        layer: Layer,
        /// The first row of the tile this part carries (row 0 = lowest y).
        row: u8,
        /// The rows' cells, row-major, as a [`super::Tile`] of `layer` carries them.
        data: RestoreData,
    },
    /// Every stored tile the last `Window` brought back has been sent (version 8, appended): a
    /// robot holding a lidar turn for them ([`RunConfig::window_hold`]) maps it now. Ignored
    /// when nothing is held, so a host may send it after every `Window`.
    Resume,
}
