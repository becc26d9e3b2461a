//! Bresenham rays in the closed form of [`crate::map::ray`], specialised to the sampler's short rays.
//!
//! Step `i` of the ray `s → e` is the cell with major coordinate `s + σ·i` and minor coordinate
//! `s' + σ'·⌊(2ia + n) / 2n⌋` (`n` = major extent, `a` = minor extent) — exactly
//! [`crate::map::ray::Ray::cell_at`]. Stored rays are at most [`MAX_STEPS`] = 2¹⁵ long (the ray store
//! enforces it), so `2ia + n < 2³¹` and the per-step arithmetic is 32-bit with one hardware
//! division (64-bit division is a library call on a Cortex-M4); only clipping against far-away
//! boxes uses `i64`.

use crate::types::geometry::CellCoord;

use crate::sampler::ray_store::MAX_STEPS;

/// A ray from `start` over `n` steps (16 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    pub(crate) start: CellCoord,
    n: u16,
    a: u16,
    sx: i8,
    sy: i8,
    x_major: bool,
}

/// √(1 + (i/256)²) in Q12 for i = 0 ..= 256.
static STEP_TABLE: [u16; 257] = build_step_table();

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_step_table() -> [u16; 257] {
    let mut t = [0u16; 257];
    let mut i = 0;
    while i <= 256 {
        let r = i as f64 / 256.0;
        let v = 1.0 + r * r; // in [1, 2]: Newton from 1.5 converges in a few steps
        let mut x = 1.25;
        let mut k = 0;
        while k < 8 {
            x = 0.5 * (x + v / x);
            k += 1;
        }
        t[i] = (x * 4096.0 + 0.5) as u16;
        i += 1;
    }
    t
}

/// ⌈p / q⌉ for q > 0.
#[inline]
fn ceil_div(p: i64, q: i64) -> i64 {
    -((-p).div_euclid(q))
}

impl Segment {
    /// The ray `s → e`; extents are clamped to [`MAX_STEPS`] (callers never exceed it).
    #[inline]
    pub(crate) fn new(s: CellCoord, e: CellCoord) -> Segment {
        let (dx, dy) = (
            i64::from(e.x) - i64::from(s.x),
            i64::from(e.y) - i64::from(s.y),
        );
        let cap = u64::from(MAX_STEPS);
        let (ax, ay) = (
            dx.unsigned_abs().min(cap) as u16,
            dy.unsigned_abs().min(cap) as u16,
        );
        Segment {
            start: s,
            n: ax.max(ay),
            a: ax.min(ay),
            sx: if dx < 0 { -1 } else { 1 },
            sy: if dy < 0 { -1 } else { 1 },
            x_major: ax >= ay,
        }
    }

    /// Number of steps (the far end is step `n`).
    #[inline]
    pub(crate) fn n(&self) -> u32 {
        u32::from(self.n)
    }

    /// Length of one step in cells, Q12 (4096 = 1, up to √2 = 5793): √(1 + (a/n)²) from a
    /// 257-entry table indexed by a/n in Q8, interpolated (error < 2·10⁻⁵).
    #[inline]
    pub(crate) fn step_q12(&self) -> u16 {
        if self.n == 0 {
            return 4096;
        }
        let r = (u32::from(self.a) << 16) / u32::from(self.n); // a/n in Q16, ≤ 65536
        let (i, frac) = ((r >> 8) as usize, (r & 0xFF) as i32);
        let lo = i32::from(STEP_TABLE.get(i).copied().unwrap_or(5793));
        let hi = i32::from(STEP_TABLE.get(i + 1).copied().unwrap_or(5793));
        (lo + (((hi - lo) * frac + 128) >> 8)) as u16
    }

    /// (⌊(2ia + n) / 2n⌋, (2ia + n) mod 2n): the minor offset of step `i ≤ n` and the
    /// Bresenham error term, from one 32-bit division.
    #[inline]
    fn minor(&self, i: u32) -> (u32, u32) {
        let (n, a) = (u32::from(self.n), u32::from(self.a));
        if n == 0 {
            return (0, 0);
        }
        let i = i.min(n);
        let (num, den) = (2 * i * a + n, 2 * n);
        let q = num / den;
        (q, num - q * den)
    }

    /// The cell of step `i` (0 ..= n).
    #[cfg(test)]
    pub(crate) fn cell_at(&self, i: u32) -> CellCoord {
        self.cell_from(i.min(self.n()), self.minor(i).0)
    }

    #[inline]
    fn cell_from(&self, major: u32, minor: u32) -> CellCoord {
        let (ox, oy) = if self.x_major {
            (major, minor)
        } else {
            (minor, major)
        };
        CellCoord {
            x: self
                .start
                .x
                .wrapping_add(i32::from(self.sx).wrapping_mul(ox as i32)),
            y: self
                .start
                .y
                .wrapping_add(i32::from(self.sy).wrapping_mul(oy as i32)),
        }
    }

    /// `(start, sign)` of the major and minor axes.
    #[inline]
    fn axes(&self) -> ((i32, i32), (i32, i32)) {
        let (sx, sy) = (i32::from(self.sx), i32::from(self.sy));
        if self.x_major {
            ((self.start.x, sx), (self.start.y, sy))
        } else {
            ((self.start.y, sy), (self.start.x, sx))
        }
    }

    /// Steps (within `0..=n`) whose major coordinate lies in `[lo, hi]` (major-axis coordinates).
    #[inline]
    fn major_steps(&self, lo: i32, hi: i32) -> Option<(u32, u32)> {
        let ((s, sign), _) = self.axes();
        let (a, b) = (
            i64::from(sign) * i64::from(lo - s),
            i64::from(sign) * i64::from(hi - s),
        );
        let (a, b) = (a.min(b).max(0), a.max(b).min(i64::from(self.n())));
        (a <= b).then_some((a as u32, b as u32))
    }

    /// Steps whose major coordinate is within `h` of `c`'s (at most 2h + 1 of them); the cells
    /// of the (2h+1)² box around `c` that the ray visits are among these.
    #[inline]
    pub(crate) fn major_range(&self, c: CellCoord, h: i32) -> Option<(u32, u32)> {
        let m = if self.x_major { c.x } else { c.y };
        self.major_steps(m - h, m + h)
    }

    /// The exact steps inside the box `[x0, x1] × [y0, y1]`: a step is in the result iff its
    /// cell is in the box (the steps inside a box are contiguous).
    pub(crate) fn clip(&self, x0: i32, y0: i32, x1: i32, y1: i32) -> Option<(u32, u32)> {
        let (mlo, mhi, nlo, nhi) = if self.x_major {
            (x0, x1, y0, y1)
        } else {
            (y0, y1, x0, x1)
        };
        let (mut first, mut last) = self.major_steps(mlo, mhi)?;
        let (_, (s, sign)) = self.axes();
        // Minor offset q must satisfy s + sign·q ∈ [nlo, nhi].
        let (q0, q1) = (
            i64::from(sign) * i64::from(nlo - s),
            i64::from(sign) * i64::from(nhi - s),
        );
        let (qlo, qhi) = (q0.min(q1), q0.max(q1));
        if self.n == 0 || self.a == 0 {
            if !(qlo <= 0 && 0 <= qhi) {
                return None;
            }
        } else {
            // q(i) ≥ qlo ⟺ i ≥ ⌈(2n·qlo − n) / 2a⌉;  q(i) ≤ qhi ⟺ i ≤ ⌈(2n·(qhi+1) − n) / 2a⌉ − 1
            let (n, a2) = (i64::from(self.n()), 2 * i64::from(self.a));
            let lo = ceil_div(2 * n * qlo - n, a2).max(0);
            let hi = ceil_div(2 * n * (qhi + 1) - n, a2) - 1;
            first = first.max(lo.min(i64::from(u32::MAX)) as u32);
            if hi < 0 {
                return None;
            }
            last = last.min(hi.min(i64::from(u32::MAX)) as u32);
        }
        (first <= last).then_some((first, last))
    }

    /// Calls `f(step, cell)` for steps `first..=last` (clamped to `n`) in order, incrementally
    /// (one division in all), until `f` returns `false`.
    #[inline]
    pub(crate) fn walk(&self, first: u32, last: u32, mut f: impl FnMut(u32, CellCoord) -> bool) {
        if first > last {
            return;
        }
        let last = last.min(self.n());
        let (q, mut rem) = self.minor(first);
        let mut c = self.cell_from(first, q);
        let (two_n, two_a) = (2 * self.n(), 2 * u32::from(self.a));
        let mut i = first;
        loop {
            if !f(i, c) || i >= last {
                return;
            }
            i += 1;
            rem += two_a;
            let bump = rem >= two_n;
            if bump {
                rem -= two_n;
            }
            let (sx, sy) = (i32::from(self.sx), i32::from(self.sy));
            if self.x_major {
                c.x += sx;
                if bump {
                    c.y += sy;
                }
            } else {
                c.y += sy;
                if bump {
                    c.x += sx;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::ray::Ray;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// Same cells as the general `Ray`, same exact clipping, same incremental walk.
        #[test]
        fn matches_ray(x0 in -90i32..90, y0 in -90i32..90, x1 in -90i32..90, y1 in -90i32..90,
                       bx in -20i32..40, by in -20i32..40, bw in 0i32..30, bh in 0i32..30) {
            let (s, e) = (CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let (seg, ray) = (Segment::new(s, e), Ray::new(s, e));
            prop_assert_eq!(u64::from(seg.n()), ray.steps());
            for i in 0..=seg.n() {
                prop_assert_eq!(seg.cell_at(i), ray.cell_at(u64::from(i)));
            }
            let inside: Vec<u32> = (0..=seg.n())
                .filter(|&i| { let c = seg.cell_at(i); c.x >= bx && c.x <= bx + bw && c.y >= by && c.y <= by + bh })
                .collect();
            let want = inside.first().map(|&f| (f, *inside.last().unwrap()));
            prop_assert_eq!(seg.clip(bx, by, bx + bw, by + bh), want);
            if seg.n() > 0 {
                let len = (f64::from(x1 - x0).powi(2) + f64::from(y1 - y0).powi(2)).sqrt();
                let want = len / f64::from(seg.n()) * 4096.0;
                prop_assert!((f64::from(seg.step_q12()) - want).abs() <= 1.0, "{} vs {}", seg.step_q12(), want);
            }
            let mut walked = Vec::new();
            seg.walk(0, seg.n(), |i, c| { walked.push((i, c)); true });
            prop_assert_eq!(walked, (0..=seg.n()).map(|i| (i, seg.cell_at(i))).collect::<Vec<_>>());
        }
    }
}
