//! The face refine: Gauss–Newton that puts each point on the face of its wall, where the map's
//! log-odds change sign, after the NDT passes (see the [module docs](crate::localize)).
//!
//! Why: under a range noise of several cells (the robot's face band, σ = 3 cells) a wall in the
//! log-odds map is a slab 6–9 cells thick whose cells all saturate; the NDT window of a point
//! inside the slab is flat (no pull) and its centroid lies in the slab, not on the face. The
//! sign change is where the surface is (the face band's expected update changes sign there), it
//! is as sharp as the evidence allows, and its slope does not vanish there: the residual is the
//! map's signed value at the point, bilinearly interpolated, with target 0.

use crate::localize::field::Field;
use crate::localize::matcher::{Frame, Normal, State, J_LIM};

/// Below this slope² (Q16 per cell²: 1/32 of the field per cell) a point has no face near.
const MIN_SLOPE2: i64 = 64;

/// The face field of a grid: log-odds scaled to `±FACE_ONE` (clamped) at `±scale`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FaceField {
    /// `2^24 / scale`: `l · inv >> 16` is `l · 256 / scale`.
    inv: i32,
}

impl FaceField {
    /// The field saturating at `scale` log-odds (at least 1).
    pub(crate) fn new(scale: i16) -> Self {
        FaceField {
            inv: (1i32 << 24) / i32::from(scale.max(1)),
        }
    }

    /// A cell's value, Q8 in `±FACE_ONE`.
    #[inline(always)]
    fn value(&self, raw: i16) -> i32 {
        // |raw| < 2^15, inv ≤ 2^24: the product fits an i64, the result is clamped.
        ((i64::from(raw) * i64::from(self.inv)) >> 16).clamp(-256, 256) as i32
    }

    /// The bilinearly interpolated value at a sub-cell position and its gradient (Q8 per cell):
    /// `(f, df/dx, df/dy)`; `None` if the four cells around it are not all inside the grid.
    /// Four reads.
    #[inline]
    pub(crate) fn at(&self, field: &Field<'_>, gx: i32, gy: i32) -> Option<(i32, i32, i32)> {
        // Cell centres lie at 128 sub-cells: the cell below-left of the position and the
        // position's fraction (Q8) towards the next centre.
        let (x, y) = (gx.checked_sub(128)?, gy.checked_sub(128)?);
        let (i, j) = (x >> 8, y >> 8);
        if i < 0 || j < 0 || i + 1 >= field.w || j + 1 >= field.h {
            return None;
        }
        let (ax, ay) = (x & 255, y & 255);
        let w = field.w as usize;
        let k = j as usize * w + i as usize;
        let row0 = field.cells.get(k..k + 2)?;
        let row1 = field.cells.get(k + w..k + w + 2)?;
        let (v00, v10) = (self.value(row0.first()?.0), self.value(row0.get(1)?.0));
        let (v01, v11) = (self.value(row1.first()?.0), self.value(row1.get(1)?.0));
        // Values ≤ 2^8, fractions ≤ 2^8: every product below 2^25.
        let bottom = (256 - ax) * v00 + ax * v10;
        let top = (256 - ax) * v01 + ax * v11;
        let f = ((256 - ay) * bottom + ay * top) >> 16;
        let dx = ((256 - ay) * (v10 - v00) + ay * (v11 - v01)) >> 8;
        let dy = (top - bottom) >> 8;
        Some((f, dx, dy))
    }

    /// The value of the cell containing a sub-cell position, 0 (unknown) outside the grid.
    #[inline(always)]
    fn nearest(&self, field: &Field<'_>, gx: i32, gy: i32) -> i32 {
        field.raw(gx, gy).map_or(0, |l| self.value(l))
    }

    /// How much a point at (`gx`, `gy`), seen along the beam (`rx`, `ry`) (the point relative
    /// to the robot, sub-cells), looks like it lies on a face: the value `reach` sub-cells
    /// behind it less the value as far in front (Q8, `±2·FACE_ONE`). A face within `reach` of
    /// the point scores up to 2 (occupied behind, free in front); inside a slab or in free
    /// space 0, unknown 0. Two reads.
    ///
    /// Why: the score of a point on a thick wall's cells is the same all across the slab; this
    /// one peaks where the wall's surface is, over a width of `2·reach` (the range noise).
    #[inline]
    pub(crate) fn score(&self, field: &Field<'_>, g: (i32, i32), r: (i32, i32), reach: i32) -> i32 {
        let (rx, ry) = (i64::from(r.0), i64::from(r.1));
        // |r| within 7 % (max + 3/8 min), at least one sub-cell.
        let (ax, ay) = (rx.abs(), ry.abs());
        let len = (ax.max(ay) + ((3 * ax.min(ay)) >> 3)).max(1);
        let q = (i64::from(reach) << 16) / len;
        let (ox, oy) = ((rx * q) >> 16, (ry * q) >> 16);
        // |o| ≤ reach ≤ 2^16: the positions stay within i32 of the point.
        let (ox, oy) = (ox as i32, oy as i32);
        let behind = self.nearest(field, g.0.saturating_add(ox), g.1.saturating_add(oy));
        let front = self.nearest(field, g.0.saturating_sub(ox), g.1.saturating_sub(oy));
        behind - front
    }
}

impl Frame<'_> {
    /// One face pass over every point at the grid's level: the normal equations in the NDT
    /// pass's units (Q28 per cell², the rotation as `φ = θ · 2^lever_k` cells), each point
    /// weighing `gain_q8 / 256` per unit of the field's slope². A point counts only where the
    /// field rises along its beam (from free towards occupied): the far side of a wall's slab
    /// and a hit from the wrong side of a wall do not pull.
    pub(crate) fn face_pass(
        &self,
        s: &State,
        ff: &FaceField,
        (gain_q8, cauchy_q8): (i32, i32),
        lever_k: u32,
    ) -> Normal {
        let (tx, ty, c, sn) = self.transform(s);
        let mut n = Normal::default();
        let (mut h00, mut h01, mut h02, mut h11, mut h12, mut h22) = (0i64, 0, 0, 0, 0, 0);
        let (mut b0, mut b1, mut b2) = (0i64, 0, 0);
        let gain = i64::from(gain_q8.clamp(0, 1 << 10));
        for p in self.points {
            let (px, py) = (i64::from(p.x), i64::from(p.y));
            let rx = ((px * c - py * sn) >> 30) as i32;
            let ry = ((px * sn + py * c) >> 30) as i32;
            let Some((f, fx, fy)) = ff.at(&self.field, tx + rx, ty + ry) else {
                continue;
            };
            if i64::from(fx) * i64::from(rx) + i64::from(fy) * i64::from(ry) <= 0 {
                continue;
            }
            // Point-to-face: the face's normal n = g/|g| and the distance to it along n,
            // d = f/|g| (the Newton step to the zero of the field), so that a point weighs the
            // same whatever the slope of its wall; no square root: n nᵀ = g gᵀ/|g|².
            let (gx, gy) = (i64::from(fx), i64::from(fy));
            let g2 = gx * gx + gy * gy;
            if g2 < MIN_SLOPE2 {
                continue;
            }
            // 2^32 / |g|², |g|² in Q16: |g|² ≥ 64 so this is at most 2^26.
            let inv = (1i64 << 32) / g2;
            let f64_ = i64::from(f);
            // d² in Q8 cells² (f² Q16 · inv >> 24).
            let d2 = (f64_ * f64_ * inv) >> 24;
            let c2 = i64::from(cauchy_q8.max(1));
            let robust = (c2 << 8) / (c2 + d2); // Q8
            n.used += 1;
            let lim = J_LIM as i32;
            let jx = i64::from((-ry >> lever_k).clamp(-lim, lim));
            let jy = i64::from((rx >> lever_k).clamp(-lim, lim));
            // dφ column: the slope along the point's motion, Q8 (|gt| ≤ |g| · 2^7).
            let gt = (gx * jx + gy * jy) >> 8;
            let r = -f64_;
            let wq = (gain * robust) >> 8; // Q8, ≤ 2^10
                                           // a·b/|g|² in Q16 (≤ 2^46 >> 16: |gt|² / |g|² ≤ 2^14·2^16), × weight Q8 >> 8,
                                           // << 12: Q28 (below 2^44 a point, 2^57 for 8192 points).
            let w = |a: i64, b: i64| ((((a * b * inv) >> 16) * wq) >> 8) << 12;
            h00 += w(gx, gx);
            h01 += w(gx, gy);
            h02 += w(gx, gt);
            h11 += w(gy, gy);
            h12 += w(gy, gt);
            h22 += w(gt, gt);
            b0 += w(gx, r);
            b1 += w(gy, r);
            b2 += w(gt, r);
        }
        n.h = [[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]];
        n.b = [b0, b1, b2];
        n
    }
}

impl Frame<'_> {
    /// The face score ([`FaceField::score`]) of every `stride`-th point at state `s`.
    pub(crate) fn face_score(&self, s: &State, ff: &FaceField, reach: i32, stride: usize) -> i64 {
        let (tx, ty, c, sn) = self.transform(s);
        let mut sum = 0i64;
        for p in self.points.iter().step_by(stride.max(1)) {
            let (px, py) = (i64::from(p.x), i64::from(p.y));
            let rx = ((px * c - py * sn) >> 30) as i32;
            let ry = ((px * sn + py * c) >> 30) as i32;
            sum += i64::from(ff.score(&self.field, (tx + rx, ty + ry), (rx, ry), reach));
        }
        sum
    }

    /// The face search: from `s`, the best of `2·turns + 1` headings `turn` apart (within
    /// `±win_th`), then the best of the `(2·shifts + 1)²` translations one cell apart (within
    /// `±win`) at that heading, scored on every `stride`-th point. A tie keeps the one nearer
    /// the start. Reads `2 · ⌈n / stride⌉` cells per candidate.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn face_search(
        &self,
        s: State,
        ff: &FaceField,
        reach: i32,
        stride: usize,
        (turns, turn, win_th): (i32, i32, i32),
        (shifts, win): (i32, i32),
    ) -> State {
        let mut best = s;
        let mut best_score = self.face_score(&s, ff, reach, stride);
        let start = s;
        for i in 1..=2 * turns {
            let j = if i % 2 == 1 { (i + 1) / 2 } else { -(i / 2) };
            let dth = start.dth.saturating_add(j.saturating_mul(turn));
            if dth.abs() > win_th {
                continue;
            }
            let c = State { dth, ..start };
            let v = self.face_score(&c, ff, reach, stride);
            if v > best_score {
                (best, best_score) = (c, v);
            }
        }
        let centre = best;
        for dy in -shifts..=shifts {
            for dx in -shifts..=shifts {
                if dx == 0 && dy == 0 {
                    continue;
                }
                let c = State {
                    dx: centre.dx.saturating_add(dx << 8).clamp(-win, win),
                    dy: centre.dy.saturating_add(dy << 8).clamp(-win, win),
                    ..centre
                };
                let v = self.face_score(&c, ff, reach, stride);
                if v > best_score {
                    (best, best_score) = (c, v);
                }
            }
        }
        best
    }
}
