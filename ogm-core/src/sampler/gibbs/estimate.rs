//! How the sampler turns its chain into per-cell marginals p(m_k = 1 | z).

use super::count::row_dither;
use super::{Count, Gibbs, LocalRay, PatchCandidate, PatchPrior};
use crate::config::Estimator;
use crate::types::geometry::CellCoord;

/// p(occupied) of a log-odds value in Q16 (65 536 = 1), from a 129-entry table over
/// −8192 ..= 8192 LSB in steps of 128 (the map's clamp is ±5120): exact at every multiple of 128
/// — every value the default Hähnel model produces — and linearly interpolated between.
pub(crate) fn probability_q16(l: crate::LogOdds) -> u32 {
    let v = i32::from(l.0).clamp(-8192, 8192) + 8192;
    let (i, f) = ((v >> 7) as usize, (v & 127) as u32);
    let a = PROB_TABLE.get(i).copied().unwrap_or(1 << 16);
    let b = PROB_TABLE.get(i + 1).copied().unwrap_or(a);
    (a * (128 - f) + b * f + 64) >> 7
}

static PROB_TABLE: [u32; 129] = build_prob_table();

// Const-evaluated: an out-of-range index fails compilation, not a run.
#[allow(clippy::indexing_slicing)]
const fn build_prob_table() -> [u32; 129] {
    let mut t = [0u32; 129];
    let mut i = 0;
    while i < 129 {
        // p = 1 / (1 + 2^(−l/512)) with l = 128·i − 8192 LSB of ln 2 / 512.
        let x = -((i as f64) * 128.0 - 8192.0) / 512.0 * core::f64::consts::LN_2;
        // exp by squaring a Taylor series of exp(x/64): |x/64| ≤ 0.18.
        let y = x / 64.0;
        let mut term = 1.0;
        let mut e = 1.0;
        let mut k = 1;
        while k < 20 {
            term = term * y / (k as f64);
            e += term;
            k += 1;
        }
        let mut s = 0;
        while s < 6 {
            e *= e;
            s += 1;
        }
        t[i] = (65536.0 / (1.0 + e) + 0.5) as u32;
        i += 1;
    }
    t
}

impl<P, B, C, L, K, N> Gibbs<P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    /// [`Estimator::Average`] after a multi-candidate update that drew `drawn`: with
    /// `rao_blackwell`, moves every cell's estimate towards its conditional occupancy
    /// probability, Σ of the weights `q` of the candidates that occupy it over their sum `total`;
    /// otherwise towards the draw.
    pub(super) fn rao_blackwell(
        &mut self,
        centre: CellCoord,
        cands: &[PatchCandidate],
        q: &[u32],
        total: u32,
        drawn: u16,
    ) {
        let Estimator::Average { rao_blackwell, .. } = self.config.estimator else {
            return;
        };
        if !cfg!(feature = "rao-blackwell") || !rao_blackwell || total == 0 {
            self.average_config(centre, drawn);
            return;
        }
        // Each cell's occupied weight, one pass over the candidates' set bits; weights in Q11
        // so that occ · 2^16 fits a u32 (Σ q ≤ 17 · 2^11 < 2^16) and the division is one
        // hardware instruction.
        let mut occ = [0u32; 9];
        let mut tot = 0u32;
        for (k, &x) in cands.iter().zip(q) {
            let x = x >> 5;
            tot += x;
            let mut c = k.config;
            while c != 0 && x != 0 {
                let b = c.trailing_zeros() as usize;
                c &= c - 1;
                if let Some(o) = occ.get_mut(b) {
                    *o += x;
                }
            }
        }
        let tot = tot.max(1);
        let shift = self.visit_shift.shift;
        self.for_patch_counts(centre, |bit, c| {
            let o = occ.get(bit as usize).copied().unwrap_or(0);
            *c = c.ema((o << 16) / tot, shift);
        });
    }

    /// [`Estimator::Average`] towards a configuration: each cell's value is 0 or 1.
    #[inline]
    pub(super) fn average_config(&mut self, centre: CellCoord, config: u16) {
        if self.config.estimator == Estimator::Counts {
            return;
        }
        let shift = &self.visit_shift;
        // xorshift32 (Marsaglia 2003): full period over the non-zero words.
        let mut dither = self.dither;
        dither ^= dither << 13;
        dither ^= dither >> 17;
        dither ^= dither << 5;
        self.dither = dither;
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let width = usize::from(self.geometry.width());
        let counts = self.buf.counts.as_mut();
        if size == 3 {
            // Patch centres keep the prior's margin from the edge: the patch is in the map.
            let start = (centre.y - 1) as usize * width + (centre.x - 1) as usize;
            N::average_patch3_at(counts, start, width, u32::from(config), shift, dither);
            return;
        }
        for (r, dy) in (-h..=h).enumerate() {
            // Patch centres keep the prior's margin from the edge: the row is in the map.
            let start = (centre.y + dy) as usize * width + (centre.x - h) as usize;
            let bits = u32::from(config) >> (r as i32 * size);
            N::average_row(
                counts,
                start,
                size as usize,
                bits,
                shift.shift,
                row_dither(dither, r),
            );
        }
    }

    /// Calls `f(bit, count)` for the marginal count of every cell of the patch at `centre`.
    #[inline]
    fn for_patch_counts(&mut self, centre: CellCoord, mut f: impl FnMut(u32, &mut N)) {
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let width = usize::from(self.geometry.width());
        let counts = self.buf.counts.as_mut();
        let mut bit = 0u32;
        for dy in -h..=h {
            // Patch centres keep the prior's margin from the edge: the row is in the map.
            let start = (centre.y + dy) as usize * width + (centre.x - h) as usize;
            let Some(row) = counts.get_mut(start..start + size as usize) else {
                return;
            };
            for c in row {
                f(bit, c);
                bit += 1;
            }
        }
    }

    /// [`Gibbs::accumulate`] after `n` updates: at once for [`Estimator::Average`], whose
    /// estimates move in the update itself (only the sweep count is kept here).
    pub(super) fn accumulate_n(&mut self, n: u32) {
        if self.config.estimator == Estimator::Counts {
            // (`accumulate` stays out of line: inlined in this loop it cost 2 KiB of flash.)
            for _ in 0..n {
                self.accumulate();
            }
            return;
        }
        self.count_sweeps(n);
    }

    /// The sweep count after `n` more updates, as `n` single steps: each wraps at `sweep_len`
    /// (≥ 1) and counts a sweep. Saturating: only a budget near 2^32 in one call could reach
    /// it, and it would only undercount sweeps (a 32-bit division; a 64-bit one is a library
    /// call on the M4).
    #[inline]
    fn count_sweeps(&mut self, n: u32) {
        let total = self.in_sweep.saturating_add(n);
        let len = self.sweep_len.max(1);
        self.stats.sweeps = self.stats.sweeps.saturating_add(total / len);
        self.in_sweep = total % len;
    }

    /// Advances the marginal-accumulation cursor by L cells; counts sweeps.
    #[inline(never)]
    pub(super) fn accumulate(&mut self) {
        if self.config.estimator != Estimator::Counts {
            // Only the sweep count.
            self.count_sweeps(1);
            return;
        }
        let size = usize::from(self.prior.size());
        let k = self.geometry.len();
        let counting = self.stats.sweeps >= self.config.burn_in_sweeps
            && self.config.estimator == Estimator::Counts;
        if counting && self.cursor == 0 {
            self.halving = self.samples >= N::MAX;
        }
        if counting {
            let end = (self.cursor + size * size).min(k);
            for i in self.cursor..end {
                let bit = u32::from(self.occupied(i));
                let halving = self.halving;
                if let Some(c) = self.buf.counts.as_mut().get_mut(i) {
                    *c = N::set(if halving {
                        c.get() / 2 + bit
                    } else {
                        c.get() + bit
                    });
                }
            }
        }
        self.cursor = (self.cursor + size * size).min(k);
        self.in_sweep += 1;
        if self.in_sweep >= self.sweep_len {
            if counting {
                self.samples = if self.halving {
                    self.samples / 2 + 1
                } else {
                    (self.samples + 1).min(N::MAX)
                };
                self.halving = false;
            }
            self.in_sweep = 0;
            self.cursor = 0;
            self.stats.sweeps = self.stats.sweeps.saturating_add(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Estimator;
    use crate::LogOdds;

    #[test]
    fn rao_blackwellised_averages_need_their_feature() {
        let rb = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: false,
            rao_blackwell: true,
        };
        assert!(rb.rao_blackwellised());
        assert_eq!(rb.available(), cfg!(feature = "rao-blackwell"));
        assert!(Estimator::Counts.available() && !Estimator::Counts.rao_blackwellised());
        let draws = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: false,
            rao_blackwell: false,
        };
        assert!(draws.available() && !draws.rao_blackwellised());
    }

    #[test]
    fn the_average_lengthens_by_one_shift_per_doubling_of_the_age() {
        let e = Estimator::Average {
            shift: 3,
            max_shift: 7,
            reset_on_change: true,
            rao_blackwell: false,
        };
        let shifts: std::vec::Vec<u8> = [0u8, 1, 2, 3, 6, 7, 14, 15, 255]
            .iter()
            .map(|&a| e.shift_at(a))
            .collect();
        assert_eq!(shifts, [3, 4, 4, 5, 5, 6, 6, 7, 7]);
        assert!(e.lengthens());
        let fixed = Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: true,
            rao_blackwell: false,
        };
        assert!(!fixed.lengthens());
        assert_eq!(fixed.shift_at(200), 3);
        assert_eq!(Estimator::Counts.shift_at(9), 0);
    }

    #[test]
    fn probability_table_matches_the_float_probability() {
        for raw in (-8192i32..=8192)
            .step_by(7)
            .chain([-5120, -1024, 0, 1024, 5120])
        {
            let l = LogOdds(raw as i16);
            let want = l.probability() * 65536.0;
            let got = f64::from(probability_q16(l));
            // Exact on the table's knots, interpolation error < 0.2 % between them.
            let tol = if raw % 128 == 0 { 1.0 } else { 0.002 * 65536.0 };
            assert!((got - want).abs() <= tol, "{raw}: {got} vs {want}");
        }
        assert_eq!(probability_q16(LogOdds(0)), 32768);
        assert_eq!(
            probability_q16(LogOdds(i16::MAX)),
            probability_q16(LogOdds(8192))
        );
    }
}
