//! Finding the candidates of a border: the bit filter and the bucket search over the stored
//! borders, their candidate slices in flash, the back-off for unseen borders
//! ([`candidates_into`]) and the unconditioned L = 9 prior.

use super::{table, Candidate, Candidates, PriorSource, K_MAX, LOG_ZERO};
use crate::sampler::patch::{despeckle, ring_majority, CONFIG_MASK};

/// Bits of [`STORED`], a one-hash filter over the stored borders.
const FILTER_BITS: u32 = 14;

/// The filter bit of `border` (Fibonacci hashing: the top bits of `border × 2^32/φ`).
#[inline]
const fn filter_bit(border: u16) -> usize {
    ((border as u32).wrapping_mul(0x9E37_79B9) >> (32 - FILTER_BITS)) as usize
}

/// Bit [`filter_bit`]`(b)` is set for every stored border `b` (2 KiB of flash, built at compile
/// time from the table): a border whose bit is clear is not stored, known after one load. Most
/// lookups of the back-off (sixteen neighbours of a border the table lacks) are of such borders
/// (with 1 055 stored borders, 6 % of the bits are set).
static STORED: [u32; 1 << (FILTER_BITS - 5)] = build_filter();

// Const-evaluated: an out-of-range index fails compilation, not a run.
#[allow(clippy::indexing_slicing)]
const fn build_filter() -> [u32; 1 << (FILTER_BITS - 5)] {
    let mut f = [0u32; 1 << (FILTER_BITS - 5)];
    let mut hi = 0;
    while hi < 256 {
        let mut j = table::BORDER_BUCKET[hi] as usize;
        while j < table::BORDER_BUCKET[hi + 1] as usize {
            let b = filter_bit(((hi as u16) << 8) | table::BORDER_LOW[j] as u16);
            f[b / 32] |= 1 << (b % 32);
            j += 1;
        }
        hi += 1;
    }
    f
}

/// Index of `border` among the stored borders, if it was kept.
fn border_index(border: u16) -> Option<usize> {
    let b = filter_bit(border);
    if STORED.get(b / 32).copied().unwrap_or(0) >> (b % 32) & 1 == 0 {
        return None;
    }
    let hi = usize::from(border >> 8);
    let start = usize::from(*table::BORDER_BUCKET.get(hi)?);
    let end = usize::from(*table::BORDER_BUCKET.get(hi + 1)?);
    let lows = table::BORDER_LOW.get(start..end)?;
    lows.binary_search(&(border as u8)).ok().map(|i| start + i)
}

/// The stored candidates of `border`, all of them, or `None` if the border is not in the table.
pub fn border_candidates(border: u16) -> Option<Candidates> {
    let (configs, log_priors) = slot_tables(border_slot(border)?)?;
    if configs.is_empty() {
        return None;
    }
    Some(Candidates::new(
        configs,
        log_priors,
        usize::MAX,
        PriorSource::Border,
    ))
}

/// The position of `border` among the stored borders (for [`slot_tables`]), or `None` if the
/// table has no entry for it. What a lookup cache keys on.
#[inline]
pub fn border_slot(border: u16) -> Option<u16> {
    border_index(border).and_then(|i| u16::try_from(i).ok())
}

/// The candidates (configurations, log-priors; most likely first) of stored border `slot`
/// ([`border_slot`]) as flash tables.
#[inline]
pub fn slot_tables(slot: u16) -> Option<(&'static [u16], &'static [i16])> {
    let i = usize::from(slot);
    let s = usize::from(*table::CAND_START.get(i)?);
    let e = usize::from(*table::CAND_START.get(i + 1)?);
    Some((
        table::CAND_CONFIG.get(s..e)?,
        table::CAND_LOG_PRIOR.get(s..e)?,
    ))
}

/// Bits a candidate slice's start in the flash tables takes ([`slot_span`]): the sampler's
/// border cache packs a start, a length − 1 (4 bits: at most [`K_MAX`] = 16 candidates) and a
/// tag into 32 bits.
pub const SPAN_START_BITS: u32 = 13;
const _: () = assert!(
    K_MAX <= 16 && table::CAND_CONFIG.len() < 1 << SPAN_START_BITS,
    "the border cache's packing needs more bits"
);

/// Where the candidates of stored border `slot` ([`border_slot`]) start in the flash tables,
/// and how many there are (1 ..= [`K_MAX`]): what [`span_tables`] takes.
#[inline]
pub fn slot_span(slot: u16) -> Option<(u16, u8)> {
    let i = usize::from(slot);
    let s = *table::CAND_START.get(i)?;
    let e = *table::CAND_START.get(i + 1)?;
    let n = u8::try_from(e.checked_sub(s)?).ok()?;
    (n > 0).then_some((s, n))
}

/// The `len` candidates (configurations, log-priors) from `start` in the flash tables
/// ([`slot_span`]).
#[inline]
pub fn span_tables(start: u16, len: u8) -> Option<(&'static [u16], &'static [i16])> {
    let r = usize::from(start)..usize::from(start) + usize::from(len);
    Some((
        table::CAND_CONFIG.get(r.clone())?,
        table::CAND_LOG_PRIOR.get(r)?,
    ))
}

/// Whether `border` has its own entry in the table (otherwise [`candidates`] falls back).
#[inline]
pub fn border_seen(border: u16) -> bool {
    border_index(border).is_some()
}

/// The at most `k` most likely 3×3 configurations given a 16-cell `border`, with
/// `ln p(config | border)`; for a border not in the table, the `k` most likely unconditioned
/// configurations with `ln p(config)` (flagged [`PriorSource::Fallback`]).
///
/// Never empty: `k = 0` is treated as 1. Relative weights are what matters to a sampler; the
/// values of one border are normalised over *all* its stored candidates, so a prefix sums to
/// less than 1.
pub fn candidates(border: u16, k: usize) -> Candidates {
    match border_candidates(border) {
        Some(all) => Candidates::new(all.configs, all.log_priors, k, PriorSource::Border),
        None => Candidates::new(
            &table::L9_CONFIG,
            &table::L9_LOG_PRIOR,
            k,
            PriorSource::Fallback,
        ),
    }
}

/// The stored border the sampler uses for `border` when it takes one border's candidates whole:
/// `border` itself if it is stored, else its [`despeckle`]d image if that is, else its
/// [`ring_majority`] image if that is (the first three steps of [`candidates_into`]'s
/// back-off). Its position ([`border_slot`]) and which of the three it is, or `None`.
#[inline]
pub fn smooth_slot(border: u16) -> Option<(u16, PriorSource)> {
    if let Some(s) = border_slot(border) {
        return Some((s, PriorSource::Border));
    }
    let d = despeckle(border);
    if d != border {
        if let Some(s) = border_slot(d) {
            return Some((s, PriorSource::Despeckled));
        }
    }
    let m = ring_majority(border);
    if m != border && m != d {
        if let Some(s) = border_slot(m) {
            return Some((s, PriorSource::RingMajority));
        }
    }
    None
}

/// The candidates the sampler uses for `border`, most likely first, written into `out` (at most
/// `out.len()`; never 0 for a non-empty `out`): the stored candidates of the border, or else
/// those of its [`despeckle`]d image, or else those of its [`ring_majority`] image, or else the
/// union of those of the stored borders one cell away (each configuration with its largest
/// log-prior), or else the unconditioned prior. See the [module docs](super).
pub fn candidates_into(border: u16, out: &mut [Candidate]) -> (usize, PriorSource) {
    if let Some((slot, source)) = smooth_slot(border) {
        let (configs, log_priors) = slot_tables(slot).unwrap_or((&[], &[]));
        let c = Candidates::new(configs, log_priors, usize::MAX, source);
        let n = c.iter().zip(out.iter_mut()).map(|(c, o)| *o = c).count();
        if n > 0 {
            return (n, source);
        }
    }
    // The union, at most `out.len()` of the most likely kept. `seen` is the set of the
    // configurations in `out` (9 bits each), so a new configuration costs no search; `worst`
    // is the least likely kept one once `out` is full.
    let mut seen = [0u32; 16];
    let mut n = 0usize;
    let mut worst: Option<usize> = None;
    for bit in 0..16 {
        let Some(c) = border_candidates(border ^ (1 << bit)) else {
            continue;
        };
        for cand in c.iter() {
            let (w, b) = (usize::from(cand.config >> 5) & 15, cand.config & 31);
            if let Some(i) = worst {
                // Full, and this border's candidates come most likely first: the rest of
                // them cannot displace anything nor raise a kept log-prior.
                if out.get(i).is_none_or(|o| cand.log_prior <= o.log_prior) {
                    break;
                }
            }
            // Whether the least likely kept one may have changed.
            let mut moved = false;
            if seen.get(w).copied().unwrap_or(0) >> b & 1 != 0 {
                if let Some((i, o)) = out.get_mut(..n).and_then(|f| {
                    f.iter_mut()
                        .enumerate()
                        .find(|(_, o)| o.config == cand.config)
                }) {
                    if cand.log_prior > o.log_prior {
                        o.log_prior = cand.log_prior;
                        moved = worst == Some(i);
                    }
                }
            } else if let Some(o) = out.get_mut(n) {
                *o = cand;
                n += 1;
                if let Some(s) = seen.get_mut(w) {
                    *s |= 1 << b;
                }
                moved = n == out.len();
            } else if let Some(o) = worst.and_then(|i| out.get_mut(i)) {
                // Full: the new one replaces the least likely.
                let (ow, ob) = (usize::from(o.config >> 5) & 15, o.config & 31);
                if let Some(s) = seen.get_mut(ow) {
                    *s &= !(1 << ob);
                }
                *o = cand;
                if let Some(s) = seen.get_mut(w) {
                    *s |= 1 << b;
                }
                moved = true;
            }
            if moved {
                worst = least_likely(out);
            }
        }
    }
    if n > 0 {
        sort_most_likely_first(out.get_mut(..n).unwrap_or(&mut []));
        return (n, PriorSource::Nearby);
    }
    let c = unconditioned(out.len());
    let n = c.iter().zip(out.iter_mut()).map(|(c, o)| *o = c).count();
    (n, PriorSource::Fallback)
}

/// Index of the least likely of `c` (ties: the larger configuration, the one sorted last).
fn least_likely(c: &[Candidate]) -> Option<usize> {
    (0..c.len()).min_by_key(|&i| c.get(i).map_or(i32::MIN, sort_key))
}

/// Sort key, larger first: the log-prior, ties by smaller configuration.
#[inline]
fn sort_key(c: &Candidate) -> i32 {
    (i32::from(c.log_prior) << 16) | i32::from(!c.config)
}

/// Sorts by decreasing log-prior, ties by configuration. An insertion sort on packed keys:
/// `out` holds the sampler's few candidates (≤ 16), and core's `sort_unstable` cost 8.4 KB of
/// flash.
fn sort_most_likely_first(c: &mut [Candidate]) {
    for i in 1..c.len() {
        let Some(&cur) = c.get(i) else { break };
        let key = sort_key(&cur);
        let mut j = i;
        while j > 0 {
            let Some(&prev) = c.get(j - 1) else { break };
            if sort_key(&prev) >= key {
                break;
            }
            if let Some(slot) = c.get_mut(j) {
                *slot = prev;
            }
            j -= 1;
        }
        if let Some(slot) = c.get_mut(j) {
            *slot = cur;
        }
    }
}

/// The `k` most likely 3×3 configurations without conditioning (`k = 0` is treated as 1), with
/// `ln p(config)`. All configurations seen in training are stored.
pub fn unconditioned(k: usize) -> Candidates {
    Candidates::new(
        &table::L9_CONFIG,
        &table::L9_LOG_PRIOR,
        k,
        PriorSource::Unconditioned,
    )
}

/// `ln p(config)` of the unconditioned L = 9 prior, or [`LOG_ZERO`] if `config` was never seen
/// (bits above bit 8 are ignored). A linear scan of at most 512 entries.
pub fn l9_log_prior(config: u16) -> i16 {
    unconditioned(usize::MAX)
        .log_prior_of(config & CONFIG_MASK)
        .unwrap_or(LOG_ZERO)
}

#[cfg(test)]
mod tests {
    use super::super::TABLE_INFO;
    use super::*;
    use crate::sampler::patch::{
        border_of, patch_of, window_from, BORDERS, CONFIG_FREE, CONFIG_OCCUPIED,
    };

    proptest::proptest! {
        #[test]
        fn insertion_sort_orders_like_core_sort(
            raw in proptest::collection::vec((0u16..512, -40i16..0), 0..24)
        ) {
            let mut mine: std::vec::Vec<Candidate> = raw
                .iter()
                .map(|&(config, log_prior)| Candidate { config, log_prior })
                .collect();
            let mut theirs = mine.clone();
            sort_most_likely_first(&mut mine);
            theirs.sort_by(|a, b| b.log_prior.cmp(&a.log_prior).then(a.config.cmp(&b.config)));
            proptest::prop_assert_eq!(mine, theirs);
        }
    }

    #[test]
    fn every_stored_border_round_trips() {
        let mut n = 0;
        for hi in 0..256usize {
            let s = usize::from(table::BORDER_BUCKET[hi]);
            let e = usize::from(table::BORDER_BUCKET[hi + 1]);
            let lows = &table::BORDER_LOW[s..e];
            assert!(lows.windows(2).all(|w| w[0] < w[1]), "sorted, unique");
            for (j, &lo) in lows.iter().enumerate() {
                let border = ((hi as u16) << 8) | u16::from(lo);
                assert_eq!(border_index(border), Some(s + j));
                let c = border_candidates(border).unwrap();
                let (cs, ce) = (
                    usize::from(table::CAND_START[s + j]),
                    usize::from(table::CAND_START[s + j + 1]),
                );
                assert_eq!(c.configs(), &table::CAND_CONFIG[cs..ce]);
                assert_eq!(c.source(), PriorSource::Border);
                n += 1;
            }
        }
        assert_eq!(n, TABLE_INFO.borders_stored as usize);
    }

    #[test]
    fn fallback_is_never_empty_and_k_is_respected() {
        for b in 0..BORDERS {
            let b = b as u16;
            for k in [0usize, 1, 2, 4, 13, usize::MAX] {
                let c = candidates(b, k);
                assert!(!c.is_empty());
                assert!(c.len() <= k.max(1));
                assert!(c.len() <= K_MAX.max(table::L9_CONFIG.len()));
                assert_eq!(c.iter().len(), c.len());
                assert_eq!(c.source() == PriorSource::Border, border_seen(b));
                assert!(c.configs().iter().all(|&x| x <= CONFIG_MASK));
                assert!(c.log_priors().windows(2).all(|w| w[0] >= w[1]));
                assert!(c.log_priors().iter().all(|&l| l <= 0 && l != LOG_ZERO));
            }
            if let Some(all) = border_candidates(b) {
                assert!(all.len() <= K_MAX);
                let top4 = candidates(b, 4);
                assert_eq!(top4.configs(), &all.configs()[..all.len().min(4)]);
            }
        }
        let fb = unconditioned(usize::MAX);
        assert!(fb.configs().contains(&CONFIG_FREE));
        assert!(fb.configs().contains(&CONFIG_OCCUPIED));
        assert_eq!(unconditioned(0).len(), 1);
    }

    /// `candidates_into` of `border` transformed by `t` gives `got` (from `border`, source
    /// `src`) transformed: the same source, count and (configuration, log-prior) set.
    fn assert_transformed_alike(
        border: u16,
        got: &[Candidate],
        src: PriorSource,
        t: crate::sampler::patch::Dihedral,
    ) {
        let mut out = [Candidate {
            config: 0,
            log_prior: 0,
        }; 16];
        let (n, s) = candidates_into(t.border(border), &mut out);
        assert_eq!((n, s), (got.len(), src), "border {border:#06x}");
        let mut a: Vec<(u16, i16)> = got
            .iter()
            .map(|c| (t.config(c.config), c.log_prior))
            .collect();
        let mut b: Vec<(u16, i16)> = out[..n].iter().map(|c| (c.config, c.log_prior)).collect();
        a.sort();
        b.sort();
        assert_eq!(a, b, "border {border:#06x}");
    }

    #[test]
    fn candidates_into_backs_off_to_despeckled_then_nearby_borders_symmetrically() {
        use crate::sampler::patch::Dihedral;
        let mut sources = [0usize; 5];
        for border in 0..=u16::MAX {
            let mut out = [Candidate {
                config: 0,
                log_prior: 0,
            }; 16];
            let (n, src) = candidates_into(border, &mut out);
            assert!((1..=16).contains(&n), "border {border:#06x}");
            let got = &out[..n];
            assert!(got.windows(2).all(|w| w[0].log_prior >= w[1].log_prior));
            match src {
                PriorSource::Border => {
                    sources[0] += 1;
                    assert_eq!(got, &candidates(border, 16).iter().collect::<Vec<_>>()[..]);
                }
                PriorSource::Despeckled | PriorSource::RingMajority => {
                    let d = if src == PriorSource::Despeckled {
                        sources[3] += 1;
                        despeckle(border)
                    } else {
                        sources[4] += 1;
                        assert!(!border_seen(despeckle(border)));
                        ring_majority(border)
                    };
                    assert!(
                        !border_seen(border) && border_seen(d),
                        "border {border:#06x}"
                    );
                    assert_eq!(got, &candidates(d, 16).iter().collect::<Vec<_>>()[..]);
                    assert_eq!(smooth_slot(border), Some((border_slot(d).unwrap(), src)));
                    // The same image after any rotation/flip.
                    for t in Dihedral::ALL {
                        assert_transformed_alike(border, got, src, t);
                    }
                }
                PriorSource::Nearby => {
                    sources[1] += 1;
                    assert!(!border_seen(border) && !border_seen(despeckle(border)));
                    assert!(!border_seen(ring_majority(border)));
                    assert_eq!(smooth_slot(border), None);
                    assert!((0..16).any(|b| border_seen(border ^ (1 << b))));
                    // Against a brute-force union: every configuration with its largest
                    // log-prior over the neighbours, the most likely kept.
                    let mut union = std::collections::BTreeMap::<u16, i16>::new();
                    for b in 0..16 {
                        for c in candidates(border ^ (1 << b), usize::MAX).iter() {
                            if border_seen(border ^ (1 << b)) {
                                let e = union.entry(c.config).or_insert(c.log_prior);
                                *e = (*e).max(c.log_prior);
                            }
                        }
                    }
                    let mut want: Vec<i16> = union.values().copied().collect();
                    want.sort_by(|a, b| b.cmp(a));
                    want.truncate(16);
                    let lps: Vec<i16> = got.iter().map(|c| c.log_prior).collect();
                    assert_eq!(lps, want, "border {border:#06x}");
                    assert!(got
                        .iter()
                        .all(|c| union.get(&c.config) == Some(&c.log_prior)));
                    if n < 16 {
                        // Untruncated: the union is the same set after any rotation/flip.
                        assert_transformed_alike(border, got, src, Dihedral::ALL[3]);
                    }
                }
                PriorSource::Fallback => {
                    sources[2] += 1;
                    assert!(!border_seen(despeckle(border)));
                    assert!(!border_seen(ring_majority(border)));
                    assert!((0..16).all(|b| !border_seen(border ^ (1 << b))));
                }
                PriorSource::Unconditioned => unreachable!(),
            }
        }
        assert!(sources.iter().all(|&c| c > 0), "{sources:?}");
        // Inside a solid region with one random hole in the border: fill it.
        let mut out = [Candidate {
            config: 0,
            log_prior: 0,
        }; 16];
        let (n, src) = candidates_into(0xFFFF ^ (1 << 7), &mut out);
        if src != PriorSource::Border {
            assert_eq!(
                out[..n].first().map(|c| c.config),
                Some(crate::sampler::patch::CONFIG_OCCUPIED)
            );
        }
    }

    #[test]
    fn window_helpers_agree_with_the_table_layout() {
        // A common real-world window: a straight wall along the bottom two rows.
        let w = 0b11111_11111;
        let c = candidates(border_of(w), K_MAX);
        assert_eq!(c.source(), PriorSource::Border);
        assert!(c.configs().contains(&patch_of(w)));
        assert_eq!(window_from(patch_of(w), border_of(w)), w);
    }
}
