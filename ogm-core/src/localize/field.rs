//! The map as the matcher sees it: a read-only view of log-odds cells, the ramp that turns a
//! cell's log-odds into a map value, and bilinear samples (with gradient) of the max-pooled
//! pyramid levels, computed on the fly.
//!
//! Positions are in sub-cells ([`SUB`] per cell) from the grid's lower-left corner. A cell's
//! value sits at its centre, so a sample at `u` interpolates between the centres around it:
//! `u − ½` cell, floored, is the lower-left corner of the four.

use crate::error::{Error, Result};
use crate::localize::{MAX_LEVEL, SUB};
use crate::map::grid::LogOddsGrid;
use crate::types::fixed::LogOdds;
use crate::types::geometry::GridGeometry;

/// Map value one (Q15).
pub const ONE: i32 = 1 << 15;

/// A read-only view of a log-odds grid.
#[derive(Clone, Copy, Debug)]
pub struct MapView<'a> {
    cells: &'a [LogOdds],
    geometry: GridGeometry,
}

impl<'a> MapView<'a> {
    /// A view of `cells` (row-major, `geometry.len()` of them).
    pub fn new(cells: &'a [LogOdds], geometry: GridGeometry) -> Result<Self> {
        if cells.len() != geometry.len() {
            return Err(Error::BufferSize {
                expected: geometry.len(),
                actual: cells.len(),
            });
        }
        Ok(MapView { cells, geometry })
    }

    /// A view of a grid.
    pub fn of<S: AsRef<[LogOdds]>>(grid: &'a LogOddsGrid<S>) -> Self {
        MapView {
            cells: grid.cells(),
            geometry: *grid.geometry(),
        }
    }

    /// The grid's geometry.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// The cells.
    pub fn cells(&self) -> &'a [LogOdds] {
        self.cells
    }
}

/// Log-odds → map value: 0 at or below `floor`, [`ONE`] at or above `full`, linear between.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Ramp {
    floor: i32,
    span: i32,
    /// `2^31 / span`: `(l − floor) · scale ≤ 2^31` fits a `u32`.
    scale: u32,
}

impl Ramp {
    /// The ramp from `floor` to `full` (`floor < full`; otherwise a step at `floor`).
    pub(crate) fn new(floor: LogOdds, full: LogOdds) -> Self {
        let f = i32::from(floor.0);
        let span = (i32::from(full.0) - f).max(1);
        Ramp {
            floor: f,
            span,
            scale: (1u32 << 31) / span as u32,
        }
    }

    /// The map value (Q15, 0..=ONE) of a raw log-odds.
    #[inline(always)]
    pub(crate) fn value(&self, raw: i16) -> i32 {
        let d = (i32::from(raw) - self.floor).clamp(0, self.span) as u32;
        // d · scale ≤ span · 2^31 / span = 2^31; >> 16 gives Q15.
        ((d * self.scale) >> 16) as i32
    }
}

/// A bilinear sample: value and gradient (per cell of the sample's level), Q15.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Sample {
    pub(crate) m: i32,
    pub(crate) dx: i32,
    pub(crate) dy: i32,
}

/// The grid's dimensions as `i32` and its cells: what the inner loops need.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Field<'a> {
    pub(crate) cells: &'a [LogOdds],
    pub(crate) w: i32,
    pub(crate) h: i32,
    pub(crate) ramp: Ramp,
}

impl<'a> Field<'a> {
    pub(crate) fn new(map: &MapView<'a>, ramp: Ramp) -> Self {
        Field {
            cells: map.cells,
            w: i32::from(map.geometry.width()),
            h: i32::from(map.geometry.height()),
            ramp,
        }
    }

    /// Map value of the cell containing the sub-cell position, 0 outside the grid: one read.
    #[inline]
    pub(crate) fn nearest(&self, gx: i32, gy: i32) -> i32 {
        let (i, j) = (gx >> 8, gy >> 8);
        if i < 0 || j < 0 || i >= self.w || j >= self.h {
            return 0;
        }
        // 0 ≤ i < w, 0 ≤ j < h: the index is below w·h ≤ 2^32 − 1; `get` still checks.
        let idx = j as usize * self.w as usize + i as usize;
        self.cells.get(idx).map_or(0, |l| self.ramp.value(l.0))
    }

    /// Bilinear sample of level `level` at a sub-cell position of the grid; `None` if the four
    /// level cells around it are not all inside the grid. Reads `4^(level+1)` cells.
    #[inline]
    pub(crate) fn sample(&self, gx: i32, gy: i32, level: u8) -> Option<Sample> {
        let k = u32::from(level.min(MAX_LEVEL));
        // Position in sub-cells of the level's cells, relative to the centres' lattice.
        let u = (gx >> k).saturating_sub(SUB / 2);
        let v = (gy >> k).saturating_sub(SUB / 2);
        let (i, j) = (u >> 8, v >> 8);
        let (fx, fy) = (u & 0xFF, v & 0xFF);
        let n = 1i32 << k; // grid cells per level cell
        let (x0, y0) = (i.checked_mul(n)?, j.checked_mul(n)?);
        if x0 < 0 || y0 < 0 || x0 > self.w - 2 * n || y0 > self.h - 2 * n {
            return None;
        }
        let (m00, m10, m01, m11) = if k == 0 {
            let w = self.w as usize;
            let idx = y0 as usize * w + x0 as usize;
            let [a, b] = self.cells.get(idx..idx + 2)? else {
                return None;
            };
            let [c, d] = self.cells.get(idx + w..idx + w + 2)? else {
                return None;
            };
            (a.0, b.0, c.0, d.0)
        } else {
            self.pooled(x0, y0, n)?
        };
        let r = &self.ramp;
        let (m00, m10, m01, m11) = (r.value(m00), r.value(m10), r.value(m01), r.value(m11));
        // Values ≤ 2^15 and fractions < 2^8: every product fits an i32.
        let a = m00 + (((m10 - m00) * fx) >> 8);
        let b = m01 + (((m11 - m01) * fx) >> 8);
        let m = a + (((b - a) * fy) >> 8);
        let dx = (m10 - m00) + (((m11 - m01 - m10 + m00) * fy) >> 8);
        let dy = b - a;
        Some(Sample { m, dx, dy })
    }

    /// The maxima of the four `n × n` blocks of the `2n × 2n` block at (`x0`, `y0`) (inside the
    /// grid): lower-left, lower-right, upper-left, upper-right.
    fn pooled(&self, x0: i32, y0: i32, n: i32) -> Option<(i16, i16, i16, i16)> {
        let (w, n) = (self.w as usize, n as usize);
        let mut q = [i16::MIN; 4];
        for r in 0..2 * n {
            let start = (y0 as usize + r) * w + x0 as usize;
            let row = self.cells.get(start..start + 2 * n)?;
            let (left, right) = row.split_at(n);
            let lm = left.iter().map(|l| l.0).max().unwrap_or(i16::MIN);
            let rm = right.iter().map(|l| l.0).max().unwrap_or(i16::MIN);
            let half = usize::from(r >= n) * 2;
            if let Some(s) = q.get_mut(half) {
                *s = (*s).max(lm);
            }
            if let Some(s) = q.get_mut(half + 1) {
                *s = (*s).max(rm);
            }
        }
        let [a, b, c, d] = q;
        Some((a, b, c, d))
    }
}
