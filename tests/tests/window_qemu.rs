//! The rolling window in QEMU (issue 38): a simulated building larger than the firmware's
//! 12.8 m window, crossed by a robot whose scans reach 3 m. The firmware shifts its window
//! before the scans that need it and streams the tiles that leave; the stream must equal the
//! host replay message for message (bit-exact), and the stitched map — the newest streamed
//! tile of every building tile — must equal an unbounded host map of the same scans, cell for
//! cell.
//!
//! Needs the firmware toolchain and QEMU, like `firmware_qemu.rs` (skipped without them
//! unless `OGM_REQUIRE_FIRMWARE=1`). Runtime: a few seconds after the firmware build.

use std::collections::HashMap;
use std::time::Duration;

use host_sim::firmware::{print_report, run_scans};
use host_sim::sim::boxes;
use host_sim::sim::explore::ScanRecord;
use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::Layer;
use ogm_field::stream::DeviceEvent;

const CELL: i32 = 50;
const MAX_RANGE: u32 = 3000;
const MARGIN: u16 = 72;

/// Scans every 150 mm through a 30 m × 22 m building (outer walls, seeded pillars and wall
/// stubs), whole-mm ranges, so the LD06 packets carry them exactly and the host's unbounded map
/// sees the firmware's beams.
fn scans(waypoints: &[(f64, f64)]) -> Vec<ScanRecord> {
    boxes::scans(
        &boxes::building(22_000.0, 50, true),
        waypoints,
        0.15,
        MAX_RANGE,
    )
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
    // Starts in the middle of the first window, crosses the building east, then north. It
    // never comes back to a region that left the window: without tiles sent back (designed in
    // docs/wire.md, not yet on the wire) a region visited again starts unknown on the robot
    // (ogm-core's tests/window.rs checks the restore).
    let scans = scans(&[(6.4, 6.4), (26.0, 6.8), (26.5, 17.5)]);
    let (r, events) = run_scans(&config, &scans, Duration::from_secs(120)).expect("run");
    print_report(&r);
    assert_eq!(
        r.exit_code,
        Some(0),
        "firmware exit status (log {:?})",
        r.log
    );
    assert!(
        r.identical(),
        "firmware vs host replay:\n{}",
        r.mismatches.join("\n")
    );
    let windows: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            DeviceEvent::Window(w) => Some(*w),
            _ => None,
        })
        .collect();
    let last = *windows.last().expect("a Window at the end");
    assert!(last.shifts >= 3, "{last:?}");
    assert_eq!(
        (last.scans_clipped, last.beams_clipped, last.shifts_refused),
        (0, 0, 0)
    );
    // The stitched map: the newest log-odds tile of every building tile.
    let mut stitched: HashMap<(i32, i32), Vec<i16>> = HashMap::new();
    for e in &events {
        if let DeviceEvent::Tile(t) = e {
            if t.layer == Layer::LogOdds {
                let cells = t
                    .data
                    .chunks_exact(2)
                    .map(|c| i16::from_le_bytes([c[0], c[1]]));
                stitched.insert((t.tx, t.ty), cells.collect());
            }
        }
    }
    assert!(
        stitched.keys().any(|&(tx, _)| tx >= 16),
        "tiles beyond the first window"
    );
    // The unbounded map: one host session over the whole building.
    let (x0, y0, w, h) = (-64i32, -64i32, 768u16, 576u16);
    let mut host = Session::new(
        config
            .with_window_margin_cells(0)
            .with_origin_mm(x0 * CELL, y0 * CELL),
        Owned::<u8>::buffers(&Sizes::grid(w, h)),
    )
    .unwrap();
    // The beams as the firmware reads them: through the LD06 packets (clockwise order).
    let mut ts = 0u16;
    for s in &scans {
        let bytes = host_sim::firmware::input::scan_packets(&s.beams, &mut ts).unwrap();
        let mut beams = Vec::new();
        ogm_core::lidar::ld06::Ld06Parser::new().feed(&bytes, |p| {
            let p = p.expect("a packet");
            beams.extend((0..12).filter_map(|i| p.beam(i)));
        });
        assert_eq!(beams.len(), s.beams.len());
        host.insert(&s.pose, &beams).unwrap();
    }
    let (mut differ, mut known) = (0usize, 0usize);
    for (i, l) in host.log_odds().iter().enumerate() {
        let (bx, by) = (
            x0 + (i % usize::from(w)) as i32,
            y0 + (i / usize::from(w)) as i32,
        );
        let tile = (bx.div_euclid(16), by.div_euclid(16));
        let k = (by.rem_euclid(16) * 16 + bx.rem_euclid(16)) as usize;
        let got = stitched.get(&tile).map_or(0, |t| t[k]);
        known += usize::from(l.0 != 0);
        differ += usize::from(got != l.0);
    }
    assert!(known > 40_000, "mapped cells: {known}");
    assert_eq!(
        differ, 0,
        "stitched vs unbounded: {differ} of {known} cells differ"
    );
    eprintln!(
        "window: {} shifts, {} tiles out; worst scan step {} instructions",
        last.shifts, last.tiles_out, r.figures.insert_per_scan_max
    );
}
