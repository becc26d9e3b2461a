//! Moving a row-major `width × height` map by whole cells in place: what a rolling window does to
//! each of its per-cell arrays when its origin moves ([`crate::session::Session::apply_shift`]).
//!
//! A shift by `(dx, dy)` makes cell `(x, y)` hold what cell `(x + dx, y + dy)` held; cells whose
//! source lies outside the map get a fill value. The copy is one `copy_within` (a `memmove`)
//! per row for typed cells and a word-wise bit copy for bitsets, so the map keeps its linear
//! indexing and every hot loop stays as it is (docs/performance.md, "Rolling window").
//!
//! Rows are visited so that no source row is overwritten before it is read (ascending for
//! `dy > 0`, descending for `dy < 0`); within one row `copy_within` and [`copy_bits`] handle
//! the overlap. Shifts of `width` or `height` cells or more fill everything.

/// One run of a shift ([`shift_rows`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Run {
    /// Cells `src .. src + len` go to `dst ..` (the ranges may overlap).
    Copy {
        /// First destination cell.
        dst: usize,
        /// First source cell.
        src: usize,
        /// Cells.
        len: usize,
    },
    /// Cells `start .. start + len` have no source.
    Fill {
        /// First cell.
        start: usize,
        /// Cells.
        len: usize,
    },
}

/// Calls `run` with every row run of a shift of `(dx, dy)` cells on a `width × height`
/// row-major map — the runs that keep a source ([`Run::Copy`]) and those that have none
/// ([`Run::Fill`]) — in an order that is safe in place.
pub fn shift_rows(width: usize, height: usize, dx: i32, dy: i32, mut run: impl FnMut(Run)) {
    let (w, h) = (width as i64, height as i64);
    let (dx, dy) = (i64::from(dx), i64::from(dy));
    if dx.abs() >= w || dy.abs() >= h {
        for y in 0..height {
            run(Run::Fill {
                start: y * width,
                len: width,
            });
        }
        return;
    }
    // Columns that keep a source: x in [x0, x1), source x + dx.
    let (x0, x1) = ((-dx).max(0), (w - dx).min(w));
    let keep = (x1 - x0) as usize;
    let mut row = |y: i64| {
        let dst = (y * w) as usize;
        let sy = y + dy;
        if !(0..h).contains(&sy) {
            run(Run::Fill {
                start: dst,
                len: width,
            });
            return;
        }
        run(Run::Copy {
            dst: dst + x0 as usize,
            src: (sy * w + x0 + dx) as usize,
            len: keep,
        });
        if x0 > 0 {
            run(Run::Fill {
                start: dst,
                len: x0 as usize,
            });
        }
        if x1 < w {
            run(Run::Fill {
                start: dst + x1 as usize,
                len: (w - x1) as usize,
            });
        }
    };
    if dy >= 0 {
        (0..h).for_each(&mut row);
    } else {
        (0..h).rev().for_each(&mut row);
    }
}

/// Shifts the typed cells of a `width × height` map (see the module); cells without a source
/// become `fill`. A slice shorter than the map is left as it is.
pub fn shift_cells<T: Copy>(
    cells: &mut [T],
    width: usize,
    height: usize,
    dx: i32,
    dy: i32,
    fill: T,
) {
    if cells.len() < width.saturating_mul(height) {
        return;
    }
    // Overlapping ranges are fine: `copy_within` is a memmove. The runs lie inside the map
    // (`shift_rows`); the checks keep the function free of panic paths.
    shift_rows(width, height, dx, dy, |r| match r {
        Run::Copy { dst, src, len } => {
            if src.max(dst).saturating_add(len) <= cells.len() {
                cells.copy_within(src..src + len, dst);
            }
        }
        Run::Fill { start, len } => {
            if let Some(run) = cells.get_mut(start..start.saturating_add(len)) {
                run.fill(fill);
            }
        }
    });
}

/// Shifts a bitset of one bit per cell (bit `i % 32` of word `i / 32` is cell `i`) like
/// [`shift_cells`]; cells without a source become `fill`.
pub fn shift_bits(words: &mut [u32], width: usize, height: usize, dx: i32, dy: i32, fill: bool) {
    if words.len() < width.saturating_mul(height).div_ceil(32) {
        return;
    }
    shift_rows(width, height, dx, dy, |r| match r {
        Run::Copy { dst, src, len } => copy_bits(words, dst, src, len),
        Run::Fill { start, len } => fill_bits(words, start, len, fill),
    });
}

/// Bits `src .. src + len` copied to `dst ..` (overlap allowed, like `memmove`), in chunks of up
/// to 16 bits, in the direction that reads every source bit before it is overwritten.
pub fn copy_bits(words: &mut [u32], dst: usize, src: usize, len: usize) {
    const CHUNK: usize = 16;
    let mut move_chunk = |off: usize, n: usize| {
        let v = get_bits(words, src + off, n);
        set_bits(words, dst + off, n, v);
    };
    if dst <= src {
        let mut off = 0;
        while off < len {
            let n = CHUNK.min(len - off);
            move_chunk(off, n);
            off += n;
        }
    } else {
        let mut end = len;
        while end > 0 {
            let n = CHUNK.min(end);
            move_chunk(end - n, n);
            end -= n;
        }
    }
}

/// Sets bits `start .. start + len` to `v`.
pub fn fill_bits(words: &mut [u32], start: usize, len: usize, v: bool) {
    let mut i = start;
    let end = start.saturating_add(len);
    while i < end {
        let (w, off) = (i / 32, i % 32);
        let n = (32 - off).min(end - i);
        let mask = if n == 32 {
            u32::MAX
        } else {
            ((1u32 << n) - 1) << off
        };
        if let Some(word) = words.get_mut(w) {
            if v {
                *word |= mask;
            } else {
                *word &= !mask;
            }
        }
        i += n;
    }
}

/// `n` ≤ 16 bits from bit `index`, bit 0 first (bits past the slice read 0).
fn get_bits(words: &[u32], index: usize, n: usize) -> u32 {
    let (w, off) = (index / 32, (index % 32) as u32);
    let lo = u64::from(words.get(w).copied().unwrap_or(0));
    let hi = u64::from(words.get(w + 1).copied().unwrap_or(0));
    (((hi << 32 | lo) >> off) & ((1u64 << n) - 1)) as u32
}

/// Writes the `n` ≤ 16 bits `v` at bit `index`.
fn set_bits(words: &mut [u32], index: usize, n: usize, v: u32) {
    let (w, off) = (index / 32, (index % 32) as u32);
    let mask = (1u64 << n) - 1;
    let (m, v) = (mask << off, (u64::from(v) & mask) << off);
    if let Some(lo) = words.get_mut(w) {
        *lo = (*lo & !(m as u32)) | v as u32;
    }
    if off as usize + n > 32 {
        if let Some(hi) = words.get_mut(w + 1) {
            *hi = (*hi & !((m >> 32) as u32)) | (v >> 32) as u32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The shift by definition: cell (x, y) takes (x + dx, y + dy) or the fill.
    fn naive<T: Copy>(cells: &[T], w: usize, h: usize, dx: i32, dy: i32, fill: T) -> Vec<T> {
        let mut out = vec![fill; w * h];
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let (sx, sy) = (x + i64::from(dx), y + i64::from(dy));
                if (0..w as i64).contains(&sx) && (0..h as i64).contains(&sy) {
                    out[(y * w as i64 + x) as usize] = cells[(sy * w as i64 + sx) as usize];
                }
            }
        }
        out
    }

    proptest! {
        #[test]
        fn cells_shift_as_defined(
            w in 1usize..40, h in 1usize..40, dx in -50i32..50, dy in -50i32..50, seed: u64,
        ) {
            let cells: Vec<u16> = (0..w * h).map(|i| (i as u64 ^ seed) as u16).collect();
            let mut got = cells.clone();
            shift_cells(&mut got, w, h, dx, dy, 0xFFFF);
            prop_assert_eq!(got, naive(&cells, w, h, dx, dy, 0xFFFF));
        }

        #[test]
        fn bits_shift_as_defined(
            w in 1usize..70, h in 1usize..30, dx in -80i32..80, dy in -40i32..40,
            seed: u64, fill: bool,
        ) {
            let n = w * h;
            let mut state = seed | 1;
            let bits: Vec<bool> = (0..n).map(|_| {
                state ^= state << 13; state ^= state >> 7; state ^= state << 17;
                state & 1 == 1
            }).collect();
            let mut words = vec![0u32; n.div_ceil(32)];
            for (i, b) in bits.iter().enumerate() {
                if *b { words[i / 32] |= 1 << (i % 32); }
            }
            // Bits past the map (in the last word) are left alone.
            let past = if n % 32 == 0 { 0 } else { !((1u32 << (n % 32)) - 1) };
            words[n / 32 - usize::from(n % 32 == 0)] |= past & (seed as u32);
            let tail = words.last().copied().unwrap_or(0) & past;
            shift_bits(&mut words, w, h, dx, dy, fill);
            let got: Vec<bool> = (0..n).map(|i| words[i / 32] >> (i % 32) & 1 == 1).collect();
            prop_assert_eq!(got, naive(&bits, w, h, dx, dy, fill));
            let tail_after = words.last().copied().unwrap_or(0) & past;
            prop_assert_eq!(tail, tail_after);
        }

        #[test]
        fn extreme_shifts_fill_everything(dx: i32, dy: i32) {
            let mut cells = vec![7u8; 12];
            shift_cells(&mut cells, 4, 3, dx, dy, 0);
            let expect = naive(&[7u8; 12], 4, 3, dx.clamp(-5, 5), dy.clamp(-5, 5), 0);
            prop_assert_eq!(cells, expect);
        }
    }

    #[test]
    fn short_buffers_are_left_alone() {
        let mut cells = vec![1u8; 5];
        shift_cells(&mut cells, 4, 4, 1, 0, 0);
        assert_eq!(cells, vec![1u8; 5]);
        let mut words = vec![u32::MAX; 1];
        shift_bits(&mut words, 8, 8, 1, 1, false);
        assert_eq!(words, vec![u32::MAX]);
    }
}
