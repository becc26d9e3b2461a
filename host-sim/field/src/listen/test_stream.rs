//! Test streams for the listener's tests: hand-made frames of a 40 x 24 grid.

use ogm_core::config::RunConfig;
use ogm_core::wire::{self, Counters, DeviceMsg, Hello, Layer, SamplerReport, ScanReport, Tile};

use super::args::default_config;

pub(super) fn frame(msg: &DeviceMsg<'_>) -> Vec<u8> {
    let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
    wire::encode(msg, &mut buf).unwrap().to_vec()
}

/// COBS with the terminating 0x00.
pub(super) fn cobs(raw: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    for &b in raw {
        if b == 0 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
            continue;
        }
        out.push(b);
        if out.len() - code_at == 255 {
            out[code_at] = 255;
            code_at = out.len();
            out.push(0);
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out.push(0);
    out
}

pub(super) fn hello() -> Vec<u8> {
    hello_of(40, 24)
}

/// The test robot's `Hello` with a `width × height` grid of 16-cell tiles.
pub(super) fn hello_of(width: u16, height: u16) -> Vec<u8> {
    frame(&DeviceMsg::Hello(Hello {
        firmware: "test",
        board: "host",
        tick_hz: 1000,
        width,
        height,
        tile_edge: 16,
        max_beams: 456,
        ray_capacity: 1,
        scan_capacity: 1,
        local_capacity: 1,
        count_max: 255,
    }))
}

pub(super) fn config() -> RunConfig {
    RunConfig {
        origin_x_mm: -1000,
        origin_y_mm: 500,
        ..default_config()
    }
}

/// A run of `seqs` scans on a 40 x 24 grid (3 x 2 tiles): each scan sends one log-odds and
/// one counts tile; values depend on the scan.
pub(super) fn stream(seqs: &[u32]) -> Vec<u8> {
    let mut s = hello();
    s.extend(frame(&DeviceMsg::Configured(config())));
    for &q in seqs {
        s.extend(frame(&DeviceMsg::Scan(ScanReport {
            seq: q,
            ..ScanReport::default()
        })));
        let (tx, ty) = ((q % 3) as u16, ((q / 3) % 2) as u16);
        let w = if tx == 2 { 8 } else { 16 };
        let h = if ty == 1 { 8 } else { 16 };
        let lo: Vec<u8> = (0..w * h)
            .flat_map(|i| (((i as i16) * 37 + q as i16 * 101) % 3000 - 1500).to_le_bytes())
            .collect();
        let counts: Vec<u8> = (0..w * h)
            .map(|i| ((i * 7 + q as usize) % 256) as u8)
            .collect();
        for (layer, data) in [(Layer::LogOdds, &lo), (Layer::Counts, &counts)] {
            s.extend(frame(&DeviceMsg::Tile(Tile {
                layer,
                tx: tx.into(),
                ty: ty.into(),
                data,
            })));
        }
        s.extend(frame(&DeviceMsg::Sampler(SamplerReport {
            samples: 9,
            ..SamplerReport::default()
        })));
        s.extend(frame(&DeviceMsg::Counters(Counters {
            scans: q + 1,
            ..Counters::default()
        })));
    }
    s
}
