//! Self-test when no host is on the link (e.g. `scripts/firmware.sh run`): maps a synthetic
//! square room from four poses through the same code path as host scans (`App` scan processing,
//! sampler included) and streams the result to the link as usual (UART1 → a file), so the run
//! logs the per-scan/per-cell/per-patch instruction counts without a host.
//!
//! The scene is integer arithmetic through ogm-core's own trigonometry:
//! * room: walls on x = ±4000 mm and y = ±4000 mm; grid origin (−6400, −6400) mm, 5 cm cells;
//! * scan: 360 beams, beam i at `Angle::from_centidegrees(100 · i)` relative to the heading,
//!   range = distance to the first wall along `heading + angle` (Q30 sin/cos,
//!   `((±4000 − p) << 30) / dir` truncated), `Hit` if < 12 000 mm else `NoReturn`;
//! * inserts: the [`POSES`] in order; sampler: [`UPDATES_PER_SCAN`] patch updates per scan, seed 1.

use embedded_io::Write;
use ogm_core::config::{Budget, RunConfig};
use ogm_core::lidar::turn::Turn;
use ogm_core::session::Storage;
use ogm_core::{Angle, Beam, Pose, Range, ScanBuf};

use crate::app::App;
use crate::platform::Platform;

/// Beams per synthetic scan.
const BEAMS: u32 = 360;
/// Sensor range.
const MAX_RANGE_MM: u32 = 12_000;
/// Half the side of the room.
const ROOM_HALF_MM: i64 = 4_000;
/// Sampler work per scan.
pub const UPDATES_PER_SCAN: u32 = 4_000;

/// Poses the synthetic scan is taken from, in order (the first twice).
const POSES: [Pose; 4] = [
    pose(0, 0, 0),
    pose(1_500, -1_000, 30),
    pose(-2_000, 1_800, 200),
    pose(0, 0, 0),
];

const fn pose(x_mm: i32, y_mm: i32, heading_deg: u32) -> Pose {
    Pose {
        x_mm,
        y_mm,
        // = Angle::from_centidegrees(heading_deg * 100), which is not `const`.
        heading: Angle(((heading_deg as u64 * 65_536 + 180) / 360) as u16),
    }
}

/// Runs the self-test; returns the exit code.
pub fn run<W: Write, S: Storage, P: Platform>(
    app: &mut App<'_, S>,
    link: &mut W,
    platform: &mut P,
) -> i32 {
    // The robot's settings, a constant (no floating-point code).
    let config = RunConfig::ROBOT
        .with_origin_mm(-6400, -6400)
        .with_max_range_mm(MAX_RANGE_MM)
        .with_seed(1)
        .with_budget(Budget::Fixed {
            updates: UPDATES_PER_SCAN,
        });
    app.configure(link, platform, config);
    for (k, p) in POSES.iter().enumerate() {
        room_scan(p, app.scan);
        let scan = Turn {
            seq: k as u32,
            pose: *p,
            t_us: 0,
            beams: app.scan.beams(),
            overflow: app.scan.overflow(),
        };
        app.state.process_scan(link, platform, &scan);
        app.report(link);
    }
    app.finish(link, platform)
}

/// Fills `scan` with the synthetic square-room scan seen from `pose`.
fn room_scan<const N: usize>(pose: &Pose, scan: &mut ScanBuf<N>) {
    scan.clear();
    for i in 0..BEAMS {
        let angle = Angle::from_centidegrees(i * 36_000 / BEAMS);
        let dir = pose.heading.wrapping_add(angle);
        let tx = wall_distance(pose.x_mm, dir.cos_q30());
        let ty = wall_distance(pose.y_mm, dir.sin_q30());
        let r = tx.min(ty);
        let range = if r < i64::from(MAX_RANGE_MM) {
            Range::Hit(r as u32)
        } else {
            Range::NoReturn
        };
        scan.push(Beam { angle, range });
    }
}

/// Distance (mm) from coordinate `p` to the wall at ±`ROOM_HALF_MM` along a direction whose
/// component on this axis is `d` (Q30); `i64::MAX` if parallel.
fn wall_distance(p: i32, d: i32) -> i64 {
    let (p, d) = (i64::from(p), i64::from(d));
    match d {
        0 => i64::MAX,
        d if d > 0 => ((ROOM_HALF_MM - p) << 30) / d,
        d => ((-ROOM_HALF_MM - p) << 30) / d,
    }
}
