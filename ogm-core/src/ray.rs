//! Integer ray traversal (Bresenham, in closed form).
//!
//! A ray from cell `a` to cell `b` visits `N + 1` cells, `N = max(|Δx|, |Δy|)`: step `i` moves one
//! cell along the major axis, and the minor coordinate is `round(i · |Δminor| / N)` (halves round
//! up), which is exactly the cell sequence of Bresenham's algorithm. Writing it in closed form
//! buys two things:
//! * **clipping** is exact and cheap: the steps whose cells lie inside the grid form one interval
//!   that [`Ray::clip`] solves for with integer arithmetic, so a ray that starts or ends far outside
//!   the map costs no more than its visible part, however long it is;
//! * **random access**: [`Ray::cell_at`] gives any step's cell, which the sampler uses to find
//!   where a stored ray crosses a patch.
//!
//! Each step advances one cell along the major axis, so the Euclidean distance of step `i` from
//! the start is `i · len / N` with `len/N ∈ [1, √2]` — the forward sensor model uses that scale.

use crate::geometry::CellCoord;

/// A ray between two cells (either may lie outside the grid).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ray {
    start: CellCoord,
    /// Number of steps `N`; the ray has `N + 1` cells.
    n: u64,
    /// |Δ| along the minor axis (≤ n).
    minor_delta: u64,
    step_x: i32,
    step_y: i32,
    x_major: bool,
}

/// An inclusive range of step indices `first..=last`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Steps {
    /// First step.
    pub first: u64,
    /// Last step (inclusive).
    pub last: u64,
}

impl Ray {
    /// The ray from `from` to `to`.
    pub fn new(from: CellCoord, to: CellCoord) -> Ray {
        let dx = i64::from(to.x) - i64::from(from.x);
        let dy = i64::from(to.y) - i64::from(from.y);
        let (ax, ay) = (dx.unsigned_abs(), dy.unsigned_abs());
        let x_major = ax >= ay;
        Ray {
            start: from,
            n: ax.max(ay),
            minor_delta: if x_major { ay } else { ax },
            step_x: if dx < 0 { -1 } else { 1 },
            step_y: if dy < 0 { -1 } else { 1 },
            x_major,
        }
    }

    /// Number of steps `N` (the ray's last cell is step `N`).
    #[inline]
    pub const fn steps(&self) -> u64 {
        self.n
    }

    /// First cell.
    #[inline]
    pub const fn start(&self) -> CellCoord {
        self.start
    }

    /// `(major, minor)` offset of step `i` from the start (both ≥ 0, before applying signs).
    #[inline]
    fn offsets(&self, i: u64) -> (u64, u64) {
        if self.n == 0 {
            return (0, 0);
        }
        // u128: i · 2·minor_delta can exceed u64 for absurd (hostile) coordinates.
        let q = (u128::from(i) * 2 * u128::from(self.minor_delta) + u128::from(self.n))
            / (2 * u128::from(self.n));
        (i, q as u64)
    }

    /// The cell at step `i` (any `i`, even past the end: the line continues).
    pub fn cell_at(&self, i: u64) -> CellCoord {
        let (major, minor) = self.offsets(i);
        let (ox, oy) = if self.x_major {
            (major, minor)
        } else {
            (minor, major)
        };
        CellCoord {
            x: offset(self.start.x, self.step_x, ox),
            y: offset(self.start.y, self.step_y, oy),
        }
    }

    /// The steps (within `0..=N`) whose cells lie in `[0, width) × [0, height)`, or `None` if the
    /// ray misses the grid. Exact: a step is in the result iff its cell is inside.
    pub fn clip(&self, width: u16, height: u16) -> Option<Steps> {
        let (major_start, major_step, major_len, minor_start, minor_step, minor_len) =
            if self.x_major {
                (
                    self.start.x,
                    self.step_x,
                    width,
                    self.start.y,
                    self.step_y,
                    height,
                )
            } else {
                (
                    self.start.y,
                    self.step_y,
                    height,
                    self.start.x,
                    self.step_x,
                    width,
                )
            };
        // Major axis: coordinate = s + sign·i must be in [0, len-1].
        let (lo, hi) = axis_interval(major_start, major_step, major_len);
        // Minor axis: offset q(i) must be in [qlo, qhi].
        let (qlo, qhi) = axis_interval(minor_start, minor_step, minor_len);
        let n = i128::from(self.n);
        let (mut first, mut last) = (lo.max(0), hi.min(n));
        if self.n == 0 || self.minor_delta == 0 {
            if !(qlo <= 0 && 0 <= qhi) {
                return None;
            }
        } else {
            // q(i) = floor((2ia + N) / 2N) ≥ qlo  ⟺  i ≥ ceil((2N·qlo − N) / 2a)
            // q(i) ≤ qhi                          ⟺  i ≤ ceil((2N·(qhi+1) − N) / 2a) − 1
            let a2 = 2 * i128::from(self.minor_delta);
            first = first.max(ceil_div(2 * n * qlo - n, a2));
            last = last.min(ceil_div(2 * n * (qhi + 1) - n, a2) - 1);
        }
        if first > last || last < 0 {
            return None;
        }
        Some(Steps {
            first: first as u64,
            last: last as u64,
        })
    }

    /// Calls `f(step, row_major_index)` for every step in `steps`, in order. The caller must have
    /// obtained `steps` from [`Ray::clip`] with the same `width`/`height`, so every index is inside
    /// a `width × height` grid; this is the mapper's hot loop and does no bounds checks of its own
    /// (indexing with the result is still checked by the caller).
    #[inline]
    pub fn for_each_index(&self, steps: Steps, width: u16, mut f: impl FnMut(u64, usize)) {
        self.walk(steps, width, |i, idx| {
            f(i, idx);
            true
        });
    }

    /// [`Ray::for_each_index`] that stops as soon as `f` returns `false`.
    #[inline]
    fn walk(&self, steps: Steps, width: u16, mut f: impl FnMut(u64, usize) -> bool) {
        let w = width as isize;
        let (major_stride, minor_stride) = if self.x_major {
            (self.step_x as isize, self.step_y as isize * w)
        } else {
            (self.step_y as isize * w, self.step_x as isize)
        };
        let c = self.cell_at(steps.first);
        // In-grid (the steps come from `clip`), so this fits an isize; every later full step is
        // in-grid too, so the running index never overflows.
        let mut index = c.y as isize * w + c.x as isize;
        // Coordinates are i32, so N < 2^33 and 2N, 2a, rem + 2a all fit a u64.
        let (two_n, two_a) = (2 * self.n, 2 * self.minor_delta);
        // Remainder of (2ia + N) / 2N at the first step; the minor offset increments when it
        // reaches 2N.
        let mut rem = if self.n == 0 {
            0
        } else {
            ((u128::from(steps.first) * u128::from(two_a) + u128::from(self.n)) % u128::from(two_n))
                as u64
        };
        let mut i = steps.first;
        loop {
            if !f(i, index as usize) || i >= steps.last {
                break;
            }
            i += 1;
            index += major_stride;
            rem += two_a;
            if rem >= two_n {
                rem -= two_n;
                index += minor_stride;
            }
        }
    }
}

impl Ray {
    /// The first step in `steps` (from [`Ray::clip`] with the same `width`) whose row-major
    /// index satisfies `pred`, walking in ray order and stopping there.
    #[inline]
    pub fn find_step(
        &self,
        steps: Steps,
        width: u16,
        mut pred: impl FnMut(usize) -> bool,
    ) -> Option<u64> {
        let mut found = None;
        self.walk(steps, width, |i, idx| {
            if pred(idx) {
                found = Some(i);
                false
            } else {
                true
            }
        });
        found
    }
}

/// Interval of offsets `k ≥ ?` such that `start + sign·k ∈ [0, len − 1]`.
fn axis_interval(start: i32, sign: i32, len: u16) -> (i128, i128) {
    let s = i128::from(start);
    let l = i128::from(len) - 1;
    if sign > 0 {
        (-s, l - s)
    } else {
        (s - l, s)
    }
}

fn offset(start: i32, sign: i32, k: u64) -> i32 {
    let v = i128::from(start) + i128::from(sign) * i128::from(k);
    v.clamp(i128::from(i32::MIN), i128::from(i32::MAX)) as i32
}

/// ⌈p / q⌉ for q > 0.
fn ceil_div(p: i128, q: i128) -> i128 {
    -((-p).div_euclid(q))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn c(x: i32, y: i32) -> CellCoord {
        CellCoord { x, y }
    }

    #[test]
    fn textbook_cases() {
        let r = Ray::new(c(0, 0), c(5, 2));
        let cells: [CellCoord; 6] = core::array::from_fn(|i| r.cell_at(i as u64));
        assert_eq!(
            cells,
            [c(0, 0), c(1, 0), c(2, 1), c(3, 1), c(4, 2), c(5, 2)]
        );
        let r = Ray::new(c(3, 3), c(3, 3));
        assert_eq!(r.steps(), 0);
        assert_eq!(r.clip(10, 10), Some(Steps { first: 0, last: 0 }));
        assert_eq!(r.clip(3, 10), None);
        let r = Ray::new(c(0, 0), c(-4, 0));
        assert_eq!(r.cell_at(4), c(-4, 0));
        assert_eq!(r.clip(10, 10), Some(Steps { first: 0, last: 0 }));
    }

    #[test]
    fn ray_from_far_outside_is_clipped_cheaply() {
        let r = Ray::new(c(-2_000_000_000, 5), c(2_000_000_000, 6));
        let s = r.clip(100, 100).unwrap();
        assert_eq!(s.last - s.first, 99);
        let mut n = 0;
        r.for_each_index(s, 100, |_, idx| {
            assert!(idx < 100 * 100);
            n += 1;
        });
        assert_eq!(n, 100);
    }

    fn brute_force(r: &Ray, w: u16, h: u16) -> Vec<(u64, usize)> {
        (0..=r.steps())
            .filter_map(|i| {
                let cc = r.cell_at(i);
                (cc.x >= 0 && cc.y >= 0 && cc.x < i32::from(w) && cc.y < i32::from(h))
                    .then(|| (i, cc.y as usize * w as usize + cc.x as usize))
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Consecutive cells are 8-neighbours, the ray ends at its end cell, and has N+1 cells.
        #[test]
        fn connected_and_exact_endpoints(x0 in -300i32..300, y0 in -300i32..300, x1 in -300i32..300, y1 in -300i32..300) {
            let r = Ray::new(c(x0, y0), c(x1, y1));
            prop_assert_eq!(r.steps(), (x1 - x0).unsigned_abs().max((y1 - y0).unsigned_abs()) as u64);
            prop_assert_eq!(r.cell_at(0), c(x0, y0));
            prop_assert_eq!(r.cell_at(r.steps()), c(x1, y1));
            for i in 0..r.steps() {
                let (p, q) = (r.cell_at(i), r.cell_at(i + 1));
                prop_assert!((p.x - q.x).abs() <= 1 && (p.y - q.y).abs() <= 1 && p != q);
            }
        }

        /// Each cell lies within half a cell (perpendicular to the major axis) of the ideal line.
        #[test]
        fn close_to_the_ideal_line(x1 in -200i32..200, y1 in -200i32..200) {
            let r = Ray::new(c(0, 0), c(x1, y1));
            let n = r.steps() as f64;
            for i in 0..=r.steps() {
                let p = r.cell_at(i);
                let t = if n == 0.0 { 0.0 } else { i as f64 / n };
                let (ix, iy) = (t * f64::from(x1), t * f64::from(y1));
                prop_assert!((f64::from(p.x) - ix).abs() <= 0.5 + 1e-9);
                prop_assert!((f64::from(p.y) - iy).abs() <= 0.5 + 1e-9);
            }
        }

        /// Clipping plus incremental traversal visits exactly the in-grid cells of the full ray.
        #[test]
        fn clip_matches_brute_force(x0 in -80i32..120, y0 in -80i32..120, x1 in -80i32..120, y1 in -80i32..120,
                                    w in 1u16..60, h in 1u16..60) {
            let r = Ray::new(c(x0, y0), c(x1, y1));
            let want = brute_force(&r, w, h);
            let mut got = Vec::new();
            if let Some(s) = r.clip(w, h) {
                r.for_each_index(s, w, |i, idx| got.push((i, idx)));
            }
            prop_assert_eq!(got, want);
        }
    }
}
