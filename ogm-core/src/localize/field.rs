//! The map as the matcher sees it: a read-only view of log-odds cells, the ramp that turns a
//! cell's log-odds into a map value, and bilinear samples (with gradient) of the max-pooled
//! pyramid levels, computed on the fly.
//!
//! Positions are in sub-cells ([`SUB`] per cell) from the grid's lower-left corner. A cell's
//! value sits at its centre, so a sample at `u` interpolates between the centres around it:
//! `u − ½` cell, floored, is the lower-left corner of the four.

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

    /// Quadratic B-spline sample of level `level` at a sub-cell position of the grid: the value
    /// and gradient of `Σ wᵢ(u) wⱼ(v) d(c+i, r+j)` over the 3 × 3 level cells around the one that
    /// contains the position, where `d` is the map value dilated by `reach` level cells (see
    /// [`dilate`]). `None` if the cells it needs are not all inside the grid. Reads
    /// `(3 + 2·reach)² · 4^level` cells.
    ///
    /// Why a B-spline and not bilinear interpolation (Hector's): with bilinear interpolation a
    /// wall two cells thick is a flat plateau between their centres (a pose anywhere on it is as
    /// good) and a point more than one cell away feels no pull. The quadratic B-spline is C¹,
    /// peaks midway on a two-cell wall, and pulls from 1.5 cells away.
    #[inline]
    pub(crate) fn sample(&self, gx: i32, gy: i32, level: u8, reach: u8) -> Option<Sample> {
        let k = u32::from(level.min(MAX_LEVEL));
        let r = i32::from(reach.min(MAX_REACH));
        let (u, v) = (gx >> k, gy >> k);
        // The level cell containing the position and the offset within it, Q8.
        let (i, j) = (u >> 8, v >> 8);
        let (tx, ty) = (u & 0xFF, v & 0xFF);
        let n = 1i32 << k; // grid cells per level cell
        let side = 3 + 2 * r; // level cells per side of the block read
        let (x0, y0) = (
            i.checked_sub(1 + r)?.checked_mul(n)?,
            j.checked_sub(1 + r)?.checked_mul(n)?,
        );
        if x0 < 0 || y0 < 0 || x0 > self.w - side * n || y0 > self.h - side * n {
            return None;
        }
        let mut block = [[0i32; BLOCK]; BLOCK];
        self.read_block(x0, y0, n as usize, side as usize, &mut block)?;
        let m = dilate(&block, r as usize);
        let (wx, dx) = spline_weights(tx);
        let (wy, dy) = spline_weights(ty);
        // Rows: value (Q15 · Q15 weights → Q30 → Q15) and x-derivative (Q15 · Q8 → Q23 → Q15).
        let mut rv = [0i32; 3];
        let mut rd = [0i32; 3];
        for ((row, v), d) in m.iter().zip(rv.iter_mut()).zip(rd.iter_mut()) {
            let [a, b, c] = *row;
            *v = (a * wx[0] + b * wx[1] + c * wx[2]) >> 15;
            *d = (a * dx[0] + b * dx[1] + c * dx[2]) >> 8;
        }
        let mv = (rv[0] * wy[0] + rv[1] * wy[1] + rv[2] * wy[2]) >> 15;
        let mx = (rd[0] * wy[0] + rd[1] * wy[1] + rd[2] * wy[2]) >> 15;
        let my = (rv[0] * dy[0] + rv[1] * dy[1] + rv[2] * dy[2]) >> 8;
        Some(Sample {
            m: mv,
            dx: mx,
            dy: my,
        })
    }

    /// The ramped maxima of the `side × side` blocks of `n × n` grid cells from (`x0`, `y0`)
    /// (inside the grid) into `out[row][column]`, from the lower left.
    fn read_block(
        &self,
        x0: i32,
        y0: i32,
        n: usize,
        side: usize,
        out: &mut [[i32; BLOCK]; BLOCK],
    ) -> Option<()> {
        let w = self.w as usize;
        if n == 1 {
            for (r, orow) in out.iter_mut().take(side).enumerate() {
                let start = (y0 as usize + r) * w + x0 as usize;
                let row = self.cells.get(start..start + side)?;
                for (o, l) in orow.iter_mut().zip(row) {
                    *o = self.ramp.value(l.0);
                }
            }
            return Some(());
        }
        let mut q = [[i16::MIN; BLOCK]; BLOCK];
        for r in 0..side * n {
            let start = (y0 as usize + r) * w + x0 as usize;
            let row = self.cells.get(start..start + side * n)?;
            let qrow = q.get_mut(r / n)?;
            for (slot, b) in qrow.iter_mut().zip(row.chunks_exact(n)) {
                let m = b.iter().map(|l| l.0).max().unwrap_or(i16::MIN);
                *slot = (*slot).max(m);
            }
        }
        for (orow, qrow) in out.iter_mut().zip(q).take(side) {
            for (o, l) in orow.iter_mut().zip(qrow).take(side) {
                *o = self.ramp.value(l);
            }
        }
        Some(())
    }
}

/// The largest dilation reach, level cells.
pub const MAX_REACH: u8 = 3;

/// Side of the largest block a sample reads, level cells.
const BLOCK: usize = 3 + 2 * MAX_REACH as usize;

/// The 3 × 3 values at the centre of `block` (side `3 + 2·reach`), each the maximum over the
/// cells within `reach` (L1 distance `d`) of `value − d · ONE / (reach + 1)`, at least 0:
/// a dilation whose value falls off linearly with distance, separable (rows, then columns).
///
/// Why: the robot's own map of a wall seen from a metre or two away is a dotted line (one beam
/// a degree apart hits every few cells at range), and a point of the next scan often falls
/// between the dots. Dilating bridges the gaps and widens the basin without shifting the wall
/// (block-aligned pooling shifts it by up to half a block).
fn dilate(block: &[[i32; BLOCK]; BLOCK], reach: usize) -> [[i32; 3]; 3] {
    let mut out = [[0i32; 3]; 3];
    if reach == 0 {
        for (o, b) in out.iter_mut().zip(block) {
            for (x, y) in o.iter_mut().zip(b) {
                *x = *y;
            }
        }
        return out;
    }
    let step = ONE / (reach as i32 + 1);
    let side = 3 + 2 * reach;
    // Along rows: h[r][c] for the three centre columns.
    let mut h = [[0i32; 3]; BLOCK];
    for (hr, br) in h.iter_mut().zip(block).take(side) {
        for (c, hc) in hr.iter_mut().enumerate() {
            let mut best = 0;
            for (d, v) in br.iter().skip(c).take(2 * reach + 1).enumerate() {
                let dist = (d as i32 - reach as i32).abs();
                best = best.max(v - dist * step);
            }
            *hc = best;
        }
    }
    // Along columns.
    for (r, orow) in out.iter_mut().enumerate() {
        for (c, o) in orow.iter_mut().enumerate() {
            let mut best = 0;
            for (d, hr) in h.iter().skip(r).take(2 * reach + 1).enumerate() {
                let dist = (d as i32 - reach as i32).abs();
                if let Some(v) = hr.get(c) {
                    best = best.max(v - dist * step);
                }
            }
            *o = best;
        }
    }
    out
}

/// Quadratic B-spline weights (Q15, summing to 2^15) and their derivatives per cell (Q8) for the
/// cells left of, at and right of the one containing the position, whose offset from that cell's
/// lower edge is `t` (Q8, 0..256): `w = ((1−t)²/2, ½ + t − t², t²/2)`, `w' = (t − 1, 1 − 2t, t)`.
#[inline(always)]
fn spline_weights(t: i32) -> ([i32; 3], [i32; 3]) {
    let s = 256 - t;
    // s² is (1−t)² in Q16; (1−t)²/2 in Q15 is s²/4.
    let a = (s * s) >> 2;
    let c = (t * t) >> 2;
    ([a, (1 << 15) - a - c, c], [-s, s - t, t])
}
