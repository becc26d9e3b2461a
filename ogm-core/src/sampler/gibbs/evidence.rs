//! The measurement term of Eq. 1 without rays: per-cell evidence from the log-odds map.
//!
//! The paper's conclusion proposes "correlating cells in only the prior (i.e., not
//! measurements)": the measurements enter per cell, as the evidence the robot keeps anyway —
//! its log-odds map `l_k = log p(z | m_k = 1) / p(z | m_k = 0)` (the map starts at 0, so it holds
//! no prior) — and only the patch prior correlates cells. Under that model
//!
//! ```text
//! p(a_k = w | z, m_¬a_k) = η · p(a_k = w | border) · Π_{i ∈ a_k} exp(g · l_i · w_i)
//! ```
//!
//! so a candidate's weight is its log-prior plus the (gain-scaled) log-odds of the cells it
//! sets occupied: O(9 × candidates) per patch, no rays, and memory that does not grow with the
//! mission. The log-odds clamp makes the term saturate with evidence, so a cell seen free a
//! hundred times weighs as much as one seen free five times — enough to overrule the prior
//! (a clamped cell is worth 6.9 nats, more than the prior's pruning floor of 1 %) but not
//! unbounded. [`DataTerm::Hybrid`] adds this term, scaled by the share of beams the ray store
//! has dropped, to the rays' forward-model likelihood, so thinning the store loses nothing.

use rand_core::Rng;

use super::update::{below, weight_q16};
use super::{Count, Gibbs, LocalRay, PatchCandidate, PatchPrior, MAX_CANDIDATES};
use crate::types::fixed::LogOdds;
use crate::types::geometry::CellCoord;

/// The evidence of one patch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct PatchEvidence {
    /// Log-odds of each patch cell (bit order of [`crate::sampler::patch`]), LSB.
    pub(crate) l: [i16; 9],
    /// Cells whose log-odds is positive.
    pub(crate) occupied: u16,
    /// Cells with any evidence (log-odds ≠ 0).
    pub(crate) known: u16,
}

impl PatchEvidence {
    /// The evidence term of `config`: Σ over the cells it sets occupied of their log-odds,
    /// positive ones scaled by `occ_q8 / 256` and negative ones by `free_q8 / 256` (both ≤
    /// [`MAX_GAIN_Q8`]) — its log-likelihood relative to the all-free configuration.
    #[inline]
    pub(crate) fn of(&self, config: u16, occ_q8: i32, free_q8: i32) -> i32 {
        // Only cells with evidence contribute.
        let mut c = config & self.known;
        let mut s = 0i32;
        while c != 0 {
            let b = c.trailing_zeros() as usize;
            c &= c - 1;
            let l = i32::from(self.l.get(b).copied().unwrap_or(0));
            // |l| ≤ 2^15 and gains ≤ 2^12: each term fits an i32, nine of them too.
            s += (l * if l > 0 { occ_q8 } else { free_q8 }) >> 8;
        }
        s
    }

    /// The configuration the evidence alone prefers: cells with positive log-odds occupied,
    /// cells with negative log-odds free, unobserved cells as in `current`.
    #[inline]
    pub(crate) fn data_config(&self, current: u16) -> u16 {
        (current & !self.known) | self.occupied
    }
}

/// The evidence term of every configuration of one 3 × 3 patch, as three 8-entry tables of
/// subset sums (one per row): a candidate's term is three loads and two adds, however many
/// cells it sets. Equal to [`PatchEvidence::of`] with the same gains.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct PatchTerms([[i32; 8]; 3]);

impl PatchTerms {
    /// The terms of the 3 × 3 patch centred at `centre` (which keeps a 1-cell margin from the
    /// map's edge; rows outside the map contribute nothing).
    #[inline]
    pub(crate) fn new(
        map: &[LogOdds],
        width: usize,
        centre: CellCoord,
        occ_q8: i32,
        free_q8: i32,
    ) -> Self {
        let l = Self::cells(map, width, centre);
        // |l| ≤ 2^15 and gains ≤ 2^16: each term fits an i32, nine of them too.
        let v = |i: usize| {
            let l = l.get(i).copied().unwrap_or(0);
            (l * if l > 0 { occ_q8 } else { free_q8 }) >> 8
        };
        let row = |r: usize| {
            let (a, b, c) = (v(3 * r), v(3 * r + 1), v(3 * r + 2));
            [0, a, b, a + b, c, a + c, b + c, a + b + c]
        };
        PatchTerms([row(0), row(1), row(2)])
    }

    /// The log-odds of the patch's cells ([`crate::sampler::patch`] bit order), 0 in rows not wholly in
    /// the map (they contribute nothing). Widened here, where they are loaded (as `i16` the
    /// merge with the cold path cost a sign extension per cell).
    #[inline]
    fn cells(map: &[LogOdds], width: usize, centre: CellCoord) -> [i32; 9] {
        let x0 = centre.x - 1;
        // The usual case, the whole patch in the map: one bounds check for its three rows.
        if x0 >= 0 && centre.y >= 1 {
            let start = (centre.y - 1) as usize * width + x0 as usize;
            if let Some(area) = map.get(start..start + 2 * width + 3) {
                let at = |i: usize| area.get(i).map_or(0, |l| i32::from(l.0));
                let (w1, w2) = (width, 2 * width);
                return [
                    at(0),
                    at(1),
                    at(2),
                    at(w1),
                    at(w1 + 1),
                    at(w1 + 2),
                    at(w2),
                    at(w2 + 1),
                    at(w2 + 2),
                ];
            }
        }
        Self::cells_by_rows(map, width, centre)
    }

    /// [`PatchTerms::cells`] a row at a time, each only if it is wholly in the map. Out of line
    /// and cold: patch centres keep their margin, so only a map shorter than its geometry gets
    /// here.
    #[cold]
    #[inline(never)]
    fn cells_by_rows(map: &[LogOdds], width: usize, centre: CellCoord) -> [i32; 9] {
        let mut l = [0i32; 9];
        let x0 = centre.x - 1;
        for (r, out) in l.chunks_exact_mut(3).enumerate() {
            let y = centre.y - 1 + r as i32;
            if y < 0 || x0 < 0 {
                continue;
            }
            let start = y as usize * width + x0 as usize;
            if let Some(row) = map.get(start..start + 3) {
                for (o, c) in out.iter_mut().zip(row) {
                    *o = i32::from(c.0);
                }
            }
        }
        l
    }

    /// The evidence term of `config` ([`crate::sampler::patch`] bit order).
    #[inline]
    pub(crate) fn of(&self, config: u16) -> i32 {
        let c = usize::from(config);
        let [r0, r1, r2] = &self.0;
        r0.get(c & 7).copied().unwrap_or(0)
            + r1.get(c >> 3 & 7).copied().unwrap_or(0)
            + r2.get(c >> 6 & 7).copied().unwrap_or(0)
    }
}

/// The evidence of the `size × size` patch (size 1 or 3) centred at `centre` in the row-major
/// log-odds map `map` of `width` columns. Cells outside the map have no evidence.
#[inline]
pub(crate) fn patch_evidence(
    map: &[LogOdds],
    width: usize,
    centre: CellCoord,
    size: i32,
) -> PatchEvidence {
    let mut e = PatchEvidence::default();
    let h = size / 2;
    let (x0, n) = (centre.x - h, size as usize);
    let (mut known, mut occupied) = (0u32, 0u32);
    let mut bit = 0usize;
    for dy in -h..=h {
        let y = centre.y + dy;
        // Patch centres keep a margin from the map edge, so rows are whole; a row that is not
        // (only reachable through this function's own tests) reads as no evidence.
        if y >= 0 && x0 >= 0 && x0 as usize + n <= width {
            let start = y as usize * width + x0 as usize;
            if let (Some(row), Some(out)) = (map.get(start..start + n), e.l.get_mut(bit..bit + n)) {
                for (k, (o, l)) in out.iter_mut().zip(row).enumerate() {
                    *o = l.0;
                    let v = i32::from(l.0);
                    // Sign bits, branch-free: −v < 0 iff v > 0; v | −v < 0 iff v ≠ 0.
                    occupied |= ((v.wrapping_neg() as u32) >> 31) << (bit + k);
                    known |= (((v | v.wrapping_neg()) as u32) >> 31) << (bit + k);
                }
            }
        }
        bit += n;
    }
    (e.known, e.occupied) = (known as u16, occupied as u16);
    e
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
    /// [`DataTerm::Evidence`]'s update straight from the prior's flash tables (the hot path on
    /// the robot: no candidate copies, no ray work). The same distribution as the general path:
    /// candidates are the top-k of `configs` plus, with [`SamplerConfig::data_candidate`], the
    /// evidence's own configuration at the floor log-prior; weights are log-prior + evidence.
    /// Returns the new configuration (and updates the estimates), and whether it was the only
    /// candidate (the caller counts those in [`SamplerReport::single_candidate`]).
    ///
    /// [`DataTerm::Evidence`]: crate::config::DataTerm::Evidence
    /// [`SamplerConfig::data_candidate`]: super::SamplerConfig::data_candidate
    /// [`SamplerReport::single_candidate`]: crate::wire::SamplerReport::single_candidate
    #[allow(clippy::too_many_arguments)]
    pub(super) fn evidence_update(
        &mut self,
        map: &[LogOdds],
        centre: CellCoord,
        current: u16,
        (known, occupied): (u16, u16),
        configs: &'static [u16],
        log_priors: &'static [i16],
    ) -> (u16, bool) {
        let k = usize::from(self.ev_k)
            .min(configs.len())
            .min(log_priors.len());
        let (configs, log_priors) = (
            configs.get(..k).unwrap_or(&[]),
            log_priors.get(..k).unwrap_or(&[]),
        );
        // The evidence's own configuration, a candidate (at the floor log-prior) when the
        // prior's top-k lacks it: checked against the first candidate here, and against the
        // others in the weights' pass (it is only needed where there are weights).
        let data_candidate = self.config.data_candidate;
        let d = (current & !known) | occupied;
        let first = configs.first().copied().unwrap_or(current);
        if k <= 1 && (!data_candidate || (k == 1 && first == d)) {
            self.average_config(centre, first);
            return (first, true);
        }
        let floor = i32::from(self.config.floor_log_prior);
        // The patch's log-odds, read only now that weights are needed, and only if a cell has
        // any (unobserved patches, common in the uniform share of tile visits, weigh by the
        // prior alone).
        let ev = if known != 0 {
            PatchTerms::new(
                map,
                usize::from(self.geometry.width()),
                centre,
                self.ev_gain,
                self.ev_free_gain,
            )
        } else {
            PatchTerms::default()
        };
        // Log-weights, the extra candidate last, and the best of them in the same pass; then,
        // in place, the weights (`weights_q16`'s, one array instead of two). The array is the
        // sampler's scratch: only its first `n` entries are read, each written first (a local
        // array would be zeroed on every update).
        let q = &mut self.scratch;
        let mut best = i32::MIN;
        let mut listed = false;
        for ((qi, &c), &lp) in q.iter_mut().zip(configs).zip(log_priors) {
            let w = i32::from(lp) + ev.of(c);
            best = best.max(w);
            *qi = w as u32;
            listed |= c == d;
        }
        let extra = (data_candidate && !listed).then_some(d);
        let n = match extra {
            Some(d) => {
                let w = floor + ev.of(d);
                best = best.max(w);
                if let Some(qi) = q.get_mut(k) {
                    *qi = w as u32;
                }
                k + 1
            }
            None => k,
        };
        // `weights_q16`'s loop, in place, without its saturation: a log-weight is an i16
        // log-prior plus nine cells' |log-odds| ≤ 2^15 times a gain ≤ 2^16 (Q8), so `best − w`
        // is below 2^29, and the sum of at most 17 weights ≤ 2^16 is below 2^21.
        let mut total = 0u32;
        for qi in q.iter_mut().take(n) {
            *qi = weight_q16(best.wrapping_sub(*qi as i32) as u32);
            total = total.wrapping_add(*qi);
        }
        let config_of = |j: usize| configs.get(j).copied().or(extra).unwrap_or(current);
        let mut r = below(self.rng.next_u32(), total.max(1));
        let mut new = first;
        for (j, &qj) in q.iter().take(n).enumerate() {
            if r < qj {
                new = config_of(j);
                break;
            }
            r -= qj;
        }
        if cfg!(feature = "rao-blackwell") && self.config.estimator.rao_blackwellised() {
            let mut cands = [PatchCandidate::default(); MAX_CANDIDATES + 1];
            for (j, c) in cands.iter_mut().enumerate().take(n) {
                c.config = config_of(j);
            }
            let q = self.scratch;
            self.rao_blackwell(
                centre,
                cands.get(..n).unwrap_or(&[]),
                q.get(..n).unwrap_or(&[]),
                total,
                new,
            );
        } else {
            self.average_config(centre, new);
        }
        (new, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evidence_reads_the_patch_in_bit_order() {
        // 5 × 4 map, patch centred at (2, 1).
        let w = 5;
        let mut map = vec![LogOdds(0); 20];
        map[1] = LogOdds(-1024); // bit 0: (1, 0)
        map[w + 3] = LogOdds(2048); // bit 5: (3, 1)
        map[2 * w + 2] = LogOdds(512); // bit 7: (2, 2)
        let e = patch_evidence(&map, w, CellCoord { x: 2, y: 1 }, 3);
        assert_eq!(e.known, 1 | 1 << 5 | 1 << 7);
        assert_eq!(e.occupied, 1 << 5 | 1 << 7);
        assert_eq!((e.l[0], e.l[5], e.l[7]), (-1024, 2048, 512));
        assert_eq!(e.of(1 << 5 | 1 << 7 | 1, 256, 256), 2048 + 512 - 1024);
        // Occupied and free evidence scale separately; cells without evidence add nothing.
        assert_eq!(e.of(1 << 5 | 1 | 1 << 8, 128, 64), 1024 - 256);
        assert_eq!(e.of(0, 256, 256), 0);
        // Unobserved cells keep the current state, observed ones follow their sign.
        assert_eq!(e.data_config(0b1_1111_1111), 0b1_1111_1111 & !1);
        assert_eq!(e.data_config(0), 1 << 5 | 1 << 7);
    }

    #[test]
    fn patch_terms_equal_the_per_cell_sum() {
        let w = 6;
        let mut state = 12345u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state
        };
        for _ in 0..200 {
            let map: Vec<LogOdds> = (0..w * 5)
                .map(|_| {
                    LogOdds(match next() % 4 {
                        0 => 0,
                        _ => (next() % 10_241) as i16 - 5120,
                    })
                })
                .collect();
            let centre = CellCoord {
                x: 1 + (next() % 4) as i32,
                y: 1 + (next() % 3) as i32,
            };
            let (occ, free) = ((next() % 4097) as i32, (next() % 4097) as i32);
            let e = patch_evidence(&map, w, centre, 3);
            let t = PatchTerms::new(&map, w, centre, occ, free);
            for config in 0..512u16 {
                assert_eq!(t.of(config), e.of(config, occ, free), "{config:09b}");
            }
        }
    }

    #[test]
    fn patch_terms_skip_rows_outside_the_map() {
        // 4 × 3 map: the patch at (2, 2) has its top row past the end, the one at (0, 1) its
        // left column outside (no row is whole).
        let map: Vec<LogOdds> = (0..12).map(|i| LogOdds(100 * i as i16 - 500)).collect();
        let t = PatchTerms::new(&map, 4, CellCoord { x: 2, y: 2 }, 300, 200);
        let v = |l: i32| (l * if l > 0 { 300 } else { 200 }) >> 8;
        let l = |x: usize, y: usize| i32::from(map[y * 4 + x].0);
        let want = v(l(1, 1)) + v(l(3, 1)) + v(l(2, 2));
        assert_eq!(t.of(0b111_010_101), want);
        // One cell shorter, the middle row is not whole either.
        let short = PatchTerms::new(&map[..11], 4, CellCoord { x: 2, y: 2 }, 300, 200);
        assert_eq!(short.of(0b111_010_101), v(l(1, 1)) + v(l(3, 1)));
        let left = PatchTerms::new(&map, 4, CellCoord { x: 0, y: 1 }, 300, 200);
        assert_eq!(left, PatchTerms::default());
    }

    #[test]
    fn rows_not_wholly_in_the_map_have_no_evidence() {
        let map = vec![LogOdds(100); 9];
        let corner = patch_evidence(&map, 3, CellCoord { x: 0, y: 0 }, 3);
        assert_eq!(corner.known, 0);
        let top = patch_evidence(&map, 3, CellCoord { x: 1, y: 2 }, 3);
        assert_eq!(top.known, 0b000_111_111);
    }
}
