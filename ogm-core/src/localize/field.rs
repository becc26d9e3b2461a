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
    sxx: i32,
    sxy: i32,
    syy: i32,
}

impl Moments {
    /// Adds a row of the window: its sums `Σw`, `Σw·c`, `Σw·c²` over the columns `c` (cells
    /// from the window's centre), at row `rj` (cells from the centre).
    #[inline(always)]
    fn add_row(&mut self, rj: i32, (r0, r1, r2): (i32, i32, i32)) {
        self.s0 += r0;
        self.s1x += r1;
        self.sxx += r2;
        self.s1y += rj * r0;
        self.sxy += rj * r1;
        self.syy += rj * rj * r0;
    }
}

/// The row sums `(Σw, Σw·c, Σw·c²)` (weights Q8, `c` the column from the window's centre,
/// starting at `c0`) of the cells above the ramp's floor; free and unknown cells cost a compare.
#[inline(always)]
fn row_sums<I: Iterator<Item = i16>>(ramp: &Ramp, row: I, c0: i32) -> (i32, i32, i32) {
    let floor = ramp.floor_raw();
    let (mut r0, mut r1, mut r2) = (0i32, 0i32, 0i32);
    // A counter, not `(c0..).zip(row)`: the zip costs ~4 % more instructions per scan on the M4.
    let mut c = c0;
    #[allow(clippy::explicit_counter_loop)]
    for l in row {
        if l > floor {
            let w = ramp.weight_q8(l);
            let wc = w * c;
            r0 += w;
            r1 += wc;
            r2 += wc * c;
        }
        c += 1;
    }
    (r0, r1, r2)
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
        // Two cells (512 sub-cells) along the dominant axis of the beam: the beam scaled down to
        // 11 bits first (|r| < 2^25), so the division is a 32-bit one.
        let m = rx.unsigned_abs().max(ry.unsigned_abs()).max(1);
        let sh = (32 - m.leading_zeros()).saturating_sub(11);
        let m = ((m >> sh) as i32).max(1);
        let sx = ((rx >> sh) << 9) / m;
        let sy = ((ry >> sh) << 9) / m;
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
    #[cfg(all(test, feature = "reference"))]
    pub(crate) fn near(&self, gx: i32, gy: i32, level: u8, p: &NearParams) -> Option<Near> {
        let at = Cell::of(gx, gy, level);
        Some(self.window(at.i, at.j, level, p)?.near(&at, p))
    }

    /// The distribution of the window centred on level cell (`i`, `j`), what [`Field::near`]
    /// needs of it whatever the position inside that cell (so a pass can reuse it for the
    /// points that fall in the same cell). Reads `(2·radius + 1)² · 4^level` cells.
    pub(crate) fn window(&self, i: i32, j: i32, level: u8, p: &NearParams) -> Option<Window> {
        let k = u32::from(level.min(MAX_LEVEL));
        let r = i32::from(p.radius.clamp(1, MAX_RADIUS));
        let n = 1i32 << k;
        let side = 2 * r + 1;
        let (x0, y0) = (
            i.checked_sub(r)?.checked_mul(n)?,
            j.checked_sub(r)?.checked_mul(n)?,
        );
        if x0 < 0 || y0 < 0 || x0 > self.w - side * n || y0 > self.h - side * n {
            return None;
        }
        // Moments about the window's centre cell, in whole level cells: |c| ≤ r ≤ 3, weights Q8
        // ≤ 2^8, at most 49 cells: every sum is below 2^17 (i32, no 64-bit arithmetic).
        let mut m = Moments::default();
        let (w, side) = (self.w as usize, side as usize);
        if n == 1 {
            // The grid's own cells: straight from the rows.
            for (rj, y) in (-r..=r).zip(y0 as usize..) {
                let start = y * w + x0 as usize;
                let row = self.cells.get(start..start + side)?;
                m.add_row(rj, row_sums(&self.ramp, row.iter().map(|l| l.0), -r));
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
            for (rj, qrow) in (-r..=r).zip(q.iter()) {
                m.add_row(
                    rj,
                    row_sums(&self.ramp, qrow.iter().take(side).copied(), -r),
                );
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
        // Centroid about the centre cell, Q8 (|Σw·c| < 2^15: << 8 fits); second moments Q12
        // (< 2^17 · 2^12 = 2^29); the covariance is the same about any origin.
        let (cx, cy) = ((s1x << 8) / s0, (s1y << 8) / s0);
        let cxx = (sxx << 12) / s0 - ((cx * cx) >> 4);
        let cyy = (syy << 12) / s0 - ((cy * cy) >> 4);
        let cxy = (sxy << 12) / s0 - ((cx * cy) >> 4);
        let reg = p.reg.clamp(1, MAX_REG);
        let (cxx, cyy) = (cxx + reg, cyy + reg);
        // cxx, cyy ≤ ~2^16 + reg: the determinant (Q24) fits an i64; Q12 fits an i32.
        let det = ((i64::from(cxx) * i64::from(cyy) - i64::from(cxy) * i64::from(cxy)) >> 12)
            .clamp(0, i64::from(i32::MAX)) as i32;
        if det <= 0 || cxx <= 0 || cyy <= 0 {
            return None;
        }
        // |c| < 2^18, so c · 2^12 fits an i32.
        let inv = |c: i32| (c << 12) / det;
        Some(Window {
            cx,
            cy,
            oxx: inv(cyy),
            oxy: inv(-cxy),
            oyy: inv(cxx),
        })
    }
}

/// A position as [`Field::near`] sees it at one level: Q8 level cells and the level cell
/// containing it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Cell {
    u: i32,
    v: i32,
    pub(crate) i: i32,
    pub(crate) j: i32,
}

impl Cell {
    /// The sub-cell position (`gx`, `gy`) at `level`.
    #[inline(always)]
    pub(crate) fn of(gx: i32, gy: i32, level: u8) -> Cell {
        let k = u32::from(level.min(MAX_LEVEL));
        let (u, v) = (gx >> k, gy >> k);
        Cell {
            u,
            v,
            i: u >> 8,
            j: v >> 8,
        }
    }
}

/// A window's distribution: the centroid relative to the centre cell's centre (Q8 level cells), and the inverse covariance (Q12 per level
/// cell², before the robust weight).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Window {
    cx: i32,
    cy: i32,
    oxx: i32,
    oxy: i32,
    oyy: i32,
}

impl Window {
    /// The distribution as seen from a position inside the window's centre cell: the offset to
    /// the centroid and the inverse covariance scaled by the Cauchy weight.
    #[inline(always)]
    pub(crate) fn near(&self, at: &Cell, p: &NearParams) -> Near {
        // Point → centroid, Q8: the centre cell's centre relative to the point, plus the
        // centroid relative to that centre.
        let mx = (at.i << 8) + 128 - at.u + self.cx;
        let my = (at.j << 8) + 128 - at.v + self.cy;
        let (oxx, oxy, oyy) = (self.oxx, self.oxy, self.oyy);
        // Squared Mahalanobis distance, Q12: μ Q8 · Ω Q12 · μ Q8 = Q28.
        let (mx64, my64) = (i64::from(mx), i64::from(my));
        let d2 = (mx64 * (i64::from(oxx) * mx64 + i64::from(oxy) * my64)
            + my64 * (i64::from(oxy) * mx64 + i64::from(oyy) * my64))
            >> 16;
        // c² < 2^18: c² · 2^12 fits an i32; Q12, at most 4096.
        let c2 = p.cauchy.clamp(1, MAX_CAUCHY);
        let wq = (c2 << 12) / c2.saturating_add(d2.clamp(0, i64::from(i32::MAX)) as i32);
        let scale = |o: i32| ((i64::from(o) * i64::from(wq)) >> 12) as i32;
        Near {
            mx,
            my,
            oxx: scale(oxx),
            oxy: scale(oxy),
            oyy: scale(oyy),
        }
    }
}
