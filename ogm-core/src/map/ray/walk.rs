//! Walking a ray's clipped steps by row-major index: the `u64` walk for any ray, and the 32-bit
//! [`IndexWalk`] the mapper runs (from [`Ray::index_walk`], or set up for a ray between two
//! cells of the grid by [`GridRay`]).

use super::{Ray, Steps};
use crate::types::geometry::CellCoord;

impl Ray {
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

    /// The 32-bit walk over `steps` (from [`Ray::clip`] with the same `width`), or `None` if
    /// `2N` or the number of steps does not fit an `i32`/`u32` (rays from more than 2^30 cells
    /// away; [`Ray::for_each_index`] still handles those).
    #[inline]
    pub(crate) fn index_walk(&self, steps: Steps, width: u16) -> Option<IndexWalk> {
        let two_n = i32::try_from(2 * self.n).ok()?;
        let left = u32::try_from(steps.last.saturating_sub(steps.first) + 1).ok()?;
        let (index, rem) = if steps.first == 0 {
            // The usual case (the walk starts at the ray's first cell): no division at all.
            let s = self.start;
            let index = (s.y as isize as usize)
                .wrapping_mul(usize::from(width))
                .wrapping_add(s.x as isize as usize);
            // quot_rem(0) = (0, N).
            (index, self.n)
        } else {
            let (index, (_, rem)) = self.index_at(steps.first, width);
            (index, rem)
        };
        let (major, minor) = self.strides(width);
        Some(IndexWalk {
            index,
            // rem < 2N ≤ i32::MAX.
            g: two_n - 1 - rem as i32,
            // 2a ≤ 2N.
            two_a: (2 * self.minor_delta) as i32,
            two_n,
            major,
            minor,
            left,
        })
    }

    /// [`Ray::for_each_index`] that stops as soon as `f` returns `false`.
    ///
    /// Two loops with the same sequence: [`IndexWalk`]'s 32-bit state whenever `2N` fits an
    /// `i32` (always for a ray between cells of a `u16` grid, and for any ray that crosses one
    /// from up to 2^30 cells away), which a 32-bit core keeps in registers; otherwise `u64`.
    #[inline(always)]
    fn walk(&self, steps: Steps, width: u16, mut f: impl FnMut(u64, usize) -> bool) {
        if let Some(mut wk) = self.index_walk(steps, width) {
            let mut k = 0u32;
            loop {
                if !f(steps.first.wrapping_add(u64::from(k)), wk.index) || wk.left <= 1 {
                    break;
                }
                wk.left -= 1;
                k = k.wrapping_add(1);
                wk.advance();
            }
            return;
        }
        self.walk_u64(steps, width, f);
    }

    /// [`Ray::walk`] with `u64` state, for any ray (the fallback when `2N` exceeds an `i32`).
    fn walk_u64(&self, steps: Steps, width: u16, mut f: impl FnMut(u64, usize) -> bool) {
        let (mut index, (_, mut rem)) = self.index_at(steps.first, width);
        let (major_stride, minor_stride) = self.strides(width);
        let (two_n, two_a) = (2 * self.n, 2 * self.minor_delta);
        // 2N < 2^34, so rem + 2a < 2^35 fits.
        let mut i = steps.first;
        loop {
            if !f(i, index) || i >= steps.last {
                break;
            }
            i += 1;
            index = index.wrapping_add(major_stride);
            rem += two_a;
            if rem >= two_n {
                rem -= two_n;
                index = index.wrapping_add(minor_stride);
            }
        }
    }

    /// Row-major index (in a grid `width` wide) and `(q, r)` (see [`Ray::quot_rem`]) of step
    /// `i`. Wrapping: only meaningful for in-grid cells, but panic-free for any input.
    // Out of line: a walk that starts past a ray's first cell is the rare case (a clipped ray),
    // and each inlined copy of its divisions costs ~1.4 KiB of flash on a Cortex-M4.
    #[inline(never)]
    fn index_at(&self, i: u64, width: u16) -> (usize, (u64, u64)) {
        let qr = self.quot_rem(i);
        let c = if self.n == 0 {
            self.start
        } else {
            self.cell_at_offsets(i, qr.0)
        };
        let index = (c.y as isize as usize)
            .wrapping_mul(usize::from(width))
            .wrapping_add(c.x as isize as usize);
        (index, qr)
    }

    /// Strides of the row-major index for a step along the major and along the minor axis
    /// (two's complement, to be added with wrapping arithmetic).
    #[inline]
    fn strides(&self, width: u16) -> (usize, usize) {
        let sx = self.step_x as isize as usize;
        let sy = (self.step_y as isize as usize).wrapping_mul(usize::from(width));
        if self.x_major {
            (sx, sy)
        } else {
            (sy, sx)
        }
    }
}

/// A ray between two cells of a grid (the mapper's usual case: the pose's cell and a beam's end
/// cell both in the grid), set up in 32-bit arithmetic with no clipping: the same steps as
/// [`Ray::new`] between the same cells, whose `u64` set-up a Cortex-M4 spends ~100 instructions
/// per beam on (`tests::grid_ray_walks_like_ray`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct GridRay {
    /// Row-major index of the first cell.
    from: usize,
    /// Number of steps `N` (< 2^16).
    n: u32,
    /// |Δ| along the minor axis (≤ N).
    a: u32,
    /// Index strides of a major and of a minor step (two's complement).
    major: usize,
    minor: usize,
}

impl GridRay {
    /// The ray from `from` to `to`, both in a grid `width` wide and at most 65 535 rows high
    /// (so every coordinate and difference fits 17 bits and every index a `u32`). Panic-free
    /// for any input, but meaningless for cells outside such a grid.
    #[inline]
    pub(crate) fn new(from: CellCoord, to: CellCoord, width: u16) -> GridRay {
        let (dx, dy) = (to.x.wrapping_sub(from.x), to.y.wrapping_sub(from.y));
        let (ax, ay) = (dx.unsigned_abs(), dy.unsigned_abs());
        let w = usize::from(width);
        let sx = if dx < 0 { usize::MAX } else { 1 };
        let sy = if dy < 0 { w.wrapping_neg() } else { w };
        let (n, a, major, minor) = if ax >= ay {
            (ax, ay, sx, sy)
        } else {
            (ay, ax, sy, sx)
        };
        GridRay {
            from: (from.y as usize)
                .wrapping_mul(w)
                .wrapping_add(from.x as usize),
            n,
            a,
            major,
            minor,
        }
    }

    /// Number of steps `N` (the ray has `N + 1` cells).
    #[inline]
    pub(crate) fn steps(&self) -> u32 {
        self.n
    }

    /// The walk over all the ray's cells, from its first.
    #[inline]
    pub(crate) fn walk(&self) -> IndexWalk {
        // In a grid N < 2^16, so none of these wraps (wrapping only keeps misuse panic-free).
        // At step 0 the remainder is N (`quot_rem`), so g = 2N − 1 − N (−1 for N = 0, as in
        // `Ray::index_walk`).
        IndexWalk {
            index: self.from,
            g: (self.n as i32).wrapping_sub(1),
            two_a: (self.a as i32).wrapping_mul(2),
            two_n: (self.n as i32).wrapping_mul(2),
            major: self.major,
            minor: self.minor,
            left: self.n.wrapping_add(1),
        }
    }

    /// The walk over the ray's last `cells` cells (`1 ≤ cells ≤ N + 1`), backwards from its last
    /// cell, whose row-major index is `end_index`.
    ///
    /// No division, unlike a walk from any other step than the first ([`Ray::index_walk`]): at
    /// step `N` the remainder `(2N·a + N) mod 2N` is `N`, and a step back subtracts `2a` from it,
    /// taking the minor step back when it drops below 0 — the forward step's mirror image, so
    /// the cells are exactly the forward walk's, in reverse
    /// (`tests::backward_walk_is_the_forward_walk_reversed`).
    #[inline]
    pub(crate) fn walk_back(&self, end_index: usize, cells: u32) -> IndexWalk {
        IndexWalk {
            index: end_index,
            // In [0, 2N) (for N = 0, g = 0 and 2a = 0: the walk never wraps). N < 2^16 in a
            // grid, as in `GridRay::walk`.
            g: self.n as i32,
            two_a: (self.a as i32).wrapping_mul(2),
            two_n: (self.n as i32).wrapping_mul(2),
            major: self.major.wrapping_neg(),
            minor: self.minor.wrapping_neg(),
            left: cells,
        }
    }
}

/// A walk along a ray's clipped steps with 32-bit Bresenham state: the mapper's hot loop.
///
/// Instead of the remainder `r ∈ [0, 2N)` it keeps `g = 2N − 1 − r`, also in `[0, 2N)`: the
/// minor coordinate advances when `r + 2a ≥ 2N`, i.e. when `g − 2a < 0`, so a step is one
/// subtraction and a sign test (which a Cortex-M4 gets from the subtraction's flags), and no
/// intermediate value leaves `[−2N, 2N)`. (For `N = 0`, `g = −1` and the minor stride is added
/// at every step, as the `u64` walk does; a clipped walk of such a ray has a single cell.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct IndexWalk {
    /// Row-major index of the current cell.
    pub(super) index: usize,
    pub(super) g: i32,
    pub(super) two_a: i32,
    pub(super) two_n: i32,
    pub(super) major: usize,
    pub(super) minor: usize,
    /// Cells left, the current one included (≥ 1 until [`IndexWalk::take`] took them all).
    pub(super) left: u32,
}

impl IndexWalk {
    /// Row-major index of the current cell.
    #[inline(always)]
    pub(crate) fn index(&self) -> usize {
        self.index
    }

    /// Cells left, the current one included.
    #[inline(always)]
    pub(crate) fn left(&self) -> u32 {
        self.left
    }

    /// Claims up to `max` of the cells left (the caller then visits them with
    /// [`IndexWalk::index`] and [`IndexWalk::advance`]); returns how many.
    #[inline(always)]
    pub(crate) fn take(&mut self, max: u32) -> u32 {
        let m = self.left.min(max);
        self.left -= m;
        m
    }

    /// Moves to the next cell (past the last one the index is meaningless, but never panics).
    #[inline(always)]
    pub(crate) fn advance(&mut self) {
        self.index = self.index.wrapping_add(self.major);
        self.g -= self.two_a;
        if self.g < 0 {
            self.g += self.two_n;
            self.index = self.index.wrapping_add(self.minor);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{c, coord};
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// The 32-bit walk ([`IndexWalk`], what the mapper runs) visits exactly the (step,
        /// index) sequence of the u64 walk, for clipped rays from near and far and for any
        /// sub-range of their steps (which starts the walk with a division).
        #[test]
        fn fast_walk_matches_u64_walk(x0 in coord(), y0 in coord(), x1 in -400i32..400, y1 in -400i32..400,
                                      w in 1u16..300, h in 1u16..300, cut in 0u64..400, keep in 0u64..400) {
            let r = Ray::new(c(x0, y0), c(x1, y1));
            let Some(full) = r.clip(w, h) else { return Ok(()); };
            let first = (full.first + cut).min(full.last);
            let s = Steps { first, last: (first + keep).min(full.last) };
            let mut fast = Vec::new();
            r.for_each_index(s, w, |i, idx| fast.push((i, idx)));
            let mut slow = Vec::new();
            r.walk_u64(s, w, |i, idx| { slow.push((i, idx)); true });
            prop_assert_eq!(&fast, &slow);
            // Chunked, as the mapper drives it.
            if let Some(mut wk) = r.index_walk(s, w) {
                let mut chunked = Vec::new();
                while wk.left() > 0 {
                    let m = wk.take(7);
                    for _ in 0..m {
                        chunked.push(wk.index());
                        wk.advance();
                    }
                }
                prop_assert_eq!(chunked, slow.iter().map(|&(_, idx)| idx).collect::<Vec<_>>());
            }
            // Marking the walk run by run sets exactly the bits of its cells.
            if let Some(wk) = r.index_walk(s, w) {
                let mut want = vec![0u32; (usize::from(w) * usize::from(h)).div_ceil(32)];
                for &(_, idx) in &slow {
                    want[idx / 32] |= 1 << (idx % 32);
                }
                let mut got = vec![0u32; want.len()];
                wk.mark_all(&mut got);
                prop_assert_eq!(got, want);
            }
            // find_step stops at the first match, on both paths alike.
            if let Some(&(step, idx)) = slow.get(slow.len() / 2) {
                prop_assert_eq!(r.find_step(s, w, |i| i == idx), Some(step));
            }
        }

        /// A ray between two cells of a grid set up in 32 bits walks like [`Ray`]'s walk between
        /// the same cells.
        #[test]
        fn grid_ray_walks_like_ray(x0 in 0i32..65535, y0 in 0i32..65535, x1 in 0i32..65535,
                                   y1 in 0i32..65535, w in 1u16..=65535) {
            let (x0, x1) = (x0 % i32::from(w), x1 % i32::from(w));
            let r = Ray::new(c(x0, y0), c(x1, y1));
            let g = GridRay::new(c(x0, y0), c(x1, y1), w);
            prop_assert_eq!(u64::from(g.steps()), r.steps());
            let all = Steps { first: 0, last: r.steps() };
            prop_assert_eq!(Some(g.walk()), r.index_walk(all, w));
        }

        /// The walk back from a ray's last cell visits the forward walk's last cells, in
        /// reverse, for any number of them (the mapper walks a face band that way).
        #[test]
        fn backward_walk_is_the_forward_walk_reversed(x0 in 0i32..300, y0 in 0i32..300,
                                                      x1 in 0i32..300, y1 in 0i32..300,
                                                      w in 1u16..300, cut in 0u64..700) {
            let (x0, x1) = (x0 % i32::from(w), x1 % i32::from(w));
            let r = Ray::new(c(x0, y0), c(x1, y1));
            let all = Steps { first: 0, last: r.steps() };
            let mut forward = Vec::new();
            r.walk_u64(all, w, |_, idx| { forward.push(idx); true });
            let cells = (r.steps() + 1 - cut.min(r.steps())) as u32;
            let end = (y1 * i32::from(w) + x1) as usize;
            prop_assert_eq!(forward.last().copied(), Some(end));
            let mut wk = GridRay::new(c(x0, y0), c(x1, y1), w).walk_back(end, cells);
            let mut back = Vec::new();
            while wk.take(1) == 1 {
                back.push(wk.index());
                wk.advance();
            }
            back.reverse();
            prop_assert_eq!(&back[..], &forward[forward.len() - cells as usize..]);
        }
    }
}
