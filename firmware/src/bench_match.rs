//! Benchmark of the scan-to-map matcher (issue 39) on the target: instructions per scan.
//!
//! Built only with the `bench-match` feature (`FIRMWARE_FEATURES=bench-match
//! scripts/firmware.sh run`): the image then runs this instead of the application and exits.
//! Under QEMU's `-icount shift=0` one nanosecond of the board's clock is one instruction, so the
//! durations it logs are instruction counts (±40, one tick).
//!
//! The scene is synthetic and integer-only, so nothing is stored and the run is deterministic:
//! * an office-like room, walls on x = ±5000 mm and y = ±4000 mm, with a pillar, a cabinet and a
//!   partition (axis-aligned segments, [`WALLS`]); grid 5 cm cells from (−6400, −6400) mm;
//! * scans of [`BEAMS`] beams (an LD06 turn: 0.8° apart), range = distance to the first segment
//!   along the beam (`Angle::cos_sin_q30`), `NoReturn` beyond [`MAX_RANGE_MM`];
//! * the map: the scans from [`MAP_POSES`] inserted by the ordinary `Mapper`;
//! * the benchmark: from each of [`TEST_POSES`] (not among the map's), a scan is turned into
//!   points and matched from a prediction off by [`PRED_ERROR`]; only `prepare_points` +
//!   `match_scan` are timed (what `localize::Tracker::update` does per scan, less two pose
//!   compositions).

use ogm_core::localize::{match_scan, prepare_points, MapView, MatchConfig, ScanPoint};
use ogm_core::map::mapper::Mapper;
use ogm_core::{Angle, Beam, GridGeometry, LogOdds, LogOddsGrid, MapperConfig, Pose, Range};

use crate::platform::Platform;

/// Beams per scan (an LD06 turn at 10 Hz: ~450).
pub const BEAMS: usize = 450;
/// Sensor range.
const MAX_RANGE_MM: u32 = 12_000;
/// Cell size.
const CELL_MM: u32 = 50;
/// Points the matcher may use (the tracker's buffer).
const MAX_POINTS: usize = 512;

/// Axis-aligned wall segments `(x0, y0, x1, y1)`, mm (`x0 == x1` or `y0 == y1`).
const WALLS: [(i64, i64, i64, i64); 14] = [
    // The room.
    (-5000, -4000, 5000, -4000),
    (-5000, 4000, 5000, 4000),
    (-5000, -4000, -5000, 4000),
    (5000, -4000, 5000, 4000),
    // A pillar, 40 cm square.
    (1500, 1000, 1900, 1000),
    (1500, 1400, 1900, 1400),
    (1500, 1000, 1500, 1400),
    (1900, 1000, 1900, 1400),
    // A cabinet against the south wall.
    (-3500, -4000, -3500, -3400),
    (-2300, -4000, -2300, -3400),
    (-3500, -3400, -2300, -3400),
    // A partition from the north wall, and a door recess in the east wall.
    (-1000, 4000, -1000, 1500),
    (5000, -1000, 4700, -1000),
    (4700, -1000, 4700, -2000),
];

/// Where the map's scans are taken (mm, mm, degrees).
const MAP_POSES: [(i32, i32, u32); 6] = [
    (0, 0, 0),
    (-3000, 1000, 90),
    (3000, -2000, 180),
    (-2500, -2000, 45),
    (3200, 2500, 270),
    (0, -2500, 300),
];

/// Where the benchmark's scans are taken (mm, mm, degrees).
const TEST_POSES: [(i32, i32, u32); 5] = [
    (500, 300, 10),
    (-2000, 0, 120),
    (2500, -1200, 200),
    (-3800, 2800, 330),
    (1000, 2600, 75),
];

/// The prediction's error: mm, mm, angle units (1.5° ≈ 273).
const PRED_ERROR: (i32, i32, i16) = (60, -40, 273);

/// Runs the benchmark and returns the exit code (0, or 1 if the map could not be built).
pub fn run<P: Platform>(grid: &mut [LogOdds], marks: &mut [u32], w: u16, h: u16, clock: &P) -> i32 {
    let Ok(geometry) = GridGeometry::new(w, h, CELL_MM, -6400, -6400) else {
        defmt::error!("bench-match: bad geometry");
        return 1;
    };
    let cells = geometry.len();
    let (Some(grid), Some(marks)) = (grid.get_mut(..cells), marks.get_mut(..)) else {
        return 1;
    };
    grid.fill(LogOdds::ZERO);
    let Ok(g) = LogOddsGrid::new(geometry, grid) else {
        return 1;
    };
    let Ok(mut mapper) = Mapper::new(g, marks, MapperConfig::new(MAX_RANGE_MM)) else {
        defmt::error!("bench-match: mapper");
        return 1;
    };
    let mut beams = [Beam {
        angle: Angle::ZERO,
        range: Range::NoReturn,
    }; BEAMS];
    for &(x, y, d) in &MAP_POSES {
        let p = pose(x, y, d);
        scan(&p, &mut beams);
        if mapper.insert_scan(&p, &beams).is_err() {
            return 1;
        }
    }
    let d = MatchConfig::default();
    // The default, and the variants measured against the budget (NOTES-39.md).
    let configs: [(&str, MatchConfig); 3] = [
        ("default", d),
        (
            "no budget",
            MatchConfig {
                budget_reads: 0,
                ..d
            },
        ),
        (
            "round 3 (levels 2, spacing 30, no budget)",
            MatchConfig {
                levels: 2,
                min_spacing_mm: 30,
                budget_reads: 0,
                ..d
            },
        ),
    ];
    for (name, cfg) in &configs {
        bench(name, cfg, &mapper, &mut beams, clock);
    }
    0
}

/// Matches the scans of [`TEST_POSES`] with `cfg` and logs the instructions.
fn bench<P: Platform, S: AsRef<[LogOdds]> + AsMut<[LogOdds]>, M: AsRef<[u32]> + AsMut<[u32]>>(
    name: &str,
    cfg: &MatchConfig,
    mapper: &Mapper<S, M>,
    beams: &mut [Beam; BEAMS],
    clock: &P,
) {
    let cfg = *cfg;
    let mut points = [ScanPoint::default(); MAX_POINTS];
    let (mut total, mut worst) = (0u64, 0u64);
    for (k, &(x, y, d)) in TEST_POSES.iter().enumerate() {
        let truth = pose(x, y, d);
        scan(&truth, beams);
        let predicted = Pose::new(
            x + PRED_ERROR.0,
            y + PRED_ERROR.1,
            truth.heading.wrapping_add(Angle(PRED_ERROR.2 as u16)),
        );
        let map = MapView::of(mapper.grid());
        let t0 = clock.now();
        let st = prepare_points(&beams[..], CELL_MM, &cfg, &mut points);
        let r = match_scan(&map, points.get(..st.kept).unwrap_or(&[]), &predicted, &cfg);
        let t1 = clock.now();
        let insns = P::ticks_to_ns(u64::from(t1.wrapping_sub(t0)));
        total += insns;
        worst = worst.max(insns);
        let (ex, ey) = (r.pose.x_mm - truth.x_mm, r.pose.y_mm - truth.y_mm);
        defmt::info!(
            "bench-match [{=str}]: scan {=usize}: {=u64} instructions, {=usize} points, {=u32} reads, {=u16} passes, {} , error {=i32} {=i32} mm {=i16} units (from 60 -40 mm 273 units)",
            name,
            k,
            insns,
            st.kept,
            r.work.reads,
            r.work.passes,
            r.verdict,
            ex,
            ey,
            r.pose.heading.signed_diff(truth.heading)
        );
    }
    defmt::info!(
        "bench-match [{=str}]: {=usize} scans of {=usize} beams: mean {=u64} max {=u64} instructions per scan (budget 1500000)",
        name,
        TEST_POSES.len(),
        BEAMS,
        total / TEST_POSES.len() as u64,
        worst
    );
}

/// A pose from mm and whole degrees.
fn pose(x_mm: i32, y_mm: i32, deg: u32) -> Pose {
    Pose::new(x_mm, y_mm, Angle::from_centidegrees(deg * 100))
}

/// Fills `beams` with the scan seen from `p`: beam i at `i · 360° / BEAMS`.
fn scan(p: &Pose, beams: &mut [Beam; BEAMS]) {
    for (i, b) in beams.iter_mut().enumerate() {
        let angle = Angle::from_centidegrees((i as u32 * 36_000) / BEAMS as u32);
        let (c, s) = p.heading.wrapping_add(angle).cos_sin_q30();
        let range = first_hit(
            i64::from(p.x_mm),
            i64::from(p.y_mm),
            i64::from(c),
            i64::from(s),
        );
        *b = Beam {
            angle,
            range: match range {
                Some(r) if r < i64::from(MAX_RANGE_MM) => Range::Hit(r as u32),
                _ => Range::NoReturn,
            },
        };
    }
}

/// Distance (mm) from (`px`, `py`) along the Q30 direction (`c`, `s`) to the nearest segment.
fn first_hit(px: i64, py: i64, c: i64, s: i64) -> Option<i64> {
    let mut best: Option<i64> = None;
    for &(x0, y0, x1, y1) in &WALLS {
        let t = if x0 == x1 {
            if c == 0 {
                continue;
            }
            let t = ((x0 - px) << 30) / c;
            if t <= 0 || t > 1 << 24 {
                continue;
            }
            let y = py + ((t * s) >> 30);
            if y < y0.min(y1) || y > y0.max(y1) {
                continue;
            }
            t
        } else {
            if s == 0 {
                continue;
            }
            let t = ((y0 - py) << 30) / s;
            if t <= 0 || t > 1 << 24 {
                continue;
            }
            let x = px + ((t * c) >> 30);
            if x < x0.min(x1) || x > x0.max(x1) {
                continue;
            }
            t
        };
        best = Some(best.map_or(t, |b: i64| b.min(t)));
    }
    best
}
