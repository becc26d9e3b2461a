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
//!
//! One file per part: `clip` ([`Ray::clip`]), `walk` (walking a ray's steps by grid index:
//! [`Ray::for_each_index`], the mapper's `IndexWalk` and `GridRay`) and `mark` (setting a
//! walk's cells in a bitset, run by run where that is cheaper).

mod clip;
mod mark;
mod walk;

pub(crate) use walk::{GridRay, IndexWalk};

use crate::types::geometry::CellCoord;
use core::num::{NonZeroU128, NonZeroU32, NonZeroU64};

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

    /// `(q, r)` with `2i·a + N = q·2N + r`, `0 ≤ r < 2N`: `q` is the minor offset of step `i`, `r`
    /// the Bresenham remainder there. `(0, 0)` for `N = 0`.
    ///
    /// Uses the narrowest division that holds the operands: `i = 0` needs none, rays of up to
    /// 46 000 steps fit `u32` (one `udiv` on a Cortex-M4), and only absurd (hostile) coordinates
    /// reach the `u128` fallback.
    #[inline]
    fn quot_rem(&self, i: u64) -> (u64, u64) {
        let n = self.n;
        // n < 2^33 (coordinates are i32), so 2n and 2a fit a u64. A non-zero divisor by type:
        // no division-by-zero panic path in the binary.
        let Some(two_n) = NonZeroU64::new(2 * n) else {
            return (0, 0);
        };
        if i == 0 {
            return (0, n);
        }
        let two_a = 2 * self.minor_delta;
        match i.checked_mul(two_a).and_then(|p| p.checked_add(n)) {
            Some(num) => match (u32::try_from(num), NonZeroU32::try_from(two_n)) {
                (Ok(num), Ok(den)) => (u64::from(num / den), u64::from(num % den)),
                _ => (num / two_n, num % two_n),
            },
            None => {
                let num = u128::from(i) * u128::from(two_a) + u128::from(n);
                let den = NonZeroU128::from(two_n);
                // q ≤ i (as a ≤ N) and r < 2N: both fit a u64.
                ((num / den) as u64, (num % den) as u64)
            }
        }
    }

    /// The cell `major` steps along the major axis and `minor` along the minor one (saturating
    /// at the `i32` range).
    #[inline]
    fn cell_at_offsets(&self, major: u64, minor: u64) -> CellCoord {
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

    /// The cell at step `i` (any `i`, even past the end: the line continues).
    pub fn cell_at(&self, i: u64) -> CellCoord {
        if self.n == 0 {
            return self.start;
        }
        self.cell_at_offsets(i, self.quot_rem(i).0)
    }
}

#[cfg(test)]
impl Ray {
    /// The original, all-`u128`/`i128` `cell_at`.
    pub(crate) fn cell_at_reference(&self, i: u64) -> CellCoord {
        let (major, minor) = if self.n == 0 {
            (0, 0)
        } else {
            let q = (u128::from(i) * 2 * u128::from(self.minor_delta) + u128::from(self.n))
                / (2 * u128::from(self.n));
            (i, q as u64)
        };
        let (ox, oy) = if self.x_major {
            (major, minor)
        } else {
            (minor, major)
        };
        let off = |start: i32, sign: i32, k: u64| {
            let v = i128::from(start) + i128::from(sign) * i128::from(k);
            v.clamp(i128::from(i32::MIN), i128::from(i32::MAX)) as i32
        };
        CellCoord {
            x: off(self.start.x, self.step_x, ox),
            y: off(self.start.y, self.step_y, oy),
        }
    }
}

/// `start + sign·k`, saturated to the `i32` range.
#[inline]
fn offset(start: i32, sign: i32, k: u64) -> i32 {
    // The common case in 32-bit arithmetic.
    if let Ok(k) = i32::try_from(k) {
        let v = if sign > 0 {
            start.checked_add(k)
        } else {
            start.checked_sub(k)
        };
        if let Some(v) = v {
            return v;
        }
    }
    // k > i64::MAX lies beyond the i32 range in the direction of `sign` anyway.
    let k = i64::try_from(k).unwrap_or(i64::MAX);
    let v = if sign > 0 {
        i64::from(start).saturating_add(k)
    } else {
        i64::from(start).saturating_sub(k)
    };
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    pub(super) fn c(x: i32, y: i32) -> CellCoord {
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

    /// Any coordinates, from tiny to the whole i32 range.
    pub(super) fn coord() -> impl Strategy<Value = i32> {
        prop_oneof![
            -300i32..300,
            -70_000i32..70_000,
            any::<i32>(),
            Just(i32::MIN),
            Just(i32::MAX),
        ]
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
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// `cell_at` with narrow divisions equals the original u128 one, at any step (even past
        /// the end, and at absurd step numbers).
        #[test]
        fn cell_at_matches_u128_reference(x0 in coord(), y0 in coord(), x1 in coord(), y1 in coord(),
                                          i in prop_oneof![0u64..1000, 0u64..(1 << 34), any::<u64>()]) {
            let r = Ray::new(c(x0, y0), c(x1, y1));
            prop_assert_eq!(r.cell_at(i), r.cell_at_reference(i));
            prop_assert_eq!(r.cell_at(r.steps()), r.cell_at_reference(r.steps()));
        }
    }
}
