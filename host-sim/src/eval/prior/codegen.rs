//! Pruning and emitting the generated tables (`ogm-core/src/sampler/prior/table.rs`, `l25_table.rs`).
//!
//! The output is a pure function of the training result and [`PruneParams`]: no timestamps,
//! no host paths, sorted everywhere, log-priors rounded by the same function the target uses
//! ([`log_prior_of_probability`], `libm`), so regeneration is byte-for-byte reproducible.

use std::fmt::Write as _;

use anyhow::{bail, Result};
use ogm_core::sampler::patch::CONFIG_MASK;
use ogm_core::sampler::prior::{log_prior_of_probability, LOG_ZERO};

use super::train::Training;
use super::{Distributions, CELL_SIZE_M, HOUSEEXPO_M_PER_PX, MIN_OCCUPIED_FRACTION};

/// How the border table is pruned to fit flash. Every rule depends only on counts, which are
/// equal for a border and its 8 images, so the pruned table stays symmetric.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PruneParams {
    /// Borders seen fewer times than this (counting all 8 transforms) are dropped: they use
    /// the fallback. Rare borders carry noisy conditional distributions anyway.
    pub min_border_count: u64,
    /// Candidates with `p(config | border)` below this (parts per million) are dropped.
    pub candidate_floor_ppm: u32,
    /// At most this many candidates per border, most likely first; a group of equally likely
    /// candidates that would straddle the cap is dropped as a whole.
    pub k_max: usize,
}

impl Default for PruneParams {
    fn default() -> Self {
        PruneParams {
            min_border_count: 32,
            candidate_floor_ppm: 10_000,
            k_max: 16,
        }
    }
}

/// The pruned tables, as they are emitted.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CoreTables {
    /// Kept borders, ascending, each with its kept candidates `(config, log_prior)` by
    /// descending probability (ties: ascending config).
    pub borders: Vec<(u16, Vec<(u16, i16)>)>,
    /// Unconditioned L = 9: every seen config with `ln p`, by descending probability.
    pub l9: Vec<(u16, i16)>,
    /// L = 1: `[ln p(free), ln p(occupied)]` per neighbour byte ([`LOG_ZERO`] for zero).
    pub l1: Vec<[i16; 2]>,
    /// `[ln p(free), ln p(occupied)]` of a cell.
    pub occ: [i16; 2],
    /// Distinct borders before pruning.
    pub borders_seen: usize,
    /// Windows whose border was dropped.
    pub dropped_border_mass: u64,
    /// Windows of kept borders whose configuration was dropped.
    pub dropped_candidate_mass: u64,
    /// Total count.
    pub total: u64,
    /// The parameters used.
    pub params: PruneParams,
}

fn lp(count: u64, total: u64) -> i16 {
    if total == 0 || count == 0 {
        LOG_ZERO
    } else {
        log_prior_of_probability(count as f64 / total as f64)
    }
}

/// `a / b` in parts per million, rounded half up.
pub fn ppm(a: u64, b: u64) -> u32 {
    if b == 0 {
        return 0;
    }
    let v = (u128::from(a) * 1_000_000 + u128::from(b) / 2) / u128::from(b);
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// Applies the floor and the cap to one border's candidates (sorted by descending count).
pub fn prune_candidates(cands: &[(u16, u64)], params: &PruneParams) -> Vec<(u16, u64)> {
    let total: u64 = cands.iter().map(|c| c.1).sum();
    let mut kept: Vec<(u16, u64)> = cands
        .iter()
        .copied()
        .filter(|&(_, n)| {
            u128::from(n) * 1_000_000 >= u128::from(params.candidate_floor_ppm) * u128::from(total)
        })
        .collect();
    if kept.len() > params.k_max {
        let cut = kept.get(params.k_max).map_or(0, |c| c.1);
        kept.retain(|&(_, n)| n > cut);
    }
    kept
}

impl CoreTables {
    /// Prunes `d` with `params`.
    pub fn build(d: &Distributions, params: &PruneParams) -> CoreTables {
        let mut borders = Vec::new();
        let (mut dropped_border_mass, mut dropped_candidate_mass) = (0, 0);
        for (&b, cands) in &d.border {
            let total: u64 = cands.iter().map(|c| c.1).sum();
            let kept = if total >= params.min_border_count {
                prune_candidates(cands, params)
            } else {
                Vec::new()
            };
            if kept.is_empty() {
                dropped_border_mass += total;
                continue;
            }
            let kept_total: u64 = kept.iter().map(|c| c.1).sum();
            dropped_candidate_mass += total - kept_total;
            borders.push((
                b,
                kept.iter().map(|&(c, n)| (c, lp(n, kept_total))).collect(),
            ));
        }
        let mut l9: Vec<(u16, u64)> = (0u16..=CONFIG_MASK)
            .filter_map(|c| {
                let n = d.l9.get(usize::from(c)).copied().unwrap_or(0);
                (n > 0).then_some((c, n))
            })
            .collect();
        l9.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let l9 = l9.iter().map(|&(c, n)| (c, lp(n, d.total))).collect();
        let l1 =
            d.l1.iter()
                .map(|&[f, o]| [lp(f, f + o), lp(o, f + o)])
                .collect();
        let occ = [
            lp(d.total - d.centre_occupied, d.total),
            lp(d.centre_occupied, d.total),
        ];
        CoreTables {
            borders,
            l9,
            l1,
            occ,
            borders_seen: d.border.len(),
            dropped_border_mass,
            dropped_candidate_mass,
            total: d.total,
            params: *params,
        }
    }

    /// Number of stored candidates.
    pub fn candidates(&self) -> usize {
        self.borders.iter().map(|b| b.1.len()).sum()
    }

    /// Bytes of the data arrays as laid out in flash.
    pub fn flash_bytes(&self) -> usize {
        257 * 2
            + self.borders.len()
            + (self.borders.len() + 1) * 2
            + self.candidates() * 4
            + self.l9.len() * 4
            + 256 * 4
            + 4
    }
}

/// The provenance header shared by both generated files.
pub fn header(t: &Training, what: &str) -> String {
    let mut h = String::new();
    let c = &t.corpus;
    let used: Vec<_> = t.maps.iter().filter(|m| m.skipped.is_none()).collect();
    let _ = writeln!(h, "// @generated by `host-sim train-prior` — DO NOT EDIT.");
    let _ = writeln!(h, "//");
    let _ = writeln!(h, "// {what}");
    let _ = writeln!(h, "//");
    let _ = writeln!(
        h,
        "// Regenerate: cargo run --release -p host-sim -- train-prior   (check: add --check)"
    );
    let _ = writeln!(
        h,
        "// Reproducibility test: host-sim/tests/prior_regen.rs. Notes: docs/prior.md."
    );
    let _ = writeln!(h, "//");
    let _ = writeln!(
        h,
        "// Corpus: ../shared/data/maps/train, {} files, {} maps ({} used).",
        c.files.len(),
        t.maps.len(),
        used.len()
    );
    let _ = writeln!(h, "// Corpus SHA-256: {}", c.sha256);
    let _ = writeln!(h, "//   = cd maps/train && find houseexpo ros -type f | LC_ALL=C sort | xargs sha256sum | sha256sum");
    let _ = writeln!(h, "// Canonical cell: {CELL_SIZE_M} m. Maps are read with map_server semantics (p = (255 - v)/255;");
    let _ = writeln!(h, "//   occupied > 0.65, free < 0.196, else unknown), then resampled to the canonical cell: a cell is");
    let _ = writeln!(h, "//   occupied if any covered source pixel is, else free if any is, else unknown (upsampling takes");
    let _ = writeln!(
        h,
        "//   the pixel under the cell centre). ROS maps use their YAML resolution (0.05-0.1 m)."
    );
    let _ = writeln!(h, "// HouseExpo scale: {HOUSEEXPO_M_PER_PX} m/px (not stated; interior walls measure 10-11 px, taken as 0.10-0.11 m).");
    let _ = writeln!(
        h,
        "// Maps with < {} % occupied known cells are skipped (no walls).",
        MIN_OCCUPIED_FRACTION * 100.0
    );
    let _ = writeln!(
        h,
        "// Windows: every 5x5 window without an unknown cell, with all 8 rotations/flips."
    );
    let _ = writeln!(
        h,
        "// Windows counted: {} (x8 = {}).",
        t.windows(),
        t.windows() * 8
    );
    let _ = writeln!(h, "//");
    let _ = writeln!(
        h,
        "// Maps (windows counted at {CELL_SIZE_M} m, or why skipped):"
    );
    for m in &t.maps {
        match &m.skipped {
            Some(why) => {
                let _ = writeln!(h, "//   {}: SKIPPED, {why}", m.rel_path);
            }
            None => {
                let _ = writeln!(
                    h,
                    "//   {}: {}x{} cells, {:.2} % occupied, {} windows",
                    m.rel_path,
                    m.size.0,
                    m.size.1,
                    m.occupied_fraction * 100.0,
                    m.windows
                );
            }
        }
    }
    let _ = writeln!(h, "//");
    let _ = writeln!(h, "// Files (sha256, bytes, path):");
    for f in &c.files {
        let _ = writeln!(h, "//   {} {:>8} {}", f.sha256, f.bytes, f.rel_path);
    }
    h
}

fn emit_array<T: std::fmt::Display>(
    out: &mut String,
    doc: &str,
    name: &str,
    ty: &str,
    items: &[T],
    per_line: usize,
) {
    let _ = writeln!(out);
    for line in doc.lines() {
        let _ = writeln!(out, "/// {line}");
    }
    let _ = writeln!(out, "#[rustfmt::skip]");
    let _ = writeln!(out, "pub(crate) static {name}: [{ty}; {}] = [", items.len());
    for chunk in items.chunks(per_line.max(1)) {
        let line: Vec<String> = chunk.iter().map(|x| x.to_string()).collect();
        let _ = writeln!(out, "    {},", line.join(", "));
    }
    let _ = writeln!(out, "];");
}

fn log_str(v: i16) -> String {
    if v == LOG_ZERO {
        "Z".to_string()
    } else {
        v.to_string()
    }
}

/// The text of `ogm-core/src/sampler/prior/table.rs`.
pub fn emit_core_table(t: &Training, params: &PruneParams) -> Result<String> {
    let d = t.l25.distributions();
    let tables = CoreTables::build(&d, params);
    emit_core_tables(t, &tables)
}

/// The text of `ogm-core/src/sampler/prior/table.rs` for already pruned tables.
pub fn emit_core_tables(t: &Training, tables: &CoreTables) -> Result<String> {
    let n_cand = tables.candidates();
    if n_cand > usize::from(u16::MAX) || tables.borders.len() > usize::from(u16::MAX) {
        bail!("table too large for u16 offsets: {n_cand} candidates");
    }
    let p = &tables.params;
    let mut out = header(
        t,
        "Data-driven patch prior (Merali & Barfoot, §III-A/B) for ogm_core::sampler::prior: 3x3 patch given its \
         16-cell border, unconditioned 3x3, 1 cell given its 8 neighbours, p(m_k). Layouts: ogm_core::sampler::patch.",
    );
    let _ = writeln!(out, "//");
    let _ = writeln!(out, "// Pruning: borders seen < {} times (x8 counting) dropped -> fallback ({} of {} borders kept,", p.min_border_count, tables.borders.len(), tables.borders_seen);
    let _ = writeln!(out, "//   {} ppm of windows); candidates with p(config|border) < {} ppm dropped and at most {} per border", ppm(tables.dropped_border_mass, tables.total), p.candidate_floor_ppm, p.k_max);
    let _ = writeln!(out, "//   ({} ppm of windows); kept candidates renormalised per border. {} candidates, {} bytes of flash.", ppm(tables.dropped_candidate_mass, tables.total), n_cand, tables.flash_bytes());
    let _ = writeln!(out, "// Log-priors: ln p in units of ln(4)/1024 nats, rounded (ogm_core::sampler::prior::log_prior_of_probability).");
    let _ = writeln!(out);
    let _ = writeln!(out, "use super::TableInfo;");
    let _ = writeln!(out);
    let _ = writeln!(out, "/// Probability zero.");
    let _ = writeln!(out, "const Z: i16 = super::LOG_ZERO;");
    let _ = writeln!(out);
    let _ = writeln!(out, "/// Cap on candidates per border.");
    let _ = writeln!(out, "pub(crate) const K_MAX: usize = {};", p.k_max);
    let _ = writeln!(out);
    let _ = writeln!(out, "/// Provenance and pruning.");
    let _ = writeln!(out, "#[rustfmt::skip]");
    let _ = writeln!(out, "pub(crate) const INFO: TableInfo = TableInfo {{");
    let _ = writeln!(
        out,
        "    cell_size_mm: {},",
        (CELL_SIZE_M * 1000.0).round() as u32
    );
    let _ = writeln!(out, "    corpus_sha256: \"{}\",", t.corpus.sha256);
    let _ = writeln!(
        out,
        "    maps: {},",
        t.maps.iter().filter(|m| m.skipped.is_none()).count()
    );
    let _ = writeln!(out, "    windows: {},", tables.total);
    let _ = writeln!(out, "    borders_seen: {},", tables.borders_seen);
    let _ = writeln!(out, "    borders_stored: {},", tables.borders.len());
    let _ = writeln!(out, "    candidates_stored: {n_cand},");
    let _ = writeln!(out, "    k_max: {},", p.k_max);
    let _ = writeln!(out, "    min_border_count: {},", p.min_border_count);
    let _ = writeln!(out, "    candidate_floor_ppm: {},", p.candidate_floor_ppm);
    let _ = writeln!(
        out,
        "    dropped_border_mass_ppm: {},",
        ppm(tables.dropped_border_mass, tables.total)
    );
    let _ = writeln!(
        out,
        "    dropped_candidate_mass_ppm: {},",
        ppm(tables.dropped_candidate_mass, tables.total)
    );
    let _ = writeln!(out, "    l9_configs: {},", tables.l9.len());
    let _ = writeln!(out, "}};");

    // Border directory: bucket by high byte, sorted low bytes.
    let mut bucket = vec![0u16; 257];
    for (b, _) in &tables.borders {
        if let Some(x) = bucket.get_mut(usize::from(b >> 8) + 1) {
            *x += 1;
        }
    }
    for i in 1..bucket.len() {
        let prev = bucket.get(i - 1).copied().unwrap_or(0);
        if let Some(x) = bucket.get_mut(i) {
            *x += prev;
        }
    }
    let lows: Vec<String> = tables
        .borders
        .iter()
        .map(|(b, _)| format!("0x{:02x}", b & 0xFF))
        .collect();
    let mut starts = vec![0u16];
    let mut configs = Vec::with_capacity(n_cand);
    let mut logs = Vec::with_capacity(n_cand);
    for (_, cands) in &tables.borders {
        for &(c, l) in cands {
            configs.push(format!("0x{c:03x}"));
            logs.push(log_str(l));
        }
        starts.push(configs.len() as u16);
    }
    emit_array(
        &mut out,
        "Border directory: stored borders with high byte `h` are `BORDER_LOW[BORDER_BUCKET[h]..BORDER_BUCKET[h + 1]]`.",
        "BORDER_BUCKET",
        "u16",
        &bucket,
        16,
    );
    emit_array(
        &mut out,
        "Low bytes of the stored borders, ascending within each bucket.",
        "BORDER_LOW",
        "u8",
        &lows,
        16,
    );
    emit_array(
        &mut out,
        "Candidates of stored border `i`: `CAND_START[i]..CAND_START[i + 1]`.",
        "CAND_START",
        "u16",
        &starts,
        16,
    );
    emit_array(
        &mut out,
        "Candidate configurations, most likely first per border.",
        "CAND_CONFIG",
        "u16",
        &configs,
        16,
    );
    emit_array(
        &mut out,
        "`ln p(config | border)` of each candidate.",
        "CAND_LOG_PRIOR",
        "i16",
        &logs,
        16,
    );
    let l9c: Vec<String> = tables
        .l9
        .iter()
        .map(|(c, _)| format!("0x{c:03x}"))
        .collect();
    let l9l: Vec<String> = tables.l9.iter().map(|&(_, l)| log_str(l)).collect();
    emit_array(
        &mut out,
        "Unconditioned L = 9: every configuration seen, most likely first.",
        "L9_CONFIG",
        "u16",
        &l9c,
        16,
    );
    emit_array(
        &mut out,
        "`ln p(config)` of each `L9_CONFIG`.",
        "L9_LOG_PRIOR",
        "i16",
        &l9l,
        16,
    );
    let l1: Vec<String> = tables
        .l1
        .iter()
        .map(|[f, o]| format!("[{}, {}]", log_str(*f), log_str(*o)))
        .collect();
    emit_array(
        &mut out,
        "L = 1: `[ln p(free), ln p(occupied)]` of a cell given its 8 neighbours (`Z` = never seen).",
        "L1_LOG_PRIOR",
        "[i16; 2]",
        &l1,
        8,
    );
    let _ = writeln!(out);
    let _ = writeln!(out, "/// `[ln p(free), ln p(occupied)]` of a cell: p(m_k).");
    let _ = writeln!(
        out,
        "pub(crate) const OCC_LOG_PRIOR: [i16; 2] = [{}, {}];",
        log_str(tables.occ[0]),
        log_str(tables.occ[1])
    );
    Ok(out)
}

/// The text of `host-sim/src/eval/prior/l25_table.rs`.
pub fn emit_l25_table(t: &Training) -> String {
    let mut out = header(
        t,
        "Unconditioned L = 25 (5x5) prior for the host-side reference sampler: the symmetrised window \
         histogram, one entry per orbit under the 8 rotations/flips (canonical = smallest window; \
         every window of the orbit has the count). All other tables derive from it.",
    );
    let orbits = t.l25.orbits();
    let _ = writeln!(out, "//");
    let _ = writeln!(
        out,
        "// {} orbits, {} distinct windows, total count {}.",
        orbits.len(),
        t.l25.distinct(),
        t.l25.total()
    );
    let items: Vec<String> = orbits
        .iter()
        .map(|o| format!("(0x{:07x}, {})", o.canonical, o.count))
        .collect();
    emit_array(
        &mut out,
        "`(canonical window, count of each window of its orbit)`, ascending by window.",
        "ORBITS",
        "(u32, u64)",
        &items,
        6,
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pruning_keeps_tie_groups_whole() {
        let p = PruneParams {
            min_border_count: 0,
            candidate_floor_ppm: 0,
            k_max: 2,
        };
        let c = [(1u16, 10u64), (2, 5), (3, 5), (4, 1)];
        assert_eq!(prune_candidates(&c, &p), vec![(1, 10)]);
        let p3 = PruneParams { k_max: 3, ..p };
        assert_eq!(prune_candidates(&c, &p3), vec![(1, 10), (2, 5), (3, 5)]);
        let floor = PruneParams {
            candidate_floor_ppm: 100_000,
            k_max: 16,
            ..p
        };
        assert_eq!(prune_candidates(&c, &floor), vec![(1, 10), (2, 5), (3, 5)]);
        assert_eq!(ppm(1, 3), 333_333);
        assert_eq!(ppm(2, 3), 666_667);
        assert_eq!(ppm(1, 0), 0);
    }
}
