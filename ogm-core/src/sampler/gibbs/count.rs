//! The marginal counter cell ([`Count`]) and its averaging arithmetic: `u8` counts three cells
//! at a time in one 32-bit word (the firmware's hot path), wider counts a cell at a time.

/// A marginal counter cell: `u8` on the firmware (64 KB for 256×256), `u16`/`u32` on the host
/// when more samples should be averaged before the counts halve.
pub trait Count: Copy + Default {
    /// Largest count; the sample total halves when it reaches this.
    const MAX: u32;
    /// As `u32`.
    fn get(self) -> u32;
    /// From `u32` (saturating at `MAX`).
    fn set(v: u32) -> Self;
    /// Moves the value, read as a probability `self / MAX`, by `2^-shift` of the way towards
    /// `target_q16 / 2^16` (rounded to nearest): the Rao-Blackwellised estimator's update.
    #[inline]
    fn ema(self, target_q16: u32, shift: u8) -> Self {
        let t = Self::from_probability_q16(target_q16).get();
        Self::set(ema_u32(self.get(), t, shift))
    }
    /// [`Count::ema`] towards 0 or 1.
    #[inline]
    fn ema_bit(self, occupied: bool, shift: u8) -> Self {
        Self::set(ema_u32(
            self.get(),
            if occupied { Self::MAX } else { 0 },
            shift,
        ))
    }
    /// [`Count::ema_bit`] of the `n` cells `counts[start..start + n]` towards bit `k` of `bits`
    /// for cell `k` (cells out of range are skipped): what every patch update does per row.
    /// `dither` is a uniformly random word: `u8` estimates round stochastically with its byte
    /// `k` for cell `k` (see the `u8` implementation); wider counts round to nearest and
    /// ignore it.
    #[inline]
    fn average_row(counts: &mut [Self], start: usize, n: usize, bits: u32, shift: u8, dither: u32) {
        let _ = dither;
        if let Some(row) = counts.get_mut(start..start + n) {
            for (k, c) in row.iter_mut().enumerate() {
                *c = c.ema_bit(bits >> k & 1 != 0, shift);
            }
        }
    }
    /// [`Count::average_row`] of the three rows of a 3 × 3 patch, row r starting at
    /// `start + r · width` with bits `3r ..= 3r + 2` of `config` and dither
    /// `dither.rotate_right(8 r)`.
    #[inline]
    fn average_patch3(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: u8,
        dither: u32,
    ) {
        average_rows(counts, start, width, config, shift, dither);
    }
    /// [`Count::average_patch3`] with the shift's derived masks ([`AverageShift`], computed
    /// once per tile visit instead of once per update).
    #[inline]
    fn average_patch3_at(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: &AverageShift,
        dither: u32,
    ) {
        Self::average_patch3(counts, start, width, config, shift.shift, dither);
    }
    /// The value of probability `p_q16 / 2^16` (clamped to 1), rounded to nearest.
    #[inline]
    fn from_probability_q16(p_q16: u32) -> Self {
        let p = p_q16.min(1 << 16);
        Self::set(if Self::MAX <= 0xFFFF {
            // < 2^16 · 2^16: fits (32-bit arithmetic for u8/u16 counts).
            (p * Self::MAX + (1 << 15)) >> 16
        } else {
            ((u64::from(p) * u64::from(Self::MAX) + (1 << 15)) >> 16) as u32
        })
    }
}

/// `m + round((t − m) / 2^shift)`, within `[min(m, t), max(m, t)]`, for any `u32` (the
/// estimate settles within half a step of its target); shift 0 → `t`. Branch-free 32-bit
/// arithmetic when both fit 16 bits (`u8`/`u16` counts), 64-bit otherwise.
#[inline]
fn ema_u32(m: u32, t: u32, shift: u8) -> u32 {
    let s = u32::from(shift.min(31));
    if s == 0 {
        return t;
    }
    let half = 1i64 << (s - 1);
    if m <= 0xFFFF && t <= 0xFFFF {
        // |t − m| < 2^16: no overflow; the arithmetic shift rounds half-steps up.
        let (m, t) = (m as i32, t as i32);
        return (m + ((t - m + half as i32) >> s)) as u32;
    }
    let (m, t) = (i64::from(m), i64::from(t));
    (m + ((t - m + half) >> s)) as u32
}

macro_rules! impl_count {
    ($($t:ty),*) => {$(
        impl Count for $t {
            const MAX: u32 = <$t>::MAX as u32;
            #[inline]
            fn get(self) -> u32 {
                u32::from(self)
            }
            #[inline]
            fn set(v: u32) -> Self {
                v.min(<Self as Count>::MAX) as $t
            }
        }
    )*};
}
impl_count!(u16, u32);

impl Count for u8 {
    const MAX: u32 = 255;
    #[inline]
    fn get(self) -> u32 {
        u32::from(self)
    }
    #[inline]
    fn set(v: u32) -> Self {
        v.min(255) as u8
    }
    /// Three cells at once in one 32-bit word (SIMD within a register; the firmware's hot path),
    /// with stochastic rounding so that long averages stay unbiased in 8 bits: cell `k` moves
    /// `⌊(d + u_k mod 2^s) / 2^s⌋` towards its target, `d` its distance to the target (`m` or
    /// `255 − m`), `s = min(shift, 7)` and `u_k` byte `k` of `dither`. The expected move is
    /// exactly `d / 2^s`, where truncation (what an 8-bit average of fixed rounding does) would
    /// lose up to one LSB a step and stop a rarely occupied cell from ever registering at
    /// `s` ≥ 5. A fourth byte rides along unchanged.
    #[inline]
    fn average_row(counts: &mut [Self], start: usize, n: usize, bits: u32, shift: u8, dither: u32) {
        let Some(w4) = counts.get_mut(start..start + 4).filter(|_| n == 3) else {
            // Not a 3-cell row with a byte after it: one cell at a time, the same rule.
            if let Some(row) = counts.get_mut(start..start + n) {
                for (k, c) in row.iter_mut().enumerate() {
                    *c = average_byte(
                        *c,
                        bits >> k & 1 != 0,
                        shift,
                        (dither >> (8 * (k & 3))) as u8,
                    );
                }
            }
            return;
        };
        let mut bytes = [0u8; 4];
        bytes.copy_from_slice(w4);
        let m = u32::from_le_bytes(bytes);
        w4.copy_from_slice(&average_word(m, bits, &AverageShift::new(shift), dither).to_le_bytes());
    }
    #[inline]
    fn average_patch3(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: u8,
        dither: u32,
    ) {
        Self::average_patch3_at(
            counts,
            start,
            width,
            config,
            &AverageShift::new(shift),
            dither,
        );
    }
    /// The robot's hot path: one bounds check for the patch, three unaligned word updates.
    #[inline]
    fn average_patch3_at(
        counts: &mut [Self],
        start: usize,
        width: usize,
        config: u32,
        shift: &AverageShift,
        dither: u32,
    ) {
        let Some(area) = counts.get_mut(start..start + 2 * width + 4) else {
            // At the map's last cell there is no byte after the patch: the general path.
            average_rows_u8(counts, start, width, config, shift.shift, dither);
            return;
        };
        for r in 0..3 {
            let Some(w4) = area
                .get_mut(r * width..r * width + 4)
                .and_then(|w| <&mut [u8; 4]>::try_from(w).ok())
            else {
                continue;
            };
            let d = row_dither(dither, r);
            *w4 = average_word(u32::from_le_bytes(*w4), config >> (3 * r), shift, d).to_le_bytes();
        }
    }
}

/// [`Count::average_patch3`] for `u8` a row at a time: where the patch has no byte after it.
/// Out of line and cold, so that the hot path's registers are not planned around it.
#[cold]
#[inline(never)]
fn average_rows_u8(
    counts: &mut [u8],
    start: usize,
    width: usize,
    config: u32,
    shift: u8,
    dither: u32,
) {
    average_rows(counts, start, width, config, shift, dither);
}

/// The body of [`Count::average_patch3`]'s default: [`Count::average_row`] of each of the
/// patch's three rows. One copy for the default and [`average_rows_u8`] (which `u8`'s override
/// cannot reach through the trait method: it would call itself).
#[inline(always)]
fn average_rows<N: Count>(
    counts: &mut [N],
    start: usize,
    width: usize,
    config: u32,
    shift: u8,
    dither: u32,
) {
    for r in 0..3 {
        N::average_row(
            counts,
            start + r * width,
            3,
            config >> (3 * r),
            shift,
            row_dither(dither, r),
        );
    }
}

/// The dither of row `r` of a patch: the patch's word rotated by `8 r` bits, so the three cells
/// of a column take different bytes. Every averaging path takes its rows' dither from here.
#[inline]
pub(super) fn row_dither(dither: u32, r: usize) -> u32 {
    dither.rotate_right(8 * r as u32)
}

/// The `u8` rule of [`Count::average_row`] for one cell: moves `m` towards 255 (`occupied`) or
/// 0 by `⌊(d + u mod 2^s) / 2^s⌋`, `d` the distance, `s = min(shift, 7)`.
#[inline]
pub fn average_byte(m: u8, occupied: bool, shift: u8, u: u8) -> u8 {
    let s = u32::from(shift.min(7));
    let d = if occupied {
        255 - u32::from(m)
    } else {
        u32::from(m)
    };
    // ≤ 255 + 127 before the shift; the step is ≤ d.
    let step = ((d + (u32::from(u) & ((1 << s) - 1))) >> s) as u8;
    if occupied {
        m.saturating_add(step)
    } else {
        m.saturating_sub(step)
    }
}

/// An averaging shift and what `average_word` derives from it: `s = min(shift, 7)`, the
/// remainder mask `2^s − 1` and the quotient mask `0xFF >> s` in bytes 0..3.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AverageShift {
    pub(super) shift: u8,
    s: u32,
    low: u32,
    quotient: u32,
}

impl AverageShift {
    /// The masks of `shift`. Not inlined: once per tile visit.
    #[inline(never)]
    pub fn new(shift: u8) -> Self {
        const LANES: u32 = 0x0001_0101;
        let s = u32::from(shift.min(7));
        AverageShift {
            shift,
            s,
            low: ((1 << s) - 1) * LANES,
            quotient: (0xFF >> s) * LANES,
        }
    }

    /// The shift.
    #[inline]
    pub fn shift(&self) -> u8 {
        self.shift
    }
}

/// [`average_word`]'s byte masks: byte k of entry t is 0xFF iff bit k of t is set.
static FLIP: [u32; 8] = build_flip();

// Const-evaluated: an out-of-range index would fail compilation, not panic at run time.
#[allow(clippy::indexing_slicing)]
const fn build_flip() -> [u32; 8] {
    let mut f = [0u32; 8];
    let mut t = 0;
    while t < 8 {
        f[t] = ((t as u32 & 1) | (t as u32 & 2) << 7 | (t as u32 & 4) << 14) * 0xFF;
        t += 1;
    }
    f
}

/// [`average_byte`] of three `u8` cells packed in bytes 0..3 of `m`, towards bits 0..3 of
/// `bits`, with byte `k` of `dither` for cell `k`; byte 3 is unchanged. Branch-free: the bytes
/// whose target is 255 are complemented so that every target is 0, the distance's quotient and
/// the dithered remainder's carry are taken bytewise (neither crosses a byte: the remainder
/// and the dither are < 2^s ≤ 128 each), subtracted, and complemented back.
#[inline]
fn average_word(m: u32, bits: u32, shift: &AverageShift, dither: u32) -> u32 {
    let (s, low) = (shift.s, shift.low);
    // Bytes 0..3 = 0xFF where bit k of bits is set: one load (the bit spreading was six
    // instructions a row on the M4).
    let flip = FLIP.get((bits & 7) as usize).copied().unwrap_or(0);
    let d = m ^ flip;
    let quotient = (d >> s) & shift.quotient;
    // The sum is < 2^(s+1) per byte: its bit s is the carry. Masked with `!low` before the
    // shift, not with LANES after it, so the averaging needs one constant less in a register.
    let carry = (((d & low) + (dither & low)) & !low) >> s;
    // Per byte the step is ≤ d: no borrow between bytes.
    (d - (quotient + carry)) ^ flip
}
