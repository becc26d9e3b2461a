//! Blocking scan and pose traits, [`RangeSensor`] and [`PoseSource`]: *not* the way scans
//! reach the engine. They stay until host-sim's evaluation path (its synthetic lidar, a
//! replayed laser log, `session::pipeline::map_next_scan`) and the blocking readers
//! ([`crate::lidar::ld06::Ld06Reader`], [`crate::lidar::rplidar::RplidarReader`], host-side
//! conveniences over `embedded_io::Read`) move off them; nothing in ogm-core's engine or the
//! firmware depends on them.
//!
//! # The one seam: bytes, not scans
//!
//! Scans and poses enter the engine one way, the sans-IO path the robot runs: lidar bytes →
//! [`crate::lidar::ld06::Ld06Parser`] or [`crate::lidar::rplidar::RplidarParser`] (byte by
//! byte, whatever the UART delivered) → [`crate::lidar::turn::Turns`] (packets placed by the
//! timestamped poses of [`crate::wire::HostMsg::Pose`] from the link, which
//! [`crate::lidar::link::LinkRx`] decodes from the other UART) → one
//! [`crate::session::Session::insert`] per completed turn. The simulator feeds the firmware
//! through that same seam: `host-sim firmware --robot` sends it LD06 bytes and pose frames, and
//! runs the firmware's own application on them.
//!
//! A blocking `read_scan` does not fit the robot: its one loop interleaves two UARTs (the
//! lidar's, ~4 500 points/s, and the host link with the poses those points need), reads a
//! UART only while the turn queue has room for what it may complete, and must go on reading
//! the link while a turn is assembled — a call that blocks until a whole turn has arrived
//! would stall the poses that turn waits for. A sans-IO parser takes whatever bytes arrived
//! and never waits, so the board and the host drive the identical code with the identical
//! bytes (the replay is bit-exact).
// TODO(issue 36): remove the traits after host-sim migrates (and with them `ReadError`, the
// readers' `RangeSensor` impls and `session::pipeline`).

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
