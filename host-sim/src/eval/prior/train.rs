//! Counting 5×5 windows over the training corpus.
//!
//! The corpus is `maps/train/houseexpo/*.png` (HouseExpo plans, no stated scale: loaded at
//! [`HOUSEEXPO_M_PER_PX`]) and `maps/train/ros/*.yaml` (ROS map_server maps, at their stated
//! resolution), in sorted path order. Each map is loaded with map_server semantics
//! ([`ogm_field::world::load_world`]), resampled to [`CELL_SIZE_M`] ([`World::resample`]: a cell is
//! Occupied if any covered source cell is, else Free if any is, else Unknown), and every 5×5
//! window without an Unknown cell is counted. Maps with almost no walls
//! ([`MIN_OCCUPIED_FRACTION`]) are skipped.
//!
//! Windows are extracted incrementally: per map row a 5-bit column word is kept for every
//! column (shifted up one row at a time), and sliding along a row shifts the 25-bit window by
//! one column and ORs in the new column through a 32-entry spread table — O(1) per window.
//! Maps are processed on `threads` worker threads; counts are merged by addition, so the
//! result does not depend on scheduling.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::{bail, Context, Result};
use ogm_core::sampler::patch::WINDOW_MASK;
use ogm_field::world::{load_world, Truth, World};
use sha2::{Digest, Sha256};

use super::{CELL_SIZE_M, HOUSEEXPO_M_PER_PX, L25, MIN_OCCUPIED_FRACTION};

/// A multiplicative hasher for 25-bit window keys (the std SipHash is needlessly slow here).
#[derive(Default, Clone, Copy)]
pub struct WindowHasher(u64);

impl Hasher for WindowHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u32(&mut self, i: u32) {
        self.0 = (u64::from(i) ^ self.0).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 ^= self.0 >> 29;
    }
}

/// `BuildHasher` for [`WindowHasher`].
pub type BuildWindowHasher = BuildHasherDefault<WindowHasher>;

/// Which loader a training map needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapKind {
    /// A HouseExpo PNG (no stated scale).
    HouseExpo,
    /// A ROS map_server YAML.
    Ros,
}

/// One file of the corpus, for the provenance header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CorpusFile {
    /// Path relative to the corpus root, `/`-separated.
    pub rel_path: String,
    /// Size in bytes.
    pub bytes: u64,
    /// SHA-256 of the content, lower-case hex.
    pub sha256: String,
}

/// One training map.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CorpusMap {
    /// Path relative to the corpus root.
    pub rel_path: String,
    /// Absolute path.
    pub path: PathBuf,
    /// Loader.
    pub kind: MapKind,
}

/// The training corpus: `houseexpo/` and `ros/` under a root.
#[derive(Clone, Debug)]
pub struct Corpus {
    /// The root (`.../maps/train`).
    pub root: PathBuf,
    /// Every file of the two folders (maps, YAMLs and their images), sorted by relative path.
    pub files: Vec<CorpusFile>,
    /// The maps, sorted by relative path.
    pub maps: Vec<CorpusMap>,
    /// SHA-256 of the text `"<sha256>  <rel_path>\n"` over [`Corpus::files`] in order — what
    /// `cd maps/train && find houseexpo ros -type f | LC_ALL=C sort | xargs sha256sum |
    /// sha256sum` prints.
    pub sha256: String,
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn sha256_file(path: &Path) -> Result<(u64, String)> {
    let mut f = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut n = 0u64;
    loop {
        let k = f
            .read(&mut buf)
            .with_context(|| format!("reading {}", path.display()))?;
        if k == 0 {
            break;
        }
        n += k as u64;
        h.update(buf.get(..k).unwrap_or(&[]));
    }
    Ok((n, hex(&h.finalize())))
}

impl Corpus {
    /// Lists and hashes the corpus under `root`. Fails with a clear message if `root` or one of
    /// its two folders is missing.
    pub fn scan(root: &Path) -> Result<Corpus> {
        if root.exists() && !root.is_dir() {
            bail!(
                "training corpus {}: not a directory (expected a folder with houseexpo/ and ros/)",
                root.display()
            );
        }
        if !root.is_dir() {
            bail!(
                "training corpus {} not found (expected ../shared/data/maps/train beside the \
                 project)",
                root.display()
            );
        }
        let mut files = Vec::new();
        let mut maps = Vec::new();
        for (dir, kind) in [("houseexpo", MapKind::HouseExpo), ("ros", MapKind::Ros)] {
            let d = root.join(dir);
            let entries =
                std::fs::read_dir(&d).with_context(|| format!("listing {}", d.display()))?;
            let mut names: Vec<String> = Vec::new();
            for e in entries {
                let e = e.with_context(|| format!("listing {}", d.display()))?;
                if e.file_type()?.is_file() {
                    names.push(e.file_name().to_string_lossy().into_owned());
                }
            }
            names.sort();
            for name in names {
                let path = d.join(&name);
                let rel_path = format!("{dir}/{name}");
                let (bytes, sha256) = sha256_file(&path)?;
                files.push(CorpusFile {
                    rel_path: rel_path.clone(),
                    bytes,
                    sha256,
                });
                let ext = name.rsplit('.').next().unwrap_or("").to_ascii_lowercase();
                let is_map = match kind {
                    MapKind::HouseExpo => ext == "png" || ext == "pgm",
                    MapKind::Ros => ext == "yaml" || ext == "yml",
                };
                if is_map {
                    maps.push(CorpusMap {
                        rel_path,
                        path,
                        kind,
                    });
                }
            }
        }
        files.sort_by(|a, b| a.rel_path.cmp(&b.rel_path));
        maps.sort_by(|a, b| a.rel_path.cmp(&b.rel_path));
        let mut h = Sha256::new();
        for f in &files {
            h.update(format!("{}  {}\n", f.sha256, f.rel_path).as_bytes());
        }
        Ok(Corpus {
            root: root.to_path_buf(),
            files,
            maps,
            sha256: hex(&h.finalize()),
        })
    }
}

/// Loads one training map at [`CELL_SIZE_M`].
pub fn load_canonical(map: &CorpusMap) -> Result<World> {
    let scale = match map.kind {
        MapKind::HouseExpo => Some(HOUSEEXPO_M_PER_PX),
        MapKind::Ros => None,
    };
    let w = load_world(&map.path, scale)?;
    Ok(w.resample(CELL_SIZE_M))
}

/// Raw (not yet symmetrised) counts of the 5×5 windows of some maps.
#[derive(Clone, Debug, Default)]
pub struct WindowCounts {
    /// Count per window (layout of [`ogm_core::sampler::patch`]).
    pub counts: HashMap<u32, u64, BuildWindowHasher>,
    /// Windows counted.
    pub windows: u64,
}

impl WindowCounts {
    /// Adds `other`.
    pub fn merge(&mut self, other: &WindowCounts) {
        for (&w, &n) in &other.counts {
            *self.counts.entry(w).or_default() += n;
        }
        self.windows += other.windows;
    }
}

/// Bits of window column 4 (`c = 4` in every row).
const COL4: u32 = (1 << 4) | (1 << 9) | (1 << 14) | (1 << 19) | (1 << 24);

/// Column word (bit `k` = row `k`) → the same cells as window column 4.
const SPREAD: [u32; 32] = {
    let mut t = [0u32; 32];
    let mut v = 0;
    while v < 32 {
        let mut k = 0;
        while k < 5 {
            if (v >> k) & 1 == 1 {
                t[v] |= 1 << (5 * k + 4);
            }
            k += 1;
        }
        v += 1;
    }
    t
};

/// Counts every 5×5 window of `world` that has no Unknown cell. Window cell (`r`, `c`) is world
/// cell (`x0 + c`, `y0 + r`) for the window whose lower-left cell is (`x0`, `y0`).
pub fn count_world(world: &World) -> WindowCounts {
    let mut out = WindowCounts::default();
    let (w, h) = (world.width, world.height);
    if w < 5 || h < 5 || world.cells.len() < w * h {
        return out;
    }
    let spread = |v: u32| SPREAD.get(v as usize & 31).copied().unwrap_or(0);
    let mut occ_col = vec![0u32; w];
    let mut unk_col = vec![0u32; w];
    let (mut n_free, mut n_full) = (0u64, 0u64);
    for (y, row) in world.cells.chunks_exact(w).take(h).enumerate() {
        for ((o, u), t) in occ_col.iter_mut().zip(unk_col.iter_mut()).zip(row) {
            *o = (*o >> 1) | (u32::from(*t == Truth::Occupied) << 4);
            *u = (*u >> 1) | (u32::from(*t == Truth::Unknown) << 4);
        }
        if y < 4 {
            continue;
        }
        let (mut win, mut unk) = (0u32, 0u32);
        for (x, (&o, &u)) in occ_col.iter().zip(&unk_col).enumerate() {
            win = ((win >> 1) & !COL4) | spread(o);
            unk = ((unk >> 1) & !COL4) | spread(u);
            if x >= 4 && unk == 0 {
                match win {
                    0 => n_free += 1,
                    WINDOW_MASK => n_full += 1,
                    _ => *out.counts.entry(win).or_default() += 1,
                }
            }
        }
    }
    for (k, n) in [(0, n_free), (WINDOW_MASK, n_full)] {
        if n > 0 {
            *out.counts.entry(k).or_default() += n;
        }
    }
    out.windows = out.counts.values().sum();
    out
}

/// Adds to `hist` the lengths of the horizontal and vertical runs of Occupied cells that have
/// a Free cell at both ends: wall crossings. Crossings perpendicular to a straight wall measure
/// its thickness exactly, so the mode of the histogram is the typical wall thickness in cells
/// (runs along a wall are long and rare). Used to choose [`HOUSEEXPO_M_PER_PX`].
pub fn wall_run_lengths(world: &World, hist: &mut std::collections::BTreeMap<usize, u64>) {
    let (w, h) = (world.width, world.height);
    let at = |x: usize, y: usize| world.cells.get(y * w + x).copied();
    let mut scan = |len: usize, cell: &dyn Fn(usize) -> Option<Truth>| {
        let mut i = 0;
        while i < len {
            if cell(i) == Some(Truth::Occupied) {
                let start = i;
                while i < len && cell(i) == Some(Truth::Occupied) {
                    i += 1;
                }
                let before = start.checked_sub(1).and_then(cell);
                if before == Some(Truth::Free) && i < len && cell(i) == Some(Truth::Free) {
                    *hist.entry(i - start).or_default() += 1;
                }
            } else {
                i += 1;
            }
        }
    };
    for y in 0..h {
        scan(w, &|x| at(x, y));
    }
    for x in 0..w {
        scan(h, &|y| at(x, y));
    }
}

/// What training did with one map.
#[derive(Clone, Debug, PartialEq)]
pub struct MapReport {
    /// Path relative to the corpus root.
    pub rel_path: String,
    /// Size at [`CELL_SIZE_M`] (columns, rows).
    pub size: (usize, usize),
    /// Occupied share of the known cells.
    pub occupied_fraction: f64,
    /// Windows counted (before the ×8 symmetrisation).
    pub windows: u64,
    /// Why the map was left out, if it was.
    pub skipped: Option<String>,
}

/// The result of training.
#[derive(Clone, Debug)]
pub struct Training {
    /// The corpus trained on.
    pub corpus: Corpus,
    /// Per map, in corpus order.
    pub maps: Vec<MapReport>,
    /// The symmetrised histogram.
    pub l25: L25,
}

impl Training {
    /// Windows counted over all maps (before symmetrisation).
    pub fn windows(&self) -> u64 {
        self.maps.iter().map(|m| m.windows).sum()
    }
}

/// Loads and counts one map.
pub fn train_map(map: &CorpusMap) -> Result<(MapReport, WindowCounts)> {
    let world = load_canonical(map).with_context(|| format!("loading {}", map.rel_path))?;
    let c = world.counts();
    let known = c.free + c.occupied;
    let occupied_fraction = if known == 0 {
        0.0
    } else {
        c.occupied as f64 / known as f64
    };
    let mut report = MapReport {
        rel_path: map.rel_path.clone(),
        size: (world.width, world.height),
        occupied_fraction,
        windows: 0,
        skipped: None,
    };
    if occupied_fraction < MIN_OCCUPIED_FRACTION {
        report.skipped = Some(format!(
            "{} occupied of {} known cells (< {} %): a map without walls",
            c.occupied,
            known,
            MIN_OCCUPIED_FRACTION * 100.0
        ));
        return Ok((report, WindowCounts::default()));
    }
    let counts = count_world(&world);
    report.windows = counts.windows;
    Ok((report, counts))
}

/// Counts every map of `corpus` on `threads` threads (≥ 1) and symmetrises.
pub fn train(corpus: &Corpus, threads: usize) -> Result<Training> {
    let next = AtomicUsize::new(0);
    type Slot = Option<Result<(MapReport, WindowCounts)>>;
    let results: Mutex<Vec<Slot>> = Mutex::new((0..corpus.maps.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(map) = corpus.maps.get(i) else {
                    break;
                };
                let r = train_map(map);
                if let Ok(mut v) = results.lock() {
                    if let Some(slot) = v.get_mut(i) {
                        *slot = Some(r);
                    }
                }
            });
        }
    });
    let results = results
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a training thread panicked"))?;
    let mut total = WindowCounts::default();
    let mut maps = Vec::with_capacity(results.len());
    for (i, r) in results.into_iter().enumerate() {
        let Some(r) = r else {
            bail!("map {i} was not processed");
        };
        let (report, counts) = r?;
        total.merge(&counts);
        maps.push(report);
    }
    if total.windows == 0 {
        bail!("no 5×5 window without unknown cells in the corpus");
    }
    Ok(Training {
        corpus: corpus.clone(),
        maps,
        l25: L25::from_raw(&total.counts),
    })
}

/// The default worker count: the machine's parallelism, at most 8.
pub fn default_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get().min(8))
        .unwrap_or(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::sampler::patch::with_window_cell;

    fn world(rows: &[&str]) -> World {
        // rows given top first, like an image
        let h = rows.len();
        let w = rows.first().map_or(0, |r| r.len());
        let mut cells = Vec::new();
        for row in rows.iter().rev() {
            for ch in row.chars() {
                cells.push(match ch {
                    '#' => Truth::Occupied,
                    '.' => Truth::Free,
                    _ => Truth::Unknown,
                });
            }
        }
        World {
            width: w,
            height: h,
            resolution_m: CELL_SIZE_M,
            origin_m: (0.0, 0.0),
            cells,
        }
    }

    /// Brute force: read each window cell by cell.
    fn brute(world: &World) -> HashMap<u32, u64> {
        let mut m = HashMap::new();
        for y0 in 0..world.height.saturating_sub(4) {
            for x0 in 0..world.width.saturating_sub(4) {
                let mut w = 0;
                let mut unknown = false;
                for r in 0..5 {
                    for c in 0..5 {
                        match world.get((x0 + c) as i64, (y0 + r) as i64) {
                            Some(Truth::Occupied) => {
                                w = with_window_cell(w, r as u32, c as u32, true)
                            }
                            Some(Truth::Free) => {}
                            _ => unknown = true,
                        }
                    }
                }
                if !unknown {
                    *m.entry(w).or_default() += 1;
                }
            }
        }
        m
    }

    #[test]
    fn wall_runs_measure_thickness() {
        let w = world(&["..###....", "..###..#.", "..###....", "?.###.##?"]);
        let mut h = std::collections::BTreeMap::new();
        wall_run_lengths(&w, &mut h);
        // All four rows cross the 3-wide wall between free cells; row 2 also crosses the
        // single cell at x = 7, and so does column 7 (y = 2). Runs touching unknown or the map
        // edge (the bottom-row stub, the wall's columns) do not count.
        assert_eq!(h.get(&3), Some(&4));
        assert_eq!(h.get(&1), Some(&2));
        assert_eq!(h.values().sum::<u64>(), 6);
    }

    #[test]
    fn incremental_extraction_matches_brute_force() {
        let w = world(&[
            "?????.....#####.",
            "??....#.....##..",
            "#.....#...?.....",
            "#.....######....",
            "#..........#....",
            "######.....#..##",
            "..#........#....",
            "..#...?....#####",
            "........#.......",
        ]);
        let fast = count_world(&w);
        let slow = brute(&w);
        let fast_std: HashMap<u32, u64> = fast.counts.iter().map(|(&k, &v)| (k, v)).collect();
        assert_eq!(fast_std, slow);
        assert_eq!(fast.windows, slow.values().sum::<u64>());
        // The bottom-left window: rows 0..5 (bottom first), columns 0..5.
        let mut expect = 0;
        for (r, row) in [
            "........#.",
            "..#...?...",
            "..#.......",
            "######....",
            "#.........",
        ]
        .iter()
        .enumerate()
        {
            for (c, ch) in row.chars().take(5).enumerate() {
                if ch == '#' {
                    expect = with_window_cell(expect, r as u32, c as u32, true);
                }
            }
        }
        assert!(slow.contains_key(&expect));
        assert_eq!(count_world(&world(&["....", "...."])).windows, 0);
    }
}
