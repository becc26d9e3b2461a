//! The scan matcher (`ogm_core::localize`, issue 39) on synthetic worlds: it recovers a known
//! offset in a room, says "ambiguous" in a corridor and along a single wall, says it cannot tell
//! when there is nothing to match, agrees with its f64 reference, and never panics.

use ogm_core::localize::reference::{match_scan_f64, point_f64};
use ogm_core::localize::{match_scan, prepare_points, MapView, MatchConfig, ScanPoint, Verdict};
use ogm_core::localize::{MAX_POINT_SUB, SUB};
use ogm_core::map::mapper::marks_len;
use ogm_core::{
    Angle, Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose, Range,
};
use proptest::prelude::*;

mod common;
use common::{pose_of, scan, Seg};

/// A 6 × 4 m room (corner at the origin) with a pillar and a niche, so that no direction and no
/// rotation is left open.
fn room() -> Vec<Seg> {
    vec![
        (0.0, 0.0, 6000.0, 0.0),
        (6000.0, 0.0, 6000.0, 4000.0),
        (6000.0, 4000.0, 2500.0, 4000.0),
        (2500.0, 4000.0, 2500.0, 3400.0),
        (2500.0, 3400.0, 1800.0, 3400.0),
        (1800.0, 3400.0, 1800.0, 4000.0),
        (1800.0, 4000.0, 0.0, 4000.0),
        (0.0, 4000.0, 0.0, 0.0),
        // Pillar.
        (4000.0, 1500.0, 4400.0, 1500.0),
        (4400.0, 1500.0, 4400.0, 1800.0),
        (4400.0, 1800.0, 4000.0, 1800.0),
        (4000.0, 1800.0, 4000.0, 1500.0),
    ]
}

/// A corridor along x, 1.6 m wide, 30 m long.
fn corridor() -> Vec<Seg> {
    vec![(0.0, 0.0, 30_000.0, 0.0), (0.0, 1600.0, 30_000.0, 1600.0)]
}

/// A map of `world` built by the online mapper from scans at `poses` (exact poses).
fn build_map(
    world: &[Seg],
    geometry: GridGeometry,
    poses: &[(f64, f64, f64)],
    max_mm: f64,
) -> Vec<LogOdds> {
    let grid = LogOddsGrid::new(geometry, vec![LogOdds::ZERO; geometry.len()]).unwrap();
    let marks = vec![0u32; marks_len(geometry.len())];
    let mut mapper = Mapper::new(grid, marks, MapperConfig::new(max_mm as u32)).unwrap();
    for &p in poses {
        mapper
            .insert_scan(&pose_of(p), &scan(world, p, 720, max_mm))
            .unwrap();
    }
    mapper.grid().cells().to_vec()
}

fn room_map() -> (GridGeometry, Vec<LogOdds>) {
    let g = GridGeometry::new(140, 100, 50, -525, -525).unwrap();
    let poses = [
        (1500.0, 1200.0, 0.0),
        (3000.0, 2500.0, 1.0),
        (5000.0, 1000.0, 2.0),
        (1000.0, 3000.0, -1.0),
        (5200.0, 3200.0, 0.5),
    ];
    let cells = build_map(&room(), g, &poses, 10_000.0);
    (g, cells)
}

/// The defaults with a prediction trusted little: the tests' offsets (5–10 cm, 2°) are far
/// larger than the one-step odometry error the defaults' prior assumes.
fn loose() -> MatchConfig {
    MatchConfig {
        prior_trans_q8: 4,
        prior_rot: 1,
        ..MatchConfig::default()
    }
}

fn points(beams: &[Beam], g: &GridGeometry, cfg: &MatchConfig) -> Vec<ScanPoint> {
    let mut buf = vec![ScanPoint::default(); 512];
    let st = prepare_points(beams, g.cell_mm(), cfg, &mut buf);
    buf.truncate(st.kept);
    buf
}

fn err(pose: &Pose, truth: (f64, f64, f64)) -> (f64, f64) {
    let d = (f64::from(pose.x_mm) - truth.0).hypot(f64::from(pose.y_mm) - truth.1);
    let a = f64::from(pose.heading.signed_diff(Angle::from_radians(truth.2))) / 65536.0 * 360.0;
    (d, a.abs())
}

#[test]
fn recovers_a_known_offset_in_a_room() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let cfg = loose();
    let truth = (3300.0, 1900.0, 0.7);
    let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
    for (ox, oy, oth) in [
        (60.0, -40.0, 2.0f64),
        (-80.0, 30.0, -1.5),
        (0.0, 90.0, 0.0),
        (40.0, 40.0, 3.0),
    ] {
        let predicted = pose_of((truth.0 + ox, truth.1 + oy, truth.2 + oth.to_radians()));
        let r = match_scan(&map, &pts, &predicted, &cfg);
        let (d, a) = err(&r.pose, truth);
        assert_eq!(r.verdict, Verdict::Trusted, "{r:?}");
        assert!(
            d < 5.0 && a < 0.1,
            "offset ({ox}, {oy}, {oth}°): error {d:.1} mm {a:.2}° {r:?}"
        );
        assert_eq!(r.accepted(), r.pose);
        assert!(u64::from(r.work.reads) <= cfg.max_reads(pts.len()));
    }
}

/// A heading error of 8–9.5° (a cheap robot's turn) without the pyramid: far points are out of
/// every window's reach and Gauss–Newton alone stops degrees short (or cannot tell); the heading
/// search ([`MatchConfig::turn_search`]) starts it in the right basin.
#[test]
fn heading_search_recovers_a_large_turn_error() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let truth = (3300.0, 1900.0, 0.7);
    let searched = MatchConfig {
        levels: 0,
        ..loose()
    };
    assert!(searched.turn_search > 0 && searched.max_turn.0 >= Angle::from_degrees(9.5).0);
    let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &searched);
    for oth in [8.0f64, -8.0, 9.5, -9.5] {
        let predicted = pose_of((truth.0 + 20.0, truth.1 - 15.0, truth.2 + oth.to_radians()));
        let with = match_scan(&map, &pts, &predicted, &searched);
        let without = match_scan(
            &map,
            &pts,
            &predicted,
            &MatchConfig {
                turn_search: 0,
                ..searched
            },
        );
        let (dw, aw) = err(&with.pose, truth);
        let (_, ao) = err(&without.pose, truth);
        assert_eq!(with.verdict, Verdict::Trusted, "{oth}°: {with:?}");
        assert!(dw < 5.0 && aw < 0.1, "{oth}°: {dw:.1} mm {aw:.2}° {with:?}");
        assert!(
            ao > 2.0 || !without.verdict.is_trusted(),
            "{oth}°: without the search {ao:.2}° {without:?}"
        );
        let budget = searched.max_reads(pts.len());
        assert!(u64::from(with.work.reads) <= budget, "{with:?} > {budget}");
    }
}

/// The budget is a hard cap on the search and the passes (reads ≤ budget + probes), and a match
/// it cuts short still ends on the grid's level, still recovering the offset.
#[test]
fn budget_caps_work_and_keeps_the_final_level() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let truth = (3300.0, 1900.0, 0.7);
    let full = MatchConfig {
        levels: 2,
        ..loose()
    };
    let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &full);
    let n = pts.len();
    let predicted = pose_of((truth.0 + 60.0, truth.1 - 40.0, truth.2 + 2f64.to_radians()));
    let probes = MatchConfig::probe_reads(n);
    let one_fine = full.pass_reads(0, n);
    for budget in [0u32, 1_000, one_fine as u32, 30_000, 50_000] {
        let cfg = MatchConfig {
            budget_reads: budget,
            ..full
        };
        let r = match_scan(&map, &pts, &predicted, &cfg);
        assert!(
            u64::from(r.work.reads) <= cfg.max_reads(n),
            "{budget}: {r:?}"
        );
        if budget > 0 {
            assert!(
                u64::from(r.work.reads) <= u64::from(budget) + probes,
                "{budget}: {r:?}"
            );
        }
        if budget == 0 || u64::from(budget) >= cfg.search_reads(n) + one_fine {
            assert_eq!(r.work.finest_level, 0, "{budget}: {r:?}");
            // From 72 mm / 2° off: a short budget leaves a coarser match, still mostly corrected.
            let (d, a) = err(&r.pose, truth);
            let (dl, al) = if budget == 0 {
                (5.0, 0.1)
            } else if budget >= 50_000 {
                (10.0, 0.1)
            } else {
                (30.0, 0.5)
            };
            assert!(d < dl && a < al, "{budget}: {d:.1} mm {a:.2}° {r:?}");
        }
    }
}

#[test]
fn corridor_is_ambiguous_along_its_axis() {
    let g = GridGeometry::new(600, 60, 50, -25, -625).unwrap();
    let world = corridor();
    let poses: Vec<_> = (0..12)
        .map(|i| (2000.0 + 2000.0 * f64::from(i), 800.0, 0.0))
        .collect();
    let cells = build_map(&world, g, &poses, 6000.0);
    let map = MapView::new(&cells, g).unwrap();
    let cfg = MatchConfig {
        max_range_mm: 6000,
        ..loose()
    };
    let truth = (15_000.0, 700.0, 0.2);
    let pts = points(&scan(&world, truth, 450, 6000.0), &g, &cfg);
    let predicted = pose_of((truth.0 + 120.0, truth.1 + 50.0, truth.2 + 0.02));
    let r = match_scan(&map, &pts, &predicted, &cfg);
    let Verdict::Ambiguous { weak_axis } = r.verdict else {
        panic!("{r:?}");
    };
    // An axis: along x means near 0 or a half turn.
    let off = weak_axis
        .signed_diff(Angle::ZERO)
        .unsigned_abs()
        .min(weak_axis.signed_diff(Angle::HALF).unsigned_abs());
    assert!(off < 1000, "weak axis {weak_axis:?}");
    // Across the corridor the match is good; along it the prior keeps the prediction.
    assert!((f64::from(r.pose.y_mm) - truth.1).abs() < 15.0, "{r:?}");
    assert!(
        (f64::from(r.pose.x_mm) - (truth.0 + 120.0)).abs() < 40.0,
        "{r:?}"
    );
    assert_eq!(r.accepted(), r.pose);
}

#[test]
fn single_wall_is_ambiguous() {
    let g = GridGeometry::new(200, 100, 50, -5025, -1025).unwrap();
    let world = vec![(-5000.0, 0.0, 5000.0, 0.0)];
    let cells = build_map(
        &world,
        g,
        &[(0.0, 1500.0, 0.0), (-2000.0, 1500.0, 0.0)],
        5000.0,
    );
    let map = MapView::new(&cells, g).unwrap();
    let cfg = MatchConfig {
        max_range_mm: 5000,
        ..loose()
    };
    let truth = (-1000.0, 1500.0, 0.3);
    let pts = points(&scan(&world, truth, 450, 5000.0), &g, &cfg);
    let r = match_scan(
        &map,
        &pts,
        &pose_of((truth.0 + 50.0, truth.1, truth.2)),
        &cfg,
    );
    assert!(matches!(r.verdict, Verdict::Ambiguous { .. }), "{r:?}");
}

#[test]
fn nothing_to_match_is_not_trusted() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let cfg = MatchConfig::default();
    let p = pose_of((3000.0, 2000.0, 0.0));
    // A lidar that sees nothing.
    let r = match_scan(&map, &[], &p, &cfg);
    assert_eq!(r.verdict, Verdict::TooFewPoints);
    assert_eq!(r.accepted(), p);
    let blind: Vec<Beam> = (0..450)
        .map(|i| Beam {
            angle: Angle((i * 145) as u16),
            range: Range::NoReturn,
        })
        .collect();
    let pts = points(&blind, &g, &cfg);
    assert_eq!(
        match_scan(&map, &pts, &p, &cfg).verdict,
        Verdict::TooFewPoints
    );
    // A scan of somewhere else: the room's scan placed 40 m away.
    let pts = points(
        &scan(&room(), (3000.0, 2000.0, 0.0), 450, 10_000.0),
        &g,
        &cfg,
    );
    let far = pose_of((43_000.0, 2000.0, 0.0));
    let r = match_scan(&map, &pts, &far, &cfg);
    assert_eq!(r.verdict, Verdict::NoOverlap, "{r:?}");
    assert_eq!(r.accepted(), far);
    // An empty map (a new area).
    let empty = vec![LogOdds::ZERO; g.len()];
    let r = match_scan(&MapView::new(&empty, g).unwrap(), &pts, &p, &cfg);
    assert_eq!(r.verdict, Verdict::NoOverlap, "{r:?}");
}

/// A new map: one scan, every cell below half occupied (one noisy scan's walls are). The match
/// against it is what keeps the turn error of a map's first steps out of the map, so it is not
/// "no overlap" (it was, while the verdict asked for a point on a cell above ½).
#[test]
fn a_new_maps_weak_walls_are_matched() {
    let g = GridGeometry::new(140, 100, 50, -525, -525).unwrap();
    let first = (3000.0, 2000.0, 0.0);
    let mut cells = build_map(&room(), g, &[first], 10_000.0);
    let cfg = loose();
    // Every occupied cell below half of the ramp, as in a one-scan face-band map.
    let weak = LogOdds(cfg.occupied.0 / 2 - 100);
    for c in cells.iter_mut().filter(|c| c.0 > weak.0) {
        *c = weak;
    }
    assert!(cells.iter().any(|c| c.0 > cfg.floor.0));
    let map = MapView::new(&cells, g).unwrap();
    let truth = (3040.0, 2010.0, 0.05);
    let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
    let predicted = pose_of((truth.0 + 40.0, truth.1 - 30.0, truth.2 + 2f64.to_radians()));
    let r = match_scan(&map, &pts, &predicted, &cfg);
    assert_eq!(r.quality.matched, 0, "no point on a cell above ½: {r:?}");
    assert!(r.verdict.is_usable(), "{r:?}");
    let (d0, a0) = err(&predicted, truth);
    let (d, a) = err(&r.pose, truth);
    assert!(
        d < d0 / 2.0 && a < a0 / 4.0,
        "{d:.1} mm {a:.2}° from {d0:.1} mm {a0:.2}°: {r:?}"
    );
}

#[test]
fn odometry_jump_is_not_trusted() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let truth = (3300.0, 1900.0, 0.7);
    for cfg in [MatchConfig::default(), loose()] {
        let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
        for (ox, oy, oth) in [
            (800.0, 0.0, 0.0),
            (0.0, -700.0, 10.0f64),
            (300.0, 300.0, 25.0),
        ] {
            let predicted = pose_of((truth.0 + ox, truth.1 + oy, truth.2 + oth.to_radians()));
            let r = match_scan(&map, &pts, &predicted, &cfg);
            assert!(!r.verdict.is_trusted(), "jump ({ox}, {oy}, {oth}°): {r:?}");
            // Mapping goes on at the prediction or nearer the truth: the match never drags the
            // pose away (with the default prior it stays within a few centimetres; a loose one
            // lets the pillar pull it partly back).
            let a = r.accepted();
            let (before, _) = err(&predicted, truth);
            let (after, _) = err(&a, truth);
            assert!(after <= before + 5.0, "jump ({ox}, {oy}, {oth}°): {r:?}");
            if cfg == MatchConfig::default() {
                let moved =
                    f64::from(a.x_mm - predicted.x_mm).hypot(f64::from(a.y_mm - predicted.y_mm));
                assert!(
                    moved < 60.0,
                    "jump ({ox}, {oy}, {oth}°): moved {moved:.0} mm {r:?}"
                );
            }
            assert!(r.quality.contradicted > 150, "{r:?}");
        }
    }
}

#[test]
fn fixed_point_agrees_with_f64_reference() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    for (levels, budget) in [(2u8, 0u32), (0, 0), (3, 0), (2, 20_000)] {
        let cfg = MatchConfig {
            levels,
            budget_reads: budget,
            ..loose()
        };
        for (k, truth) in [
            (1200.0, 1000.0, 0.1),
            (3300.0, 1900.0, 0.7),
            (5000.0, 3000.0, 2.5),
        ]
        .into_iter()
        .enumerate()
        {
            let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
            let s = k as f64;
            let predicted = pose_of((
                truth.0 + 50.0 - 30.0 * s,
                truth.1 - 40.0 + 20.0 * s,
                truth.2 + 0.02,
            ));
            let fx = match_scan(&map, &pts, &predicted, &cfg);
            let rf = match_scan_f64(&map, &pts, &predicted, &cfg);
            let d = (f64::from(fx.pose.x_mm) - rf.x_mm).hypot(f64::from(fx.pose.y_mm) - rf.y_mm);
            let a = f64::from(
                fx.pose
                    .heading
                    .signed_diff(Angle::from_radians(rf.heading_rad)),
            ) / 65536.0
                * 360.0;
            assert!(
                d < 3.0 && a.abs() < 0.05,
                "levels {levels}: {d:.2} mm {a:.3}°\n{fx:?}\n{rf:?}"
            );
            assert_eq!(fx.verdict, rf.verdict, "{fx:?}\n{rf:?}");
            // A rounding can end a level one step earlier or later.
            assert!(fx.work.passes.abs_diff(rf.passes) <= 1, "{fx:?}\n{rf:?}");
            let q = &fx.quality;
            let score = f64::from(q.score) / 32768.0;
            assert!(
                // A millimetre moves a point or two across a cell boundary.
                (score - rf.quality.score).abs() < 0.5 + 0.02 * pts.len() as f64,
                "{score} {:?}",
                rf.quality
            );
            assert!(
                (f64::from(q.drop_weak) / 1000.0 - rf.quality.drop_weak).abs() < 0.02,
                "{q:?} {:?}",
                rf.quality
            );
            assert!(
                (f64::from(q.drop_turn) / 1000.0 - rf.quality.drop_turn).abs() < 0.02,
                "{q:?} {:?}",
                rf.quality
            );
        }
    }
}

#[test]
fn points_match_f64_polar() {
    let cfg = MatchConfig::default();
    let beams: Vec<Beam> = (0..720u32)
        .map(|i| Beam {
            angle: Angle((i * 91) as u16),
            range: Range::Hit(100 + i * 27),
        })
        .collect();
    for cell_mm in [10u32, 50, 73] {
        let cfg = MatchConfig {
            min_spacing_mm: 0,
            ..cfg
        };
        let mut buf = vec![ScanPoint::default(); 1024];
        let st = prepare_points(&beams, cell_mm, &cfg, &mut buf);
        let want: Vec<_> = beams
            .iter()
            .filter_map(|b| point_f64(b, cell_mm, &cfg))
            .collect();
        assert_eq!(st.kept, want.len());
        for (p, (x, y)) in buf.iter().zip(want) {
            assert!((f64::from(p.x) / f64::from(SUB) - x).abs() < 1.0 / 128.0);
            assert!((f64::from(p.y) / f64::from(SUB) - y).abs() < 1.0 / 128.0);
        }
    }
    // A small buffer is filled evenly over the scan, not with its first beams.
    let mut small = vec![ScanPoint::default(); 100];
    let st = prepare_points(
        &beams,
        50,
        &MatchConfig {
            min_spacing_mm: 0,
            ..cfg
        },
        &mut small,
    );
    assert_eq!(st.kept, 100);
    // Ranges grow with the beam index: the last point kept comes from the scan's last beams.
    let reach = f64::from(small[99].x).hypot(f64::from(small[99].y)) / f64::from(SUB);
    assert!(reach * 50.0 > 19_000.0, "{:?}", small[99]);
}

fn any_pose() -> impl Strategy<Value = Pose> {
    let c = prop_oneof![3 => -20_000i32..20_000, 1 => any::<i32>(), 1 => Just(i32::MIN), 1 => Just(i32::MAX)];
    (c.clone(), c, any::<u16>()).prop_map(|(x, y, a)| Pose::new(x, y, Angle(a)))
}

fn any_beams() -> impl Strategy<Value = Vec<Beam>> {
    let range = prop_oneof![
        4 => (0u32..30_000).prop_map(Range::Hit),
        1 => any::<u32>().prop_map(Range::Hit),
        1 => Just(Range::NoReturn),
    ];
    prop::collection::vec(
        (any::<u16>(), range).prop_map(|(a, range)| Beam {
            angle: Angle(a),
            range,
        }),
        0..600,
    )
}

fn any_config() -> impl Strategy<Value = MatchConfig> {
    (
        (
            0u32..500,
            prop_oneof![1u32..40_000, Just(u32::MAX)],
            0u32..200,
        ),
        (
            any::<i16>(),
            any::<i16>(),
            0u8..6,
            0u8..8,
            any::<u16>(),
            0u8..5,
            any::<u16>(),
            any::<u16>(),
            any::<u16>(),
        ),
        (
            any::<u32>(),
            any::<u16>(),
            prop_oneof![0u32..500, Just(u32::MAX)],
        ),
        (0u16..100, any::<u16>(), 0u32..200_000),
    )
        .prop_map(
            |((lo, hi, sp), (f, o, lv, it, pr, ra, rg, ca, prr), (sh, tu, pb), (mp, ov, bu))| {
                MatchConfig {
                    min_range_mm: lo,
                    max_range_mm: hi,
                    min_spacing_mm: sp,
                    floor: LogOdds(f),
                    occupied: LogOdds(o),
                    levels: lv,
                    iterations: it,
                    prior_trans_q8: pr,
                    prior_rot: prr,
                    radius: ra,
                    coarse_radius: ra.wrapping_add(3) % 5,
                    coarse_thin: ra.wrapping_mul(3) % 7,
                    reg_q8: rg,
                    cauchy_q8: ca,
                    max_shift_mm: sh,
                    max_turn: Angle(tu),
                    probe_mm: pb,
                    min_points: mp,
                    min_overlap_permille: ov,
                    budget_reads: bu,
                    ..MatchConfig::default()
                }
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Any pose, beams, geometry, cells and settings: no panic, the bound holds, and an
    /// untrusted match hands back the prediction.
    #[test]
    fn never_panics(
        pose in any_pose(),
        beams in any_beams(),
        (w, h) in (1u16..40, 1u16..40),
        cell in prop_oneof![1u32..200, Just(1u32), Just(u32::MAX)],
        (ox, oy) in (prop_oneof![-5_000i32..5_000, any::<i32>()], prop_oneof![-5_000i32..5_000, any::<i32>()]),
        seed in any::<u64>(),
        cfg in any_config(),
        buf_len in 0usize..600,
    ) {
        let g = GridGeometry::new(w, h, cell, ox, oy).unwrap();
        let mut x = seed | 1;
        let cells: Vec<LogOdds> = (0..g.len())
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                LogOdds((x >> 48) as i16)
            })
            .collect();
        let map = MapView::new(&cells, g).unwrap();
        let mut buf = vec![ScanPoint::default(); buf_len];
        let st = prepare_points(&beams, cell, &cfg, &mut buf);
        prop_assert!(st.kept <= buf_len);
        for p in &buf[..st.kept] {
            prop_assert!(i64::from(p.x).abs() < MAX_POINT_SUB && i64::from(p.y).abs() < MAX_POINT_SUB);
        }
        let r = match_scan(&map, &buf[..st.kept], &pose, &cfg);
        prop_assert!(u64::from(r.work.reads) <= cfg.max_reads(st.kept));
        if !r.verdict.is_usable() {
            prop_assert_eq!(r.accepted(), pose);
        }
        let _ = match_scan_f64(&map, &buf[..st.kept], &pose, &cfg);
    }
}

#[test]
#[ignore]
fn print_room_precision() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    for (levels, radius) in [(0u8, 1u8), (0, 2), (1, 2), (2, 2), (1, 3)] {
        let cfg = MatchConfig {
            levels,
            radius,
            prior_trans_q8: 4,
            prior_rot: 1,
            ..MatchConfig::default()
        };
        let mut worst = (0.0f64, 0.0f64);
        for truth in [
            (1200.0, 1000.0, 0.1),
            (3300.0, 1900.0, 0.7),
            (5000.0, 3000.0, 2.5),
            (2000.0, 2500.0, -2.0),
        ] {
            let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
            for (ox, oy, oth) in [
                (0.0, 0.0, 0.0f64),
                (30.0, -20.0, 0.5),
                (-60.0, 40.0, -1.0),
                (10.0, 10.0, 2.0),
            ] {
                let predicted = pose_of((truth.0 + ox, truth.1 + oy, truth.2 + oth.to_radians()));
                let r = match_scan(&map, &pts, &predicted, &cfg);
                let (d, a) = err(&r.pose, truth);
                if levels == 1 && radius == 2 {
                    println!(
                        "  {truth:?} + ({ox}, {oy}, {oth}°): {d:.1} mm {a:.3}° passes {} {:?}",
                        r.work.passes, r.verdict
                    );
                }
                worst = (worst.0.max(d), worst.1.max(a));
            }
        }
        println!(
            "levels {levels} radius {radius}: worst {:.1} mm {:.3}°",
            worst.0, worst.1
        );
    }
}

#[test]
fn seen_through_map_contradicts() {
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let truth = (3300.0, 1900.0, 0.7);
    let cfg = MatchConfig {
        max_contradicted_permille: 250,
        ..MatchConfig::default()
    };
    let pts = points(&scan(&room(), truth, 450, 10_000.0), &g, &cfg);
    // Shifted along the room's long axis: the side walls still fit, the end walls land in the
    // room, where the map has seen free space behind them.
    let predicted = pose_of((truth.0 + 800.0, truth.1, truth.2));
    let r = match_scan(&map, &pts, &predicted, &cfg);
    assert_eq!(r.verdict, Verdict::Contradicted, "{r:?}");
    assert_eq!(r.accepted(), predicted);
    // At the truth, almost nothing is contradicted.
    let r = match_scan(&map, &pts, &pose_of(truth), &cfg);
    assert!(r.quality.contradicted < 20, "{r:?}");
    assert_eq!(r.verdict, Verdict::Trusted, "{r:?}");
}

/// The Session-facing API on bad input: a lidar that sees nothing, an odometry jump, and a
/// corridor's open direction. Each time the tracker says it cannot tell (or which part it cannot
/// tell) and maps on the odometry prediction; a good scan afterwards is corrected again.
#[test]
fn tracker_keeps_odometry_when_it_cannot_tell() {
    use ogm_core::localize::Tracker;
    let (g, cells) = room_map();
    let map = MapView::new(&cells, g).unwrap();
    let mut t: Tracker<512> = Tracker::new(MatchConfig::default());
    let truth = (3300.0, 1900.0, 0.7);
    // First scan: odometry's frame is the map's; the match confirms it.
    let first = t.update(&map, &pose_of(truth), &scan(&room(), truth, 450, 10_000.0));
    assert!(first.verdict().unwrap().is_usable(), "{first:?}");
    let (d, _) = err(&first.pose, truth);
    assert!(d < 10.0, "{first:?}");
    // A lidar that sees nothing: the prediction, TooFewPoints.
    let odo = pose_of((truth.0 + 100.0, truth.1, truth.2));
    let blind: Vec<Beam> = (0..450)
        .map(|i| Beam {
            angle: Angle::from_centidegrees(i * 80),
            range: Range::NoReturn,
        })
        .collect();
    let c = t.update(&map, &odo, &blind);
    assert_eq!(c.verdict(), Some(Verdict::TooFewPoints));
    assert_eq!(c.pose, c.predicted);
    // Odometry jumps 0.8 m along x: not trusted, and the pose stays at the prediction (at this
    // offset the room's x walls are out of the windows' reach, so x is reported open — Ambiguous
    // — and the prior holds it where odometry put it: mapping goes on on odometry).
    let jumped = pose_of((truth.0 + 900.0, truth.1, truth.2));
    let c = t.update(&map, &jumped, &scan(&room(), truth, 450, 10_000.0));
    assert!(!c.verdict().unwrap().is_trusted(), "{c:?}");
    let moved =
        f64::from(c.pose.x_mm - c.predicted.x_mm).hypot(f64::from(c.pose.y_mm - c.predicted.y_mm));
    assert!(moved < 60.0, "{c:?}");
    // Matching off: the correction is still applied, nothing matched.
    t.set_matching(false);
    let c = t.update(&map, &jumped, &scan(&room(), truth, 450, 10_000.0));
    assert_eq!(c.matched, None);
    assert_eq!(c.pose, t.correct(&jumped));
    // Reset: the next pose is odometry's, and a good scan there matches.
    t.set_matching(true);
    t.reset();
    let near = (truth.0 + 40.0, truth.1 - 30.0, truth.2 + 0.02);
    let c = t.update(&map, &pose_of(near), &scan(&room(), truth, 450, 10_000.0));
    assert_eq!(c.predicted, pose_of(near));
    let (before, _) = err(&c.predicted, truth);
    let (after, _) = err(&c.pose, truth);
    assert!(c.verdict().unwrap().is_usable() && after < before, "{c:?}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    /// The tracker over several scans of anything never panics and keeps its work bound.
    #[test]
    fn tracker_never_panics(
        scans in proptest::collection::vec((any_pose(), any_beams(), any::<bool>()), 1..5),
        cfg in any_config(),
        seed in any::<u64>(),
    ) {
        use ogm_core::localize::Tracker;
        let g = GridGeometry::new(40, 40, 50, -1000, -1000).unwrap();
        let mut x = seed | 1;
        let cells: Vec<LogOdds> = (0..g.len())
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                LogOdds((x >> 48) as i16)
            })
            .collect();
        let map = MapView::new(&cells, g).unwrap();
        let mut t: Tracker<128> = Tracker::new(cfg);
        for (odo, beams, on) in &scans {
            t.set_matching(*on);
            let c = t.update(&map, odo, beams);
            if let Some(m) = c.matched {
                prop_assert!(u64::from(m.work.reads) <= cfg.max_reads(128));
                if !m.verdict.is_usable() {
                    prop_assert_eq!(c.pose, c.predicted);
                }
            }
        }
    }
}
