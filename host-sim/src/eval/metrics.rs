//! Map-quality metrics against ground truth, as in Merali & Barfoot §IV.
//!
//! * **Precision / recall / F1 over thresholds.** A cell is *predicted occupied* iff its
//!   occupancy probability `p ≥ t`. Against the truth: TP = predicted occupied ∧ truth
//!   [`Truth::Occupied`], FP = predicted occupied ∧ truth [`Truth::Free`], FN = predicted free ∧
//!   truth [`Truth::Occupied`]; [`Truth::Unknown`] cells (and cells outside an optional mask) are
//!   ignored. precision = TP/(TP+FP), recall = TP/(TP+FN), F1 = 2PR/(P+R). The thresholds are the
//!   [`NUM_THRESHOLDS`] values `t_k = k/1000`, `k = 0..=1000`, evaluated exactly (the comparison
//!   is `p >= k as f64 / 1000.0`). Results are pooled over many maps, as the paper pools "all
//!   500×500×100 cells": feed every map to one [`PrAccumulator`].
//! * **The hardware mask** ([`mask_within`]): only cells within `n` cells (Euclidean, cell
//!   centres) of a mapped cell are scored, via an exact Euclidean distance transform.
//! * **KL divergence** helpers ([`kl_bernoulli`], [`kl_sum`]) for comparing marginals.

use serde::{Deserialize, Serialize};

use ogm_field::world::Truth;

/// Number of evaluated thresholds: `t_k = k/1000` for `k = 0..=1000`.
pub const NUM_THRESHOLDS: usize = 1001;

/// Histogram slots: "first failed threshold" index `0..=1000`, plus `1001` = never fails.
const NUM_BUCKETS: usize = NUM_THRESHOLDS + 1;

/// Clamp applied to the approximating distribution `q` by [`kl_sum`].
pub const KL_Q_CLAMP: f64 = 1e-12;

/// The `k`-th threshold, `k / 1000` (correctly rounded), `k = 0..=1000`.
pub fn threshold(k: usize) -> f64 {
    k as f64 / 1000.0
}

/// Errors from the metric functions.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum MetricsError {
    /// Two slices that must describe the same cells have different lengths.
    #[error("length mismatch: {what} has {got} entries, expected {expected}")]
    LengthMismatch {
        /// Which argument was the wrong length.
        what: &'static str,
        /// The length it should have had.
        expected: usize,
        /// The length it had.
        got: usize,
    },
}

/// One point of a precision–recall curve (one threshold).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PrPoint {
    /// The threshold `t`; a cell is predicted occupied iff `p ≥ t`.
    pub threshold: f64,
    /// TP / (TP + FP); `1.0` by convention when no cell is predicted occupied (`tp + fp == 0`).
    pub precision: f64,
    /// TP / (TP + FN); `0.0` by convention when the truth has no occupied cell.
    pub recall: f64,
    /// 2PR / (P + R), computed as 2TP / (2TP + FP + FN); `0.0` when TP = 0.
    pub f1: f64,
    /// True positives.
    pub tp: u64,
    /// False positives.
    pub fp: u64,
    /// False negatives.
    pub fn_: u64,
}

impl PrPoint {
    /// Whether at least one cell is predicted occupied at this threshold (so precision is a real
    /// ratio rather than the `tp + fp == 0` convention).
    pub fn any_predicted(&self) -> bool {
        self.tp + self.fp > 0
    }
}

/// The paper's Table II numbers for one method, pooled over all evaluated cells.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Highest F1 over the thresholds.
    pub max_f1: f64,
    /// Highest precision over the thresholds at which at least one cell is predicted occupied
    /// (`0.0` if there is none).
    pub max_precision: f64,
    /// The threshold attaining `max_f1` (the smallest one on ties).
    pub threshold_at_max_f1: f64,
    /// Precision at `threshold_at_max_f1`.
    pub precision_at_max_f1: f64,
    /// Recall at `threshold_at_max_f1`.
    pub recall_at_max_f1: f64,
    /// Cells that entered the counts (inside the mask, truth not `Unknown`).
    pub cells_evaluated: u64,
    /// How many of those had a NaN probability (scored as 0.5).
    #[serde(default)]
    pub nan_cells: u64,
}

/// Pools threshold histograms over any number of maps; see the module docs.
///
/// Each evaluated cell is bucketed by the first threshold index it fails (`p < t_k`), so adding a
/// map is O(cells) and [`PrAccumulator::curve`] is O(thresholds).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PrAccumulator {
    /// Truth-occupied cells per first-failed-threshold bucket (`NUM_BUCKETS` entries).
    occupied: Vec<u64>,
    /// Truth-free cells per first-failed-threshold bucket (`NUM_BUCKETS` entries).
    free: Vec<u64>,
    /// NaN probabilities among evaluated cells.
    nan_cells: u64,
}

impl Default for PrAccumulator {
    fn default() -> Self {
        Self::new()
    }
}

/// Index of the first threshold `p` fails (`p < t_k`), `0..=1000`, or `1001` if it passes all.
///
/// NaN must be replaced before calling. Negative values fail every threshold; values `≥ 1`
/// (including +∞) pass every threshold.
fn first_failed_threshold(p: f64) -> usize {
    debug_assert!(!p.is_nan());
    if p < 0.0 {
        return 0;
    }
    if p >= 1.0 {
        return NUM_THRESHOLDS;
    }
    // Largest k with p >= t_k; the floor is a guess that can be off by one at bucket edges
    // because `p * 1000.0` rounds, so correct it against the exact comparison.
    let mut k = ((p * 1000.0).floor() as usize).min(NUM_THRESHOLDS - 1);
    while k > 0 && p < threshold(k) {
        k -= 1;
    }
    while k + 1 < NUM_THRESHOLDS && p >= threshold(k + 1) {
        k += 1;
    }
    k + 1
}

impl PrAccumulator {
    /// An empty accumulator.
    pub fn new() -> Self {
        Self {
            occupied: vec![0; NUM_BUCKETS],
            free: vec![0; NUM_BUCKETS],
            nan_cells: 0,
        }
    }

    /// Adds one map: `probs[i]` is the occupancy probability of the cell whose truth is
    /// `truth[i]`; cells with `mask[i] == false` are skipped, as are `Unknown` truth cells.
    /// A NaN probability is scored as 0.5 and counted in [`PrAccumulator::nan_cells`].
    ///
    /// Errors (adding nothing) if the slice lengths differ.
    pub fn add(
        &mut self,
        probs: &[f64],
        truth: &[Truth],
        mask: Option<&[bool]>,
    ) -> Result<(), MetricsError> {
        if probs.len() != truth.len() {
            return Err(MetricsError::LengthMismatch {
                what: "probs",
                expected: truth.len(),
                got: probs.len(),
            });
        }
        if let Some(m) = mask {
            if m.len() != truth.len() {
                return Err(MetricsError::LengthMismatch {
                    what: "mask",
                    expected: truth.len(),
                    got: m.len(),
                });
            }
        }
        for (i, (&p, &t)) in probs.iter().zip(truth).enumerate() {
            if mask.is_some_and(|m| !m[i]) {
                continue;
            }
            let hist = match t {
                Truth::Occupied => &mut self.occupied,
                Truth::Free => &mut self.free,
                Truth::Unknown => continue,
            };
            let p = if p.is_nan() {
                self.nan_cells += 1;
                0.5
            } else {
                p
            };
            hist[first_failed_threshold(p)] += 1;
        }
        Ok(())
    }

    /// Pools another accumulator into this one (e.g. from parallel workers).
    pub fn merge(&mut self, other: &PrAccumulator) {
        for (a, b) in self.occupied.iter_mut().zip(&other.occupied) {
            *a += b;
        }
        for (a, b) in self.free.iter_mut().zip(&other.free) {
            *a += b;
        }
        self.nan_cells += other.nan_cells;
    }

    /// Truth-occupied cells evaluated so far.
    pub fn occupied_cells(&self) -> u64 {
        self.occupied.iter().sum()
    }

    /// Truth-free cells evaluated so far.
    pub fn free_cells(&self) -> u64 {
        self.free.iter().sum()
    }

    /// Cells evaluated so far (inside the mask, truth not `Unknown`).
    pub fn cells_evaluated(&self) -> u64 {
        self.occupied_cells() + self.free_cells()
    }

    /// Evaluated cells whose probability was NaN (scored as 0.5).
    pub fn nan_cells(&self) -> u64 {
        self.nan_cells
    }

    /// The curve at all [`NUM_THRESHOLDS`] thresholds, in increasing threshold order.
    pub fn curve(&self) -> Vec<PrPoint> {
        let total_occ = self.occupied_cells();
        // Cells passing threshold k are those whose first failure is at an index > k.
        let mut tp = total_occ - self.occupied[0];
        let mut fp = self.free_cells() - self.free[0];
        let mut out = Vec::with_capacity(NUM_THRESHOLDS);
        for k in 0..NUM_THRESHOLDS {
            let fn_ = total_occ - tp;
            let precision = if tp + fp == 0 {
                1.0
            } else {
                tp as f64 / (tp + fp) as f64
            };
            let recall = if total_occ == 0 {
                0.0
            } else {
                tp as f64 / total_occ as f64
            };
            let f1 = if tp == 0 {
                0.0
            } else {
                2.0 * tp as f64 / (2 * tp + fp + fn_) as f64
            };
            out.push(PrPoint {
                threshold: threshold(k),
                precision,
                recall,
                f1,
                tp,
                fp,
                fn_,
            });
            tp -= self.occupied[k + 1];
            fp -= self.free[k + 1];
        }
        out
    }

    /// The Table II summary of [`PrAccumulator::curve`]. With nothing evaluated every number
    /// is 0.
    pub fn summary(&self) -> Summary {
        summarize(&self.curve(), self.cells_evaluated(), self.nan_cells)
    }
}

/// Summarises a curve (as from [`PrAccumulator::curve`]); `cells_evaluated` and `nan_cells`
/// are copied into the result. Ties for max F1 go to the earliest (smallest-threshold) point.
pub fn summarize(curve: &[PrPoint], cells_evaluated: u64, nan_cells: u64) -> Summary {
    let mut best: Option<&PrPoint> = None;
    for p in curve {
        if best.is_none_or(|b| p.f1 > b.f1) {
            best = Some(p);
        }
    }
    let max_precision = curve
        .iter()
        .filter(|p| p.any_predicted())
        .map(|p| p.precision)
        .fold(0.0, f64::max);
    Summary {
        max_f1: best.map_or(0.0, |b| b.f1),
        max_precision,
        threshold_at_max_f1: best.map_or(0.0, |b| b.threshold),
        precision_at_max_f1: best.map_or(0.0, |b| b.precision),
        recall_at_max_f1: best.map_or(0.0, |b| b.recall),
        cells_evaluated,
        nan_cells,
    }
}

/// Squared Euclidean distance (in cells, between cell centres) from each cell to the nearest
/// `true` cell of `mapped`; `u64::MAX` where `mapped` has no `true` cell at all.
///
/// Exact, O(width·height): a vertical two-pass scan followed by the Felzenszwalb–Huttenlocher
/// lower envelope of parabolas along each row.
///
/// # Panics
/// If `mapped.len() != width * height`.
pub fn squared_distance_transform(mapped: &[bool], width: usize, height: usize) -> Vec<u64> {
    let mut out = Vec::with_capacity(mapped.len());
    for_each_row_sq_distance(mapped, width, height, |row| out.extend_from_slice(row));
    out
}

/// The distance transform behind [`squared_distance_transform`], handing each row's squared
/// distances (bottom row first) to `emit` instead of materialising the whole grid.
fn for_each_row_sq_distance(
    mapped: &[bool],
    width: usize,
    height: usize,
    mut emit: impl FnMut(&[u64]),
) {
    assert_eq!(
        mapped.len(),
        width * height,
        "squared_distance_transform: mapped has {} cells, expected {width}x{height}",
        mapped.len()
    );
    // Vertical pass: distance (in rows) to the nearest mapped cell in the same column, done row
    // by row (up, then down) so every access is contiguous. u32::MAX = none in this column.
    let mut g = vec![u32::MAX; mapped.len()];
    for y in 0..height {
        let row = y * width;
        if y == 0 {
            for x in 0..width {
                if mapped[x] {
                    g[x] = 0;
                }
            }
            continue;
        }
        let (prev, cur) = g[row - width..row + width].split_at_mut(width);
        for ((c, &p), &m) in cur
            .iter_mut()
            .zip(prev.iter())
            .zip(&mapped[row..row + width])
        {
            *c = if m { 0 } else { p.saturating_add(1) };
        }
    }
    for y in (0..height.saturating_sub(1)).rev() {
        let row = y * width;
        let (cur, next) = g[row..row + 2 * width].split_at_mut(width);
        for (c, &n) in cur.iter_mut().zip(next.iter()) {
            *c = (*c).min(n.saturating_add(1));
        }
    }
    // Horizontal pass: lower envelope of parabolas f(q) + (x - q)² over columns q with finite f.
    let mut row_out = vec![u64::MAX; width];
    let mut v: Vec<usize> = Vec::with_capacity(width);
    let mut z: Vec<f64> = Vec::with_capacity(width + 1);
    for y in 0..height {
        let gr = &g[y * width..(y + 1) * width];
        let f = |q: usize| -> i64 {
            let d = gr[q] as i64;
            d * d
        };
        v.clear();
        z.clear();
        for (q, &gq) in gr.iter().enumerate() {
            if gq == u32::MAX {
                continue;
            }
            if v.is_empty() {
                v.push(q);
                z.push(f64::NEG_INFINITY);
                z.push(f64::INFINITY);
                continue;
            }
            let fq = f(q) + (q * q) as i64;
            let s = loop {
                let r = *v.last().expect("envelope non-empty");
                let s = (fq - f(r) - (r * r) as i64) as f64 / (2 * (q - r)) as f64;
                // z[v.len() - 1] is where the last parabola starts; z[0] = -inf, so the envelope
                // never empties.
                if s <= z[v.len() - 1] {
                    v.pop();
                    z.pop();
                } else {
                    break s;
                }
            };
            v.push(q);
            *z.last_mut().expect("z has v.len() + 1 entries") = s;
            z.push(f64::INFINITY);
        }
        if v.is_empty() {
            row_out.fill(u64::MAX);
        } else {
            let mut k = 0;
            for (x, o) in row_out.iter_mut().enumerate() {
                while z[k + 1] < x as f64 {
                    k += 1;
                }
                let r = v[k];
                let dx = x.abs_diff(r) as u64;
                let d = gr[r] as u64;
                *o = dx * dx + d * d;
            }
        }
        emit(&row_out);
    }
}

/// The largest squared integer distance `d2` with `sqrt(d2) ≤ n`, or `None` if no distance
/// qualifies; `Some(u64::MAX - 1)` when every finite distance in a grid qualifies.
fn max_squared_distance(n: f64, width: usize, height: usize) -> Option<u64> {
    if n.is_nan() || n < 0.0 {
        return None;
    }
    let w = width.saturating_sub(1) as f64;
    let h = height.saturating_sub(1) as f64;
    if n * n > w * w + h * h + 1.0 {
        return Some(u64::MAX - 1);
    }
    let mut m = (n * n).floor() as u64;
    while m > 0 && (m as f64).sqrt() > n {
        m -= 1;
    }
    while ((m + 1) as f64).sqrt() <= n {
        m += 1;
    }
    Some(m)
}

/// The paper's hardware evaluation mask: cells whose Euclidean distance (between cell centres,
/// in cells) to some `mapped` cell is `≤ n`. Mapped cells are always included (for `n ≥ 0`);
/// a negative or NaN `n`, or no mapped cell at all, gives an all-`false` mask.
///
/// Exact and O(width·height) via [`squared_distance_transform`].
///
/// # Panics
/// If `mapped.len() != width * height`.
pub fn mask_within(mapped: &[bool], width: usize, height: usize, n: f64) -> Vec<bool> {
    assert_eq!(
        mapped.len(),
        width * height,
        "mask_within: mapped has {} cells, expected {width}x{height}",
        mapped.len()
    );
    let Some(d2max) = max_squared_distance(n, width, height) else {
        return vec![false; mapped.len()];
    };
    let mut out = Vec::with_capacity(mapped.len());
    for_each_row_sq_distance(mapped, width, height, |row| {
        out.extend(row.iter().map(|&d2| d2 <= d2max));
    });
    out
}

/// KL divergence (nats) between Bernoulli(p) and Bernoulli(q):
/// `p ln(p/q) + (1-p) ln((1-p)/(1-q))`, with `0 ln 0 = 0`. No clamping: it is `+∞` when `q` is 0
/// or 1 and `p` puts mass where `q` has none; NaN for arguments outside `[0, 1]`.
pub fn kl_bernoulli(p: f64, q: f64) -> f64 {
    fn term(a: f64, b: f64) -> f64 {
        if a == 0.0 {
            0.0
        } else {
            a * (a / b).ln()
        }
    }
    if !(0.0..=1.0).contains(&p) || !(0.0..=1.0).contains(&q) {
        return f64::NAN;
    }
    term(p, q) + term(1.0 - p, 1.0 - q)
}

/// Summed per-cell KL divergence `Σ KL(Bern(p_i) ‖ Bern(q_i))` (nats), with each `q_i` clamped
/// to `[KL_Q_CLAMP, 1 - KL_Q_CLAMP]` so a confident-but-wrong `q` gives a large finite value.
/// `p` is the reference (e.g. exact or long-run marginals), `q` the approximation.
///
/// Errors if the lengths differ.
pub fn kl_sum(p: &[f64], q: &[f64]) -> Result<f64, MetricsError> {
    if p.len() != q.len() {
        return Err(MetricsError::LengthMismatch {
            what: "q",
            expected: p.len(),
            got: q.len(),
        });
    }
    Ok(p.iter()
        .zip(q)
        .map(|(&p, &q)| kl_bernoulli(p, q.clamp(KL_Q_CLAMP, 1.0 - KL_Q_CLAMP)))
        .sum())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use Truth::{Free as F, Occupied as O, Unknown as U};

    fn next_down(x: f64) -> f64 {
        assert!(x > 0.0);
        f64::from_bits(x.to_bits() - 1)
    }

    fn next_up(x: f64) -> f64 {
        assert!(x >= 0.0);
        f64::from_bits(x.to_bits() + 1)
    }

    /// Straightforward O(cells · thresholds) reference.
    fn naive_curve(probs: &[f64], truth: &[Truth], mask: Option<&[bool]>) -> Vec<(u64, u64, u64)> {
        (0..NUM_THRESHOLDS)
            .map(|k| {
                let t = k as f64 / 1000.0;
                let (mut tp, mut fp, mut fn_) = (0, 0, 0);
                for i in 0..probs.len() {
                    if mask.is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let p = if probs[i].is_nan() { 0.5 } else { probs[i] };
                    match (p >= t, truth[i]) {
                        (true, O) => tp += 1,
                        (true, F) => fp += 1,
                        (false, O) => fn_ += 1,
                        _ => {}
                    }
                }
                (tp, fp, fn_)
            })
            .collect()
    }

    fn counts(curve: &[PrPoint]) -> Vec<(u64, u64, u64)> {
        curve.iter().map(|p| (p.tp, p.fp, p.fn_)).collect()
    }

    #[test]
    fn bucket_edges_are_exact() {
        for k in 0..NUM_THRESHOLDS {
            let t = threshold(k);
            assert_eq!(first_failed_threshold(t), k + 1, "p = t_{k}");
            if k > 0 {
                assert_eq!(
                    first_failed_threshold(next_down(t)),
                    k,
                    "p just below t_{k}"
                );
            }
            if k < NUM_THRESHOLDS - 1 {
                assert_eq!(
                    first_failed_threshold(next_up(t)),
                    k + 1,
                    "p just above t_{k}"
                );
            }
        }
        assert_eq!(first_failed_threshold(-0.1), 0);
        assert_eq!(first_failed_threshold(f64::NEG_INFINITY), 0);
        assert_eq!(first_failed_threshold(-0.0), 1);
        assert_eq!(first_failed_threshold(1.5), NUM_THRESHOLDS);
        assert_eq!(first_failed_threshold(f64::INFINITY), NUM_THRESHOLDS);
        assert_eq!(first_failed_threshold(next_down(1.0)), NUM_THRESHOLDS - 1);
    }

    #[test]
    fn hand_computed_case() {
        // p:     0.9 O, 0.6 O, 0.3 O, 0.7 F, 0.2 F, 0.5 F, 0.99 Unknown (ignored)
        let probs = [0.9, 0.6, 0.3, 0.7, 0.2, 0.5, 0.99];
        let truth = [O, O, O, F, F, F, U];
        let mut acc = PrAccumulator::new();
        acc.add(&probs, &truth, None).unwrap();
        let c = acc.curve();
        assert_eq!(c.len(), NUM_THRESHOLDS);
        assert_eq!(acc.cells_evaluated(), 6);
        assert_eq!(acc.occupied_cells(), 3);
        assert_eq!(acc.free_cells(), 3);

        // t = 0: everything predicted occupied.
        assert_eq!((c[0].tp, c[0].fp, c[0].fn_), (3, 3, 0));
        assert_eq!(c[0].precision, 0.5);
        assert_eq!(c[0].recall, 1.0);
        assert!((c[0].f1 - 2.0 / 3.0).abs() < 1e-15);
        // t = 0.5 exactly: 0.5 F counts as predicted occupied (p >= t).
        assert_eq!(c[500].threshold, 0.5);
        assert_eq!((c[500].tp, c[500].fp, c[500].fn_), (2, 2, 1));
        // t = 0.501: the 0.5 cell drops out.
        assert_eq!((c[501].tp, c[501].fp, c[501].fn_), (2, 1, 1));
        // t = 0.6 exactly keeps 0.6 O.
        assert_eq!((c[600].tp, c[600].fp, c[600].fn_), (2, 1, 1));
        assert_eq!((c[601].tp, c[601].fp, c[601].fn_), (1, 1, 2));
        // t = 0.7 exactly keeps 0.7 F; 0.701 drops it.
        assert_eq!((c[700].tp, c[700].fp), (1, 1));
        assert_eq!((c[701].tp, c[701].fp), (1, 0));
        assert_eq!(c[701].precision, 1.0);
        assert!((c[701].recall - 1.0 / 3.0).abs() < 1e-15);
        // t = 0.9 keeps the 0.9 cell; above it nothing is predicted.
        assert_eq!(c[900].tp, 1);
        assert_eq!((c[901].tp, c[901].fp, c[901].fn_), (0, 0, 3));
        assert_eq!(c[901].precision, 1.0);
        assert_eq!(c[901].recall, 0.0);
        assert_eq!(c[901].f1, 0.0);
        assert!(!c[901].any_predicted());
        assert!(c[900].any_predicted());

        // F1 by range: [0, 0.2] 2·3/(6+3)=2/3; (0.2,0.3] 6/8=0.75; (0.3,0.5] 4/(4+2+1)=4/7;
        // (0.5,0.6] 4/6=2/3; (0.6,0.7] 2/(2+1+2)=0.4; (0.7,0.9] 2/4=0.5.
        let s = acc.summary();
        assert!((s.max_f1 - 0.75).abs() < 1e-15);
        assert_eq!(s.threshold_at_max_f1, 0.201);
        assert_eq!(s.precision_at_max_f1, 0.6);
        assert_eq!(s.recall_at_max_f1, 1.0);
        assert_eq!(s.max_precision, 1.0);
        assert_eq!(s.cells_evaluated, 6);
        assert_eq!(s.nan_cells, 0);
        assert_eq!(counts(&c), naive_curve(&probs, &truth, None));
    }

    #[test]
    fn max_f1_ties_pick_smallest_threshold_and_max_precision_ignores_empty() {
        // One occupied cell at 0.4, one free at 0.1: F1 = 1 for t in (0.1, 0.4].
        let mut acc = PrAccumulator::new();
        acc.add(&[0.4, 0.1], &[O, F], None).unwrap();
        let s = acc.summary();
        assert_eq!(s.max_f1, 1.0);
        assert_eq!(s.threshold_at_max_f1, 0.101);
        assert_eq!(s.max_precision, 1.0);

        // All cells free: precision is 0 wherever anything is predicted; the vacuous 1.0 above
        // the largest probability must not count.
        let mut acc = PrAccumulator::new();
        acc.add(&[0.3, 0.6], &[F, F], None).unwrap();
        let s = acc.summary();
        assert_eq!(s.max_precision, 0.0);
        assert_eq!(s.max_f1, 0.0);
        assert_eq!(s.threshold_at_max_f1, 0.0);
    }

    #[test]
    fn empty_accumulator_summary_is_zero() {
        let acc = PrAccumulator::default();
        let s = acc.summary();
        assert_eq!(s.max_f1, 0.0);
        assert_eq!(s.max_precision, 0.0);
        assert_eq!(s.cells_evaluated, 0);
        assert_eq!(acc.curve().len(), NUM_THRESHOLDS);
    }

    #[test]
    fn unknown_and_masked_cells_are_ignored() {
        let probs = [0.9, 0.9, 0.1, 0.9, 0.1];
        let truth = [O, U, O, F, F];
        let mask = [true, true, false, false, true];
        let mut acc = PrAccumulator::new();
        acc.add(&probs, &truth, Some(&mask)).unwrap();
        // Evaluated: 0.9 O and 0.1 F only.
        assert_eq!(acc.cells_evaluated(), 2);
        let s = acc.summary();
        assert_eq!(s.max_f1, 1.0);
        assert_eq!(s.threshold_at_max_f1, 0.101);
        assert_eq!(
            counts(&acc.curve()),
            naive_curve(&probs, &truth, Some(&mask))
        );
    }

    #[test]
    fn nan_counts_as_half_and_is_reported() {
        let mut acc = PrAccumulator::new();
        acc.add(&[f64::NAN, f64::NAN, f64::NAN], &[O, F, U], None)
            .unwrap();
        assert_eq!(acc.nan_cells(), 2);
        let c = acc.curve();
        assert_eq!((c[500].tp, c[500].fp), (1, 1));
        assert_eq!((c[501].tp, c[501].fp), (0, 0));
        assert_eq!(acc.summary().nan_cells, 2);
    }

    #[test]
    fn length_mismatch_is_an_error_and_adds_nothing() {
        let mut acc = PrAccumulator::new();
        assert_eq!(
            acc.add(&[0.5], &[O, F], None),
            Err(MetricsError::LengthMismatch {
                what: "probs",
                expected: 2,
                got: 1
            })
        );
        assert!(matches!(
            acc.add(&[0.5, 0.5], &[O, F], Some(&[true])),
            Err(MetricsError::LengthMismatch { what: "mask", .. })
        ));
        assert_eq!(acc, PrAccumulator::new());
        assert!(kl_sum(&[0.5], &[]).is_err());
    }

    #[test]
    fn summary_serde_field_names() {
        let mut acc = PrAccumulator::new();
        acc.add(&[0.8, 0.2], &[O, F], None).unwrap();
        let s = acc.summary();
        let json = serde_json::to_value(s).unwrap();
        for key in [
            "max_f1",
            "max_precision",
            "threshold_at_max_f1",
            "precision_at_max_f1",
            "recall_at_max_f1",
            "cells_evaluated",
        ] {
            assert!(json.get(key).is_some(), "missing {key}");
        }
        let back: Summary = serde_json::from_value(json).unwrap();
        assert_eq!(back, s);
        let point = serde_json::to_value(acc.curve()[3]).unwrap();
        assert!(point.get("fn_").is_some());
    }

    #[test]
    fn kl_values() {
        assert_eq!(kl_bernoulli(0.3, 0.3), 0.0);
        assert_eq!(kl_bernoulli(0.0, 0.0), 0.0);
        assert_eq!(kl_bernoulli(1.0, 1.0), 0.0);
        assert!((kl_bernoulli(1.0, 0.5) - 2f64.ln()).abs() < 1e-15);
        assert!((kl_bernoulli(0.0, 0.5) - 2f64.ln()).abs() < 1e-15);
        let expected = 0.25 * (0.25f64 / 0.5).ln() + 0.75 * (0.75f64 / 0.5).ln();
        assert!((kl_bernoulli(0.25, 0.5) - expected).abs() < 1e-15);
        assert_eq!(kl_bernoulli(1.0, 0.0), f64::INFINITY);
        assert!(kl_bernoulli(1.5, 0.5).is_nan());
        // Clamped: finite, equal to -ln(1e-12) for p = 1, q = 0.
        let s = kl_sum(&[1.0, 0.5], &[0.0, 0.5]).unwrap();
        assert!((s - (-(KL_Q_CLAMP).ln())).abs() < 1e-9, "{s}");
        assert_eq!(kl_sum(&[], &[]).unwrap(), 0.0);
    }

    fn brute_force_mask(mapped: &[bool], w: usize, h: usize, n: f64) -> Vec<bool> {
        let mut out = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                out[y * w + x] = (0..h).any(|my| {
                    (0..w).any(|mx| {
                        mapped[my * w + mx] && {
                            let dx = x as f64 - mx as f64;
                            let dy = y as f64 - my as f64;
                            (dx * dx + dy * dy).sqrt() <= n
                        }
                    })
                });
            }
        }
        out
    }

    #[test]
    fn mask_within_small_cases() {
        // 5x5 with the centre mapped.
        let mut m = vec![false; 25];
        m[12] = true;
        let within1 = mask_within(&m, 5, 5, 1.0);
        assert_eq!(within1.iter().filter(|&&b| b).count(), 5);
        let within_sqrt2 = mask_within(&m, 5, 5, 2f64.sqrt());
        assert_eq!(within_sqrt2.iter().filter(|&&b| b).count(), 9);
        let within_less = mask_within(&m, 5, 5, next_down(2f64.sqrt()));
        assert_eq!(within_less.iter().filter(|&&b| b).count(), 5);
        assert_eq!(mask_within(&m, 5, 5, 0.0).iter().filter(|&&b| b).count(), 1);
        assert!(mask_within(&m, 5, 5, -1.0).iter().all(|&b| !b));
        assert!(mask_within(&m, 5, 5, f64::NAN).iter().all(|&b| !b));
        assert!(mask_within(&m, 5, 5, f64::INFINITY).iter().all(|&b| b));
        assert!(mask_within(&m, 5, 5, 100.0).iter().all(|&b| b));
        assert!(mask_within(&[false; 25], 5, 5, 100.0).iter().all(|&b| !b));
        assert!(mask_within(&[], 0, 0, 3.0).is_empty());
        assert!(mask_within(&[], 0, 7, 3.0).is_empty());
        let d = squared_distance_transform(&m, 5, 5);
        assert_eq!(d[0], 8);
        assert_eq!(d[12], 0);
        assert_eq!(d[14], 4);
    }

    #[test]
    #[should_panic(expected = "mask_within")]
    fn mask_within_panics_on_bad_length() {
        mask_within(&[true; 3], 2, 2, 1.0);
    }

    #[test]
    #[ignore = "timing check; run with --release --ignored"]
    fn mask_within_2000_timing() {
        let (w, h) = (2000, 2000);
        let mapped: Vec<bool> = (0..w * h)
            .map(|i| (i * 2654435761usize) % 97 == 0)
            .collect();
        let t0 = std::time::Instant::now();
        let m = mask_within(&mapped, w, h, 10.0);
        let dt = t0.elapsed();
        eprintln!(
            "mask_within 2000x2000: {dt:?}, {} cells",
            m.iter().filter(|&&b| b).count()
        );
        let sparse: Vec<bool> = (0..w * h).map(|i| i == 12345).collect();
        let t0 = std::time::Instant::now();
        let _ = mask_within(&sparse, w, h, 10.0);
        eprintln!("sparse: {:?}", t0.elapsed());
    }

    fn truth_strategy() -> impl Strategy<Value = Truth> {
        prop_oneof![Just(O), Just(F), Just(U)]
    }

    fn prob_strategy() -> impl Strategy<Value = f64> {
        prop_oneof![
            3 => 0.0f64..=1.0,
            // Exact bucket edges and their neighbours.
            2 => (0usize..=1000).prop_map(threshold),
            1 => (1usize..=1000).prop_map(|k| next_down(threshold(k))),
            1 => (0usize..1000).prop_map(|k| next_up(threshold(k))),
            1 => Just(f64::NAN),
            1 => Just(-0.25),
            1 => Just(1.25),
        ]
    }

    proptest! {
        #[test]
        fn curve_matches_naive(
            cells in prop::collection::vec((prob_strategy(), truth_strategy(), any::<bool>()), 0..60),
            use_mask in any::<bool>(),
        ) {
            let probs: Vec<f64> = cells.iter().map(|c| c.0).collect();
            let truth: Vec<Truth> = cells.iter().map(|c| c.1).collect();
            let mask: Vec<bool> = cells.iter().map(|c| c.2).collect();
            let mask = use_mask.then_some(mask.as_slice());
            let mut acc = PrAccumulator::new();
            acc.add(&probs, &truth, mask).unwrap();
            prop_assert_eq!(counts(&acc.curve()), naive_curve(&probs, &truth, mask));
        }

        #[test]
        fn pooled_equals_concatenated(
            maps in prop::collection::vec(
                prop::collection::vec((prob_strategy(), truth_strategy(), any::<bool>()), 0..30),
                1..5,
            ),
        ) {
            let mut pooled = PrAccumulator::new();
            let mut merged = PrAccumulator::new();
            let (mut all_p, mut all_t, mut all_m) = (vec![], vec![], vec![]);
            for map in &maps {
                let p: Vec<f64> = map.iter().map(|c| c.0).collect();
                let t: Vec<Truth> = map.iter().map(|c| c.1).collect();
                let m: Vec<bool> = map.iter().map(|c| c.2).collect();
                pooled.add(&p, &t, Some(&m)).unwrap();
                let mut single = PrAccumulator::new();
                single.add(&p, &t, Some(&m)).unwrap();
                merged.merge(&single);
                all_p.extend(p);
                all_t.extend(t);
                all_m.extend(m);
            }
            let mut concat = PrAccumulator::new();
            concat.add(&all_p, &all_t, Some(&all_m)).unwrap();
            prop_assert_eq!(&pooled, &concat);
            prop_assert_eq!(&merged, &concat);
            prop_assert_eq!(pooled.summary(), concat.summary());
        }

        #[test]
        fn mask_within_matches_brute_force(
            w in 1usize..14,
            h in 1usize..14,
            density in 0.0f64..0.3,
            seed in any::<u64>(),
            n in prop_oneof![0.0f64..8.0, (0u32..40).prop_map(|k| (k as f64).sqrt()), Just(0.0)],
        ) {
            // Cheap deterministic pseudo-random occupancy from the seed.
            let mut s = seed | 1;
            let mapped: Vec<bool> = (0..w * h)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s >> 11) as f64 / (1u64 << 53) as f64 <= density
                })
                .collect();
            prop_assert_eq!(mask_within(&mapped, w, h, n), brute_force_mask(&mapped, w, h, n));
            let d2 = squared_distance_transform(&mapped, w, h);
            for y in 0..h {
                for x in 0..w {
                    let best = (0..h)
                        .flat_map(|my| (0..w).map(move |mx| (mx, my)))
                        .filter(|&(mx, my)| mapped[my * w + mx])
                        .map(|(mx, my)| {
                            let dx = x.abs_diff(mx) as u64;
                            let dy = y.abs_diff(my) as u64;
                            dx * dx + dy * dy
                        })
                        .min()
                        .unwrap_or(u64::MAX);
                    prop_assert_eq!(d2[y * w + x], best);
                }
            }
        }
    }
}
