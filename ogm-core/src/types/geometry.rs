//! Poses, cell coordinates and the world ↔ cell transform.
//!
//! World coordinates are integer millimetres in a right-handed frame (x right, y up, as in ROS).
//! The grid's `origin` is the world position of the *lower-left corner* of cell (0, 0), as in a
//! ROS `map_server` YAML; cell (x, y) covers `[origin + x·s, origin + (x+1)·s)` on each axis.

use crate::error::{Error, Result};
use crate::types::angle::{Angle, Q30_ONE};

/// A robot pose: position in millimetres and heading.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Pose {
    /// x in mm.
    pub x_mm: i32,
    /// y in mm.
    pub y_mm: i32,
    /// Heading (0 = +x, counter-clockwise).
    pub heading: Angle,
}

impl Pose {
    /// A pose at (`x_mm`, `y_mm`) facing `heading`.
    pub const fn new(x_mm: i32, y_mm: i32, heading: Angle) -> Self {
        Pose {
            x_mm,
            y_mm,
            heading,
        }
    }

    /// The world point (mm, as i64 so nothing overflows) at `range_mm` along the direction
    /// `heading + beam`.
    pub fn beam_end(&self, beam: Angle, range_mm: u32) -> (i64, i64) {
        let (dx, dy) = self.beam_offset(beam, range_mm);
        (i64::from(self.x_mm) + dx, i64::from(self.y_mm) + dy)
    }

    /// [`Pose::beam_end`] relative to the pose: `(dx, dy)` in mm, each of magnitude at most
    /// `range_mm`.
    #[inline]
    pub fn beam_offset(&self, beam: Angle, range_mm: u32) -> (i64, i64) {
        let (cos, sin) = self.heading.wrapping_add(beam).cos_sin_q30();
        let r = i64::from(range_mm);
        let half = i64::from(Q30_ONE) / 2;
        // Round to nearest mm (the shift floors; adding half first rounds). |cos|, |sin| ≤ 2^30,
        // so |r·cos + half| >> 30 ≤ r.
        (
            (r * i64::from(cos) + half) >> 30,
            (r * i64::from(sin) + half) >> 30,
        )
    }
}

/// A cell coordinate that may lie outside the grid (rays start and end anywhere).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CellCoord {
    /// Column.
    pub x: i32,
    /// Row (increasing with world y).
    pub y: i32,
}

/// Size, resolution and placement of a grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridGeometry {
    width: u16,
    height: u16,
    cell_mm: u32,
    origin_x_mm: i32,
    origin_y_mm: i32,
}

impl GridGeometry {
    /// A `width` × `height` grid of `cell_mm` square cells with its lower-left corner at
    /// (`origin_x_mm`, `origin_y_mm`). Errors if any size is zero.
    pub const fn new(
        width: u16,
        height: u16,
        cell_mm: u32,
        origin_x_mm: i32,
        origin_y_mm: i32,
    ) -> Result<Self> {
        if width == 0 || height == 0 || cell_mm == 0 {
            return Err(Error::InvalidGeometry);
        }
        Ok(GridGeometry {
            width,
            height,
            cell_mm,
            origin_x_mm,
            origin_y_mm,
        })
    }

    /// Columns.
    #[inline]
    pub const fn width(&self) -> u16 {
        self.width
    }
    /// Rows.
    #[inline]
    pub const fn height(&self) -> u16 {
        self.height
    }
    /// Cell edge length in mm.
    #[inline]
    pub const fn cell_mm(&self) -> u32 {
        self.cell_mm
    }
    /// World position of the lower-left corner of cell (0, 0).
    #[inline]
    pub const fn origin_mm(&self) -> (i32, i32) {
        (self.origin_x_mm, self.origin_y_mm)
    }
    /// Number of cells (`width × height`, at most 2³²).
    #[inline]
    pub const fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }
    /// Always false: a geometry has at least one cell.
    #[inline]
    pub const fn is_empty(&self) -> bool {
        false
    }

    /// The cell containing a world point (mm), possibly outside the grid. Saturates at the
    /// `i32` range for absurd inputs.
    pub fn cell_of_point(&self, x_mm: i64, y_mm: i64) -> CellCoord {
        // ≥ 1 by construction; `max` lets the compiler drop the division's zero check.
        let s = i64::from(self.cell_mm.max(1));
        let fx = x_mm
            .saturating_sub(i64::from(self.origin_x_mm))
            .div_euclid(s);
        let fy = y_mm
            .saturating_sub(i64::from(self.origin_y_mm))
            .div_euclid(s);
        CellCoord {
            x: saturate_i32(fx),
            y: saturate_i32(fy),
        }
    }

    /// The cell containing the pose's position.
    pub fn cell_of_pose(&self, pose: &Pose) -> CellCoord {
        self.cell_of_point(i64::from(pose.x_mm), i64::from(pose.y_mm))
    }

    /// World position (mm) of the centre of a cell (which may be outside the grid).
    pub fn cell_center_mm(&self, c: CellCoord) -> (i64, i64) {
        let s = i64::from(self.cell_mm);
        (
            i64::from(self.origin_x_mm) + i64::from(c.x) * s + s / 2,
            i64::from(self.origin_y_mm) + i64::from(c.y) * s + s / 2,
        )
    }

    /// Whether the cell is inside the grid.
    #[inline]
    pub fn contains(&self, c: CellCoord) -> bool {
        c.x >= 0 && c.y >= 0 && c.x < i32::from(self.width) && c.y < i32::from(self.height)
    }

    /// Row-major index (`y · width + x`) of an in-grid cell, or `None` outside.
    #[inline]
    pub fn index(&self, c: CellCoord) -> Option<usize> {
        if self.contains(c) {
            Some(c.y as usize * self.width as usize + c.x as usize)
        } else {
            None
        }
    }

    /// The cell of a row-major index, or `None` if the index is out of range.
    pub fn coord(&self, index: usize) -> Option<CellCoord> {
        if index >= self.len() {
            return None;
        }
        let w = self.width as usize;
        Some(CellCoord {
            x: (index % w) as i32,
            y: (index / w) as i32,
        })
    }

    /// The same grid moved by `(dx, dy)` whole cells (cell `(x, y)` of the result is cell
    /// `(x + dx, y + dy)` of `self`); `None` if the origin would leave the `i32` mm range.
    pub fn shifted(&self, dx: i32, dy: i32) -> Option<Self> {
        let s = i64::from(self.cell_mm);
        let ox = i64::from(self.origin_x_mm).checked_add(i64::from(dx).checked_mul(s)?)?;
        let oy = i64::from(self.origin_y_mm).checked_add(i64::from(dy).checked_mul(s)?)?;
        Some(GridGeometry {
            origin_x_mm: i32::try_from(ox).ok()?,
            origin_y_mm: i32::try_from(oy).ok()?,
            ..*self
        })
    }

    /// Range in cells (rounded down) of a distance in mm.
    pub fn mm_to_cells(&self, mm: u32) -> u32 {
        mm / self.cell_mm
    }
}

fn saturate_i32(v: i64) -> i32 {
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms() {
        let g = GridGeometry::new(100, 50, 50, -1000, -500).unwrap();
        assert_eq!(g.len(), 5000);
        assert_eq!(g.cell_of_point(-1000, -500), CellCoord { x: 0, y: 0 });
        assert_eq!(g.cell_of_point(-1001, -500), CellCoord { x: -1, y: 0 });
        assert_eq!(g.cell_of_point(0, 0), CellCoord { x: 20, y: 10 });
        assert_eq!(g.cell_center_mm(CellCoord { x: 20, y: 10 }), (25, 25));
        assert_eq!(g.index(CellCoord { x: 99, y: 49 }), Some(4999));
        assert_eq!(g.index(CellCoord { x: 100, y: 0 }), None);
        assert_eq!(g.coord(4999), Some(CellCoord { x: 99, y: 49 }));
        assert_eq!(g.coord(5000), None);
        assert_eq!(
            g.cell_of_point(i64::MAX, i64::MIN),
            CellCoord {
                x: i32::MAX,
                y: i32::MIN
            }
        );
        assert!(GridGeometry::new(0, 1, 1, 0, 0).is_err());
        assert!(GridGeometry::new(1, 1, 0, 0, 0).is_err());
    }

    #[test]
    fn beam_end_is_rounded_polar() {
        let p = Pose {
            x_mm: 100,
            y_mm: -200,
            heading: Angle::QUARTER,
        };
        assert_eq!(p.beam_end(Angle::ZERO, 1000), (100, 800));
        assert_eq!(p.beam_end(Angle::QUARTER, 1000), (-900, -200));
        let (x, y) = p.beam_end(Angle::from_degrees(-45.0), 10_000);
        assert_eq!((x, y), (100 + 7071, -200 + 7071));
    }
}
