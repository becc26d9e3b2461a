//! The traits through which scans and poses reach the engine: [`RangeSensor`] (complete scans
//! from a byte source: [`crate::lidar::ld06::Ld06Reader`] and
//! [`crate::lidar::rplidar::RplidarReader`] over any `embedded_io::Read`, the simulator's
//! synthetic lidar, a replayed laser log) and [`PoseSource`] (the pose of each scan).

use crate::types::geometry::Pose;
use crate::types::scan::ScanBuf;

/// Errors of a [`RangeSensor`] reading a byte source ([`crate::lidar::ld06::Ld06Reader`],
/// [`crate::lidar::rplidar::RplidarReader`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ReadError<E> {
    /// The byte source failed.
    Io(E),
    /// The byte source ended (`read` returned 0).
    Eof,
}

impl<E: core::fmt::Debug> core::fmt::Display for ReadError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "lidar byte source failed: {e:?}"),
            ReadError::Eof => f.write_str("lidar byte source ended"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for ReadError<E> {}

/// A source of complete scans (one sensor revolution).
pub trait RangeSensor {
    /// Transport or protocol error.
    type Error;
    /// Blocks until the next complete scan is available and writes it into `scan` (which the
    /// implementation clears first).
    fn read_scan<const N: usize>(&mut self, scan: &mut ScanBuf<N>) -> Result<(), Self::Error>;
}

/// A source of robot poses (known-pose mapping, as in the papers).
pub trait PoseSource {
    /// Transport or protocol error.
    type Error;
    /// The pose at which the most recently read scan was taken.
    fn current_pose(&mut self) -> Result<Pose, Self::Error>;
}
