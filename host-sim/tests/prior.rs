//! Patch prior: the trainer against a brute-force count on a small synthetic corpus, codegen
//! determinism, and the compiled ogm-core table against the generator (no shared data needed).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use host_sim::eval::prior::codegen::{emit_core_table, emit_l25_table, CoreTables, PruneParams};
use host_sim::eval::prior::train::{train, Corpus};
use host_sim::eval::prior::{HOUSEEXPO_M_PER_PX, L25};
use ogm_core::sampler::patch::Dihedral;
use ogm_core::sampler::prior::{self, log_prior_of_probability, PriorSource};

/// A map drawn with `#` occupied, `.` free, `?` unknown; rows given top first (as an image).
struct Drawing(&'static [&'static str]);

impl Drawing {
    fn width(&self) -> usize {
        self.0.first().map_or(0, |r| r.len())
    }
    fn height(&self) -> usize {
        self.0.len()
    }
    /// Cell (x, y) with y = 0 at the bottom.
    fn cell(&self, x: usize, y: usize) -> char {
        let row = self.0[self.height() - 1 - y];
        row.as_bytes()[x] as char
    }
    /// Grey image, `scale` pixels per cell, map_server values.
    fn image(&self, scale: usize) -> image::GrayImage {
        let (w, h) = (self.width() * scale, self.height() * scale);
        image::GrayImage::from_fn(w as u32, h as u32, |px, py| {
            let ch = self.0[py as usize / scale].as_bytes()[px as usize / scale];
            image::Luma([match ch {
                b'#' => 0,
                b'.' => 254,
                _ => 128,
            }])
        })
    }
}

const HOUSE: Drawing = Drawing(&[
    "????????????????????",
    "?##################?",
    "?#.......#........#?",
    "?#.......#........#?",
    "?#.......#...###..#?",
    "?#................#?",
    "?####..####.......#?",
    "?#.......#........#?",
    "?#.......#..#.....#?",
    "?#.......#........#?",
    "?##################?",
    "????????????????????",
]);

const LAB: Drawing = Drawing(&[
    "..........................",
    ".######....##.......#.....",
    ".#....#....##......###....",
    ".#....#..............#....",
    ".#.....?.......####.......",
    ".#....#........#..#.......",
    ".######..#.....####...#...",
    ".........#............#...",
    "..#####..#....?.......#...",
    "....................#.....",
]);

const EMPTY: Drawing = Drawing(&[
    "..........",
    "..........",
    "..........",
    "..........",
    "..........",
]);

fn write_corpus(dir: &Path) {
    let hx = dir.join("houseexpo");
    let ros = dir.join("ros");
    std::fs::create_dir_all(&hx).unwrap();
    std::fs::create_dir_all(&ros).unwrap();
    // HouseExpo: no stated scale; 5 px per 0.05 m cell at the assumed 0.01 m/px.
    assert_eq!(HOUSEEXPO_M_PER_PX, 0.01);
    HOUSE.image(5).save(hx.join("house.png")).unwrap();
    // ROS: 0.05 m, no resampling.
    LAB.image(1).save(ros.join("lab.png")).unwrap();
    std::fs::write(
        ros.join("lab.yaml"),
        "image: lab.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
    EMPTY.image(1).save(ros.join("empty.png")).unwrap();
    std::fs::write(
        ros.join("empty.yaml"),
        "image: empty.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
}

/// Border cells in bit order, config cells in bit order (the documented layout, spelled out).
fn border_cells() -> Vec<(u32, u32)> {
    let mut v: Vec<(u32, u32)> = (0..5).map(|c| (0, c)).collect();
    v.extend((0..5).map(|c| (4, c)));
    v.extend((1..4).map(|r| (r, 0)));
    v.extend((1..4).map(|r| (r, 4)));
    v
}
fn config_cells() -> Vec<(u32, u32)> {
    (1..4).flat_map(|r| (1..4).map(move |c| (r, c))).collect()
}

#[derive(Default)]
struct Brute {
    windows: HashMap<u32, u64>,
    border: BTreeMap<u16, BTreeMap<u16, u64>>,
    l9: BTreeMap<u16, u64>,
    l1: BTreeMap<u8, [u64; 2]>,
    total: u64,
}

/// Counts every fully known window of `d` under every transform, reading cells one by one.
fn brute(d: &Drawing, out: &mut Brute) {
    let (bc, cc) = (border_cells(), config_cells());
    for y0 in 0..d.height().saturating_sub(4) {
        for x0 in 0..d.width().saturating_sub(4) {
            let at = |r: u32, c: u32| d.cell(x0 + c as usize, y0 + r as usize);
            if (0..5).any(|r| (0..5).any(|c| at(r, c) == '?')) {
                continue;
            }
            for t in Dihedral::ALL {
                let inv = t.inverse();
                let occ = |r: u32, c: u32| {
                    let (r0, c0) = inv.map_cell(r, c);
                    at(r0, c0) == '#'
                };
                let mut window = 0u32;
                for r in 0..5 {
                    for c in 0..5 {
                        if occ(r, c) {
                            window |= 1 << (5 * r + c);
                        }
                    }
                }
                let border = bc
                    .iter()
                    .enumerate()
                    .fold(0u16, |b, (i, &(r, c))| b | (u16::from(occ(r, c)) << i));
                let config = cc
                    .iter()
                    .enumerate()
                    .fold(0u16, |b, (i, &(r, c))| b | (u16::from(occ(r, c)) << i));
                let neighbours = cc
                    .iter()
                    .filter(|&&rc| rc != (2, 2))
                    .enumerate()
                    .fold(0u8, |b, (i, &(r, c))| b | (u8::from(occ(r, c)) << i));
                *out.windows.entry(window).or_default() += 1;
                *out.border
                    .entry(border)
                    .or_default()
                    .entry(config)
                    .or_default() += 1;
                *out.l9.entry(config).or_default() += 1;
                out.l1.entry(neighbours).or_default()[usize::from(occ(2, 2))] += 1;
                out.total += 1;
            }
        }
    }
}

#[test]
fn trainer_agrees_with_brute_force_on_a_synthetic_corpus() {
    let dir = tempfile::tempdir().unwrap();
    write_corpus(dir.path());
    let corpus = Corpus::scan(dir.path()).unwrap();
    assert_eq!(corpus.files.len(), 5);
    assert_eq!(corpus.maps.len(), 3);
    let t = train(&corpus, 2).unwrap();
    let skipped: Vec<_> = t.maps.iter().filter(|m| m.skipped.is_some()).collect();
    assert_eq!(skipped.len(), 1, "the wall-less map is skipped");
    assert_eq!(skipped[0].rel_path, "ros/empty.yaml");

    let mut b = Brute::default();
    brute(&HOUSE, &mut b);
    brute(&LAB, &mut b);
    assert!(b.total > 0);
    assert_eq!(t.windows() * 8, b.total);

    // L = 25.
    let got: HashMap<u32, u64> = t.l25.windows().collect();
    assert_eq!(got, b.windows);
    assert_eq!(t.l25.total(), b.total);

    // Derived distributions.
    let d = t.l25.distributions();
    assert_eq!(d.total, b.total);
    for c in 0..512u16 {
        assert_eq!(
            d.l9[usize::from(c)],
            b.l9.get(&c).copied().unwrap_or(0),
            "L9 {c}"
        );
    }
    for n in 0..=255u8 {
        assert_eq!(
            d.l1[usize::from(n)],
            b.l1.get(&n).copied().unwrap_or([0, 0]),
            "L1 {n}"
        );
    }
    assert_eq!(d.border.len(), b.border.len());
    for (border, cands) in &b.border {
        let mine: BTreeMap<u16, u64> = d.border[border].iter().copied().collect();
        assert_eq!(&mine, cands, "border {border:#06x}");
    }

    // Unpruned tables: the log-priors are the rounded conditional frequencies, most likely first.
    let none = PruneParams {
        min_border_count: 0,
        candidate_floor_ppm: 0,
        k_max: 512,
    };
    let tables = CoreTables::build(&d, &none);
    assert_eq!(tables.borders.len(), b.border.len());
    assert_eq!(
        tables.dropped_border_mass + tables.dropped_candidate_mass,
        0
    );
    for (border, cands) in &tables.borders {
        let bc = &b.border[border];
        let total: u64 = bc.values().sum();
        assert_eq!(cands.len(), bc.len());
        for &(config, lp) in cands {
            assert_eq!(
                lp,
                log_prior_of_probability(bc[&config] as f64 / total as f64)
            );
        }
        assert!(cands.windows(2).all(|w| w[0].1 >= w[1].1));
    }
    let l9_total: u64 = b.l9.values().sum();
    for &(config, lp) in &tables.l9 {
        assert_eq!(
            lp,
            log_prior_of_probability(b.l9[&config] as f64 / l9_total as f64)
        );
    }

    // Pruned tables stay symmetric and respect the cap.
    let p = PruneParams {
        min_border_count: 16,
        candidate_floor_ppm: 50_000,
        k_max: 2,
    };
    let pruned = CoreTables::build(&d, &p);
    let stored: BTreeMap<u16, Vec<(u16, i16)>> = pruned.borders.iter().cloned().collect();
    for (border, cands) in &stored {
        assert!(cands.len() <= 2 && !cands.is_empty());
        for t in Dihedral::ALL {
            let mut a: Vec<(u16, i16)> = cands.iter().map(|&(c, l)| (t.config(c), l)).collect();
            let mut o = stored[&t.border(*border)].clone();
            a.sort_unstable();
            o.sort_unstable();
            assert_eq!(a, o);
        }
    }

    // Deterministic output, whatever the thread count.
    let t1 = train(&corpus, 1).unwrap();
    let t3 = train(&corpus, 3).unwrap();
    let params = PruneParams::default();
    let a = emit_core_table(&t1, &params).unwrap();
    assert_eq!(a, emit_core_table(&t3, &params).unwrap());
    assert_eq!(a, emit_core_table(&t, &params).unwrap());
    assert_eq!(emit_l25_table(&t1), emit_l25_table(&t3));
    assert!(a.contains(&corpus.sha256));
    assert!(a.contains("houseexpo/house.png"));
    assert!(a.contains("ros/empty.yaml: SKIPPED"));
}

#[test]
fn missing_corpus_is_reported_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let e = Corpus::scan(&dir.path().join("nope")).unwrap_err();
    assert!(e.to_string().contains("not found"), "{e}");
}

/// The compiled ogm-core table is exactly what the generator makes from the committed L = 25
/// histogram (which the regeneration test ties to the corpus).
#[test]
fn compiled_table_matches_the_generator() {
    let l25 = L25::committed();
    let d = l25.distributions();
    let tables = CoreTables::build(&d, &PruneParams::default());
    let info = prior::TABLE_INFO;
    assert_eq!(info.windows, d.total);
    assert_eq!(info.borders_seen as usize, d.border.len());
    assert_eq!(info.borders_stored as usize, tables.borders.len());
    assert_eq!(prior::table_flash_bytes(), tables.flash_bytes());
    let stored: BTreeMap<u16, &Vec<(u16, i16)>> =
        tables.borders.iter().map(|(b, c)| (*b, c)).collect();
    for border in 0..=u16::MAX {
        let got = prior::border_candidates(border);
        match stored.get(&border) {
            Some(cands) => {
                let got = got.unwrap();
                let pairs: Vec<(u16, i16)> = got.iter().map(|c| (c.config, c.log_prior)).collect();
                assert_eq!(&pairs, *cands, "border {border:#06x}");
                assert_eq!(prior::candidates(border, 3).source(), PriorSource::Border);
            }
            None => {
                assert!(got.is_none());
                let fb = prior::candidates(border, 5);
                assert_eq!(fb.source(), PriorSource::Fallback);
                assert!(!fb.is_empty());
            }
        }
    }
    let l9: Vec<(u16, i16)> = prior::unconditioned(usize::MAX)
        .iter()
        .map(|c| (c.config, c.log_prior))
        .collect();
    assert_eq!(l9, tables.l9);
    for n in 0..=255u8 {
        let p = prior::cell_prior(n);
        let [f, o] = tables.l1[usize::from(n)];
        if p.source == PriorSource::Border {
            assert_eq!([p.log_p_free, p.log_p_occupied], [f, o]);
        } else {
            assert_eq!([f, o], [prior::LOG_ZERO; 2]);
        }
    }
}
