//! `host-sim export --stream`: a robot's captured map stream, cut off mid-frame, becomes a ROS
//! map with the robot's own cell size and origin; the marginals layer falls back to the log-odds
//! where no marginal tile arrived, and cells without evidence stay unknown.

use std::process::Command;

use host_sim::world::{load_world, Truth};
use ogm_core::wire::{self, Budget, DeviceMsg, Hello, Layer, RunConfig, Tile};

const W: usize = 32;
const EDGE: usize = 16;

fn frame(msg: &DeviceMsg<'_>, out: &mut Vec<u8>) {
    let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
    out.extend_from_slice(wire::encode(msg, &mut buf).unwrap());
}

/// Cell index of local cell `i` of tile (tx, ty).
fn cell(tx: usize, ty: usize, i: usize) -> usize {
    (ty * EDGE + i / EDGE) * W + tx * EDGE + i % EDGE
}

#[test]
fn a_cut_off_stream_exports_with_the_robots_geometry() {
    let mut s = Vec::new();
    frame(
        &DeviceMsg::Hello(Hello {
            firmware: "test",
            board: "none",
            tick_hz: 25_000_000,
            width: W as u16,
            height: W as u16,
            tile_edge: EDGE as u16,
            max_beams: 456,
            ray_capacity: 0,
            scan_capacity: 0,
            local_capacity: 0,
            count_max: 255,
        }),
        &mut s,
    );
    let config = RunConfig::robot((-1000, 500), 8000, 1, Budget::Fixed { updates: 1 });
    let config = RunConfig {
        cell_mm: 100,
        ..config
    };
    frame(&DeviceMsg::Configured(config), &mut s);
    // Tile (0, 0): strong free evidence in its left half, occupied in its right half; the
    // sampler's marginals say the opposite of the log-odds in its top row.
    let lo: Vec<u8> = (0..EDGE * EDGE)
        .flat_map(|i| {
            let l: i16 = if i % EDGE < EDGE / 2 { -3072 } else { 3072 };
            l.to_le_bytes()
        })
        .collect();
    let counts: Vec<u8> = (0..EDGE * EDGE)
        .map(|i| {
            let occupied = (i % EDGE >= EDGE / 2) != (i / EDGE == EDGE - 1);
            if occupied {
                250
            } else {
                3
            }
        })
        .collect();
    for (tx, ty) in [(0, 0), (1, 1)] {
        frame(
            &DeviceMsg::Tile(Tile {
                layer: Layer::LogOdds,
                tx,
                ty,
                data: &lo,
            }),
            &mut s,
        );
    }
    // Marginals only for tile (0, 0).
    frame(
        &DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: 0,
            ty: 0,
            data: &counts,
        }),
        &mut s,
    );
    // Cut off in the middle of a frame.
    let mut tail = Vec::new();
    frame(
        &DeviceMsg::Tile(Tile {
            layer: Layer::LogOdds,
            tx: 1,
            ty: 0,
            data: &lo,
        }),
        &mut tail,
    );
    s.extend_from_slice(&tail[..tail.len() / 2]);

    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("capture.bin");
    std::fs::write(&input, &s).unwrap();
    for layer in ["marginals", "log-odds"] {
        let yaml = dir.path().join(format!("{layer}.yaml"));
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(["export", "--layer", layer, "--stream"])
            .arg(&input)
            .arg("--out")
            .arg(&yaml)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let world = load_world(&yaml, None).unwrap();
        assert_eq!((world.width, world.height), (W, W));
        assert!((world.resolution_m - 0.1).abs() < 1e-9);
        assert!((world.origin_m.0 + 1.0).abs() < 1e-9 && (world.origin_m.1 - 0.5).abs() < 1e-9);
        for i in 0..EDGE * EDGE {
            let by_log_odds = if i % EDGE < EDGE / 2 {
                Truth::Free
            } else {
                Truth::Occupied
            };
            let flipped = match by_log_odds {
                Truth::Free => Truth::Occupied,
                _ => Truth::Free,
            };
            let want = if layer == "marginals" && i / EDGE == EDGE - 1 {
                flipped
            } else {
                by_log_odds
            };
            assert_eq!(
                world.cells[cell(0, 0, i)],
                want,
                "{layer}: tile (0, 0) cell {i}"
            );
            // No marginals arrived for tile (1, 1): its log-odds decide.
            assert_eq!(
                world.cells[cell(1, 1, i)],
                by_log_odds,
                "{layer}: tile (1, 1)"
            );
            // Nothing (or only a cut-off frame) for the other two.
            assert_eq!(world.cells[cell(1, 0, i)], Truth::Unknown);
            assert_eq!(world.cells[cell(0, 1, i)], Truth::Unknown);
        }
    }
}
