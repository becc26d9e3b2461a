//! The scan matcher (issue 39) with input-chosen everything: a 48 × 48 grid of any log-odds
//! (sparse writes over a chosen background), any settings (invalid ones included), any beams
//! (no returns, zero and huge ranges) and any odometry poses (far outside the grid, jumps), through
//! `ogm_core::localize::Tracker::update` over several scans, as a `Session` would call it.
//! Invariants: nothing panics; a call reads no more cells than `MatchConfig::max_reads` allows;
//! an unusable verdict keeps the prediction.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use ogm_core::localize::{MapView, MatchConfig, Tracker};
use ogm_core::{Angle, Beam, GridGeometry, LogOdds, Pose, Range};

const W: u16 = 48;
const H: u16 = 48;
const POINTS: usize = 64;

#[derive(Arbitrary, Debug)]
struct Input {
    cell_mm: u8,
    background: i16,
    writes: Vec<(u16, i16)>,
    cfg: [u16; 12],
    scans: Vec<Scan>,
}

#[derive(Arbitrary, Debug)]
struct Scan {
    odometry: (i32, i32, u16),
    beams: Vec<(u16, u32)>,
    matching: bool,
}

fuzz_target!(|input: Input| {
    let cell_mm = u32::from(input.cell_mm).max(1) * 10;
    let Ok(g) = GridGeometry::new(W, H, cell_mm, -(i32::from(W) * cell_mm as i32) / 2, -1000)
    else {
        return;
    };
    let mut cells = vec![LogOdds(input.background); g.len()];
    for &(i, v) in &input.writes {
        if let Some(c) = cells.get_mut(usize::from(i) % g.len()) {
            *c = LogOdds(v);
        }
    }
    let c = input.cfg;
    let cfg = MatchConfig {
        floor: LogOdds(c[0] as i16),
        occupied: LogOdds(c[1] as i16),
        levels: (c[2] % 5) as u8,
        radius: (c[3] % 5) as u8,
        coarse_radius: (c[3] / 5 % 5) as u8,
        coarse_thin: (c[3] / 25 % 8) as u8,
        iterations: (c[4] % 16) as u8,
        turn_search: (c[4] / 16 % 8) as u8,
        reg_q8: c[5],
        cauchy_q8: c[6],
        prior_trans_q8: c[7],
        prior_rot: c[8],
        max_shift_mm: u32::from(c[9]) * 4,
        max_turn: Angle(c[10]),
        budget_reads: u32::from(c[11]) * 16,
        ..MatchConfig::default()
    };
    let Ok(map) = MapView::new(&cells, g) else {
        return;
    };
    let mut t: Tracker<POINTS> = Tracker::new(cfg);
    for s in input.scans.iter().take(8) {
        let beams: Vec<Beam> = s
            .beams
            .iter()
            .take(400)
            .map(|&(a, r)| Beam {
                angle: Angle(a),
                range: if r % 7 == 0 {
                    Range::NoReturn
                } else {
                    Range::Hit(r)
                },
            })
            .collect();
        t.set_matching(s.matching);
        let odo = Pose::new(s.odometry.0, s.odometry.1, Angle(s.odometry.2));
        let out = t.update(&map, &odo, &beams);
        if let Some(m) = out.matched {
            assert!(u64::from(m.work.reads) <= cfg.max_reads(POINTS), "{m:?}");
            if !m.verdict.is_usable() {
                assert_eq!(out.pose, out.predicted);
            }
        }
    }
});
