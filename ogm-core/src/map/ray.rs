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

    /// The steps (within `0..=N`) whose cells lie in `[0, width) × [0, height)`, or `None` if the
    /// ray misses the grid. Exact: a step is in the result iff its cell is inside.
    pub fn clip(&self, width: u16, height: u16) -> Option<Steps> {
        // Every cell of the ray lies in the bounding box of its end cells (the major coordinate
        // is monotone and the minor offset runs from 0 to a), so a ray with both ends inside is
        // inside: the common case for a mapper whose robot is on the map, and division free.
        let end = self.cell_at_offsets(self.n, self.minor_delta);
        let inside = |c: CellCoord| {
            c.x >= 0 && c.y >= 0 && c.x < i32::from(width) && c.y < i32::from(height)
        };
        if inside(self.start) && inside(end) {
            return Some(Steps {
                first: 0,
                last: self.n,
            });
        }
        self.clip_general(width, height)
    }

    /// [`Ray::clip`] for rays with an end outside the grid.
    fn clip_general(&self, width: u16, height: u16) -> Option<Steps> {
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
        // All of these fit an i64 with room to spare: |start| ≤ 2^31, len ≤ 2^16, N, a < 2^33.
        // Major axis: coordinate = s + sign·i must be in [0, len-1].
        let (lo, hi) = axis_interval(major_start, major_step, major_len);
        // Minor axis: offset q(i) must be in [qlo, qhi].
        let (qlo, qhi) = axis_interval(minor_start, minor_step, minor_len);
        let n = self.n as i64;
        let a = self.minor_delta as i64;
        let (mut first, mut last) = (lo.max(0), hi.min(n));
        if first > last {
            return None;
        }
        if a == 0 {
            // Also covers N = 0: the minor offset is 0 at every step.
            if !(qlo <= 0 && 0 <= qhi) {
                return None;
            }
        } else {
            // q(i) = floor((2ia + N) / 2N) ≥ qlo  ⟺  i ≥ ceil((2N·qlo − N) / 2a)
            // q(i) ≤ qhi                          ⟺  i ≤ ceil((2N·(qhi+1) − N) / 2a) − 1
            // q(i) ≥ 0 for every step, so the first bound only matters if qlo > 0; q(i) ≤ a,
            // so the second only matters if qhi < a (otherwise it is ≥ N).
            if qlo > 0 {
                first = first.max(ceil_div_affine(2 * n, qlo, -n, 2 * a));
            }
            if qhi < a {
                last = last.min(ceil_div_affine(2 * n, qhi + 1, -n, 2 * a) - 1);
            }
        }
        if first > last {
            return None;
        }
        // 0 ≤ first ≤ last ≤ N.
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
}

#[cfg(test)]
impl Ray {
    /// The original, all-`i128` clip: the reference the tiered [`Ray::clip`] is tested against.
    pub(crate) fn clip_reference(&self, width: u16, height: u16) -> Option<Steps> {
        let axis = |start: i32, sign: i32, len: u16| {
            let (s, l) = (i128::from(start), i128::from(len) - 1);
            if sign > 0 {
                (-s, l - s)
            } else {
                (s - l, s)
            }
        };
        let ceil_div = |p: i128, q: i128| -((-p).div_euclid(q));
        let (major, minor) = if self.x_major {
            (
                axis(self.start.x, self.step_x, width),
                axis(self.start.y, self.step_y, height),
            )
        } else {
            (
                axis(self.start.y, self.step_y, height),
                axis(self.start.x, self.step_x, width),
            )
        };
        let ((lo, hi), (qlo, qhi)) = (major, minor);
        let n = i128::from(self.n);
        let (mut first, mut last) = (lo.max(0), hi.min(n));
        if self.n == 0 || self.minor_delta == 0 {
            if !(qlo <= 0 && 0 <= qhi) {
                return None;
            }
        } else {
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
    index: usize,
    g: i32,
    two_a: i32,
    two_n: i32,
    major: usize,
    minor: usize,
    /// Cells left, the current one included (≥ 1 until [`IndexWalk::take`] took them all).
    left: u32,
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

    /// Sets the bit `index % 32` of word `index / 32` of `words` for every cell left in the
    /// walk (bits of indices past the end of `words` are ignored), consuming the walk.
    ///
    /// Run by run ([`RunWalk::mark`]) where that is cheaper: runs of consecutive indices, set
    /// with a mask per word (on a 32-bit core only when they are long, see
    /// [`SHORT_CONTIGUOUS_RUNS`]), and runs of other cells when they are long; otherwise cell by
    /// cell, since a run costs about as much to set up as three cells cost to step through.
    #[inline]
    pub(crate) fn mark_all(self, words: &mut [u32]) {
        let runs = self.runs();
        if (SHORT_CONTIGUOUS_RUNS && runs.contiguous()) || runs.long() {
            runs.mark(words);
        } else {
            self.mark_cells(words);
        }
    }

    /// [`IndexWalk::mark_all`] one cell at a time.
    ///
    /// Without a data-dependent branch: the sign of `g` selects the stride (`major` or
    /// `major + minor`) and the correction of `g` (`2N` or 0), because where a ray's minor steps
    /// fall is irregular and a deeply pipelined core would mispredict them.
    #[inline(never)]
    fn mark_cells(self, words: &mut [u32]) {
        let IndexWalk {
            mut index,
            mut g,
            two_a,
            two_n,
            major,
            minor,
            left,
        } = self;
        let diagonal = major.wrapping_add(minor);
        for _ in 0..left {
            // An index past the end (never, for a walk from `Ray::clip`) sets nothing: a branch
            // that is never taken, fewer instructions than clamping the index.
            if let Some(word) = words.get_mut(index / 32) {
                *word |= 1 << (index % 32);
            }
            // g ∈ [−2a, 2N) after the subtraction and back in [0, 2N) after the correction
            // (−1 and 0 for N = 0, whose walk has one cell). The corrected value is computed
            // before the select and only used when g < 0, where it is exact; wrapping keeps the
            // unused one (up to 4N) from overflowing.
            g -= two_a;
            let wrapped = g.wrapping_add(two_n);
            index = index.wrapping_add(if g < 0 { diagonal } else { major });
            g = if g < 0 { wrapped } else { g };
        }
    }

    /// The walk as runs of its more frequent kind of step (see [`RunWalk`]).
    #[inline]
    pub(crate) fn runs(self) -> RunWalk {
        let IndexWalk {
            index,
            g,
            two_a,
            two_n,
            major,
            minor,
            left,
        } = self;
        // 0 ≤ 2a ≤ 2N ≤ i32::MAX and g ∈ [0, 2N) (g = −1 only for N = 0, a single cell, for
        // which 2a = 0 and `Runs::new` does not read g).
        let (two_a, two_n) = (two_a as u32, two_n as u32);
        if two_a <= two_n - two_a {
            // Straight steps are the frequent ones (2a ≤ N).
            RunWalk {
                index,
                runs: Runs::new(g as u32, two_a, two_n, left),
                stride: major,
                minor,
            }
        } else {
            // Diagonal steps are: the same walk seen with g' = 2N − 1 − g (in [0, 2N)),
            // 2a' = 2N − 2a, whose plain step is the diagonal one and whose wrapping step takes
            // the minor step back (`tests::fast_walk_matches_u64_walk` checks the cells).
            RunWalk {
                index,
                runs: Runs::new(two_n - 1 - g as u32, two_n - two_a, two_n, left),
                stride: major.wrapping_add(minor),
                minor: minor.wrapping_neg(),
            }
        }
    }
}

/// The lengths of the runs of a walk that makes plain steps except that, whenever its decision
/// value `g` (in `[0, 2N)`) would drop below 0, it wraps by `2N` and the step is a different
/// one; with `2a ≤ N` every run but the first and the last has `Q = ⌊N/a⌋ ≥ 2` or `Q + 1`
/// cells (or the whole walk is one run if `a = 0`).
///
/// From a cell with decision value `g` the walk makes `⌊g / 2a⌋` plain steps before the next
/// wrapping one, so the run has `L = ⌊g / 2a⌋ + 1` cells, after which `g` becomes
/// `h − 2a + 2N` with `h = g mod 2a`. With `2N = Q·2a + R` (`0 ≤ R < 2a`), every later run has
/// `L = Q + ⌊(h + R) / 2a⌋` cells (`h + R < 4a`: `Q` or `Q + 1`) and the new `h` is
/// `(h + R) mod 2a`: two divisions per walk, none per run or cell.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Runs {
    /// Length of the current run, before it is cut to `left`.
    run: u32,
    h: u32,
    q: u32,
    r: u32,
    two_a: u32,
    /// Cells left, the current run included.
    left: u32,
}

impl Runs {
    /// `two_a ≤ two_n / 2 < 2^31`, `g < two_n` unless `two_a = 0`.
    #[inline]
    fn new(g: u32, two_a: u32, two_n: u32, left: u32) -> Runs {
        if two_a == 0 {
            // One run of every cell: `next` returns `left`, then 0 (h + r = 0 < 1 makes the
            // next run `q`, never `q + 1`).
            return Runs {
                run: u32::MAX,
                h: 0,
                q: u32::MAX,
                r: 0,
                two_a: 1,
                left,
            };
        }
        Runs {
            run: g / two_a + 1,
            h: g % two_a,
            q: two_n / two_a,
            r: two_n % two_a,
            two_a,
            left,
        }
    }

    /// The length of the current run (0 once the walk is done), moving on to the next.
    #[inline(always)]
    fn next(&mut self) -> u32 {
        let l = self.run.min(self.left);
        self.left -= l;
        // h + r < 2·2a ≤ 2N < 2^31: no overflow.
        let t = self.h + self.r;
        (self.run, self.h) = if t >= self.two_a {
            (self.q + 1, t - self.two_a)
        } else {
            (self.q, t)
        };
        l
    }
}

/// Runs of at least this many cells are cheaper to mark run by run than cell by cell when they
/// are not contiguous: a run costs about as much to set up as three cells cost to step through
/// (chosen with callgrind on x86-64 on the shared CARMEN logs, docs/insertion.md).
const LONG_RUN: u32 = 4;

/// Whether runs of consecutive indices shorter than [`LONG_RUN`] are marked run by run too. On
/// a 64-bit host a mask per word beats stepping their cells (callgrind, docs/insertion.md); a
/// Cortex-M4 spills the run loop's state to the stack and spends ~47 instructions per run
/// against ~14 per cell stepped, so there a ray of short runs (slope ⅓ … ½) is stepped cell by
/// cell (per-scan step 133.0 → 131.2 instructions per updated cell, docs/benchmarks.md).
const SHORT_CONTIGUOUS_RUNS: bool = cfg!(target_pointer_width = "64");

/// An [`IndexWalk`] as runs: `index` is the first cell of the current run, its cells follow at
/// `stride` (two's complement), and the next run starts one stride past the last cell plus
/// `minor`. For an x-major ray whose straight steps are the frequent ones the stride is `±1`
/// and a run is a stretch of consecutive bits of the mark words, set with one mask per word.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RunWalk {
    index: usize,
    runs: Runs,
    stride: usize,
    minor: usize,
}

impl RunWalk {
    /// Whether this walk's runs are stretches of consecutive indices.
    #[inline]
    pub(crate) fn contiguous(&self) -> bool {
        self.stride == 1 || self.stride == usize::MAX
    }

    /// Whether its runs are long enough (≥ [`LONG_RUN`] cells) to walk run by run even when
    /// they are not contiguous.
    #[inline]
    pub(crate) fn long(&self) -> bool {
        self.runs.q >= LONG_RUN
    }

    /// Sets the bit of every cell of the walk (see [`IndexWalk::mark_all`]).
    #[inline(never)]
    pub(crate) fn mark(self, words: &mut [u32]) {
        let RunWalk {
            mut index,
            mut runs,
            stride,
            minor,
        } = self;
        if stride == 1 || stride == usize::MAX {
            loop {
                let l = runs.next();
                if l == 0 {
                    break;
                }
                let lo = if stride == 1 {
                    index
                } else {
                    // Going down: the same cells from the lowest one (in-grid indices of a
                    // clipped walk, so `index ≥ l − 1`).
                    index.wrapping_sub(l as usize - 1)
                };
                set_bits(words, lo, l);
                index = next_run(index, l, stride, minor);
            }
        } else if stride % 32 == 0 {
            // Chosen once per ray, not per run.
            mark_runs(words, index, runs, stride, minor, mark_strided_words);
        } else {
            mark_runs(words, index, runs, stride, minor, mark_strided);
        }
    }
}

/// Marks every run of a strided walk from `index` with `mark(words, first, length, stride)`.
#[inline(always)]
fn mark_runs(
    words: &mut [u32],
    mut index: usize,
    mut runs: Runs,
    stride: usize,
    minor: usize,
    mark: impl Fn(&mut [u32], usize, u32, usize),
) {
    loop {
        let l = runs.next();
        if l == 0 {
            break;
        }
        mark(words, index, l, stride);
        index = next_run(index, l, stride, minor);
    }
}

/// The first cell of the run after one of `l` cells from `index`.
#[inline(always)]
fn next_run(index: usize, l: u32, stride: usize, minor: usize) -> usize {
    index
        .wrapping_add((l as usize).wrapping_mul(stride))
        .wrapping_add(minor)
}

/// [`mark_strided`] for a stride that is a whole number of words (`stride % 32 == 0`: a row of
/// a grid 32·k cells wide, e.g. the firmware's): every cell has the same bit, in a word
/// `stride / 32` further on.
#[inline(always)]
fn mark_strided_words(words: &mut [u32], index: usize, n: u32, stride: usize) {
    let (bit, step) = (1u32 << (index % 32), (stride as isize / 32) as usize);
    let mut w = index / 32;
    for _ in 0..n {
        if let Some(word) = words.get_mut(w) {
            *word |= bit;
        }
        w = w.wrapping_add(step);
    }
}

/// Marks `n` cells from `index` in steps of `stride` (two's complement).
#[inline(always)]
fn mark_strided(words: &mut [u32], index: usize, n: u32, stride: usize) {
    let mut i = index;
    for _ in 0..n {
        if let Some(word) = words.get_mut(i / 32) {
            *word |= 1 << (i % 32);
        }
        i = i.wrapping_add(stride);
    }
}

/// Sets `n` consecutive bits of `words` starting at bit `lo` (bit `k` is bit `k % 32` of word
/// `k / 32`); bits past the end of `words` are ignored.
#[inline(always)]
fn set_bits(words: &mut [u32], lo: usize, n: u32) {
    let (mut k, mut n) = (lo, n);
    while n > 0 {
        let b = (k % 32) as u32;
        // 1 ≤ take ≤ 32 - b, so the shifts below are in range.
        let take = n.min(32 - b);
        let mask = (u32::MAX >> (32 - take)) << b;
        if let Some(word) = words.get_mut(k / 32) {
            *word |= mask;
        }
        k = k.wrapping_add(take as usize);
        n -= take;
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

/// Interval of offsets `k` such that `start + sign·k ∈ [0, len − 1]`.
fn axis_interval(start: i32, sign: i32, len: u16) -> (i64, i64) {
    let s = i64::from(start);
    let l = i64::from(len) - 1;
    if sign > 0 {
        (-s, l - s)
    } else {
        (s - l, s)
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

/// ⌈(m·q + c) / d⌉ for d > 0, clamped to ±2^62 (callers compare it with steps in [0, 2^33], so
/// the clamp changes nothing, and subtracting 1 cannot overflow). Uses the narrowest division
/// that holds the operands: `i32` (one `sdiv`) for rays near a `u16` grid, `i128` only for
/// absurd coordinates.
fn ceil_div_affine(m: i64, q: i64, c: i64, d: i64) -> i64 {
    const LIMIT: i64 = 1 << 62;
    match m.checked_mul(q).and_then(|p| p.checked_add(c)) {
        Some(p) => match (i32::try_from(p), i32::try_from(d)) {
            (Ok(p32), Ok(d32)) => {
                match (p32.checked_div_euclid(d32), p32.checked_rem_euclid(d32)) {
                    (Some(fl), Some(r)) => i64::from(fl) + i64::from(r != 0),
                    _ => ceil_div_i64(p, d),
                }
            }
            _ => ceil_div_i64(p, d),
        }
        .clamp(-LIMIT, LIMIT),
        None => ceil_div_wide(i128::from(m) * i128::from(q) + i128::from(c), d),
    }
}

/// ⌈p / d⌉ for d > 0, clamped to ±2^62 like [`ceil_div_affine`] (0 if d ≤ 0, which callers
/// never pass), by shift and subtract: only absurd coordinates get here, and a 128-bit
/// division would put ~1.5 KiB of code into the firmware's flash for them.
#[cold]
fn ceil_div_wide(p: i128, d: i64) -> i64 {
    const SHIFT: u32 = 62;
    let Ok(d) = u64::try_from(d) else { return 0 };
    if d == 0 {
        return 0;
    }
    let (negative, mut rest) = (p < 0, p.unsigned_abs());
    let d = u128::from(d);
    // d < 2^63, so d·2^62 < 2^125 fits. |p| ≥ d·2^62 means |p / d| ≥ 2^62: the clamp.
    if rest >= d << SHIFT {
        return if negative { -(1 << SHIFT) } else { 1 << SHIFT };
    }
    // ⌊|p| / d⌋ < 2^62, a bit at a time from the top (the smallest code of the variants
    // measured: ~0.6 KiB).
    let mut quotient = 0u64;
    for bit in (0..SHIFT).rev() {
        if rest >= d << bit {
            rest -= d << bit;
            quotient |= 1 << bit;
        }
    }
    let quotient = quotient as i64;
    // ⌈p / d⌉ = ⌊|p| / d⌋ + (remainder ≠ 0) for p ≥ 0, −⌊|p| / d⌋ for p < 0; < 2^62 either way.
    if negative {
        -quotient
    } else {
        quotient + i64::from(rest != 0)
    }
}

/// ⌈p / d⌉ for d > 0 (0 if d ≤ 0, which callers never pass).
fn ceil_div_i64(p: i64, d: i64) -> i64 {
    match (p.checked_div_euclid(d), p.checked_rem_euclid(d)) {
        (Some(fl), Some(r)) => fl + i64::from(r != 0),
        _ => 0,
    }
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

    /// `ceil_div_wide` against the 128-bit division it replaces, at every magnitude of the
    /// quotient (small, near the clamp, beyond it) and both signs.
    #[test]
    fn wide_ceiling_division_matches_i128() {
        let reference = |p: i128, d: i64| {
            let f = (-p).div_euclid(i128::from(d));
            (-f).clamp(-(1i128 << 62), 1 << 62) as i64
        };
        use rand_core::{Rng, SeedableRng};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        for k in 0..20_000u32 {
            let d = (rng.next_u64() >> (rng.next_u32() % 64)).max(1) as i64 & i64::MAX;
            let d = d.max(1);
            let p = (i128::from(rng.next_u64()) << 64 | i128::from(rng.next_u64()))
                >> (1 + rng.next_u32() % 127);
            let p = if k % 2 == 0 { p } else { -p };
            assert_eq!(ceil_div_wide(p, d), reference(p, d), "{p} / {d}");
            // Exact multiples and their neighbours.
            let m = i128::from(d) * i128::from(rng.next_u32() as i32);
            for p in [m - 1, m, m + 1] {
                assert_eq!(ceil_div_wide(p, d), reference(p, d), "{p} / {d}");
            }
        }
        assert_eq!(ceil_div_wide(5, 0), 0);
        assert_eq!(ceil_div_wide(5, -3), 0);
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

    /// Any coordinates, from tiny to the whole i32 range.
    fn coord() -> impl Strategy<Value = i32> {
        prop_oneof![
            -300i32..300,
            -70_000i32..70_000,
            any::<i32>(),
            Just(i32::MIN),
            Just(i32::MAX),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// The tiered clip (fast path, i32/i64 divisions, i128 only when needed) equals the
        /// original all-i128 one, for any coordinates and grid size.
        #[test]
        fn clip_matches_i128_reference(x0 in coord(), y0 in coord(), x1 in coord(), y1 in coord(),
                                       w in prop_oneof![1u16..300, any::<u16>()],
                                       h in prop_oneof![1u16..300, any::<u16>()]) {
            prop_assume!(w > 0 && h > 0);
            let r = Ray::new(c(x0, y0), c(x1, y1));
            prop_assert_eq!(r.clip(w, h), r.clip_reference(w, h));
            prop_assert_eq!(r.clip_general(w, h), r.clip_reference(w, h));
        }

        /// `cell_at` with narrow divisions equals the original u128 one, at any step (even past
        /// the end, and at absurd step numbers).
        #[test]
        fn cell_at_matches_u128_reference(x0 in coord(), y0 in coord(), x1 in coord(), y1 in coord(),
                                          i in prop_oneof![0u64..1000, 0u64..(1 << 34), any::<u64>()]) {
            let r = Ray::new(c(x0, y0), c(x1, y1));
            prop_assert_eq!(r.cell_at(i), r.cell_at_reference(i));
            prop_assert_eq!(r.cell_at(r.steps()), r.cell_at_reference(r.steps()));
        }

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
