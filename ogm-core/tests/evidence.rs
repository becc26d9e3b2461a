//! The per-cell evidence data term (`DataTerm::Evidence`): its conditional against an f64
//! reference, the raster sweep's incremental window (debug assertions inside the sampler check
//! it against fresh reads on every update), "strong evidence wins", and the bytewise averaging
//! against a scalar reference.

use ogm_core::config::noise::free_evidence_q8;
use ogm_core::config::{DataTerm, Estimator};
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::gibbs::{
    block_words, BorderPrior, Buffers, Count, Gibbs, LocalRay, SamplerConfig, FLOOR_LOG_PRIOR,
};
use ogm_core::sampler::patch::{border_of, patch_of};
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::types::fixed::LSB_NATS;
use ogm_core::{CellCoord, GridGeometry, LogOdds};
use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Uniform in `lo..hi` (the modulo bias is irrelevant here).
fn range<T: TryFrom<i64>>(rng: &mut Xoshiro256PlusPlus, lo: i64, hi: i64) -> T
where
    T::Error: std::fmt::Debug,
{
    T::try_from(lo + (rng.next_u64() % (hi - lo) as u64) as i64).unwrap()
}

type Store = RayStore<Vec<StoredScan>, Vec<StoredRay>>;
type Sampler = Gibbs<BorderPrior, Vec<u32>, Vec<u8>, Vec<LocalRay>, Vec<u32>, u8>;

fn setup(g: GridGeometry, cfg: SamplerConfig) -> (Sampler, Store) {
    let buf = Buffers {
        sample: vec![0; g.len().div_ceil(32)],
        counts: vec![0; g.len()],
        local: vec![LocalRay::default(); 1],
        blocks: vec![0; block_words(1, cfg.block_grid)],
    };
    let s = Gibbs::new(g, BorderPrior::default(), ForwardModel::pcsm(), cfg, buf).unwrap();
    let st = RayStore::new(
        g,
        1000,
        0,
        vec![StoredScan::default(); 1],
        vec![StoredRay::default(); 1],
    )
    .unwrap();
    (s, st)
}

fn evidence_config(seed: u64) -> SamplerConfig {
    SamplerConfig {
        data: DataTerm::Evidence,
        evidence_gain_q8: 512,
        evidence_free_q8: free_evidence_q8(3.0),
        data_candidate: true,
        estimator: Estimator::Average {
            shift: 3,
            max_shift: 3,
            reset_on_change: true,
            rao_blackwell: false,
        },
        hot_share: 192,
        seed,
        ..SamplerConfig::default()
    }
}

/// A 40 × 40 map of random log-odds in whole observations (±1024 LSB steps, clamped), with
/// unobserved (0) cells, walls and open space mixed.
fn random_map(rng: &mut Xoshiro256PlusPlus, g: GridGeometry) -> Vec<LogOdds> {
    (0..g.len())
        .map(|_| LogOdds(1024 * range::<i16>(rng, -5, 6) * i16::from(rng.next_u32() % 5 != 0)))
        .collect()
}

#[test]
fn evidence_conditional_matches_f64_reference() {
    let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let cfg = evidence_config(1);
    let (occ_gain, free_gain) = (
        f64::from(cfg.evidence_gain_q8) / 256.0,
        f64::from(cfg.evidence_gain_q8) / 256.0 * f64::from(cfg.evidence_free_q8) / 256.0,
    );
    let mut worst = 0f64;
    let mut checked = 0;
    for round in 0..4 {
        let map = random_map(&mut rng, g);
        let (mut s, mut st) = setup(g, evidence_config(round));
        s.reset(&map, &mut st).unwrap();
        s.step(&mut st, &map, 2000); // wander to some state
        for _ in 0..200 {
            let c = CellCoord {
                x: range(&mut rng, 2, 38),
                y: range(&mut rng, 2, 38),
            };
            // The reference: the same candidates, f64 weights.
            let mut window = 0u32;
            for r in 0..5 {
                for k in 0..5 {
                    let i = (c.y - 2 + r) as usize * 40 + (c.x - 2 + k) as usize;
                    window |= u32::from(s.occupied(i)) << (5 * r + k);
                }
            }
            let (current, border) = (patch_of(window), border_of(window));
            let mut buf = [ogm_core::sampler::prior::Candidate {
                config: 0,
                log_prior: 0,
            }; 16];
            let (n, _) = ogm_core::sampler::prior::candidates_into(border, &mut buf);
            let mut cands: Vec<(u16, f64)> = buf[..n]
                .iter()
                .map(|c| (c.config, f64::from(c.log_prior) * LSB_NATS))
                .collect();
            let l = |bit: u32| {
                let (r, k) = (bit as i32 / 3, bit as i32 % 3);
                map[(c.y - 1 + r) as usize * 40 + (c.x - 1 + k) as usize].0
            };
            let data = (0..9).fold(current, |d, b| match l(b).signum() {
                1 => d | 1 << b,
                -1 => d & !(1 << b),
                _ => d,
            });
            if !cands.iter().any(|(c, _)| *c == data) {
                cands.push((data, f64::from(FLOOR_LOG_PRIOR) * LSB_NATS));
            }
            let logw: Vec<f64> = cands
                .iter()
                .map(|&(cfg, lp)| {
                    lp + (0..9)
                        .filter(|b| cfg & (1 << b) != 0)
                        .map(|b| {
                            let v = f64::from(l(b));
                            v * if v > 0.0 { occ_gain } else { free_gain } * LSB_NATS
                        })
                        .sum::<f64>()
                })
                .collect();
            let max = logw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let z: f64 = logw.iter().map(|w| (w - max).exp()).sum();
            let mut out = [(0u16, 0f64); 17];
            let got = s.conditional(&mut st, &map, c, &mut out);
            assert_eq!(got, cands.len(), "at {c:?}");
            for ((cfg, p), (rc, w)) in out[..got].iter().zip(cands.iter().zip(&logw)) {
                assert_eq!(*cfg, rc.0);
                worst = worst.max((p - (w - max).exp() / z).abs());
            }
            checked += 1;
        }
    }
    eprintln!("{checked} patches, worst probability difference {worst:.5}");
    // Q16 weights from a 512-entry exp2 table, and the gains rounded to Q8: 0.005.
    assert!(worst < 0.005, "worst {worst}");
}

#[test]
fn strong_evidence_wins_over_the_prior() {
    // A map observed everywhere, five times (clamped), by a precise sensor (σ = 1 cell: free
    // evidence at full weight): thin (one-cell) walls the corpus rarely shows, a lone post, open
    // space. The sampler must reproduce it exactly.
    let g = GridGeometry::new(48, 48, 50, 0, 0).unwrap();
    let wall = |x: usize, y: usize| x == 20 || y == 30 || (x == 8 && y == 8);
    let map: Vec<LogOdds> = (0..g.len())
        .map(|i| LogOdds(if wall(i % 48, i / 48) { 5120 } else { -5120 }))
        .collect();
    let (mut s, mut st) = setup(
        g,
        SamplerConfig {
            evidence_free_q8: free_evidence_q8(1.0),
            // No p_randPatch moves: one late random patch would be legitimately wrong.
            p_rand_patch: 0.0,
            ..evidence_config(3)
        },
    );
    s.reset(&map, &mut st).unwrap();
    // Start from the opposite of the evidence, then sweep.
    for i in 0..g.len() {
        s.seed(i, !wall(i % 48, i / 48));
    }
    s.step(&mut st, &map, 400_000);
    let inner = |i: usize| (2..46).contains(&(i % 48)) && (2..46).contains(&(i / 48));
    let wrong: Vec<usize> = (0..g.len())
        .filter(|&i| inner(i) && s.occupied(i) != wall(i % 48, i / 48))
        .collect();
    assert!(
        wrong.is_empty(),
        "{} cells disagree with the evidence: {wrong:?}",
        wrong.len()
    );
    // And the estimates followed: every inner cell within 0.1 of its evidence.
    for i in (0..g.len()).filter(|&i| inner(i)) {
        let p = s.marginal(i).unwrap();
        assert!(
            (p - f32::from(u8::from(wall(i % 48, i / 48)))).abs() < 0.1,
            "{i}: {p}"
        );
    }
}

#[test]
fn raster_sweep_keeps_its_window_in_step() {
    // An odd width (rows straddle words) and a multiple of 32 (the firmware's fast path).
    for (w, h) in [(37, 29), (64, 40)] {
        raster_sweep_on(w, h);
    }
}

fn raster_sweep_on(w: u16, h: u16) {
    // Random maps and states, scans between steps (the map changes under the sampler): the
    // sampler's debug assertions compare its incremental window and masks with fresh reads on
    // every update (this test runs in the debug profile).
    let g = GridGeometry::new(w, h, 50, 0, 0).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let mut map = random_map(&mut rng, g);
    let (mut s, mut st) = setup(g, evidence_config(2));
    s.reset(&map, &mut st).unwrap();
    for round in 0..20 {
        // Change some evidence, as a scan would, and tell the sampler.
        for _ in 0..50 {
            let i: usize = range(&mut rng, 0, g.len() as i64);
            let before = map[i];
            map[i] = LogOdds(1024 * range::<i16>(&mut rng, -5, 6));
            s.note_changed(i, before, map[i]);
        }
        s.step(&mut st, &map, 1000 + round * 37);
    }
    let st = s.stats();
    assert!(
        st.updates > 20_000 && st.changed > 0 && st.tile_visits > 10,
        "{st:?}"
    );
}

#[test]
fn raster_runs_the_same_chain_however_the_budget_is_split() {
    // One call of 5 000 updates and the same updates in calls of 1 to 7: segment runs, row
    // reuse and the bulk sweep count must not depend on where a call ends.
    let g = GridGeometry::new(45, 38, 50, 0, 0).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
    let map = random_map(&mut rng, g);
    let (mut a, mut sa) = setup(g, evidence_config(5));
    let (mut b, mut sb) = setup(g, evidence_config(5));
    a.reset(&map, &mut sa).unwrap();
    b.reset(&map, &mut sb).unwrap();
    a.step(&mut sa, &map, 5000);
    let mut left = 5000u32;
    while left > 0 {
        let n = range::<u32>(&mut rng, 1, 8).min(left);
        b.step(&mut sb, &map, n);
        left -= n;
    }
    assert_eq!(a.stats(), b.stats());
    assert_eq!(
        (a.rays_examined(), a.rays_gathered()),
        (b.rays_examined(), b.rays_gathered())
    );
    assert!(
        a.stats().sweeps > 0 && a.stats().changed > 0,
        "{:?}",
        a.stats()
    );
    for i in 0..g.len() {
        assert_eq!(a.occupied(i), b.occupied(i), "cell {i}");
        assert_eq!(a.count(i), b.count(i), "cell {i}");
    }
}

/// The `u8` estimate's rule for one cell, in floating point: move `⌊(d + u mod 2^s) / 2^s⌋`
/// towards the target, `d` the distance, `s = min(shift, 7)`.
fn byte_rule(m: u8, occupied: bool, shift: u8, u: u8) -> u8 {
    let s = i32::from(shift.min(7));
    let d = if occupied {
        255.0 - f64::from(m)
    } else {
        f64::from(m)
    };
    let frac = f64::from(u32::from(u) % (1 << s));
    let step = ((d + frac) / f64::from(1 << s)).floor();
    (f64::from(m) + if occupied { step } else { -step }) as u8
}

#[test]
fn bytewise_averaging_matches_the_scalar_rule() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    for _ in 0..20_000 {
        let cells: Vec<u8> = (0..6).map(|_| rng.next_u32() as u8).collect();
        let (bits, shift): (u32, u8) = (range(&mut rng, 0, 8), range(&mut rng, 0, 9));
        let dither = rng.next_u32();
        let mut fast = cells.clone();
        u8::average_row(&mut fast, 1, 3, bits, shift, dither);
        let mut want = cells.clone();
        for k in 0..3 {
            let u = (dither >> (8 * k)) as u8;
            want[1 + k] = byte_rule(cells[1 + k], bits >> k & 1 != 0, shift, u);
            assert_eq!(
                ogm_core::sampler::gibbs::average_byte(cells[1 + k], bits >> k & 1 != 0, shift, u),
                want[1 + k]
            );
        }
        assert_eq!(fast, want, "{cells:?} bits {bits:03b} shift {shift}");
    }
}

#[test]
fn stochastic_rounding_is_unbiased_and_reaches_both_ends() {
    // Over every dither byte the mean move is exactly d / 2^s: no drift from rounding, so a
    // long average of a cell occupied in a fraction p of the draws settles at 255 p.
    for shift in 1..=7u8 {
        for m in [0u8, 1, 3, 100, 200, 254, 255] {
            for occupied in [false, true] {
                let sum: i32 = (0..=255u8)
                    .map(|u| {
                        i32::from(ogm_core::sampler::gibbs::average_byte(
                            m, occupied, shift, u,
                        )) - i32::from(m)
                    })
                    .sum();
                let d = if occupied {
                    255 - i32::from(m)
                } else {
                    -i32::from(m)
                };
                assert_eq!(
                    sum * (1 << shift),
                    d * 256,
                    "m {m} shift {shift} {occupied}"
                );
            }
        }
    }
    // Always-occupied and always-free draws end at exactly 255 and 0.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let (mut hi, mut lo) = ([0u8; 4], [255u8; 4]);
    for _ in 0..4000 {
        u8::average_row(&mut hi, 0, 3, 0b111, 7, rng.next_u32());
        u8::average_row(&mut lo, 0, 3, 0, 7, rng.next_u32());
    }
    assert_eq!((hi, lo), ([255, 255, 255, 0], [0, 0, 0, 255]));
}

#[test]
fn border_prior_caches_return_what_the_table_does() {
    use ogm_core::sampler::gibbs::{PatchCandidate, PatchPrior};
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let mut cached = BorderPrior::default();
    let plain = BorderPrior::default();
    // Few distinct borders, so the border cache hits and gets replaced.
    let borders: Vec<u16> = (0..40)
        .map(|_| rng.next_u32() as u16)
        .chain([0, 0xFFFF])
        .collect();
    for _ in 0..5000 {
        let b = borders[range::<usize>(&mut rng, 0, borders.len() as i64)];
        let k: usize = range(&mut rng, 1, 17);
        let (mut x, mut y) = (
            [PatchCandidate::default(); 16],
            [PatchCandidate::default(); 16],
        );
        let n = cached.candidates_cached(b, &mut x[..k]);
        assert_eq!(
            n,
            plain.candidates(b, &mut y[..k]),
            "border {b:016b}, k {k}"
        );
        // The same top-k, up to which of equally likely candidates fills the last places.
        let lps = |c: &[PatchCandidate]| c.iter().map(|p| p.log_prior).collect::<Vec<_>>();
        assert_eq!(lps(&x[..n]), lps(&y[..n]), "border {b:016b}, k {k}");
        let mut all = [PatchCandidate::default(); 16];
        let m = plain.candidates(b, &mut all);
        assert!(
            x[..n].iter().all(|c| all[..m].contains(c)),
            "border {b:016b}, k {k}"
        );
        match cached.table(b) {
            Some((configs, lps)) => {
                assert!(
                    configs.len() >= n
                        && configs[..n]
                            .iter()
                            .zip(&x[..n])
                            .all(|(c, p)| *c == p.config)
                );
                assert!(lps[..n]
                    .iter()
                    .zip(&x[..n])
                    .all(|(l, p)| i32::from(*l) == p.log_prior));
            }
            None => assert!(ogm_core::sampler::prior::smooth_slot(b).is_none()),
        }
    }
}

#[test]
fn border_cache_packs_every_border_s_slice_exactly() {
    use ogm_core::sampler::gibbs::PatchPrior;
    use ogm_core::sampler::prior::{slot_span, slot_tables, smooth_slot, span_tables};
    let mut cached = BorderPrior::default();
    // Each border twice in a row (a miss, then a hit), every entry filled and replaced.
    for b in 0..=u16::MAX {
        let want = smooth_slot(b).and_then(|(s, _)| slot_tables(s));
        if let Some((s, _)) = smooth_slot(b) {
            let (start, len) = slot_span(s).unwrap();
            assert_eq!(span_tables(start, len), want);
        }
        assert_eq!(cached.table(b), want, "border {b:#06x}");
        assert_eq!(cached.table(b), want, "border {b:#06x}, cached");
    }
    // Borders sharing a cache entry (same low byte xor hash of the high byte) evict each other.
    for b in [0x0000u16, 0x0100, 0xFFFF, 0x00FF, 0x1234, 0x3412] {
        let want = smooth_slot(b).and_then(|(s, _)| slot_tables(s));
        assert_eq!(cached.table(b), want, "border {b:#06x}");
    }
}

#[test]
fn patch_averaging_matches_the_scalar_rule_row_by_row() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let width = 5;
    for _ in 0..5_000 {
        let cells: Vec<u8> = (0..width * 3).map(|_| rng.next_u32() as u8).collect();
        let (config, shift): (u32, u8) = (range(&mut rng, 0, 512), range(&mut rng, 1, 9));
        let dither = rng.next_u32();
        // Patches whose last row ends at the map's last cell too (no byte after it).
        let start: usize = range(&mut rng, 0, 3);
        let mut fast = cells.clone();
        u8::average_patch3(&mut fast, start, width, config, shift, dither);
        let mut want = cells.clone();
        for r in 0..3 {
            let row_dither = dither.rotate_right(8 * r as u32);
            for k in 0..3 {
                let i = start + r * width + k;
                let u = (row_dither >> (8 * k)) as u8;
                want[i] = byte_rule(cells[i], config >> (3 * r + k) & 1 != 0, shift, u);
            }
        }
        assert_eq!(fast, want, "{cells:?} config {config:09b} shift {shift}");
    }
}

#[test]
fn estimates_restart_only_when_evidence_appears_or_flips() {
    let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let map = random_map(&mut rng, g);
    let (mut s, mut st) = setup(g, evidence_config(5));
    s.reset(&map, &mut st).unwrap();
    s.step(&mut st, &map, 20_000);
    let (free, occ) = (LogOdds(-2048), LogOdds(2048));
    // 255 = p 1 in a u8 estimate; LogOdds(-2048) is p = 1/17 → 15 after a restart.
    let restarted = |s: &Sampler, i: usize| s.count(i) == 15 || s.count(i) == 240;
    let cells: Vec<usize> = (0..g.len()).filter(|&i| map[i].0 != 0).take(200).collect();
    let mut kept = 0;
    for &i in &cells {
        let before = map[i];
        let same_sign = if before.0 > 0 { occ } else { free };
        let c0 = s.count(i);
        s.note_changed(i, before, same_sign);
        assert_eq!(
            s.count(i),
            c0,
            "cell {i}: evidence only grew, estimate kept"
        );
        kept += usize::from(!restarted(&s, i));
        let flipped = if before.0 > 0 { free } else { occ };
        s.note_changed(i, same_sign, flipped);
        assert!(
            restarted(&s, i),
            "cell {i}: sign flipped, estimate {}",
            s.count(i)
        );
    }
    assert!(
        kept > 100,
        "most sampled estimates are not at the restart value: {kept}"
    );
    // A cell seen for the first time restarts too.
    let fresh = (0..g.len()).find(|&i| map[i].0 == 0).unwrap();
    s.note_changed(fresh, LogOdds(0), free);
    assert!(restarted(&s, fresh), "{}", s.count(fresh));
}

#[test]
fn an_average_that_would_shorten_is_rejected() {
    let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
    let mut cfg = evidence_config(1);
    cfg.estimator = Estimator::Average {
        shift: 3,
        max_shift: 2,
        reset_on_change: true,
        rao_blackwell: false,
    };
    let buf = Buffers {
        sample: vec![0; g.len().div_ceil(32)],
        counts: vec![0u8; g.len()],
        local: vec![LocalRay::default(); 1],
        blocks: vec![0; block_words(1, cfg.block_grid)],
    };
    let s = Gibbs::new(g, BorderPrior::default(), ForwardModel::pcsm(), cfg, buf);
    assert!(matches!(s, Err(ogm_core::Error::InvalidModel)));
}

#[test]
fn settled_tiles_average_longer() {
    // The same chain (the estimator draws no chain numbers), read out by a fixed and by a
    // lengthening average: once the tiles have been visited many times without a change, the
    // lengthening estimates move much less between two snapshots.
    let g = GridGeometry::new(40, 40, 50, 0, 0).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let map = random_map(&mut rng, g);
    let wobble = |max_shift: u8| {
        let mut cfg = evidence_config(3);
        cfg.estimator = Estimator::Average {
            shift: 3,
            max_shift,
            reset_on_change: true,
            rao_blackwell: false,
        };
        let (mut s, mut st) = setup(g, cfg);
        s.reset(&map, &mut st).unwrap();
        s.step(&mut st, &map, 60_000);
        let before: Vec<u32> = (0..g.len()).map(|i| s.count(i)).collect();
        s.step(&mut st, &map, 2_000);
        let moved: u32 = (0..g.len()).map(|i| s.count(i).abs_diff(before[i])).sum();
        (moved, s.stats())
    };
    let ((fixed, a), (long, b)) = (wobble(3), wobble(7));
    assert_eq!(a, b, "the same chain");
    assert!(long * 3 < fixed, "lengthening {long} vs fixed {fixed}");
}
