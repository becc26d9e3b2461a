//! The map as the matcher sees it: a read-only view of log-odds cells, the ramp that turns a
//! cell's log-odds into a weight, and the occupied cells near a point as a normal distribution
//! (NDT, Biber & Straßer 2003, but computed from the occupancy grid on the fly, per point, at any
//! level of a max-pooled pyramid).
//!
//! Positions are in sub-cells ([`crate::localize::SUB`] per cell) from the grid's lower-left
//! corner; a cell's weight sits at its centre.

use crate::error::{Error, Result};
use crate::localize::MAX_LEVEL;
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

    /// The raw log-odds at or below which a cell weighs nothing.
    #[inline(always)]
    pub(crate) fn floor_raw(&self) -> i16 {
        self.floor.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16
    }

    /// The weight (Q8, 0..=256) of a raw log-odds above the floor.
    #[inline(always)]
    pub(crate) fn weight_q8(&self, raw: i16) -> i32 {
        let d = (i32::from(raw) - self.floor).clamp(0, self.span) as u32;
        ((d * self.scale) >> 23) as i32
    }

    /// The map value (Q15, 0..=ONE) of a raw log-odds.
    #[inline(always)]
    pub(crate) fn value(&self, raw: i16) -> i32 {
        let d = (i32::from(raw) - self.floor).clamp(0, self.span) as u32;
        // d · scale ≤ span · 2^31 / span = 2^31; >> 16 gives Q15.
        ((d * self.scale) >> 16) as i32
    }
}

/// The occupied cells near a point as a normal distribution: the offset from the point to their
/// weighted centroid and the inverse of their covariance (times a robust weight).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Near {
    /// Point → centroid, Q8 level cells.
    pub(crate) mx: i32,
    /// Point → centroid, Q8 level cells.
    pub(crate) my: i32,
    /// Inverse covariance × robust weight, Q12 per level cell².
    pub(crate) oxx: i32,
    /// See `oxx`.
    pub(crate) oxy: i32,
    /// See `oxx`.
    pub(crate) oyy: i32,
}

/// How [`Field::near`] builds a distribution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct NearParams {
    /// Window radius, level cells (1..=[`MAX_RADIUS`]).
    pub(crate) radius: u8,
    /// Added to the covariance's diagonal, Q12 level cells² (the cell's own extent plus a
    /// regulariser: a straight wall's covariance is singular across it).
    pub(crate) reg: i32,
    /// Cauchy scale c² of the robust weight `c² / (c² + d²)`, Q12 level cells² (d² the point's
    /// squared Mahalanobis distance).
    pub(crate) cauchy: i32,
}

/// Weighted moments of a window's cells about the point.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    s0: i32,
    s1x: i32,
    s1y: i32,
    sxx: i64,
    sxy: i64,
    syy: i64,
}

impl Moments {
    /// Adds a cell of weight `w` (Q8) at offset (`ex`, `ey`) (Q8).
    #[inline(always)]
    fn add(&mut self, w: i32, ex: i32, ey: i32) {
        let (wx, wy) = (w * ex, w * ey);
        self.s0 += w;
        self.s1x += wx;
        self.s1y += wy;
        self.sxx += i64::from(wx) * i64::from(ex);
        self.sxy += i64::from(wx) * i64::from(ey);
        self.syy += i64::from(wy) * i64::from(ey);
    }
}

/// The largest window radius, level cells.
pub const MAX_RADIUS: u8 = 3;

/// Side of the largest window, level cells.
const BLOCK: usize = 2 * MAX_RADIUS as usize + 1;

/// The largest covariance regulariser, Q12 level cells² (16 cells²).
pub(crate) const MAX_REG: i32 = 1 << 16;

/// The largest Cauchy scale c², Q12 level cells² (63 cells²).
pub(crate) const MAX_CAUCHY: i32 = (1 << 18) - 1;

/// Less total weight than half an occupied cell (Q8) in a window: no distribution.
const MIN_WEIGHT: i32 = 128;

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

    /// The largest map value of the 2 × 2 block of cells (a level-1 cell) containing the
    /// sub-cell position, 0 outside the grid: four reads.
    #[inline]
    pub(crate) fn pooled(&self, gx: i32, gy: i32) -> i32 {
        let (i, j) = ((gx >> 9) << 1, (gy >> 9) << 1);
        if i < 0 || j < 0 || i + 1 >= self.w || j + 1 >= self.h {
            return 0;
        }
        let (w, i, j) = (self.w as usize, i as usize, j as usize);
        let a = self.cells.get(j * w + i..j * w + i + 2);
        let b = self.cells.get((j + 1) * w + i..(j + 1) * w + i + 2);
        let m = a
            .into_iter()
            .chain(b)
            .flatten()
            .map(|l| l.0)
            .max()
            .unwrap_or(i16::MIN);
        self.ramp.value(m)
    }

    /// Whether the map has seen through the point: its cell and the cells two and four cells
    /// farther along the beam (direction `(rx, ry)`, the point relative to the robot) are all
    /// inside the grid and at or below `free`. Three reads.
    ///
    /// Why along the beam and not around the point: walls seen at grazing angles by earlier scans
    /// are eroded (rays clip their cells), so a correct hit often lands on a freed cell; but the
    /// space *behind* a wall is unknown, not free. A hit with free space behind it contradicts the
    /// map: the pose is wrong (or a door opened).
    pub(crate) fn see_through(&self, gx: i32, gy: i32, rx: i32, ry: i32, free: i16) -> bool {
        let m = rx.unsigned_abs().max(ry.unsigned_abs()).max(1) as i64;
        // Two cells (512 sub-cells) along the dominant axis of the beam.
        let sx = ((i64::from(rx) << 9) / m) as i32;
        let sy = ((i64::from(ry) << 9) / m) as i32;
        [(0, 0), (sx, sy), (2 * sx, 2 * sy)]
            .iter()
            .all(|&(dx, dy)| self.raw(gx + dx, gy + dy).is_some_and(|l| l <= free))
    }

    /// The raw log-odds of the cell containing the sub-cell position, `None` outside the grid.
    #[inline]
    fn raw(&self, gx: i32, gy: i32) -> Option<i16> {
        let (i, j) = (gx >> 8, gy >> 8);
        if i < 0 || j < 0 || i >= self.w || j >= self.h {
            return None;
        }
        let idx = j as usize * self.w as usize + i as usize;
        self.cells.get(idx).map(|l| l.0)
    }

    /// The occupied cells of the `(2·radius + 1)²` window of level cells centred on the level
    /// cell that contains the position (a level cell is the maximum of its `2^level × 2^level`
    /// grid cells) as a distribution, see [`Near`]: weights are the ramped log-odds, the
    /// covariance gets `p.reg` on its diagonal, and the inverse is scaled by the Cauchy weight of
    /// the point's Mahalanobis distance. `None` if the window is not inside the grid or weighs
    /// less than half an occupied cell. Reads `(2·radius + 1)² · 4^level` cells.
    ///
    /// Why a distribution and not the interpolated map value (Hector): with a value that peaks on
    /// a wall, the Jacobian vanishes at the optimum and Gauss–Newton overshoots; with one that
    /// saturates, the optimum is a plateau. The distance to the wall's local centroid, measured
    /// with its covariance, is zero at the optimum and keeps its slope there (point-to-line ICP
    /// against the map's own cells), and the centroid of a slanted wall's staircase of cells
    /// lies on the wall, not on a cell centre.
    pub(crate) fn near(&self, gx: i32, gy: i32, level: u8, p: &NearParams) -> Option<Near> {
        let k = u32::from(level.min(MAX_LEVEL));
        let r = i32::from(p.radius.clamp(1, MAX_RADIUS));
        // The position in Q8 level cells and the level cell containing it.
        let (u, v) = (gx >> k, gy >> k);
        let (i, j) = (u >> 8, v >> 8);
        let n = 1i32 << k;
        let side = 2 * r + 1;
        let (x0, y0) = (
            i.checked_sub(r)?.checked_mul(n)?,
            j.checked_sub(r)?.checked_mul(n)?,
        );
        if x0 < 0 || y0 < 0 || x0 > self.w - side * n || y0 > self.h - side * n {
            return None;
        }
        // Moments about the point. Offsets of cell centres, Q8 level cells: |e| ≤ (r + 1)·256
        // ≤ 2^10; weights Q8 ≤ 2^8: first moments < 2^24, second < 2^34 (i64).
        let ex0 = ((i - r) << 8) + 128 - u;
        let ey0 = ((j - r) << 8) + 128 - v;
        let mut m = Moments::default();
        let (w, side) = (self.w as usize, side as usize);
        if n == 1 {
            // The grid's own cells: straight from the rows, free and unknown cells skipped
            // before any arithmetic (most of a window is free space).
            let mut ey = ey0;
            for r in 0..side {
                let start = (y0 as usize + r) * w + x0 as usize;
                let row = self.cells.get(start..start + side)?;
                let mut ex = ex0;
                for l in row {
                    if l.0 > self.ramp.floor_raw() {
                        m.add(self.ramp.weight_q8(l.0), ex, ey);
                    }
                    ex += 256;
                }
                ey += 256;
            }
        } else {
            let n = n as usize;
            let mut q = [[i16::MIN; BLOCK]; BLOCK];
            for r in 0..side * n {
                let start = (y0 as usize + r) * w + x0 as usize;
                let row = self.cells.get(start..start + side * n)?;
                let qrow = q.get_mut(r / n)?;
                // The common block sizes unrolled (2 and 4 cells a row): the loop overhead of a
                // generic inner loop costs as much as the maxima on a Cortex-M4.
                match n {
                    2 => {
                        for (slot, b) in qrow.iter_mut().zip(row.chunks_exact(2)) {
                            if let [a, c] = b {
                                *slot = (*slot).max(a.0.max(c.0));
                            }
                        }
                    }
                    4 => {
                        for (slot, b) in qrow.iter_mut().zip(row.chunks_exact(4)) {
                            if let [a, c, d, e] = b {
                                *slot = (*slot).max(a.0.max(c.0).max(d.0.max(e.0)));
                            }
                        }
                    }
                    _ => {
                        for (slot, b) in qrow.iter_mut().zip(row.chunks_exact(n)) {
                            for l in b {
                                *slot = (*slot).max(l.0);
                            }
                        }
                    }
                }
            }
            let mut ey = ey0;
            for qrow in q.iter().take(side) {
                let mut ex = ex0;
                for &l in qrow.iter().take(side) {
                    if l > self.ramp.floor_raw() {
                        m.add(self.ramp.weight_q8(l), ex, ey);
                    }
                    ex += 256;
                }
                ey += 256;
            }
        }
        let Moments {
            s0,
            s1x,
            s1y,
            sxx,
            sxy,
            syy,
        } = m;
        if s0 < MIN_WEIGHT {
            return None;
        }
        // Centroid, Q8; covariance, Q12 (second moments are Q16: >> 4 fits an i32).
        let (mx, my) = (s1x / s0, s1y / s0);
        // Second moments < 2^34 (Q16): >> 4 fits an i32, so the divisions are 32-bit.
        let q12 = |s: i64| (s >> 4).clamp(-i64::from(i32::MAX), i64::from(i32::MAX)) as i32 / s0;
        let reg = p.reg.clamp(1, MAX_REG);
        let cxx = q12(sxx) - ((mx * mx) >> 4) + reg;
        let cyy = q12(syy) - ((my * my) >> 4) + reg;
        let cxy = q12(sxy) - ((mx * my) >> 4);
        // cxx, cyy ≤ ~2^16 + reg: the determinant (Q24) fits an i64; Q12 fits an i32.
        let det = ((i64::from(cxx) * i64::from(cyy) - i64::from(cxy) * i64::from(cxy)) >> 12)
            .clamp(0, i64::from(i32::MAX)) as i32;
        if det <= 0 || cxx <= 0 || cyy <= 0 {
            return None;
        }
        // |c| < 2^18, so c · 2^12 fits an i32.
        let inv = |c: i32| (c << 12) / det;
        let (oxx, oxy, oyy) = (inv(cyy), inv(-cxy), inv(cxx));
        // Squared Mahalanobis distance, Q12: μ Q8 · Ω Q12 · μ Q8 = Q28.
        let (mx64, my64) = (i64::from(mx), i64::from(my));
        let d2 = (mx64 * (i64::from(oxx) * mx64 + i64::from(oxy) * my64)
            + my64 * (i64::from(oxy) * mx64 + i64::from(oyy) * my64))
            >> 16;
        // c² < 2^18: c² · 2^12 fits an i32; Q12, at most 4096.
        let c2 = p.cauchy.clamp(1, MAX_CAUCHY);
        let wq = (c2 << 12) / c2.saturating_add(d2.clamp(0, i64::from(i32::MAX)) as i32);
        let scale = |o: i32| ((i64::from(o) * i64::from(wq)) >> 12) as i32;
        Some(Near {
            mx,
            my,
            oxx: scale(oxx),
            oxy: scale(oxy),
            oyy: scale(oyy),
        })
    }
}
