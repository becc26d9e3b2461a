//! The rolling window (`ogm_core::session`'s `shift_for` / `apply_shift` / `restore_tile`): a
//! robot crossing a building larger than its window, leaving regions and coming back. The
//! tiles streamed as they leave, the tiles restored as they come back and the final window,
//! stitched, equal an unbounded map of the same scans cell for cell.

use std::collections::HashMap;

use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, RestoreError, Session, Sizes, TileRestore};
use ogm_core::wire::{self, HostMsg, Layer, RestoreFault, TileRect, TileSource};
use ogm_core::{Angle, Beam, Pose, Range};

const CELL: i32 = 50;
const EDGE: u16 = 16;
const WIN: u16 = 128;
const MARGIN: u16 = 44;
const MAX_RANGE: u32 = 1500;

/// Axis-aligned boxes (mm): the walls and furniture of a 40 m × 30 m building.
fn building() -> Vec<[f64; 4]> {
    let mut b = vec![
        [-200.0, -200.0, 40_200.0, 0.0],
        [-200.0, 30_000.0, 40_200.0, 30_200.0],
        [-200.0, -200.0, 0.0, 30_200.0],
        [40_000.0, -200.0, 40_200.0, 30_200.0],
    ];
    // Rows of pillars and wall stubs along the corridors (seeded, fixed layout).
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s % 1000) as f64 / 1000.0
    };
    for k in 0..60 {
        let x = 1_000.0 + next() * 38_000.0;
        let y = 1_000.0 + next() * 28_000.0;
        let (w, h) = if k % 3 == 0 {
            (150.0, 600.0 + 1200.0 * next())
        } else {
            (200.0 + 400.0 * next(), 200.0 + 400.0 * next())
        };
        b.push([x, y, x + w, y + h]);
    }
    b
}

/// The range along a ray from (x, y) in direction `a` to the nearest box (slab test), if any
/// within `max`.
fn cast(boxes: &[[f64; 4]], x: f64, y: f64, a: f64, max: f64) -> Option<f64> {
    let (dx, dy) = (a.cos(), a.sin());
    let mut best = f64::INFINITY;
    for [x0, y0, x1, y1] in boxes {
        if x >= *x0 && x <= *x1 && y >= *y0 && y <= *y1 {
            return Some(0.0);
        }
        let (mut t0, mut t1) = (0.0f64, max);
        for (p, d, lo, hi) in [(x, dx, *x0, *x1), (y, dy, *y0, *y1)] {
            if d.abs() < 1e-12 {
                if p < lo || p > hi {
                    t0 = f64::INFINITY;
                }
            } else {
                let (a, b) = ((lo - p) / d, (hi - p) / d);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 <= t1 && t0 < best {
            best = t0;
        }
    }
    (best < max).then_some(best)
}

/// A path of poses (every 150 mm) through waypoints, in metres.
fn path(waypoints: &[(f64, f64)]) -> Vec<Pose> {
    let mut out = Vec::new();
    for w in waypoints.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        let len = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
        let n = (len / 0.15).ceil() as usize;
        let heading = (y1 - y0).atan2(x1 - x0);
        for k in 0..n {
            let t = k as f64 / n as f64;
            out.push(Pose::new(
                ((x0 + t * (x1 - x0)) * 1000.0).round() as i32,
                ((y0 + t * (y1 - y0)) * 1000.0).round() as i32,
                Angle::from_radians(heading + 0.1 * k as f64),
            ));
        }
    }
    out
}

fn scan(boxes: &[[f64; 4]], pose: &Pose) -> Vec<Beam> {
    (0..120)
        .map(|k| {
            let a = Angle::from_centidegrees(300 * k);
            let world = pose.heading.to_radians() + a.to_radians();
            let r = cast(
                boxes,
                f64::from(pose.x_mm),
                f64::from(pose.y_mm),
                world,
                f64::from(MAX_RANGE) + 500.0,
            );
            Beam {
                angle: a,
                range: match r {
                    Some(r) if r >= 1.0 => Range::Hit(r.round() as u32),
                    _ => Range::NoReturn,
                },
            }
        })
        .collect()
}

fn config() -> RunConfig {
    RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_budget(Budget::Fixed { updates: 60 })
}

/// A tile's raw log-odds and estimate bytes.
fn tile_data(s: &impl TileSource, rect: &TileRect) -> (Vec<i16>, Vec<u8>) {
    let mut buf = [0u8; wire::MAX_TILE_BYTES];
    let lo = wire::encode_tile(s, Layer::LogOdds, rect, &mut buf).unwrap();
    let lo = lo
        .chunks_exact(2)
        .map(|c| i16::from_le_bytes([c[0], c[1]]))
        .collect();
    let est = wire::encode_tile(s, Layer::Counts, rect, &mut buf)
        .unwrap()
        .to_vec();
    (lo, est)
}

/// Sends building tile (`tx`, `ty`) through [`Session::restore_part`] in its wire parts
/// (log-odds bytes `lo`, estimates `est`); whether the last part restored it.
fn restore_by_parts(
    w: &mut Session<Owned<u8>>,
    asm: &mut TileRestore,
    tx: i32,
    ty: i32,
    lo: &[u8],
    est: &[u8],
) -> Result<bool, RestoreError> {
    let parts = wire::restore_msgs(tx, ty, Layer::LogOdds, EDGE, lo).chain(wire::restore_msgs(
        tx,
        ty,
        Layer::Counts,
        EDGE,
        est,
    ));
    let mut restored = false;
    let mut n = 0;
    for m in parts {
        let HostMsg::Restore {
            tx,
            ty,
            layer,
            row,
            data,
        } = m
        else {
            unreachable!()
        };
        let step = w.restore_part(asm, EDGE, tx, ty, layer, row, data.as_slice())?;
        restored = step.restored == Some((tx, ty));
        n += 1;
    }
    assert_eq!(n, 12, "8 log-odds and 4 estimate parts");
    Ok(restored)
}

type Stored = HashMap<(i32, i32), (Vec<i16>, Vec<u8>)>;

/// Log-odds by building cell.
type Stitched = HashMap<(i32, i32), i16>;

/// A map of the whole building: cells, building cell of index 0, size.
type Unbounded = (Vec<i16>, (i32, i32), (u16, u16));

/// Runs the path through a rolling window; returns the stitched log-odds by building cell, the
/// session and the number of tiles restored.
fn run_window(poses: &[Pose], boxes: &[[f64; 4]], restore: bool) -> (Stitched, Session<Owned<u8>>) {
    let cfg = config().with_window_margin_cells(MARGIN);
    let mut w = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    assert!(w.window_fits(EDGE));
    assert!(
        w.window_reach_cells() <= u32::from(MARGIN),
        "the margin covers the reach"
    );
    let mut stored: Stored = HashMap::new();
    let mut asm = TileRestore::new();
    let tiles = i32::from(WIN / EDGE);
    for pose in poses {
        if let Some(shift) = w.check_shift(pose, EDGE) {
            for t in shift.leaving() {
                stored.insert((t.tx, t.ty), tile_data(&w, &t.rect));
            }
            let (ox, oy) = (shift.from.0 / 16, shift.from.1 / 16);
            w.apply_shift(&shift).unwrap();
            let (nx, ny) = (shift.to().0 / 16, shift.to().1 / 16);
            if restore {
                for ty in ny..ny + tiles {
                    for tx in nx..nx + tiles {
                        let stayed =
                            (ox..ox + tiles).contains(&tx) && (oy..oy + tiles).contains(&ty);
                        if stayed {
                            continue;
                        }
                        if let Some((lo, est)) = stored.get(&(tx, ty)) {
                            // Through the wire's parts, as a host sends them.
                            let lo: Vec<u8> = lo.iter().flat_map(|v| v.to_le_bytes()).collect();
                            assert_eq!(
                                restore_by_parts(&mut w, &mut asm, tx, ty, &lo, est),
                                Ok(true)
                            );
                        }
                    }
                }
            }
        }
        let beams = scan(boxes, pose);
        let ins = w.insert(pose, &beams).unwrap();
        assert_eq!(ins.beams_clipped, 0, "no ray leaves the window");
        w.step(60);
    }
    let mut map = HashMap::new();
    for ((tx, ty), (lo, _)) in &stored {
        for (k, v) in lo.iter().enumerate() {
            let (x, y) = (k as i32 % 16, k as i32 / 16);
            map.insert((tx * 16 + x, ty * 16 + y), *v);
        }
    }
    let r = w.window();
    for (i, l) in w.log_odds().iter().enumerate() {
        let (x, y) = (i as i32 % i32::from(WIN), i as i32 / i32::from(WIN));
        map.insert((r.origin_x + x, r.origin_y + y), l.raw());
    }
    (map, w)
}

/// The same scans on one grid that holds the whole building.
fn run_unbounded(poses: &[Pose], boxes: &[[f64; 4]]) -> Unbounded {
    // Building cells −64 .. 960 × −64 .. 704.
    let (x0, y0, w, h) = (-64, -64, 1024u16, 768u16);
    let cfg = config().with_origin_mm(x0 * CELL, y0 * CELL);
    let mut s = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(w, h))).unwrap();
    for pose in poses {
        s.insert(pose, &scan(boxes, pose)).unwrap();
    }
    (
        s.log_odds().iter().map(|l| l.raw()).collect(),
        (x0, y0),
        (w, h),
    )
}

fn compare(map: &Stitched, unbounded: &Unbounded) -> usize {
    let (cells, (x0, y0), (w, _)) = unbounded;
    let (x0, y0) = (*x0, *y0);
    let mut differ = 0;
    let mut known = 0;
    for (i, v) in cells.iter().enumerate() {
        let (x, y) = (
            x0 + (i % usize::from(*w)) as i32,
            y0 + (i / usize::from(*w)) as i32,
        );
        let got = map.get(&(x, y)).copied().unwrap_or(0);
        known += usize::from(*v != 0);
        if got != *v {
            differ += 1;
        }
    }
    assert!(known > 50_000, "the building is mapped: {known} cells");
    // Nothing outside the unbounded grid was mapped.
    let (wi, hi) = (i32::from(unbounded.2 .0), i32::from(unbounded.2 .1));
    for ((x, y), v) in map {
        if *v != 0 {
            assert!((x0..x0 + wi).contains(x) && (y0..y0 + hi).contains(y));
        }
    }
    differ
}

/// Leaves the start, crosses the building, comes back to the start and to the middle.
const WAYPOINTS: [(f64, f64); 6] = [
    (3.2, 3.2),
    (36.0, 3.5),
    (36.5, 26.0),
    (3.5, 26.5),
    (3.0, 3.0),
    (20.0, 15.0),
];

#[test]
fn stitched_window_equals_the_unbounded_map() {
    let boxes = building();
    let poses = path(&WAYPOINTS);
    let (map, w) = run_window(&poses, &boxes, true);
    let r = w.window();
    assert!(r.shifts >= 10, "{r:?}");
    assert!(r.tiles_restored >= 20, "the robot came back: {r:?}");
    assert_eq!((r.restore_refused, r.shifts_refused), (0, 0));
    assert_eq!((r.scans_clipped, r.beams_clipped), (0, 0));
    let unbounded = run_unbounded(&poses, &boxes);
    assert_eq!(compare(&map, &unbounded), 0, "stitched vs unbounded");
}

#[test]
fn without_restore_the_regions_come_back_unknown_and_differ() {
    let boxes = building();
    let poses = path(&WAYPOINTS);
    let (map, w) = run_window(&poses, &boxes, false);
    assert_eq!(w.window().tiles_restored, 0);
    let differ = compare(&map, &run_unbounded(&poses, &boxes));
    assert!(differ > 100, "re-entered regions lost evidence: {differ}");
}

#[test]
fn a_shift_moves_log_odds_sample_and_estimates_and_enters_unknown() {
    let boxes = building();
    let cfg = config().with_window_margin_cells(MARGIN);
    let mut w = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    let mut fresh = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    for pose in path(&[(3.2, 3.2), (4.0, 3.3)]) {
        assert!(w.shift_for(&pose, EDGE).is_none());
        w.insert(&pose, &scan(&boxes, &pose)).unwrap();
        w.step(500);
    }
    let pose = Pose::new(4_900, 3_300, Angle::ZERO);
    let shift = w.shift_for(&pose, EDGE).expect("past the margin");
    assert_eq!((shift.dx, shift.dy), (32, 0));
    assert_eq!(shift.leaving().count(), 2 * 8);
    assert_eq!(shift.leaving_count(), 16);
    assert!(shift.leaving().all(|t| t.tx < 2 && t.rect.x0 < 32));
    let n = usize::from(WIN);
    let before: Vec<(i16, u8, bool)> = (0..n * n)
        .map(|i| (TileSource::log_odds(&w, i), w.count(i), w.occupied(i)))
        .collect();
    w.apply_shift(&shift).unwrap();
    assert_eq!(w.window().origin_x, 32);
    assert_eq!(w.geometry().origin_mm(), (32 * CELL, 0));
    for y in 0..n {
        for x in 0..n {
            let i = y * n + x;
            let now = (TileSource::log_odds(&w, i), w.count(i), w.occupied(i));
            if x + 32 < n {
                assert_eq!(now, before[i + 32], "cell ({x}, {y}) moved");
            } else {
                let unknown = (0, fresh.count(i), fresh.occupied(i));
                assert_eq!(now, unknown, "cell ({x}, {y}) entered unknown");
            }
        }
    }
    // A stale shift is refused; the sampler keeps running on the moved window.
    assert!(w.apply_shift(&shift).is_err());
    w.step(2000);
    fresh.step(10);
}

#[test]
fn extreme_poses_neither_panic_nor_overflow() {
    let cfg = config()
        .with_window_margin_cells(MARGIN)
        .with_origin_mm(i32::MAX - 3_200, i32::MIN + 100);
    let mut w = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    let beams: Vec<Beam> = (0..36)
        .map(|k| Beam {
            angle: Angle::from_centidegrees(1000 * k),
            range: Range::Hit(1000),
        })
        .collect();
    for (x, y) in [
        (i32::MAX, i32::MIN),
        (i32::MIN, i32::MAX),
        (0, 0),
        (i32::MAX, i32::MAX),
        (i32::MAX - 3_200, i32::MIN + 3_300),
    ] {
        let pose = Pose::new(x, y, Angle::ZERO);
        if let Some(s) = w.check_shift(&pose, EDGE) {
            let _ = s.leaving().count();
            w.apply_shift(&s).unwrap();
        }
        w.insert(&pose, &beams).unwrap();
        w.step(100);
    }
    let r = w.window();
    assert!(r.shifts_refused > 0, "{r:?}");
    assert!(r.beams_clipped > 0 && r.scans_clipped > 0, "{r:?}");
    // Restores outside the window or of the wrong size are refused and counted.
    assert!(w.restore_tile(i32::MAX, 0, EDGE, &[0; 256], None).is_err());
    assert!(w.restore_tile(0, 0, EDGE, &[0; 3], None).is_err());
    assert!(w.window().restore_refused >= 2);
}

#[test]
fn a_margin_without_a_band_is_refused() {
    let cfg = config().with_window_margin_cells(64);
    assert!(Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).is_err());
    let cfg = config().with_window_margin_cells(60);
    let s = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    assert!(!s.window_fits(EDGE), "60 + 16 > 64: no hysteresis band");
    assert!(s.window_fits(4));
    assert!(s.shift_for(&Pose::default(), EDGE).is_none());
}

#[test]
fn restore_parts_are_checked_and_every_refusal_is_counted() {
    let boxes = building();
    // A fixed grid restores nothing.
    let mut fixed = Session::new(config(), Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    let mut asm = TileRestore::new();
    let part = [0u8; 64];
    assert_eq!(
        fixed.restore_part(&mut asm, EDGE, 0, 0, Layer::LogOdds, 0, &part),
        Err(RestoreError::NoWindow)
    );
    assert_eq!(fixed.window().restore_refused, 1);

    let cfg = config().with_window_margin_cells(MARGIN);
    let mut w = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    let refused = std::cell::Cell::new(0);
    let expect = |w: &Session<Owned<u8>>, r: Result<(), RestoreError>, e: RestoreError| {
        assert_eq!(r, Err(e));
        refused.set(refused.get() + 1);
        assert_eq!(w.window().restore_refused, refused.get(), "{e}");
    };
    // Malformed parts: layer, row, length; and a tile outside the window.
    let r = w.restore_part(&mut asm, EDGE, 1, 1, Layer::Sample, 0, &part[..32]);
    expect(&w, r.map(|_| ()), RestoreError::Part(RestoreFault::Layer));
    let r = w.restore_part(&mut asm, EDGE, 1, 1, Layer::LogOdds, 3, &part);
    expect(&w, r.map(|_| ()), RestoreError::Part(RestoreFault::Row));
    let r = w.restore_part(&mut asm, EDGE, 1, 1, Layer::LogOdds, 16, &part);
    expect(&w, r.map(|_| ()), RestoreError::Part(RestoreFault::Row));
    let r = w.restore_part(&mut asm, EDGE, 1, 1, Layer::Counts, 4, &part[..60]);
    expect(&w, r.map(|_| ()), RestoreError::Part(RestoreFault::Length));
    let r = w.restore_part(&mut asm, EDGE, 8, 0, Layer::LogOdds, 0, &part);
    expect(&w, r.map(|_| ()), RestoreError::Outside);
    let r = w.restore_part(&mut asm, EDGE, -1, 0, Layer::LogOdds, 0, &part);
    expect(&w, r.map(|_| ()), RestoreError::Outside);
    assert_eq!(asm.pending(), None, "refused parts keep nothing");

    // An incomplete tile dropped for another is counted; repeats are idempotent.
    let step = w
        .restore_part(&mut asm, EDGE, 1, 1, Layer::LogOdds, 0, &part)
        .unwrap();
    assert_eq!((step.repeat, step.dropped), (false, None));
    let step = w
        .restore_part(&mut asm, EDGE, 1, 1, Layer::LogOdds, 0, &part)
        .unwrap();
    assert!(step.repeat);
    let step = w
        .restore_part(&mut asm, EDGE, 2, 1, Layer::LogOdds, 0, &part)
        .unwrap();
    assert_eq!(step.dropped, Some((1, 1)));
    refused.set(refused.get() + 1);
    assert_eq!(w.window().restore_refused, refused.get());

    // A whole tile where the robot has mapped is refused; an unmapped one is restored.
    let pose = Pose::new(3200, 3200, Angle::ZERO);
    let beams = scan(&boxes, &pose);
    w.insert(&pose, &beams).unwrap();
    let mut lo = vec![0u8; 512];
    lo[0] = 7; // cell (0, 0): log-odds 7
    let est = vec![200u8; 256];
    let (ox, oy) = (w.window().origin_x / 16, w.window().origin_y / 16);
    let r = restore_by_parts(&mut w, &mut asm, ox + 4, oy + 4, &lo, &est);
    refused.set(refused.get() + 1); // its first part dropped the incomplete tile (2, 1)
    expect(&w, r.map(|_| ()), RestoreError::Mapped);
    assert_eq!(
        restore_by_parts(&mut w, &mut asm, ox + 7, oy + 7, &lo, &est),
        Ok(true)
    );
    assert_eq!(w.window().tiles_restored, 1);
    assert_eq!(w.window().restore_refused, refused.get());
    let i = 7 * 16 * usize::from(WIN) + 7 * 16;
    assert_eq!(w.log_odds()[i].raw(), 7);
    // Its parts repeated right after (a host sending every frame twice): ignored.
    let r = restore_by_parts(&mut w, &mut asm, ox + 7, oy + 7, &lo, &est);
    assert_eq!(r, Ok(false));
    assert_eq!(w.window().restore_refused, refused.get());
    // After another tile, a second restore finds it no longer unknown: refused.
    let r = restore_by_parts(&mut w, &mut asm, ox + 6, oy + 7, &lo, &est);
    assert_eq!(r, Ok(true));
    let r = restore_by_parts(&mut w, &mut asm, ox + 7, oy + 7, &lo, &est);
    expect(&w, r.map(|_| ()), RestoreError::Mapped);
    assert_eq!(w.window().tiles_restored, 2);
}

#[test]
fn the_tile_restored_last_is_restored_again_after_it_left_and_came_back() {
    let cfg = config().with_window_margin_cells(MARGIN);
    let mut w = Session::new(cfg, Owned::<u8>::buffers(&Sizes::grid(WIN, WIN))).unwrap();
    let mut asm = TileRestore::new();
    let mut lo = vec![0u8; 512];
    lo[0] = 7;
    let est = vec![200u8; 256];
    assert_eq!(
        restore_by_parts(&mut w, &mut asm, 7, 7, &lo, &est),
        Ok(true)
    );
    // Away east until tile (7, 7) has left the window, then back west.
    let mut moves = 0;
    for x in (0..40)
        .map(|k| 3200 + k * 1000)
        .chain((0..40).rev().map(|k| 3200 + k * 1000))
    {
        if let Some(shift) = w.check_shift(&Pose::new(x, 3200, Angle::ZERO), EDGE) {
            w.apply_shift(&shift).unwrap();
            moves += 1;
        }
    }
    let (ox, oy) = (w.window().origin_x, w.window().origin_y);
    assert!(
        moves >= 2 && w.tile_in_window(7, 7, EDGE),
        "{:?}",
        w.window()
    );
    let i = (7 * 16 - oy) as usize * usize::from(WIN) + (7 * 16 - ox) as usize;
    assert_eq!(w.log_odds()[i].raw(), 0, "it came back unknown");
    // Its parts first again: not a repeat, the tile is restored.
    assert_eq!(
        restore_by_parts(&mut w, &mut asm, 7, 7, &lo, &est),
        Ok(true)
    );
    assert_eq!(w.log_odds()[i].raw(), 7);
    assert_eq!(w.window().tiles_restored, 2);
}
