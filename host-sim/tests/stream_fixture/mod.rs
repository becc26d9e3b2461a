//! A robot's map stream built by hand, shared by the tests that read one back (`export --stream`,
//! `listen --mcap`): a 32 × 32 map of 16 × 16 tiles, 100 mm cells, origin (−1 000, 500) mm.

use ogm_core::config::{Budget, RunConfig};
use ogm_core::wire::{self, DeviceMsg, Hello};

/// Map width and height, cells.
pub const W: usize = 32;
/// Tile edge, cells.
pub const EDGE: usize = 16;

/// Appends `msg` as one wire frame.
pub fn frame(msg: &DeviceMsg<'_>, out: &mut Vec<u8>) {
    let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
    out.extend_from_slice(wire::encode(msg, &mut buf).unwrap());
}

/// The stream's start: the robot's `Hello` (sizes above) and its `Configured` settings (the
/// robot's, with 100 mm cells and the origin above).
pub fn hello_and_config() -> Vec<u8> {
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
    let config = RunConfig {
        cell_mm: 100,
        ..RunConfig::ROBOT
            .with_origin_mm(-1000, 500)
            .with_max_range_mm(8000)
            .with_budget(Budget::Fixed { updates: 1 })
    };
    frame(&DeviceMsg::Configured(config), &mut s);
    s
}

/// A log-odds tile's bytes: strong free evidence in its left half, occupied in its right half.
pub fn half_free_tile() -> Vec<u8> {
    (0..EDGE * EDGE)
        .flat_map(|i| {
            let l: i16 = if i % EDGE < EDGE / 2 { -3072 } else { 3072 };
            l.to_le_bytes()
        })
        .collect()
}
