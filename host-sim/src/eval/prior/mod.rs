//! The data-driven patch prior: training from real maps, code generation and statistics.
//!
//! * [`train`] — walks the training corpus (`../shared/data/maps/train`: HouseExpo plans and
//!   ROS maps, never the simulation maps), brings every map to [`CELL_SIZE_M`], and counts
//!   every fully known 5×5 window ([`train::WindowCounts`]);
//! * [`L25`] — the symmetrised L = 25 histogram (all 8 rotations/flips of every window), from
//!   which every other distribution is derived ([`Distributions`]); the committed copy
//!   ([`L25::committed`], generated into `l25_table.rs`) is the unconditioned 5×5 prior of the
//!   host-side L = 25 sampler ([`crate::eval::sampling::l25`], eval-sim's `gibbs_l25`);
//! * [`codegen`] — prunes and emits `ogm-core/src/sampler/prior/table.rs` and `l25_table.rs`,
//!   byte-for-byte reproducibly;
//! * [`stats`] — `prior-stats`: the figures of §III-A/B next to the paper's.
//!
//! Bit layouts are those of [`ogm_core::sampler::patch`]. See `docs/prior.md` for the choices (cell
//! size, HouseExpo scale, skipped maps, pruning, fallback).

pub mod codegen;
pub mod stats;
pub mod train;

#[rustfmt::skip]
mod l25_table;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use ogm_core::sampler::patch::{
    border_of, canonical_window, neighbours_of, patch_of, Dihedral, CONFIGS,
};

pub use codegen::{CoreTables, PruneParams};
pub use stats::{prior_stats, PriorStats};
pub use train::{Corpus, Training};

/// Canonical cell edge every training map is resampled to (m).
pub const CELL_SIZE_M: f64 = 0.05;

/// Assumed HouseExpo scale (m per pixel). The PNGs state none; their interior walls are
/// 10–11 px thick (median run of wall pixels between free pixels, measured over all 100
/// plans, see `docs/prior.md`), so 0.01 m/px makes walls 0.10–0.11 m, inside the usual
/// 0.10–0.15 m, and maps 5×5 pixels exactly onto one 0.05 m cell.
pub const HOUSEEXPO_M_PER_PX: f64 = 0.01;

/// Maps whose occupied share of known cells (after resampling) is below this are skipped:
/// a map without walls (`willow-empty-0.05`, `willow-full` are blank canvases for Stage)
/// carries no wall structure and would only inflate the all-free patches.
pub const MIN_OCCUPIED_FRACTION: f64 = 0.001;

/// The default training corpus: `<project>/../shared/data/maps/train`.
pub fn default_corpus_dir() -> PathBuf {
    manifest_relative("../../shared/data/maps/train")
}

/// The generated ogm-core table: `<project>/ogm-core/src/sampler/prior/table.rs`.
pub fn default_core_table_path() -> PathBuf {
    manifest_relative("../ogm-core/src/sampler/prior/table.rs")
}

/// The generated host-side L = 25 table: `<project>/host-sim/src/eval/prior/l25_table.rs`.
pub fn default_l25_table_path() -> PathBuf {
    manifest_relative("src/eval/prior/l25_table.rs")
}

/// `rel` under host-sim's manifest directory, canonicalised when it exists.
fn manifest_relative(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    p.canonicalize().unwrap_or(p)
}

/// One orbit of 5×5 windows under the 8 transforms of [`Dihedral`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Orbit {
    /// The smallest window of the orbit ([`canonical_window`]).
    pub canonical: u32,
    /// Count of *each* window of the orbit in the symmetrised histogram.
    pub count: u64,
}

/// The symmetrised histogram of 5×5 windows (bit layout of [`ogm_core::sampler::patch`]).
///
/// Each raw window `w` counted once contributes one count to each of its 8 images `T(w)`, so
/// the histogram is invariant under the transforms and its total is 8 × the raw window count.
/// All windows of an orbit then have the same count; only one representative per orbit is
/// stored, sorted by window.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct L25 {
    orbits: Vec<Orbit>,
}

/// The distinct images of `window` under the 8 transforms, sorted.
pub fn orbit_members(window: u32) -> Vec<u32> {
    let mut m: Vec<u32> = Dihedral::ALL.iter().map(|t| t.window(window)).collect();
    m.sort_unstable();
    m.dedup();
    m
}

impl L25 {
    /// Symmetrises raw window counts.
    pub fn from_raw(raw: &HashMap<u32, u64, train::BuildWindowHasher>) -> L25 {
        let mut by_orbit: BTreeMap<u32, u64> = BTreeMap::new();
        for (&w, &n) in raw {
            *by_orbit.entry(canonical_window(w)).or_default() += n;
        }
        let orbits = by_orbit
            .into_iter()
            .map(|(canonical, n)| {
                // Σ over the 8 transforms of raw(T⁻¹ w) for a member w: every raw window of the
                // orbit is reached 8 / |orbit| times.
                let size = orbit_members(canonical).len() as u64;
                Orbit {
                    canonical,
                    count: n * 8 / size,
                }
            })
            .collect();
        L25 { orbits }
    }

    /// From stored orbits (checked: canonical, sorted, unique, positive counts).
    pub fn from_orbits(orbits: Vec<Orbit>) -> Result<L25> {
        for o in &orbits {
            if canonical_window(o.canonical) != o.canonical || o.count == 0 {
                bail!(
                    "orbit {:#09x} is not canonical or has no count",
                    o.canonical
                );
            }
        }
        if orbits.windows(2).any(|w| w[0].canonical >= w[1].canonical) {
            bail!("orbits are not sorted and unique");
        }
        Ok(L25 { orbits })
    }

    /// The committed histogram (generated `l25_table.rs`).
    pub fn committed() -> L25 {
        L25 {
            orbits: l25_table::ORBITS
                .iter()
                .map(|&(canonical, count)| Orbit { canonical, count })
                .collect(),
        }
    }

    /// The orbits, sorted by canonical window.
    pub fn orbits(&self) -> &[Orbit] {
        &self.orbits
    }

    /// Every window with its count (all members of every orbit), in orbit order.
    pub fn windows(&self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.orbits.iter().flat_map(|o| {
            orbit_members(o.canonical)
                .into_iter()
                .map(move |w| (w, o.count))
        })
    }

    /// Total count (8 × windows counted).
    pub fn total(&self) -> u64 {
        self.orbits
            .iter()
            .map(|o| o.count * orbit_members(o.canonical).len() as u64)
            .sum()
    }

    /// Number of distinct windows seen.
    pub fn distinct(&self) -> usize {
        self.orbits
            .iter()
            .map(|o| orbit_members(o.canonical).len())
            .sum()
    }

    /// A lookup table window → `ln p(window)` for the reference sampler (unseen windows are
    /// absent: probability zero).
    pub fn log_probabilities(&self) -> HashMap<u32, f64> {
        let total = self.total() as f64;
        self.windows()
            .map(|(w, n)| (w, (n as f64 / total).ln()))
            .collect()
    }

    /// The derived L = 9, border-conditioned, L = 1 distributions.
    pub fn distributions(&self) -> Distributions {
        Distributions::from_l25(self)
    }
}

/// All distributions derived from the L = 25 histogram (exact counts).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Distributions {
    /// Total count (8 × windows counted).
    pub total: u64,
    /// Distinct 5×5 windows.
    pub l25_distinct: usize,
    /// L = 25 counts, descending (for mass statistics).
    pub l25_counts_desc: Vec<u64>,
    /// Count of the all-free and all-occupied 5×5 windows.
    pub l25_free_occupied: (u64, u64),
    /// Unconditioned L = 9 counts by config.
    pub l9: Vec<u64>,
    /// Per seen border: its candidates `(config, count)`, by descending count then ascending
    /// config.
    pub border: BTreeMap<u16, Vec<(u16, u64)>>,
    /// L = 1: per 8-neighbour byte, counts of `[centre free, centre occupied]`.
    pub l1: Vec<[u64; 2]>,
    /// Count of windows whose centre cell is occupied.
    pub centre_occupied: u64,
}

impl Distributions {
    /// Derives everything from the symmetrised histogram.
    pub fn from_l25(l25: &L25) -> Distributions {
        let mut l9 = vec![0u64; CONFIGS];
        let mut l1 = vec![[0u64; 2]; 256];
        let mut border: HashMap<u16, BTreeMap<u16, u64>> = HashMap::new();
        let mut l25_counts_desc = Vec::new();
        let (mut total, mut centre_occupied) = (0u64, 0u64);
        let mut free_occ = (0, 0);
        for (w, n) in l25.windows() {
            let p = patch_of(w);
            total += n;
            l25_counts_desc.push(n);
            if w == 0 {
                free_occ.0 = n;
            } else if w == ogm_core::sampler::patch::WINDOW_MASK {
                free_occ.1 = n;
            }
            if let Some(c) = l9.get_mut(usize::from(p)) {
                *c += n;
            }
            let centre = usize::from(ogm_core::sampler::patch::centre_of(p));
            if let Some(c) = l1
                .get_mut(usize::from(neighbours_of(p)))
                .and_then(|a| a.get_mut(centre))
            {
                *c += n;
            }
            if centre == 1 {
                centre_occupied += n;
            }
            *border
                .entry(border_of(w))
                .or_default()
                .entry(p)
                .or_default() += n;
        }
        l25_counts_desc.sort_unstable_by(|a, b| b.cmp(a));
        let border = border
            .into_iter()
            .map(|(b, m)| {
                let mut v: Vec<(u16, u64)> = m.into_iter().collect();
                v.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
                (b, v)
            })
            .collect();
        Distributions {
            total,
            l25_distinct: l25_counts_desc.len(),
            l25_counts_desc,
            l25_free_occupied: free_occ,
            l9,
            border,
            l1,
            centre_occupied,
        }
    }
}

/// `host-sim train-prior`: trains on `corpus` and writes (or, with `check`, compares) the two
/// generated tables. Returns an error if `check` finds a difference.
pub fn train_prior_cmd(
    corpus: &Path,
    core_out: &Path,
    l25_out: &Path,
    threads: usize,
    check: bool,
) -> Result<()> {
    let t0 = std::time::Instant::now();
    let corpus = Corpus::scan(corpus)?;
    let training = train::train(&corpus, threads)?;
    let params = PruneParams::default();
    let core = codegen::emit_core_table(&training, &params)?;
    let l25 = codegen::emit_l25_table(&training);
    for m in &training.maps {
        if let Some(why) = &m.skipped {
            eprintln!("  skipped {}: {why}", m.rel_path);
        }
    }
    eprintln!(
        "trained on {} maps ({} files, corpus sha256 {}): {} windows ×8, {:.1} s",
        training.maps.iter().filter(|m| m.skipped.is_none()).count(),
        corpus.files.len(),
        corpus.sha256,
        training.windows(),
        t0.elapsed().as_secs_f64()
    );
    for (path, text) in [(core_out, &core), (l25_out, &l25)] {
        if check {
            let old = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            if &old != text {
                bail!(
                    "{} differs from what the corpus generates; run `host-sim train-prior`",
                    path.display()
                );
            }
            eprintln!("{}: up to date", path.display());
        } else {
            std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote {} ({} bytes)", path.display(), text.len());
        }
    }
    Ok(())
}

/// `host-sim train-prior --measure-walls`: the HouseExpo wall-thickness measurement behind
/// [`HOUSEEXPO_M_PER_PX`] — a histogram of wall crossings in pixels over all HouseExpo plans
/// (see [`train::wall_run_lengths`]), the per-plan modes, and the scale each assumed wall
/// thickness implies.
pub fn measure_walls_cmd(corpus: &Path) -> Result<()> {
    let corpus = Corpus::scan(corpus)?;
    let mut total: BTreeMap<usize, u64> = BTreeMap::new();
    let mut modes: BTreeMap<usize, u32> = BTreeMap::new();
    for m in corpus
        .maps
        .iter()
        .filter(|m| m.kind == train::MapKind::HouseExpo)
    {
        // Native pixels: the override only labels the cell size, nothing is resampled.
        let w = ogm_field::world::load_world(&m.path, Some(HOUSEEXPO_M_PER_PX))?;
        let mut h = BTreeMap::new();
        train::wall_run_lengths(&w, &mut h);
        let mode = h
            .iter()
            .max_by_key(|(len, n)| (**n, std::cmp::Reverse(**len)))
            .map_or(0, |(len, _)| *len);
        *modes.entry(mode).or_default() += 1;
        for (k, v) in h {
            *total.entry(k).or_default() += v;
        }
    }
    let n: u64 = total.values().sum();
    if n == 0 {
        bail!("no wall crossings found in the HouseExpo maps");
    }
    println!("HouseExpo wall crossings (free-wall-free runs, px): {n}");
    let mut acc = 0u64;
    let mut median = 0usize;
    for (&len, &c) in &total {
        acc += c;
        if median == 0 && acc * 2 >= n {
            median = len;
        }
        if len <= 30 {
            println!(
                "  {len:>3} px {c:>8} {:>6.2} %",
                c as f64 * 100.0 / n as f64
            );
        }
    }
    println!("per-plan mode (px: plans, 0 = no crossing): {modes:?}");
    println!("median {median} px");
    for wall in [0.10, 0.125, 0.15] {
        println!(
            "  walls of {wall} m -> {:.4} m/px",
            wall / median.max(1) as f64
        );
    }
    println!("chosen: {HOUSEEXPO_M_PER_PX} m/px");
    Ok(())
}

/// `host-sim prior-stats [--json]`: prints the statistics of the committed tables next to the
/// paper's.
pub fn prior_stats_cmd(json: bool) -> Result<()> {
    let s = prior_stats();
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        print!("{}", s.to_text());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetrisation_spreads_counts_over_orbits() {
        let mut raw = HashMap::default();
        // An asymmetric window (orbit of 8) counted 3 times, the empty window once.
        let w = 0b111 | (1 << 5);
        raw.insert(w, 3);
        raw.insert(0, 1);
        let l = L25::from_raw(&raw);
        assert_eq!(l.total(), 8 * 4);
        assert_eq!(l.distinct(), 8 + 1);
        for t in Dihedral::ALL {
            assert!(l.windows().any(|(x, n)| x == t.window(w) && n == 3));
        }
        assert!(l.windows().any(|(x, n)| x == 0 && n == 8));
        assert_eq!(L25::from_orbits(l.orbits().to_vec()).unwrap(), l);
        assert!(L25::from_orbits(vec![Orbit {
            canonical: 1 << 24,
            count: 1
        }])
        .is_err());
    }

    #[test]
    fn committed_histogram_is_well_formed() {
        let l = L25::committed();
        assert!(L25::from_orbits(l.orbits().to_vec()).is_ok());
        assert_eq!(l.total() % 8, 0);
        let d = l.distributions();
        assert_eq!(d.total, l.total());
        assert_eq!(d.l9.iter().sum::<u64>(), d.total);
        assert_eq!(
            d.border
                .values()
                .flat_map(|v| v.iter().map(|x| x.1))
                .sum::<u64>(),
            d.total
        );
    }
}
