//! The host assembles the building from a rolling window's stream (issue 38): the firmware's own
//! application (`ogm_firmware::App`, as the host replay runs it; no QEMU) maps a building larger
//! than its 12.8 m window, and `export --stream`'s map ([`BuildingMap`]) must equal an
//! unbounded host map of the same scans cell for cell. With the window off, the export must be
//! byte for byte what the fixed grid gave before the building map (the tiles applied in order
//! to a [`StreamedMap`]).

use host_sim::firmware::input::{beams_as_read, encode_run};
use host_sim::firmware::HostMemory;
use host_sim::sim::boxes;
use host_sim::sim::explore::ScanRecord;
use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::Layer;
use ogm_core::Beam;
use ogm_field::export::{export_world, world_from_stream};
use ogm_field::stream::{
    counts_of_one, stream_probabilities, BuildingMap, DeviceEvent, MapLayer, StreamDecoder,
    StreamedMap,
};
use ogm_field::world::probabilities_to_world;
use ogm_firmware::sizes::MPS2_AN386 as FW;
use ogm_firmware::{Fed, Platform, Work};

const CELL: i32 = 50;
const MAX_RANGE: u32 = 3000;
const MARGIN: u16 = 72;

/// Scans every `step` m through a 30 m × 22 m building of seeded pillars.
fn scans(waypoints: &[(f64, f64)], step: f64) -> Vec<ScanRecord> {
    boxes::scans(
        &boxes::building(22_000.0, 40, false),
        waypoints,
        step,
        MAX_RANGE,
    )
}

/// The host as the application's platform: no clock, a few sampler updates per step.
struct Host;

impl Platform for Host {
    const NAME: &'static str = "window stitch test";
    const TICK_HZ: u32 = 1_000_000_000;

    fn now(&self) -> u32 {
        0
    }

    fn fixed_updates(&mut self, _work: Work) -> Option<u32> {
        Some(20)
    }
}

/// What the firmware's application streams for `scans` under `config` (its `Hello` first).
fn robot_stream(config: &RunConfig, scans: &[ScanRecord]) -> Vec<u8> {
    let input = encode_run(config, scans, false).expect("input");
    let mut memory = HostMemory::<u8>::new();
    let mut app = memory.app(&Sizes::grid(FW.width, FW.height));
    let mut host = Host;
    let mut out = Vec::new();
    app.hello(&mut out, &host);
    for b in &input.bytes {
        if let Fed::Finished(code) = app.feed(std::slice::from_ref(b), &mut out, &mut host) {
            assert_eq!(code, 0, "exit code");
            break;
        }
    }
    out
}

/// The beams as the firmware reads them: through the LD06 packets.
fn as_read(s: &ScanRecord, ts: &mut u16) -> Vec<Beam> {
    beams_as_read(&s.beams, ts).unwrap()
}

fn decode(stream: &[u8]) -> Vec<DeviceEvent> {
    let mut d = StreamDecoder::new();
    let events: Vec<_> = d.push(stream).into_iter().map(|e| e.unwrap()).collect();
    assert_eq!(d.stats().bad_frames, 0);
    events
}

#[test]
fn a_windowed_stream_stitches_to_the_unbounded_map() {
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_window_margin_cells(MARGIN)
        .with_budget(Budget::Fixed { updates: 20 });
    // East across the building, then north: beyond the first window on both axes.
    let scans = scans(&[(6.4, 6.4), (26.0, 6.8), (26.5, 17.5)], 0.3);
    let stream = robot_stream(&config, &scans);
    let events = decode(&stream);
    let last = events
        .iter()
        .rev()
        .find_map(|e| match e {
            DeviceEvent::Window(w) => Some(*w),
            _ => None,
        })
        .expect("Window reports");
    assert!(last.shifts >= 3, "{last:?}");
    assert_eq!((last.beams_clipped, last.shifts_refused), (0, 0));

    // The stitched building.
    let hello = events
        .iter()
        .find_map(|e| match e {
            DeviceEvent::Hello(h) => Some(h.clone()),
            _ => None,
        })
        .unwrap();
    let mut b = BuildingMap::new(
        usize::from(hello.width),
        usize::from(hello.height),
        usize::from(hello.tile_edge),
    );
    for e in &events {
        if let DeviceEvent::Tile(t) = e {
            b.apply(t).expect("every tile fits");
        }
    }
    let r = b.render();
    assert!(r.map.width > 256 + 128 && r.map.height > 256, "{r:?}");

    // The unbounded map: one host session over the whole building.
    let (x0, y0, w, h) = (-64i32, -64i32, 768u16, 576u16);
    let mut host = Session::new(
        config
            .with_window_margin_cells(0)
            .with_origin_mm(x0 * CELL, y0 * CELL),
        Owned::<u8>::buffers(&Sizes::grid(w, h)),
    )
    .unwrap();
    let mut ts = 0u16;
    for s in &scans {
        host.insert(&s.pose, &as_read(s, &mut ts)).unwrap();
    }
    let unbounded = |bx: i64, by: i64| -> i16 {
        let (cx, cy) = (bx - i64::from(x0), by - i64::from(y0));
        if cx < 0 || cy < 0 || cx >= i64::from(w) || cy >= i64::from(h) {
            return 0;
        }
        host.log_odds()[(cy * i64::from(w) + cx) as usize].0
    };
    let (mut differ, mut known) = (0usize, 0usize);
    for (i, &l) in r.map.log_odds.iter().enumerate() {
        let bx = r.x0 + (i % r.map.width) as i64;
        let by = r.y0 + (i / r.map.width) as i64;
        known += usize::from(l != 0);
        differ += usize::from(l != unbounded(bx, by));
    }
    // Nothing known outside the stitched map either.
    let (rx1, ry1) = (r.x0 + r.map.width as i64, r.y0 + r.map.height as i64);
    let outside = host
        .log_odds()
        .iter()
        .enumerate()
        .filter(|&(i, l)| {
            let bx = i64::from(x0) + (i % usize::from(w)) as i64;
            let by = i64::from(y0) + (i / usize::from(w)) as i64;
            l.0 != 0 && !(r.x0..rx1).contains(&bx) | !(r.y0..ry1).contains(&by)
        })
        .count();
    assert!(known > 30_000, "mapped cells: {known}");
    assert_eq!((differ, outside), (0, 0), "stitched vs unbounded");

    // `export --stream` writes that building, at its place in the world.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stream.bin");
    std::fs::write(&path, &stream).unwrap();
    let world = world_from_stream(&path, "log-odds", 0.65, 0.196, || unreachable!()).unwrap();
    assert_eq!((world.width, world.height), (r.map.width, r.map.height));
    let cell_m = f64::from(CELL) / 1000.0;
    let origin = (
        f64::from(config.origin_x_mm) / 1000.0 + r.x0 as f64 * cell_m,
        f64::from(config.origin_y_mm) / 1000.0 + r.y0 as f64 * cell_m,
    );
    assert!(
        (world.origin_m.0 - origin.0).abs() < 1e-9,
        "{:?}",
        world.origin_m
    );
    assert!(
        (world.origin_m.1 - origin.1).abs() < 1e-9,
        "{:?}",
        world.origin_m
    );
    let probs: Vec<f64> = r
        .map
        .log_odds
        .iter()
        .map(|&l| {
            if l == 0 {
                0.5
            } else {
                ogm_core::LogOdds(l).probability()
            }
        })
        .collect();
    let want = probabilities_to_world(
        &probs,
        r.map.width,
        r.map.height,
        cell_m,
        origin,
        0.65,
        0.196,
    );
    assert_eq!(world.cells, want.cells);

    // `listen` sees the same building, in any chunking, and saves it.
    let mut l = ogm_field::listen::Listener::new();
    for c in stream.chunks(777) {
        l.push(c);
    }
    let lw = l.world(MapLayer::LogOdds).expect("a map");
    assert_eq!((lw.width, lw.height), (world.width, world.height));
    assert_eq!(lw.cells, world.cells);
    assert!((lw.origin_m.0 - origin.0).abs() < 1e-9 && (lw.origin_m.1 - origin.1).abs() < 1e-9);
    assert_eq!(l.stats().window, Some(last));
    assert_eq!(l.stats().bad_tiles, 0);
}

#[test]
fn a_fixed_grid_stream_exports_byte_for_byte_as_before() {
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_budget(Budget::Fixed { updates: 20 });
    // Inside the first 12.8 m grid (window off: tiles outside it are never streamed).
    let scans = scans(&[(3.0, 3.0), (9.0, 4.0), (9.5, 9.0)], 0.4);
    let stream = robot_stream(&config, &scans);
    let events = decode(&stream);
    assert!(!events.iter().any(|e| matches!(e, DeviceEvent::Window(_))));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stream.bin");
    std::fs::write(&path, &stream).unwrap();

    // Before the building map: the Hello's grid, every tile applied in order.
    let hello = events
        .iter()
        .find_map(|e| match e {
            DeviceEvent::Hello(h) => Some(h.clone()),
            _ => None,
        })
        .unwrap();
    let (w, h) = (usize::from(hello.width), usize::from(hello.height));
    let e = usize::from(hello.tile_edge);
    let mut old = StreamedMap::new(w, h, e);
    let mut have_counts = vec![false; w * h];
    let mut samples = 0;
    for ev in &events {
        match ev {
            DeviceEvent::Sampler(s) => samples = s.samples,
            DeviceEvent::Tile(t) => {
                let rect = old.apply(t).expect("a tile of the grid");
                if t.layer == Layer::Counts {
                    for c in rect.cells() {
                        have_counts[c] = true;
                    }
                }
            }
            _ => {}
        }
    }
    assert!(have_counts.iter().any(|&c| c));
    for (name, layer) in [
        ("marginals", MapLayer::Marginals),
        ("log-odds", MapLayer::LogOdds),
    ] {
        let one = counts_of_one(Some(&config), Some(&hello), samples);
        let probs = stream_probabilities(&old, &have_counts, one, layer);
        let origin = (
            f64::from(config.origin_x_mm) / 1000.0,
            f64::from(config.origin_y_mm) / 1000.0,
        );
        let before = probabilities_to_world(&probs, w, h, 0.05, origin, 0.65, 0.196);
        let now = world_from_stream(&path, name, 0.65, 0.196, || unreachable!()).unwrap();
        assert_eq!(now, before, "{name}");
        let written = |tag: &str, world| {
            let d = dir.path().join(format!("{tag}-{name}"));
            let files = export_world(&d.join("map.yaml"), world).unwrap();
            files
                .iter()
                .map(|f| std::fs::read(f).unwrap())
                .collect::<Vec<_>>()
        };
        assert_eq!(written("before", &before), written("now", &now), "{name}");
    }
}
