//! The "HAL traits": how scans and poses enter the mapper.
//!
//! [`crate::ld06::Ld06Reader`] and [`crate::rplidar::RplidarReader`] implement [`RangeSensor`]
//! over any `embedded_io::Read` byte source (a UART, a serial port); the host simulator
//! implements both traits with its synthetic lidar and known trajectory, and `eval-log` with a
//! replayed laser log. They drive [`crate::pipeline::map_next_scan`]. (The firmware today takes
//! its scans from [`crate::link::LinkRx`] — LD06 packets framed with a pose on the host link —
//! into [`crate::session::Session::insert`], the same mapper.)

use crate::angle::Angle;
use crate::geometry::Pose;

/// One range reading.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Range {
    /// The beam hit something this many millimetres away.
    Hit(u32),
    /// Nothing within the sensor's maximum range: the beam frees space only.
    NoReturn,
}

/// A beam: its direction relative to the robot's heading and what it measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Beam {
    /// Direction relative to the robot heading (counter-clockwise).
    pub angle: Angle,
    /// The reading.
    pub range: Range,
}

/// Errors of a [`RangeSensor`] reading a byte source ([`crate::ld06::Ld06Reader`],
/// [`crate::rplidar::RplidarReader`]).
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

/// A bounded buffer for one scan, filled by a [`RangeSensor`]. Beams beyond the capacity `N`
/// are dropped and counted, never written out of bounds.
#[derive(Clone, Debug, Default)]
pub struct ScanBuf<const N: usize> {
    beams: heapless::Vec<Beam, N>,
    overflow: u32,
}

impl<const N: usize> ScanBuf<N> {
    /// An empty buffer.
    pub const fn new() -> Self {
        ScanBuf {
            beams: heapless::Vec::new(),
            overflow: 0,
        }
    }

    /// Empties the buffer and resets the overflow count.
    pub fn clear(&mut self) {
        self.beams.clear();
        self.overflow = 0;
    }

    /// Appends a beam; returns `false` (and counts it) if the buffer is full.
    pub fn push(&mut self, beam: Beam) -> bool {
        if self.beams.push(beam).is_err() {
            self.overflow = self.overflow.saturating_add(1);
            false
        } else {
            true
        }
    }

    /// The beams so far.
    pub fn beams(&self) -> &[Beam] {
        &self.beams
    }

    /// Number of beams dropped because the buffer was full.
    pub const fn overflow(&self) -> u32 {
        self.overflow
    }

    /// Sorts the beams by angle (stable, so equal angles keep arrival order). The cone model
    /// requires it; LD06 scans arrive nearly sorted, which this handles in near-linear time.
    pub fn sort_by_angle(&mut self) {
        // Insertion sort: no allocation, stable, linear on the nearly-sorted data lidars emit.
        let b = self.beams.as_mut_slice();
        for i in 1..b.len() {
            let mut j = i;
            while j > 0 {
                let (Some(prev), Some(cur)) = (b.get(j - 1), b.get(j)) else {
                    break;
                };
                if prev.angle.0 <= cur.angle.0 {
                    break;
                }
                b.swap(j - 1, j);
                j -= 1;
            }
        }
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_buf_is_bounded_and_sorts() {
        let mut s: ScanBuf<3> = ScanBuf::new();
        for a in [30u16, 10, 20, 5] {
            s.push(Beam {
                angle: Angle(a),
                range: Range::NoReturn,
            });
        }
        assert_eq!(s.beams().len(), 3);
        assert_eq!(s.overflow(), 1);
        s.sort_by_angle();
        let a: Vec<u16> = s.beams().iter().map(|b| b.angle.0).collect();
        assert_eq!(a, vec![10, 20, 30]);
        s.clear();
        assert_eq!((s.beams().len(), s.overflow()), (0, 0));
    }
}
