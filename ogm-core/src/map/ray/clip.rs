//! Clipping a ray to the grid: the steps whose cells lie inside form one interval, solved for
//! with integer arithmetic in the narrowest width that holds the operands.

use super::{Ray, Steps};
use crate::types::geometry::CellCoord;

impl Ray {
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
    use super::super::tests::{c, coord};
    use super::*;
    use proptest::prelude::*;

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
    }
}
