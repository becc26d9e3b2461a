//! Marking a walk's cells in a bitset (the mapper's per-scan marks): cell by cell, or run by run
//! where a run costs less than stepping through its cells.

use super::IndexWalk;

impl IndexWalk {
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
            // the minor step back (`walk::tests::fast_walk_matches_u64_walk` checks the cells).
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
/// (chosen with callgrind on x86-64 on the shared CARMEN logs, docs/performance.md).
const LONG_RUN: u32 = 4;

/// Whether runs of consecutive indices shorter than [`LONG_RUN`] are marked run by run too. On
/// a 64-bit host a mask per word beats stepping their cells (callgrind, docs/performance.md); a
/// Cortex-M4 spills the run loop's state to the stack and spends ~47 instructions per run
/// against ~14 per cell stepped, so there a ray of short runs (slope ⅓ … ½) is stepped cell by
/// cell (per-scan step 133.0 → 131.2 instructions per updated cell, docs/performance.md).
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
