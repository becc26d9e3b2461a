//! A scan as the mapper takes it: beams (an angle relative to the robot's heading and a range
//! or "no return") in a bounded buffer.

use crate::types::angle::Angle;

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

/// A bounded buffer for one scan, filled by a lidar reader or a turn. Beams beyond the capacity `N`
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

/// What inserting a scan did: the mapper's count, which the robot's scan report carries as it
/// is ([`crate::wire::ScanReport::mapper`]).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanStats {
    /// Beams that were used.
    pub beams_used: u32,
    /// Beams dropped (closer than the minimum range).
    pub beams_dropped: u32,
    /// Cells that received the occupied update.
    pub cells_hit: u32,
    /// Cells that received the free update.
    pub cells_freed: u32,
}
