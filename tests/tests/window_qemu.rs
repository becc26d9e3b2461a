//! The rolling window in QEMU (issue 38): a simulated building larger than the firmware's
//! 12.8 m window, crossed by a robot whose scans reach 3 m, which drives a loop and comes back
//! to where it started. The firmware shifts its window before the scans that need it and
//! streams the tiles that leave; an online host (`host_sim::firmware::online`, paced in
//! lock-step with the scan reports) sends the stored tiles back when a `Window` brings them
//! into the window again. The stream must equal the host replay of the link as sent, message
//! for message (bit-exact), and the stitched map must equal an unbounded host map of the same
//! scans, cell for cell.
//!
//! Needs the firmware toolchain and QEMU, like `firmware_qemu.rs` (skipped without them
//! unless `OGM_REQUIRE_FIRMWARE=1`). Runtime: about 35 s of QEMU after the firmware build.

use std::time::Duration;

use host_sim::firmware::online::{run_scans_online, run_turns_online};
use host_sim::sim::boxes;
use host_sim::sim::explore::ScanRecord;
use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_field::stream::{BuildingMap, BuildingRender, DeviceEvent};

const CELL: i32 = 50;
const MAX_RANGE: u32 = 3000;
const MARGIN: u16 = 72;

/// Scans every 300 mm through a 30 m × 22 m building (outer walls, seeded pillars and wall
/// stubs), whole-mm ranges, so the LD06 packets carry them exactly and the host's unbounded map
/// sees the firmware's beams.
fn scans(waypoints: &[(f64, f64)]) -> Vec<ScanRecord> {
    boxes::scans(
        &boxes::building(22_000.0, 50, true),
        waypoints,
        0.3,
        MAX_RANGE,
    )
}

/// Cells of `r` that differ from the unbounded map of `scans` (and cells it knows).
fn differ(config: &RunConfig, scans: &[ScanRecord], r: &BuildingRender) -> (usize, usize) {
    // The beams as the firmware reads them: through the LD06 packets (clockwise order).
    let mut ts = 0u16;
    let read: Vec<ScanRecord> = scans
        .iter()
        .map(|s| {
            let beams = host_sim::firmware::input::beams_as_read(&s.beams, &mut ts).unwrap();
            assert_eq!(beams.len(), s.beams.len());
            ScanRecord {
                pose: s.pose,
                beams,
            }
        })
        .collect();
    differ_read(config, &read, r)
}

/// Cells of `r` that differ from the unbounded map of `scans` as the firmware read them (and
/// cells it knows).
fn differ_read(config: &RunConfig, scans: &[ScanRecord], r: &BuildingRender) -> (usize, usize) {
    let (x0, y0, w, h) = (-64i32, -64i32, 768u16, 576u16);
    let mut host = Session::new(
        config
            .with_window_margin_cells(0)
            .with_origin_mm(x0 * CELL, y0 * CELL),
        Owned::<u8>::buffers(&Sizes::grid(w, h)),
    )
    .unwrap();
    for s in scans {
        host.insert(&s.pose, &s.beams).unwrap();
    }
    let (rw, rh) = (r.map.width as i64, r.map.height as i64);
    let stitched = |bx: i64, by: i64| {
        let (x, y) = (bx - r.x0, by - r.y0);
        if (0..rw).contains(&x) && (0..rh).contains(&y) {
            r.map.log_odds[(y * rw + x) as usize]
        } else {
            0
        }
    };
    let (mut differ, mut known) = (0usize, 0usize);
    for (i, l) in host.log_odds().iter().enumerate() {
        let bx = i64::from(x0) + (i % usize::from(w)) as i64;
        let by = i64::from(y0) + (i / usize::from(w)) as i64;
        known += usize::from(l.0 != 0);
        differ += usize::from(stitched(bx, by) != l.0);
    }
    // Nothing known outside the unbounded map's area either.
    let inside = |bx: i64, by: i64| {
        (i64::from(x0)..i64::from(x0) + i64::from(w)).contains(&bx)
            && (i64::from(y0)..i64::from(y0) + i64::from(h)).contains(&by)
    };
    for (i, &l) in r.map.log_odds.iter().enumerate() {
        let (bx, by) = (r.x0 + i as i64 % rw, r.y0 + i as i64 / rw);
        differ += usize::from(l != 0 && !inside(bx, by));
    }
    (differ, known)
}

#[test]
fn a_building_larger_than_the_window_stitches_to_the_unbounded_map_in_qemu() {
    if !ogm_tests::firmware_available(
        "a_building_larger_than_the_window_stitches_to_the_unbounded_map_in_qemu",
    ) {
        return;
    }
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_window_margin_cells(MARGIN)
        .with_budget(Budget::Fixed { updates: 300 });
    // Starts in the middle of the first window, crosses the building east, then north, back
    // west and south to its start: the start region leaves the window and comes back.
    let scans = scans(&[
        (6.4, 6.4),
        (25.0, 6.8),
        (25.5, 16.0),
        (6.0, 16.5),
        (6.2, 7.0),
    ]);
    let (r, events, host) =
        run_scans_online(&config, &scans, Duration::from_secs(120), true).expect("run");
    ogm_tests::assert_ran_identical(&r);
    let windows: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            DeviceEvent::Window(w) => Some(*w),
            _ => None,
        })
        .collect();
    let last = *windows.last().expect("a Window at the end");
    assert!(last.shifts >= 6, "{last:?}");
    assert_eq!(
        (
            last.scans_clipped,
            last.beams_clipped,
            last.shifts_refused,
            last.restore_refused
        ),
        (0, 0, 0, 0),
        "{last:?}"
    );
    assert!(last.tiles_restored >= 20, "{last:?}");
    assert_eq!(host.parts_sent, 12 * u64::from(last.tiles_restored));
    // The stitched map, as the online host holds it and as a recorded stream gives it (which
    // tells restored tiles from the robot's counters alone).
    let online = host.building().expect("a Hello").render();
    let hello = r.hello.as_ref().expect("a Hello");
    let mut offline = BuildingMap::new(
        usize::from(hello.width),
        usize::from(hello.height),
        usize::from(hello.tile_edge),
    );
    for e in &events {
        match e {
            DeviceEvent::Window(w) => offline.note_window(*w),
            DeviceEvent::Tile(t) => offline.apply(t).unwrap(),
            _ => {}
        }
    }
    let v = offline.revisits();
    assert_eq!(
        (v.restored, v.merged, v.unsure),
        (u64::from(last.tiles_restored), 0, 0),
        "{v:?}"
    );
    assert_eq!(offline.render(), online);
    let (d, known) = differ(&config, &scans, &online);
    assert!(known > 40_000, "mapped cells: {known}");
    assert_eq!(d, 0, "stitched vs unbounded: {d} of {known} cells differ");
    eprintln!(
        "window: {} shifts, {} tiles out, {} restored; worst scan step {} instructions",
        last.shifts, last.tiles_out, last.tiles_restored, r.figures.insert_per_scan_max
    );
}

/// The robot loop (LD06 turns on the lidar's UART, poses on the link) with scans 4 m apart,
/// farther than the margin rule allows (margin 112 − reach 61 cells = 2.55 m): each turn that
/// shifts the window reaches tiles that just entered. With `window_hold` the robot holds that
/// turn until the host has sent them back and said `Resume`; the stitched map must still equal
/// the unbounded one, bit-exact with the replay.
#[test]
fn turns_held_for_the_hosts_tiles_stitch_steps_longer_than_the_margin_in_qemu() {
    if !ogm_tests::firmware_available(
        "turns_held_for_the_hosts_tiles_stitch_steps_longer_than_the_margin_in_qemu",
    ) {
        return;
    }
    let config = RunConfig::ROBOT
        .with_max_range_mm(MAX_RANGE)
        .with_window_margin_cells(112)
        .with_window_hold(true)
        .with_correction(ogm_core::config::PoseCorrection::Off)
        .with_budget(Budget::Fixed { updates: 300 });
    let scans = boxes::scans(
        &boxes::building(22_000.0, 50, true),
        &[
            (6.4, 6.4),
            (25.0, 6.8),
            (25.5, 16.0),
            (6.0, 16.5),
            (6.2, 7.0),
        ],
        4.0,
        MAX_RANGE,
    );
    let (r, _, host, config) =
        run_turns_online(&config, &scans, Duration::from_secs(120), true).expect("run");
    ogm_tests::assert_ran_identical(&r);
    let building = host.building().expect("a Hello");
    let last = *building.window().expect("a Window at the end");
    assert!(last.shifts >= 6 && last.tiles_restored >= 10, "{last:?}");
    assert_eq!(
        (
            last.beams_clipped,
            last.restore_refused,
            last.holds_unanswered
        ),
        (0, 0, 0),
        "{last:?}"
    );
    assert_eq!(last.turns_held, last.shifts, "{last:?}");
    let online = building.render();
    let (d, known) = differ_turns(&config, &scans, &online);
    assert!(known > 10_000, "mapped cells: {known}");
    assert_eq!(d, 0, "stitched vs unbounded: {d} of {known} cells differ");
}

/// [`differ`] for scans sent as LD06 turns (the beams as the firmware's turns hold them).
fn differ_turns(config: &RunConfig, scans: &[ScanRecord], r: &BuildingRender) -> (usize, usize) {
    let read: Vec<ScanRecord> = scans
        .iter()
        .map(|s| {
            let (pose, beams) = host_sim::firmware::log::firmware_scan(s, config.mount.heading);
            ScanRecord { pose, beams }
        })
        .collect();
    differ_read(config, &read, r)
}
