//! How scans and poses reach the engine, and the error of the blocking readers
//! ([`crate::lidar::ld06::Ld06Reader`], [`crate::lidar::rplidar::RplidarReader`]: host-side
//! conveniences over `embedded_io::Read`, e.g. a serial port or a file).
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
//! bytes (the replay is bit-exact). This is why ogm-core has no blocking scan or pose trait:
//! the robot would not use it.

/// Errors of a blocking reader of a byte source ([`crate::lidar::ld06::Ld06Reader`],
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
