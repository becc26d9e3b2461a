//! Small integer linear algebra for the matcher: a symmetric 3 × 3 solve, a 2 × 2 symmetric
//! eigen-decomposition and an integer square root.

use crate::types::angle::Angle;

/// Bits the system is scaled into before Cramer's rule: 2 × 2 minors stay below 2⁴⁰ and the
/// determinant and numerators below 2⁶¹.
const SOLVE_BITS: u32 = 19;

/// Bits of `|v|` (0 for 0).
#[inline]
fn bits(v: i64) -> u32 {
    64 - v.unsigned_abs().leading_zeros()
}

/// Solves `h · x = b` for a symmetric positive definite `h`; returns `256 · x` (x in the units
/// of `b / h`, to 1/256), saturated to ±2³⁰, or `None` if `h` is not positive definite
/// after scaling (the caller then does not move).
///
/// `h` and `b` are scaled down together by a power of two until every entry fits
/// [`SOLVE_BITS`] bits (the solution does not change), then solved by Cramer's rule in `i64`.
pub(crate) fn solve3(h: &[[i64; 3]; 3], b: &[i64; 3]) -> Option<[i64; 3]> {
    let mut top = 0u32;
    for row in h {
        for v in row {
            top = top.max(bits(*v));
        }
    }
    for v in b {
        top = top.max(bits(*v));
    }
    let s = top.saturating_sub(SOLVE_BITS);
    let [[a00, a01, a02], [_, a11, a12], [_, _, a22]] = h.map(|r| r.map(|v| v >> s));
    let c = [b[0] >> s, b[1] >> s, b[2] >> s];
    // Cofactors of a symmetric matrix (the adjugate is symmetric too).
    let c00 = a11 * a22 - a12 * a12;
    let c01 = a02 * a12 - a01 * a22;
    let c02 = a01 * a12 - a02 * a11;
    let c11 = a00 * a22 - a02 * a02;
    let c12 = a01 * a02 - a00 * a12;
    let c22 = a00 * a11 - a01 * a01;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    if det <= 0 || a00 <= 0 || c22 <= 0 {
        return None;
    }
    let num = [
        c00 * c[0] + c01 * c[1] + c02 * c[2],
        c01 * c[0] + c11 * c[1] + c12 * c[2],
        c02 * c[0] + c12 * c[1] + c22 * c[2],
    ];
    const LIM: i64 = 1 << 30;
    let x = num.map(|n| {
        // 256 · n / det without overflowing: shift the divisor when it is large.
        let q = if det >= 1 << 40 {
            n / (det >> 8)
        } else {
            n.saturating_mul(256) / det
        };
        q.clamp(-LIM, LIM)
    });
    Some(x)
}

/// Integer square root (floor) of a `u64`.
pub(crate) fn isqrt(v: u64) -> u64 {
    if v < 2 {
        return v;
    }
    // Bit by bit from the highest even bit: 32 steps, no division.
    let mut rem = v;
    let mut root = 0u64;
    let mut bit = 1u64 << ((63 - v.leading_zeros()) & !1);
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

/// Eigen-decomposition of the symmetric 2 × 2 matrix `[[a, b], [b, c]]`: the smaller and the
/// larger eigenvalue and the direction of the smaller one's eigenvector (an axis: defined to
/// half a turn). The entries are scaled into 30 bits first (the eigenvalues are scaled back,
/// to that precision), so any `i64` input is fine.
pub(crate) fn eigen2(a: i64, b: i64, c: i64) -> (i64, i64, Angle) {
    let s = bits(a).max(bits(b)).max(bits(c)).saturating_sub(30);
    let (a, b, c) = (a >> s, b >> s, c >> s);
    // In doubled units (no halving before the root): |a − c|, |2b| < 2^31, so the sum of squares
    // fits a u64.
    let rad2 = isqrt((a - c).unsigned_abs().pow(2) + (2 * b).unsigned_abs().pow(2)) as i64;
    let (lo, hi) = ((a + c - rad2) / 2, (a + c + rad2) / 2);
    // The larger eigenvalue's eigenvector is at ψ = ½·atan2(2b, a − c); the smaller one's is a
    // quarter turn on.
    let two_psi = Angle::atan2(2 * b, a - c);
    let weak = Angle((two_psi.0 >> 1).wrapping_add(Angle::QUARTER.0));
    (lo << s, hi << s, weak)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isqrt_is_floor() {
        for v in (0..10_000u64).chain([u64::MAX, u64::MAX - 1, 1 << 62, (1 << 32) - 1]) {
            let r = isqrt(v);
            assert!(u128::from(r) * u128::from(r) <= u128::from(v), "{v}");
            assert!(u128::from(r + 1) * u128::from(r + 1) > u128::from(v), "{v}");
        }
    }

    #[test]
    fn solves_spd() {
        let h = [[4_000i64, 1_000, 0], [1_000, 3_000, 500], [0, 500, 2_000]];
        let x = [3i64, -2, 5];
        let b = [4_000 * 3 - 2_000, 3_000 - 6_000 + 2_500, -1_000 + 10_000];
        let got = solve3(&h, &b).unwrap();
        for i in 0..3 {
            assert!((got[i] - 256 * x[i]).abs() <= 1, "{got:?}");
        }
        // Large entries are scaled down without changing the solution much.
        let big = h.map(|r| r.map(|v| v << 36));
        let bb = b.map(|v| v << 36);
        let got = solve3(&big, &bb).unwrap();
        for i in 0..3 {
            assert!((got[i] - 256 * x[i]).abs() <= 2, "{got:?}");
        }
        assert_eq!(solve3(&[[0; 3]; 3], &[1, 2, 3]), None);
    }

    #[test]
    fn eigen_of_axes() {
        // Strong along x, weak along y.
        let (lo, hi, weak) = eigen2(100, 0, 1);
        assert_eq!((lo, hi), (1, 100));
        assert!(
            weak.signed_diff(Angle::QUARTER).unsigned_abs() <= 2,
            "{weak:?}"
        );
        let (lo, hi, weak) = eigen2(1, 0, 100);
        assert_eq!((lo, hi), (1, 100));
        assert!(
            weak.signed_diff(Angle::ZERO).unsigned_abs() <= 2
                || weak.signed_diff(Angle::HALF).unsigned_abs() <= 2
        );
        // Strong along 45°: weak along 135°.
        let (lo, hi, weak) = eigen2(50, 49, 50);
        assert_eq!((lo, hi), (1, 99));
        let d = weak.signed_diff(Angle::from_degrees(135.0)).unsigned_abs() as i32;
        assert!(d <= 4 || (d - 32768).abs() <= 4, "{weak:?}");
    }
}
