//! `host-sim export --stream`: a robot's captured map stream, cut off mid-frame, becomes a ROS
//! map with the robot's own cell size and origin; the marginals layer falls back to the log-odds
//! where no marginal tile arrived, and cells without evidence stay unknown.

use std::process::Command;

use ogm_core::wire::{DeviceMsg, Layer, Tile};
use ogm_field::world::{load_world, Truth};

mod stream_fixture;
use stream_fixture::{frame, half_free_tile, hello_and_config, EDGE, W};

/// Cell index of local cell `i` of tile (tx, ty).
fn cell(tx: usize, ty: usize, i: usize) -> usize {
    (ty * EDGE + i / EDGE) * W + tx * EDGE + i % EDGE
}

#[test]
fn a_cut_off_stream_exports_with_the_robots_geometry() {
    let mut s = hello_and_config();
    // Tile (0, 0): strong free evidence in its left half, occupied in its right half; the
    // sampler's marginals say the opposite of the log-odds in its top row.
    let lo = half_free_tile();
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
