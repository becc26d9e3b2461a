//! Online insertion throughput: cells updated per second by `Mapper::insert_scan` (fixed point)
//! and `reference::ReferenceMapper` (f64) on the same synthetic indoor scans.
//!
//! `cargo bench -p ogm-core --bench insert` (results and discussion: docs/performance.md).
//!
//! Input: a 500 × 500 map of 5 cm cells (25 m square); a 10 m × 7 m flat (outer walls, two inner
//! walls with doorways, furniture, an open door in the outer wall) ray-cast in f64 from poses drawn
//! with a seeded RNG; 360 beams at 1°, LD06-like 12 m maximum range, ±15 mm of range noise and 1 %
//! of beams lost (`NoReturn`). Everything is deterministic, so runs are comparable.
//!
//! `insert/hahnel/fixed` is `insert_scan`, `insert/hahnel/fixed_with` is `insert_scan_with` with a
//! callback that counts first observations (the firmware's old seeding path), and
//! `insert/hahnel/fixed_notable` is `insert_scan_into` with a `Reports::Notable` listener (the
//! online sampler's path: mark words and notable cells only).
//!
//! Throughput is `Throughput::Elements(cells updated)`, where a cell counts once per scan
//! (`ScanStats::cells_hit + cells_freed`: the mapper updates every cell at most once per scan). The
//! setup also prints the cells *walked* (sum over beams of the in-grid ray length, the unit of the
//! MRPT figure in the references), to convert.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use ogm_core::map::mapper::{marks_len, Reports, UpdateListener};
use ogm_core::map::ray::Ray;
use ogm_core::map::sensor_model::InverseSensorModel;
use ogm_core::reference::{Increments, ReferenceMapper};
use ogm_core::{
    Angle, Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose, Range,
};
use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

const SIDE: u16 = 500;
const CELL_MM: u32 = 50;
const BEAMS: u32 = 360;
const MAX_RANGE_MM: u32 = 12_000;
/// Scans per benchmark iteration (beam model; the cone model visits the whole reachable square
/// per scan and gets fewer).
const SCANS: usize = 64;
const CONE_SCANS: usize = 4;
const SEED: u64 = 0x06d0_2024;

fn geometry() -> GridGeometry {
    let half = i32::from(SIDE) * CELL_MM as i32 / 2;
    GridGeometry::new(SIDE, SIDE, CELL_MM, -half, -half).unwrap()
}

/// A wall segment (mm).
type Seg = ((f64, f64), (f64, f64));
/// An axis-aligned box `(x0, y0, x1, y1)` (mm).
type Box = (f64, f64, f64, f64);

/// The flat: outer walls 10 m × 7 m with an open door on the west side, an inner wall at x = 1 m
/// with a doorway, one at y = 0 (east part) with a doorway, and furniture.
fn flat() -> (Vec<Seg>, Vec<Box>) {
    let mut segs: Vec<Seg> = vec![
        // outer walls; the west wall has an open door at y ∈ [1000, 2200]
        ((-5000.0, -3500.0), (5000.0, -3500.0)),
        ((5000.0, -3500.0), (5000.0, 3500.0)),
        ((5000.0, 3500.0), (-5000.0, 3500.0)),
        ((-5000.0, 3500.0), (-5000.0, 2200.0)),
        ((-5000.0, 1000.0), (-5000.0, -3500.0)),
        // inner wall x = 1000 with a doorway y ∈ [-500, 400]
        ((1000.0, -3500.0), (1000.0, -500.0)),
        ((1000.0, 400.0), (1000.0, 3500.0)),
        // inner wall y = 0 east of it with a doorway x ∈ [2500, 3300]
        ((1000.0, 0.0), (2500.0, 0.0)),
        ((3300.0, 0.0), (5000.0, 0.0)),
    ];
    // Furniture (axis-aligned boxes x0, y0, x1, y1): table, sofa, cabinet, pillar, bed, shelf.
    let boxes = vec![
        (-3000.0, -1500.0, -1800.0, -700.0),
        (-4600.0, 500.0, -4000.0, 2500.0),
        (3800.0, 2600.0, 4900.0, 3400.0),
        (-500.0, 1800.0, -300.0, 2000.0),
        (2000.0, -3300.0, 3600.0, -1400.0),
        (1100.0, 1500.0, 1500.0, 3400.0),
    ];
    for &(x0, y0, x1, y1) in &boxes {
        segs.push(((x0, y0), (x1, y0)));
        segs.push(((x1, y0), (x1, y1)));
        segs.push(((x1, y1), (x0, y1)));
        segs.push(((x0, y1), (x0, y0)));
    }
    (segs, boxes)
}

/// Distance from `p` along the unit direction `d` to the nearest segment, if any.
fn cast(segs: &[Seg], p: (f64, f64), d: (f64, f64)) -> Option<f64> {
    let mut best: Option<f64> = None;
    for &((ax, ay), (bx, by)) in segs {
        let (ex, ey) = (bx - ax, by - ay);
        let den = d.0 * ey - d.1 * ex;
        if den.abs() < 1e-12 {
            continue;
        }
        let (wx, wy) = (ax - p.0, ay - p.1);
        let t = (wx * ey - wy * ex) / den; // along the beam
        let u = (wx * d.1 - wy * d.0) / den; // along the segment
        if t > 0.0 && (0.0..=1.0).contains(&u) && best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    }
    best
}

fn uniform(rng: &mut Xoshiro256PlusPlus) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

struct Scan {
    pose: Pose,
    beams: Vec<Beam>,
}

/// `n` scans from random free poses in the flat (sorted by angle, as the cone model requires).
fn scans(n: usize) -> Vec<Scan> {
    let (segs, boxes) = flat();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(SEED);
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let x = -4800.0 + 9600.0 * uniform(&mut rng);
        let y = -3300.0 + 6600.0 * uniform(&mut rng);
        let inside_box = boxes.iter().any(|&(x0, y0, x1, y1)| {
            x > x0 - 250.0 && x < x1 + 250.0 && y > y0 - 250.0 && y < y1 + 250.0
        });
        let near_wall = (x - 1000.0).abs() < 250.0 || (y.abs() < 250.0 && x > 1000.0);
        if inside_box || near_wall {
            continue;
        }
        let pose = Pose {
            x_mm: x.round() as i32,
            y_mm: y.round() as i32,
            heading: Angle((rng.next_u64() >> 48) as u16),
        };
        let beams = (0..BEAMS)
            .map(|i| {
                let angle = Angle::from_centidegrees(i * 36_000 / BEAMS);
                let dir = pose.heading.wrapping_add(angle).to_radians();
                let hit = cast(
                    &segs,
                    (f64::from(pose.x_mm), f64::from(pose.y_mm)),
                    (dir.cos(), dir.sin()),
                );
                let lost = uniform(&mut rng) < 0.01;
                let noise = (uniform(&mut rng) - 0.5) * 30.0;
                let range = match hit {
                    Some(r) if !lost && r + noise < f64::from(MAX_RANGE_MM) => {
                        Range::Hit((r + noise).max(0.0).round() as u32)
                    }
                    _ => Range::NoReturn,
                };
                Beam { angle, range }
            })
            .collect();
        out.push(Scan { pose, beams });
    }
    out
}

/// A `Reports::Notable` listener that only counts what it hears.
#[derive(Clone, Copy, Debug, Default)]
struct Tally {
    words: u32,
    notable: u32,
}

impl UpdateListener for Tally {
    const REPORTS: Reports = Reports::Notable;
    fn changed(&mut self, _: usize, _: LogOdds, _: LogOdds) {
        self.notable += 1;
    }
    fn marked_words(&mut self, _: usize, words: &[u32]) {
        self.words += words.len() as u32;
    }
    fn fresh_word(&mut self, _: usize, bits: u32, _: LogOdds) {
        self.notable += bits.count_ones();
    }
}

fn fixed_mapper(cfg: MapperConfig) -> Mapper<Vec<LogOdds>, Vec<u32>> {
    let g = geometry();
    let grid = LogOddsGrid::new(g, vec![LogOdds::ZERO; g.len()]).unwrap();
    Mapper::new(grid, vec![0; marks_len(g.len())], cfg).unwrap()
}

fn reference_mapper(cfg: MapperConfig) -> ReferenceMapper<Vec<f64>, Vec<u32>> {
    let g = geometry();
    ReferenceMapper::new(
        g,
        cfg,
        Increments::effective(&cfg),
        vec![0.0; g.len()],
        vec![0u32; marks_len(g.len())],
    )
    .unwrap()
}

/// Cells updated by inserting `scans` once into a fresh mapper (the same count on every pass).
fn cells_updated(cfg: MapperConfig, scans: &[Scan]) -> u64 {
    let mut m = fixed_mapper(cfg);
    scans
        .iter()
        .map(|s| {
            let st = m.insert_scan(&s.pose, &s.beams).unwrap();
            u64::from(st.cells_hit + st.cells_freed)
        })
        .sum()
}

/// Cells walked: the in-grid length of every used beam's ray (hits include their end cell), the
/// unit of "cells per second" in MRPT-style figures.
fn cells_walked(cfg: &MapperConfig, scans: &[Scan]) -> u64 {
    let g = geometry();
    let mut total = 0;
    for s in scans {
        let origin = g.cell_of_pose(&s.pose);
        for b in &s.beams {
            let range = match b.range {
                Range::Hit(mm) if mm < cfg.max_range_mm => mm,
                _ => cfg.max_range_mm,
            };
            let (x, y) = s.pose.beam_end(b.angle, range);
            let ray = Ray::new(origin, g.cell_of_point(x, y));
            if let Some(st) = ray.clip(g.width(), g.height()) {
                total += st.last - st.first + 1;
            }
        }
    }
    total
}

fn bench_insert(c: &mut Criterion) {
    let beam_scans = scans(SCANS);
    let hahnel = MapperConfig::new(MAX_RANGE_MM);
    let mut cone = MapperConfig::new(MAX_RANGE_MM);
    // α = 2 cells, β = 1° (the beam spacing).
    cone.model = InverseSensorModel::cone(0.8, 0.2, 0.5, 100, Angle::from_degrees(1.0)).unwrap();

    let updated = cells_updated(hahnel, &beam_scans);
    let walked = cells_walked(&hahnel, &beam_scans);
    let hits = beam_scans
        .iter()
        .flat_map(|s| &s.beams)
        .filter_map(|b| match b.range {
            Range::Hit(mm) => Some(f64::from(mm)),
            Range::NoReturn => None,
        })
        .collect::<Vec<_>>();
    eprintln!(
        "insert: {SCANS} scans x {BEAMS} beams, {SIDE}x{SIDE} cells of {CELL_MM} mm; \
         mean hit range {:.0} mm, {:.1} % no return; per scan {} cells updated, {} walked \
         (walked/updated = {:.3})",
        hits.iter().sum::<f64>() / hits.len() as f64,
        100.0 * (1.0 - hits.len() as f64 / (SCANS as f64 * f64::from(BEAMS))),
        updated / SCANS as u64,
        walked / SCANS as u64,
        walked as f64 / updated as f64
    );

    let mut group = c.benchmark_group("insert");
    group
        .sample_size(30)
        .warm_up_time(Duration::from_secs(2))
        .measurement_time(Duration::from_secs(5))
        .throughput(Throughput::Elements(updated));
    let mut fixed = fixed_mapper(hahnel);
    group.bench_function(BenchmarkId::new("hahnel", "fixed"), |b| {
        b.iter(|| {
            for s in &beam_scans {
                black_box(fixed.insert_scan(&s.pose, black_box(&s.beams)).unwrap());
            }
        })
    });
    // The firmware's path: every updated cell reported (it seeds the sampler with the cells
    // seen for the first time), which takes the sweep's per-cell loop instead of the lane-wise
    // update `insert_scan` uses on a 64-bit host.
    let mut reported = fixed_mapper(hahnel);
    group.bench_function(BenchmarkId::new("hahnel", "fixed_with"), |b| {
        b.iter(|| {
            let mut first_seen = 0u32;
            for s in &beam_scans {
                black_box(
                    reported
                        .insert_scan_with(&s.pose, black_box(&s.beams), |_, before, _| {
                            first_seen += u32::from(before.0 == 0);
                        })
                        .unwrap(),
                );
            }
            black_box(first_seen)
        })
    });
    // The online sampler's path since issue 15's second round: the changed cells' mark words
    // and only the notable cells (`Reports::Notable`), with the sweep's lane-free loop.
    let mut listened = fixed_mapper(hahnel);
    group.bench_function(BenchmarkId::new("hahnel", "fixed_notable"), |b| {
        b.iter(|| {
            let mut heard = Tally::default();
            for s in &beam_scans {
                black_box(
                    listened
                        .insert_scan_into(&s.pose, black_box(&s.beams), &mut heard)
                        .unwrap(),
                );
            }
            black_box(heard)
        })
    });
    let mut reference = reference_mapper(hahnel);
    group.bench_function(BenchmarkId::new("hahnel", "f64"), |b| {
        b.iter(|| {
            for s in &beam_scans {
                black_box(reference.insert_scan(&s.pose, black_box(&s.beams)).unwrap());
            }
        })
    });
    group.finish();

    let cone_scans = &beam_scans[..CONE_SCANS];
    let cone_updated = cells_updated(cone, cone_scans);
    eprintln!(
        "insert/cone: {CONE_SCANS} scans, per scan {} cells updated",
        cone_updated / CONE_SCANS as u64
    );
    let mut group = c.benchmark_group("insert");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(2))
        .measurement_time(Duration::from_secs(5))
        .throughput(Throughput::Elements(cone_updated));
    let mut fixed = fixed_mapper(cone);
    group.bench_function(BenchmarkId::new("cone", "fixed"), |b| {
        b.iter(|| {
            for s in cone_scans {
                black_box(fixed.insert_scan(&s.pose, black_box(&s.beams)).unwrap());
            }
        })
    });
    let mut reference = reference_mapper(cone);
    group.bench_function(BenchmarkId::new("cone", "f64"), |b| {
        b.iter(|| {
            for s in cone_scans {
                black_box(reference.insert_scan(&s.pose, black_box(&s.beams)).unwrap());
            }
        })
    });
    group.finish();
}

criterion_group!(benches, bench_insert);
criterion_main!(benches);
