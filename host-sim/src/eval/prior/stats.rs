//! `prior-stats`: the statistics of §III-A/B for the committed prior, next to the paper's.
//!
//! Corpus figures are computed exactly from the committed L = 25 histogram
//! ([`super::L25::committed`], before any pruning); table figures from the compiled
//! `ogm_core::sampler::prior` table (after pruning). JSON field names are stable.

use std::fmt::Write as _;

use ogm_core::sampler::patch::{CONFIG_FREE, CONFIG_OCCUPIED};
use ogm_core::sampler::prior::{self, TABLE_INFO};
use serde::Serialize;

use super::{Distributions, CELL_SIZE_M, HOUSEEXPO_M_PER_PX, L25};

/// The figures the paper reports (and the same ones for our corpus). `None`: not reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Figures {
    /// p(m_k): share of occupied cells.
    pub p_occupied: Option<f64>,
    /// Distinct 3×3 configurations seen (of 512).
    pub l9_configs_seen: Option<u64>,
    /// Probability mass of the 50 most likely 3×3 configurations.
    pub l9_top50_mass: Option<f64>,
    /// Share of all-free 3×3 patches.
    pub l9_all_free: Option<f64>,
    /// Share of all-occupied 3×3 patches.
    pub l9_all_occupied: Option<f64>,
    /// Distinct 5×5 configurations seen (of 2²⁵).
    pub l25_configs_seen: Option<u64>,
    /// How many of the most likely 5×5 configurations hold 99.9 % of the mass.
    pub l25_configs_for_999_permille: Option<u64>,
    /// Share of all-free 5×5 patches.
    pub l25_all_free: Option<f64>,
    /// Share of all-occupied 5×5 patches.
    pub l25_all_occupied: Option<f64>,
    /// Distinct 16-cell borders seen (of 65,536).
    pub borders_seen: Option<u64>,
    /// Most 3×3 configurations seen with one border.
    pub max_candidates_per_border: Option<u64>,
    /// Mean number of configurations per seen border.
    pub mean_candidates_per_border: Option<f64>,
    /// Share of seen borders with a single configuration.
    pub single_candidate_borders: Option<f64>,
    /// Mean over seen borders of the most likely configuration's probability.
    pub mean_top1_probability: Option<f64>,
    /// Mean over seen borders of the 4 most likely configurations' total probability.
    pub mean_top4_probability: Option<f64>,
    /// As `mean_top1_probability`, but weighted by how often each border occurs.
    pub weighted_top1_probability: Option<f64>,
    /// As `mean_top4_probability`, weighted by border frequency.
    pub weighted_top4_probability: Option<f64>,
    /// Distinct 8-neighbourhoods seen (of 256).
    pub l1_borders_seen: Option<u64>,
    /// 8-neighbourhoods seen with both a free and an occupied centre.
    pub l1_mixed_borders: Option<u64>,
}

impl Figures {
    /// The paper's numbers (`../shared/docs/references.md`; §III-A/B, Fig. 4).
    pub fn paper() -> Figures {
        Figures {
            p_occupied: Some(0.234),
            l9_configs_seen: Some(124),
            l9_top50_mass: Some(0.999),
            l9_all_free: Some(0.743),
            l9_all_occupied: Some(0.211),
            l25_configs_seen: Some(2329),
            l25_configs_for_999_permille: Some(436),
            l25_all_free: Some(0.7198),
            l25_all_occupied: Some(0.1892),
            borders_seen: Some(865),
            max_candidates_per_border: Some(13),
            mean_candidates_per_border: None,
            single_candidate_borders: None,
            mean_top1_probability: Some(0.865),
            mean_top4_probability: Some(0.997),
            weighted_top1_probability: None,
            weighted_top4_probability: None,
            l1_borders_seen: Some(84),
            l1_mixed_borders: Some(40),
        }
    }

    /// Our numbers, exactly, from the derived distributions.
    pub fn of(d: &Distributions) -> Figures {
        let t = d.total.max(1) as f64;
        let mut l9: Vec<u64> = d.l9.iter().copied().filter(|&n| n > 0).collect();
        l9.sort_unstable_by(|a, b| b.cmp(a));
        let mut acc = 0u64;
        let threshold = d.total as f64 * 0.999;
        let mut l25_999 = d.l25_counts_desc.len() as u64;
        for (i, n) in d.l25_counts_desc.iter().enumerate() {
            acc += n;
            if acc as f64 >= threshold {
                l25_999 = i as u64 + 1;
                break;
            }
        }
        let nb = d.border.len().max(1) as f64;
        let (mut top1, mut top4, mut wtop1, mut wtop4, mut single) = (0.0, 0.0, 0.0, 0.0, 0usize);
        for cands in d.border.values() {
            let bt: u64 = cands.iter().map(|c| c.1).sum();
            let first = cands.first().map_or(0, |c| c.1);
            let four: u64 = cands.iter().take(4).map(|c| c.1).sum();
            top1 += first as f64 / bt as f64;
            top4 += four as f64 / bt as f64;
            wtop1 += first as f64;
            wtop4 += four as f64;
            single += usize::from(cands.len() == 1);
        }
        let count = |i: u16| d.l9.get(usize::from(i)).copied().unwrap_or(0) as f64 / t;
        Figures {
            p_occupied: Some(d.centre_occupied as f64 / t),
            l9_configs_seen: Some(l9.len() as u64),
            l9_top50_mass: Some(l9.iter().take(50).sum::<u64>() as f64 / t),
            l9_all_free: Some(count(CONFIG_FREE)),
            l9_all_occupied: Some(count(CONFIG_OCCUPIED)),
            l25_configs_seen: Some(d.l25_distinct as u64),
            l25_configs_for_999_permille: Some(l25_999),
            l25_all_free: Some(d.l25_free_occupied.0 as f64 / t),
            l25_all_occupied: Some(d.l25_free_occupied.1 as f64 / t),
            borders_seen: Some(d.border.len() as u64),
            max_candidates_per_border: Some(
                d.border.values().map(|c| c.len()).max().unwrap_or(0) as u64
            ),
            mean_candidates_per_border: Some(
                d.border.values().map(|c| c.len()).sum::<usize>() as f64 / nb,
            ),
            single_candidate_borders: Some(single as f64 / nb),
            mean_top1_probability: Some(top1 / nb),
            mean_top4_probability: Some(top4 / nb),
            weighted_top1_probability: Some(wtop1 / t),
            weighted_top4_probability: Some(wtop4 / t),
            l1_borders_seen: Some(d.l1.iter().filter(|a| a[0] + a[1] > 0).count() as u64),
            l1_mixed_borders: Some(d.l1.iter().filter(|a| a[0] > 0 && a[1] > 0).count() as u64),
        }
    }
}

/// The training corpus as recorded in the compiled table.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CorpusFigures {
    /// Canonical cell edge (m).
    pub cell_size_m: f64,
    /// Assumed HouseExpo scale (m/px).
    pub houseexpo_m_per_px: f64,
    /// SHA-256 of the corpus file list (see the generated header).
    pub corpus_sha256: String,
    /// Maps trained on.
    pub maps: u32,
    /// 5×5 windows counted, before the ×8 symmetrisation.
    pub windows: u64,
    /// Windows including all 8 transforms.
    pub windows_x8: u64,
}

/// The compiled `ogm_core::sampler::prior` table (after pruning).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TableFigures {
    /// Bytes of flash taken by the prior's data arrays.
    pub flash_bytes: usize,
    /// Borders with their own entry.
    pub borders_stored: u32,
    /// Candidates over all stored borders.
    pub candidates_stored: u32,
    /// Cap on candidates per border.
    pub k_max: u32,
    /// Most candidates of a stored border.
    pub max_candidates_stored: u64,
    /// Mean candidates per stored border.
    pub mean_candidates_stored: f64,
    /// Mean over stored borders of the top candidate's stored probability.
    pub mean_top1_stored: f64,
    /// Pruning: minimum border count (×8 counting).
    pub min_border_count: u64,
    /// Pruning: candidate probability floor (ppm).
    pub candidate_floor_ppm: u32,
    /// Share of windows whose border uses the fallback.
    pub dropped_border_mass: f64,
    /// Share of windows whose configuration was pruned from a stored border.
    pub dropped_candidate_mass: f64,
    /// Configurations in the unconditioned L = 9 table (the fallback).
    pub l9_configs: u32,
    /// Whether the compiled table was generated from the committed L = 25 histogram (same
    /// total count).
    pub consistent_with_l25: bool,
}

/// Everything `prior-stats` prints.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PriorStats {
    /// The corpus.
    pub corpus: CorpusFigures,
    /// Our figures (exact, before pruning).
    pub ours: Figures,
    /// The paper's figures (`null` where it gives none).
    pub paper: Figures,
    /// The compiled table.
    pub table: TableFigures,
}

/// Computes the statistics of the committed tables.
pub fn prior_stats() -> PriorStats {
    stats_of(&L25::committed())
}

/// Computes the statistics of `l25` and the compiled table.
pub fn stats_of(l25: &L25) -> PriorStats {
    let d = l25.distributions();
    let info = TABLE_INFO;
    let (mut max_c, mut sum_c, mut top1, mut n) = (0u64, 0u64, 0.0, 0u64);
    for b in 0..=u16::MAX {
        if let Some(c) = prior::border_candidates(b) {
            max_c = max_c.max(c.len() as u64);
            sum_c += c.len() as u64;
            top1 += c.get(0).map_or(0.0, |x| prior::probability(x.log_prior));
            n += 1;
        }
    }
    let nf = n.max(1) as f64;
    PriorStats {
        corpus: CorpusFigures {
            cell_size_m: CELL_SIZE_M,
            houseexpo_m_per_px: HOUSEEXPO_M_PER_PX,
            corpus_sha256: info.corpus_sha256.to_string(),
            maps: info.maps,
            windows: info.windows / 8,
            windows_x8: info.windows,
        },
        ours: Figures::of(&d),
        paper: Figures::paper(),
        table: TableFigures {
            flash_bytes: prior::table_flash_bytes(),
            borders_stored: info.borders_stored,
            candidates_stored: info.candidates_stored,
            k_max: info.k_max,
            max_candidates_stored: max_c,
            mean_candidates_stored: sum_c as f64 / nf,
            mean_top1_stored: top1 / nf,
            min_border_count: info.min_border_count,
            candidate_floor_ppm: info.candidate_floor_ppm,
            dropped_border_mass: f64::from(info.dropped_border_mass_ppm) / 1e6,
            dropped_candidate_mass: f64::from(info.dropped_candidate_mass_ppm) / 1e6,
            l9_configs: info.l9_configs,
            consistent_with_l25: info.windows == d.total,
        },
    }
}

fn fmt_opt_f(v: Option<f64>, pct: bool) -> String {
    match v {
        None => "—".to_string(),
        Some(x) if pct => format!("{:.2} %", x * 100.0),
        Some(x) => format!("{x:.3}"),
    }
}

fn fmt_opt_u(v: Option<u64>) -> String {
    v.map_or("—".to_string(), |x| x.to_string())
}

impl PriorStats {
    /// The human-readable side-by-side table.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let c = &self.corpus;
        let _ = writeln!(
            s,
            "Patch prior: {} maps at {} m (HouseExpo at {} m/px), {} windows (x8 = {}), corpus {}",
            c.maps,
            c.cell_size_m,
            c.houseexpo_m_per_px,
            c.windows,
            c.windows_x8,
            c.corpus_sha256.get(..16).unwrap_or("")
        );
        let _ = writeln!(s, "{:<44} {:>14} {:>14}", "figure", "ours", "paper");
        let (o, p) = (&self.ours, &self.paper);
        let rows_f: [(&str, Option<f64>, Option<f64>, bool); 12] = [
            ("p(m_k)", o.p_occupied, p.p_occupied, false),
            (
                "L=9 mass of the top 50",
                o.l9_top50_mass,
                p.l9_top50_mass,
                true,
            ),
            ("L=9 all-free", o.l9_all_free, p.l9_all_free, true),
            (
                "L=9 all-occupied",
                o.l9_all_occupied,
                p.l9_all_occupied,
                true,
            ),
            ("L=25 all-free", o.l25_all_free, p.l25_all_free, true),
            (
                "L=25 all-occupied",
                o.l25_all_occupied,
                p.l25_all_occupied,
                true,
            ),
            (
                "border: mean candidates",
                o.mean_candidates_per_border,
                p.mean_candidates_per_border,
                false,
            ),
            (
                "border: share with one candidate",
                o.single_candidate_borders,
                p.single_candidate_borders,
                true,
            ),
            (
                "border: mean top-1 probability",
                o.mean_top1_probability,
                p.mean_top1_probability,
                false,
            ),
            (
                "border: mean top-4 probability",
                o.mean_top4_probability,
                p.mean_top4_probability,
                false,
            ),
            (
                "border: top-1, weighted by frequency",
                o.weighted_top1_probability,
                p.weighted_top1_probability,
                false,
            ),
            (
                "border: top-4, weighted by frequency",
                o.weighted_top4_probability,
                p.weighted_top4_probability,
                false,
            ),
        ];
        let rows_u: [(&str, Option<u64>, Option<u64>); 7] = [
            (
                "L=9 configurations seen (of 512)",
                o.l9_configs_seen,
                p.l9_configs_seen,
            ),
            (
                "L=25 configurations seen",
                o.l25_configs_seen,
                p.l25_configs_seen,
            ),
            (
                "L=25 configurations holding 99.9 %",
                o.l25_configs_for_999_permille,
                p.l25_configs_for_999_permille,
            ),
            ("borders seen (of 65,536)", o.borders_seen, p.borders_seen),
            (
                "border: max candidates",
                o.max_candidates_per_border,
                p.max_candidates_per_border,
            ),
            (
                "L=1 borders seen (of 256)",
                o.l1_borders_seen,
                p.l1_borders_seen,
            ),
            ("L=1 borders mixed", o.l1_mixed_borders, p.l1_mixed_borders),
        ];
        for (name, a, b) in rows_u {
            let _ = writeln!(s, "{name:<44} {:>14} {:>14}", fmt_opt_u(a), fmt_opt_u(b));
        }
        for (name, a, b, pct) in rows_f {
            let _ = writeln!(
                s,
                "{name:<44} {:>14} {:>14}",
                fmt_opt_f(a, pct),
                fmt_opt_f(b, pct)
            );
        }
        let t = &self.table;
        let _ = writeln!(
            s,
            "Compiled table: {} bytes of flash; {} borders stored (seen >= {} times x8), {} candidates \
             (max {}, mean {:.2}, cap {}, floor {} ppm), mean stored top-1 {:.3}; fallback (unconditioned \
             L=9, {} configs) for {:.3} % of windows, pruned candidates {:.3} %{}",
            t.flash_bytes,
            t.borders_stored,
            t.min_border_count,
            t.candidates_stored,
            t.max_candidates_stored,
            t.mean_candidates_stored,
            t.k_max,
            t.candidate_floor_ppm,
            t.mean_top1_stored,
            t.l9_configs,
            t.dropped_border_mass * 100.0,
            t.dropped_candidate_mass * 100.0,
            if t.consistent_with_l25 {
                ""
            } else {
                " (WARNING: table and L=25 histogram come from different runs)"
            }
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn committed_stats_are_sane_and_serialise() {
        let s = prior_stats();
        assert!(
            s.table.consistent_with_l25,
            "regenerate both tables together"
        );
        assert!(s.table.flash_bytes > 0);
        let o = &s.ours;
        let p = o.p_occupied.unwrap();
        assert!(p > 0.0 && p < 1.0);
        assert!(o.l9_configs_seen.unwrap() <= 512);
        assert!(o.mean_top4_probability.unwrap() >= o.mean_top1_probability.unwrap());
        let j = serde_json::to_value(&s).unwrap();
        for k in ["corpus", "ours", "paper", "table"] {
            assert!(j.get(k).is_some(), "{k}");
        }
        assert_eq!(j["paper"]["borders_seen"], 865);
        assert!(s.to_text().contains("borders seen"));
    }
}
