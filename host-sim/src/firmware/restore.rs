//! Tests of the stored tiles sent back to the robot (`HostMsg::Restore`, issue 38) through the
//! firmware's own application on the host: a host online, as `listen` would be, keeps the
//! newest tile of every building tile, and sends a region's tiles back as soon as a `Window`
//! announces that they entered.

use std::collections::HashMap;

use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{self, DeviceMsg, ErrorCode, HostMsg, Layer, WindowReport};
use ogm_core::{Beam, Pose};
use ogm_field::stream::host_frame;

use super::input::{beams_as_read, scan_packets};
use super::replay::{HostMemory, HostPlatform, FIRMWARE_SIZES};
use crate::sim::boxes;

const CELL: i32 = 50;
const MAX_RANGE: u32 = 3000;
const MARGIN: u16 = 72;
const EDGE: u16 = 16;

/// Scans every 300 mm through a 30 m × 14 m building of seeded pillars.
fn scans(waypoints: &[(f64, f64)]) -> Vec<(Pose, Vec<Beam>)> {
    boxes::scans(
        &boxes::building(14_000.0, 30, false),
        waypoints,
        0.3,
        MAX_RANGE,
    )
    .into_iter()
    .map(|s| (s.pose, s.beams))
    .collect()
}

/// What the online host saw.
#[derive(Default)]
struct Host {
    /// Newest log-odds and estimate bytes per building tile.
    tiles: HashMap<(i32, i32), (Vec<u8>, Vec<u8>)>,
    windows: Vec<WindowReport>,
    restore_errors: Vec<u32>,
    restores_sent: usize,
}

impl Host {
    /// Reads the frames in `out[from..]`; returns the building tiles that entered the window
    /// with the `Window` messages among them.
    fn read(&mut self, out: &[u8], from: usize) -> Vec<(i32, i32)> {
        let mut entered = Vec::new();
        let tiles = |w: &WindowReport| {
            let (x0, y0) = (w.origin_x / 16, w.origin_y / 16);
            let n = i32::from(FIRMWARE_SIZES.width / EDGE);
            (0..n * n).map(move |k| (x0 + k % n, y0 + k / n))
        };
        for frame in out[from..].split(|&b| b == 0).filter(|f| !f.is_empty()) {
            let mut f = frame.to_vec();
            match wire::decode::<DeviceMsg>(&mut f).expect("a device frame") {
                DeviceMsg::Tile(t) => {
                    let e = self.tiles.entry((t.tx, t.ty)).or_default();
                    match t.layer {
                        Layer::LogOdds => e.0 = t.data.to_vec(),
                        Layer::Counts => e.1 = t.data.to_vec(),
                        Layer::Sample => {}
                    }
                }
                DeviceMsg::Window(w) => {
                    if let Some(old) = self.windows.last() {
                        let before: Vec<_> = tiles(old).collect();
                        entered.extend(tiles(&w).filter(|t| !before.contains(t)));
                    }
                    self.windows.push(w);
                }
                DeviceMsg::Error(e) if e.code == ErrorCode::Restore => {
                    self.restore_errors.push(e.detail)
                }
                _ => {}
            }
        }
        entered
    }
}

/// Runs the scans through the firmware's application with an online host; `restore`: whether
/// the host sends stored tiles back. Returns the host's view and the stitched log-odds by
/// building cell (the newest tile of every building tile).
fn run(scans: &[(Pose, Vec<Beam>)], restore: bool) -> (Host, HashMap<(i32, i32), i16>) {
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_window_margin_cells(MARGIN)
        .with_budget(Budget::Fixed { updates: 40 });
    let mut memory = HostMemory::<u8>::new();
    let mut app = memory.app(&FIRMWARE_SIZES);
    let mut platform = HostPlatform {
        updates: |_| Some(40),
        missing: None,
    };
    let mut out = Vec::new();
    app.hello(&mut out, &platform);
    let mut host = Host::default();
    app.feed(
        &host_frame(&HostMsg::Config(config)),
        &mut out,
        &mut platform,
    );
    host.windows
        .push(app.session().expect("configured").window());
    let mut ts = 0u16;
    for (seq, (pose, beams)) in scans.iter().enumerate() {
        let seq = seq as u32;
        let mut bytes = host_frame(&HostMsg::ScanStart { seq, pose: *pose });
        bytes.extend(scan_packets(beams, &mut ts).unwrap());
        bytes.extend(host_frame(&HostMsg::ScanEnd {
            seq,
            points: beams.len() as u32,
        }));
        let from = out.len();
        app.feed(&bytes, &mut out, &mut platform);
        let entered = host.read(&out, from);
        if !restore {
            continue;
        }
        for t in entered {
            // An all-unknown tile has nothing to restore (it is not streamed as it leaves; a
            // scan's changed-tile box or the round robin of marginal tiles may still have sent
            // it, unknown, while it was in the window).
            let known =
                |(lo, est): &&(Vec<u8>, Vec<u8>)| lo.iter().any(|&b| b != 0) && !est.is_empty();
            let Some((lo, est)) = host.tiles.get(&t).filter(known) else {
                continue;
            };
            let parts: Vec<_> = wire::restore_msgs(t.0, t.1, Layer::LogOdds, EDGE, lo)
                .chain(wire::restore_msgs(t.0, t.1, Layer::Counts, EDGE, est))
                .collect();
            assert_eq!(
                parts.len(),
                12,
                "tile {t:?}: {} + {} bytes",
                lo.len(),
                est.len()
            );
            for m in parts {
                // Each part twice: repeats are idempotent.
                let f = host_frame(&m);
                let from = out.len();
                app.feed(&f, &mut out, &mut platform);
                app.feed(&f, &mut out, &mut platform);
                host.read(&out, from);
                host.restores_sent += 1;
            }
        }
    }
    let from = out.len();
    app.feed(&host_frame(&HostMsg::Finish), &mut out, &mut platform);
    host.read(&out, from);
    let mut stitched = HashMap::new();
    for ((tx, ty), (lo, _)) in &host.tiles {
        for (k, c) in lo.chunks_exact(2).enumerate() {
            let (x, y) = (k as i32 % 16, k as i32 / 16);
            stitched.insert((tx * 16 + x, ty * 16 + y), i16::from_le_bytes([c[0], c[1]]));
        }
    }
    (host, stitched)
}

/// The unbounded map of the same scans (the beams as the firmware reads them, through the
/// LD06 packets); returns (cells that differ from `stitched`, cells known).
fn differ(scans: &[(Pose, Vec<Beam>)], stitched: &HashMap<(i32, i32), i16>) -> (usize, usize) {
    let config = RunConfig::ROBOT.with_max_range_mm(MAX_RANGE);
    let (x0, y0, w, h) = (-128i32, -128i32, 896u16, 544u16);
    let mut s = Session::new(
        config.with_origin_mm(x0 * CELL, y0 * CELL),
        Owned::<u8>::buffers(&Sizes::grid(w, h)),
    )
    .unwrap();
    let mut ts = 0u16;
    for (pose, beams) in scans {
        s.insert(pose, &beams_as_read(beams, &mut ts).unwrap())
            .unwrap();
    }
    let (mut differ, mut known) = (0, 0);
    for (i, l) in s.log_odds().iter().enumerate() {
        let b = (
            x0 + (i % usize::from(w)) as i32,
            y0 + (i / usize::from(w)) as i32,
        );
        known += usize::from(l.0 != 0);
        differ += usize::from(stitched.get(&b).copied().unwrap_or(0) != l.0);
    }
    (differ, known)
}

/// East across the building and back west: the west region leaves the window and comes back.
const PATH: &[(f64, f64)] = &[(6.4, 6.4), (24.0, 7.0), (5.0, 7.4)];

#[test]
fn tiles_sent_back_make_the_stitched_map_equal_the_unbounded_one() {
    let scans = scans(PATH);
    let (host, stitched) = run(&scans, true);
    let last = *host.windows.last().unwrap();
    assert!(last.shifts >= 4, "{last:?}");
    assert!(last.tiles_restored > 10, "{last:?}");
    assert!(host.restores_sent >= 12 * last.tiles_restored as usize);
    assert_eq!(
        (last.restore_refused, last.beams_clipped),
        (0, 0),
        "{last:?}"
    );
    assert!(host.restore_errors.is_empty(), "{:?}", host.restore_errors);
    let (d, known) = differ(&scans, &stitched);
    assert!(known > 30_000, "mapped cells: {known}");
    assert_eq!(d, 0, "stitched vs unbounded: {d} of {known} cells differ");
}

#[test]
fn without_tiles_sent_back_the_region_visited_again_differs() {
    let scans = scans(PATH);
    let (host, stitched) = run(&scans, false);
    let last = *host.windows.last().unwrap();
    assert_eq!((last.tiles_restored, last.restore_refused), (0, 0));
    let (d, _) = differ(&scans, &stitched);
    assert!(d > 1000, "only {d} cells differ");
}

#[test]
fn restore_parts_of_a_mapped_tile_or_outside_the_window_are_refused_and_reported() {
    let scans = scans(&[(6.4, 6.4), (7.0, 6.4)]);
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_window_margin_cells(MARGIN)
        .with_budget(Budget::Fixed { updates: 10 });
    let mut memory = HostMemory::<u8>::new();
    let mut app = memory.app(&FIRMWARE_SIZES);
    let mut platform = HostPlatform {
        updates: |_| Some(10),
        missing: None,
    };
    let mut out = Vec::new();
    let mut host = Host::default();
    app.feed(
        &host_frame(&HostMsg::Config(config)),
        &mut out,
        &mut platform,
    );
    let mut ts = 0u16;
    let (pose, beams) = &scans[0];
    let mut bytes = host_frame(&HostMsg::ScanStart {
        seq: 0,
        pose: *pose,
    });
    bytes.extend(scan_packets(beams, &mut ts).unwrap());
    bytes.extend(host_frame(&HostMsg::ScanEnd {
        seq: 0,
        points: 120,
    }));
    app.feed(&bytes, &mut out, &mut platform);
    let lo = vec![1u8; 512];
    let est = vec![9u8; 256];
    let errors_before = app.counters().errors;
    let from = out.len();
    // The robot's own tile (8, 8) is mapped; (99, 0) is outside; a Sample part is malformed.
    for m in wire::restore_msgs(8, 8, Layer::LogOdds, EDGE, &lo)
        .chain(wire::restore_msgs(8, 8, Layer::Counts, EDGE, &est))
        .chain(wire::restore_msgs(99, 0, Layer::LogOdds, EDGE, &lo).take(1))
    {
        app.feed(&host_frame(&m), &mut out, &mut platform);
    }
    let bad = HostMsg::Restore {
        tx: 1,
        ty: 1,
        layer: Layer::Sample,
        row: 0,
        data: wire::RestoreData::new(&[0; 32]).unwrap(),
    };
    app.feed(&host_frame(&bad), &mut out, &mut platform);
    host.read(&out, from);
    use ogm_core::wire::RestoreFault as F;
    assert_eq!(
        host.restore_errors,
        vec![F::Mapped.detail(), F::Outside.detail(), F::Layer.detail()]
    );
    assert_eq!(app.counters().errors, errors_before + 3);
    let w = app.session().unwrap().window();
    assert_eq!((w.restore_refused, w.tiles_restored), (3, 0));
    // JSON (`listen --send` lines) carries a part as numbers and reads it back.
    let json = serde_json::to_string(&bad).unwrap();
    assert_eq!(serde_json::from_str::<HostMsg>(&json).unwrap(), bad);
}
