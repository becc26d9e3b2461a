//! Binary angles and integer trigonometry.
//!
//! An [`Angle`] is a `u16` fraction of a full turn (65,536 = 360°), so adding a beam's angle to the
//! robot's heading is a wrapping add and no angle ever needs normalising. Sine and cosine come from
//! a 513-entry quarter-wave table (Q30, built at compile time) with linear interpolation; the worst
//! error is below 2·10⁻⁶, i.e. under 0.2 mm at 80 m. `atan2` uses a 257-entry table of
//! atan(t), t ∈ [0, 1], with interpolation (error < 0.01°). Everything is integer arithmetic, so
//! the host and the Cortex-M4 compute bit-identical rays.

/// Number of [`Angle`] units per full turn.
pub const FULL_TURN: u32 = 1 << 16;

/// An angle as a fraction of a full turn: `Angle(16384)` is 90°.
#[repr(transparent)]
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    serde::Serialize,
    serde::Deserialize,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Angle(pub u16);

/// Q30 one.
pub const Q30_ONE: i32 = 1 << 30;

const SIN_STEPS: usize = 512; // table entries per quarter turn (plus one)
static SIN_TABLE: [i32; SIN_STEPS + 1] = build_sin_table();
const ATAN_STEPS: usize = 256;
static ATAN_TABLE: [u16; ATAN_STEPS + 1] = build_atan_table();

/// sin(x) for x ∈ [0, π/2] by its Taylor series (19 terms: error far below 1e-15).
const fn const_sin(x: f64) -> f64 {
    let mut term = x;
    let mut sum = x;
    let mut k = 1;
    while k < 20 {
        term = -term * x * x / (((2 * k) * (2 * k + 1)) as f64);
        sum += term;
        k += 1;
    }
    sum
}

/// atan(t) for t ∈ [0, 1]: Euler's accelerated series, converging for all t.
const fn const_atan(t: f64) -> f64 {
    // atan t = Σ 2^{2n}(n!)^2/(2n+1)! · t^{2n+1}/(1+t^2)^{n+1}
    let y = t * t / (1.0 + t * t);
    let mut term = t / (1.0 + t * t);
    let mut sum = term;
    let mut n = 1;
    while n < 80 {
        term = term * y * ((2 * n) as f64) / ((2 * n + 1) as f64);
        sum += term;
        n += 1;
    }
    sum
}

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_sin_table() -> [i32; SIN_STEPS + 1] {
    let mut t = [0i32; SIN_STEPS + 1];
    let mut i = 0;
    while i <= SIN_STEPS {
        let x = core::f64::consts::FRAC_PI_2 * (i as f64) / (SIN_STEPS as f64);
        let v = const_sin(x) * (Q30_ONE as f64);
        t[i] = (v + 0.5) as i32;
        i += 1;
    }
    t
}

#[allow(clippy::indexing_slicing)]
const fn build_atan_table() -> [u16; ATAN_STEPS + 1] {
    let mut t = [0u16; ATAN_STEPS + 1];
    let mut i = 0;
    while i <= ATAN_STEPS {
        let a = const_atan((i as f64) / (ATAN_STEPS as f64));
        // radians → angle units; atan(1) = π/4 = 8192 units.
        t[i] = (a / (2.0 * core::f64::consts::PI) * (FULL_TURN as f64) + 0.5) as u16;
        i += 1;
    }
    t
}

/// sin of the angle `x` (0..=16384 units, i.e. the first quadrant), Q30.
#[inline]
fn quarter_sin(x: u32) -> i32 {
    // 16384 units / 512 steps = 32 units per step.
    let i = (x >> 5) as usize;
    let frac = x & 31;
    let a = SIN_TABLE.get(i).copied().unwrap_or(Q30_ONE);
    let b = SIN_TABLE.get(i + 1).copied().unwrap_or(Q30_ONE);
    // The table rises by less than 2^27 per step (`tests::sin_table_rises`), so in 32 bits
    // `(b − a)·frac < 2^32` and dividing it by 32 is a shift (no 64-bit multiply on a
    // Cortex-M4); the sum stays within [0, 2^30].
    a + ((b.wrapping_sub(a) as u32 * frac) >> 5) as i32
}

impl Angle {
    /// Zero.
    pub const ZERO: Angle = Angle(0);
    /// A quarter turn.
    pub const QUARTER: Angle = Angle(16384);
    /// A half turn.
    pub const HALF: Angle = Angle(32768);

    /// From radians (any value; wrapped to one turn). NaN and infinities give zero.
    pub fn from_radians(rad: f64) -> Angle {
        if !rad.is_finite() {
            return Angle(0);
        }
        let turns = rad / (2.0 * core::f64::consts::PI);
        let frac = turns - libm::floor(turns);
        Angle((libm::round(frac * f64::from(FULL_TURN)) as u32 & 0xFFFF) as u16)
    }

    /// From degrees (any value; wrapped).
    pub fn from_degrees(deg: f64) -> Angle {
        Angle::from_radians(deg.to_radians())
    }

    /// From hundredths of a degree (the LD06 wire unit), wrapped to one turn. Exact to 1/2 unit.
    pub fn from_centidegrees(cdeg: u32) -> Angle {
        // 35 999 × 65 536 + 18 000 < 2³²: 32-bit arithmetic (one UDIV on a Cortex-M4, not a
        // 64-bit division call).
        let cdeg = cdeg % 36_000;
        Angle(((cdeg * FULL_TURN + 18_000) / 36_000) as u16)
    }

    /// In radians, in [0, 2π).
    pub fn to_radians(self) -> f64 {
        f64::from(self.0) / f64::from(FULL_TURN) * 2.0 * core::f64::consts::PI
    }

    /// The signed difference `self - other` in units, in [-32768, 32767].
    #[inline]
    pub const fn signed_diff(self, other: Angle) -> i16 {
        self.0.wrapping_sub(other.0) as i16
    }

    /// `self + other`, wrapping around the full turn.
    #[inline]
    pub const fn wrapping_add(self, other: Angle) -> Angle {
        Angle(self.0.wrapping_add(other.0))
    }

    /// `self - other`, wrapping around the full turn.
    #[inline]
    pub const fn wrapping_sub(self, other: Angle) -> Angle {
        Angle(self.0.wrapping_sub(other.0))
    }

    /// Sine in Q30.
    pub fn sin_q30(self) -> i32 {
        let a = u32::from(self.0);
        let x = a & 0x3FFF;
        match a >> 14 {
            0 => quarter_sin(x),
            1 => quarter_sin(16384 - x),
            2 => -quarter_sin(x),
            _ => -quarter_sin(16384 - x),
        }
    }

    /// Cosine in Q30.
    pub fn cos_q30(self) -> i32 {
        self.wrapping_add(Angle::QUARTER).sin_q30()
    }

    /// `(self.cos_q30(), self.sin_q30())`, the quadrant decoded once: `cos θ = sin(θ + ¼ turn)`
    /// lies one quadrant on at the same offset within it (`tests::cos_sin_match_each`).
    #[inline]
    pub fn cos_sin_q30(self) -> (i32, i32) {
        let a = u32::from(self.0);
        let x = a & 0x3FFF;
        // The sine of the offset within the quadrant and of its complement.
        let (u, v) = (quarter_sin(x), quarter_sin(16384 - x));
        match a >> 14 {
            0 => (v, u),
            1 => (-u, v),
            2 => (-v, -u),
            _ => (u, -v),
        }
    }

    /// The direction of the vector (dx, dy); `atan2(0, 0)` is zero.
    pub fn atan2(dy: i64, dx: i64) -> Angle {
        if dx == 0 && dy == 0 {
            return Angle(0);
        }
        let (ax, ay) = (dx.unsigned_abs(), dy.unsigned_abs());
        // Angle of the first-octant vector (max, min): atan(min/max) ∈ [0, 8192].
        let (hi, lo) = if ax >= ay { (ax, ay) } else { (ay, ax) };
        // t in 1/2^16 steps, in u64: both scaled down first so that `hi < 2^47` (the ratio
        // moves by < 2^-31, far below one table step; no 128-bit division on a 32-bit MCU).
        let shift = (64 - hi.leading_zeros()).saturating_sub(47);
        let (lo, hi) = (lo >> shift, (hi >> shift).max(1));
        let t = ((lo << 16) / hi) as u32; // ≤ 65536
        let scaled = t * ATAN_STEPS as u32; // index in 1/65536 steps
        let i = (scaled >> 16) as usize;
        let frac = i64::from(scaled & 0xFFFF);
        let a = i64::from(ATAN_TABLE.get(i).copied().unwrap_or(8192));
        let b = i64::from(ATAN_TABLE.get(i + 1).copied().unwrap_or(8192));
        let oct = (a + (((b - a) * frac + 0x8000) >> 16)) as u16;
        // Unfold the octant.
        let first_quadrant = if ax >= ay { oct } else { 16384 - oct };
        let q = match (dx >= 0, dy >= 0) {
            (true, true) => first_quadrant,
            (false, true) => 32768 - first_quadrant,
            (false, false) => 32768 + first_quadrant,
            (true, false) => (65536 - u32::from(first_quadrant)) as u16,
        };
        Angle(q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `quarter_sin`'s 32-bit interpolation relies on, and that it equals the 64-bit one.
    #[test]
    fn sin_table_rises() {
        for w in SIN_TABLE.windows(2) {
            assert!(w[0] <= w[1] && w[1] - w[0] < 1 << 27, "{w:?}");
        }
        for x in 0..=16384u32 {
            let i = (x >> 5) as usize;
            let a = i64::from(SIN_TABLE.get(i).copied().unwrap_or(Q30_ONE));
            let b = i64::from(SIN_TABLE.get(i + 1).copied().unwrap_or(Q30_ONE));
            let want = (a + ((b - a) * i64::from(x & 31)) / 32) as i32;
            assert_eq!(quarter_sin(x), want, "{x}");
        }
    }

    #[test]
    fn cos_sin_match_each() {
        for a in 0..=u16::MAX {
            let ang = Angle(a);
            assert_eq!(ang.cos_sin_q30(), (ang.cos_q30(), ang.sin_q30()), "{a}");
        }
    }

    #[test]
    fn sin_cos_match_f64() {
        let mut worst = 0.0f64;
        for a in (0..=u16::MAX).step_by(3) {
            let ang = Angle(a);
            let r = ang.to_radians();
            let s = f64::from(ang.sin_q30()) / f64::from(Q30_ONE);
            let c = f64::from(ang.cos_q30()) / f64::from(Q30_ONE);
            worst = worst
                .max((s - libm::sin(r)).abs())
                .max((c - libm::cos(r)).abs());
        }
        assert!(worst < 2e-6, "worst trig error {worst}");
    }

    #[test]
    fn atan2_matches_f64() {
        let mut worst = 0i32;
        for &(dx, dy) in &[
            (1i64, 0i64),
            (0, 1),
            (-1, 0),
            (0, -1),
            (3, 4),
            (-3, 4),
            (-3, -4),
            (3, -4),
        ] {
            let _ = Angle::atan2(dy, dx);
        }
        for ix in -60i64..=60 {
            for iy in -60i64..=60 {
                if ix == 0 && iy == 0 {
                    continue;
                }
                let got = Angle::atan2(iy * 977, ix * 1013);
                let want = Angle::from_radians(libm::atan2((iy * 977) as f64, (ix * 1013) as f64));
                worst = worst.max(i32::from(got.signed_diff(want)).abs());
            }
        }
        assert!(worst <= 2, "worst atan2 error {worst} units");
    }

    #[test]
    fn conversions() {
        assert_eq!(Angle::from_degrees(90.0), Angle::QUARTER);
        assert_eq!(Angle::from_degrees(-90.0), Angle(49152));
        assert_eq!(Angle::from_degrees(360.0), Angle(0));
        assert_eq!(Angle::from_centidegrees(18_000), Angle::HALF);
        assert_eq!(Angle::from_centidegrees(36_000 + 9_000), Angle::QUARTER);
        assert_eq!(Angle::from_radians(f64::NAN), Angle(0));
        assert_eq!(Angle(10).signed_diff(Angle(65530)), 16);
        assert_eq!(Angle(65530).signed_diff(Angle(10)), -16);
    }
}
