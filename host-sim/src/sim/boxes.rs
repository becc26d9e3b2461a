//! A building of axis-aligned boxes, cast exactly: the rolling window's tests (host replay,
//! restore, QEMU) drive a robot through one larger than the firmware's window. Ranges are
//! whole millimetres at angles the LD06 carries exactly, so the firmware decodes the very beams
//! an unbounded host map is given.

use ogm_core::{Angle, Beam, Pose, Range};

use crate::sim::explore::ScanRecord;

/// A box, mm: `[x0, y0, x1, y1]`.
pub type Box2 = [f64; 4];

/// A building 30 m wide and `height_mm` tall: its outer walls (200 mm thick, outside it) and
/// `pieces` seeded boxes inside, pillars 200-600 mm square, every third a wall stub
/// (150 × 600-2100 mm) with `wall_stubs`. The same arguments give the same building.
pub fn building(height_mm: f64, pieces: usize, wall_stubs: bool) -> Vec<Box2> {
    let mut b = vec![
        [-200.0, -200.0, 30_200.0, 0.0],
        [-200.0, height_mm, 30_200.0, height_mm + 200.0],
        [-200.0, -200.0, 0.0, height_mm + 200.0],
        [30_000.0, -200.0, 30_200.0, height_mm + 200.0],
    ];
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s % 1000) as f64 / 1000.0
    };
    for k in 0..pieces {
        let (x, y) = (
            1_000.0 + next() * 28_000.0,
            1_000.0 + next() * (height_mm - 2_000.0),
        );
        let (w, h) = if wall_stubs && k % 3 == 0 {
            (150.0, 600.0 + 1500.0 * next())
        } else {
            (200.0 + 400.0 * next(), 200.0 + 400.0 * next())
        };
        b.push([x, y, x + w, y + h]);
    }
    b
}

/// Range (mm) to the nearest box along the ray from (`x`, `y`) mm at `a` rad (slab test), if
/// below `max`.
pub fn cast(boxes: &[Box2], x: f64, y: f64, a: f64, max: f64) -> Option<f64> {
    let (dx, dy) = (a.cos(), a.sin());
    let mut best = f64::INFINITY;
    for [x0, y0, x1, y1] in boxes {
        let (mut t0, mut t1) = (0.0f64, max);
        for (p, d, lo, hi) in [(x, dx, *x0, *x1), (y, dy, *y0, *y1)] {
            if d.abs() < 1e-12 {
                if p < lo || p > hi {
                    t0 = f64::INFINITY;
                }
            } else {
                let (a, b) = ((lo - p) / d, (hi - p) / d);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 <= t1 && t0 < best {
            best = t0;
        }
    }
    (best < max).then_some(best)
}

/// Scans every `step_m` along the waypoints (m), headings turning by 977/65 536 of a turn per
/// scan: 120 beams 3° apart, whole-mm ranges, cast 1 m past `max_range_mm` (hits closer than
/// 20 mm or beyond the cast: no return).
pub fn scans(
    boxes: &[Box2],
    waypoints: &[(f64, f64)],
    step_m: f64,
    max_range_mm: u32,
) -> Vec<ScanRecord> {
    let mut out = Vec::new();
    for w in waypoints.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        let n = (((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt() / step_m).ceil() as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            let pose = Pose::new(
                ((x0 + t * (x1 - x0)) * 1000.0).round() as i32,
                ((y0 + t * (y1 - y0)) * 1000.0).round() as i32,
                Angle(((k * 977) % 65_536) as u16),
            );
            let (x, y) = (f64::from(pose.x_mm), f64::from(pose.y_mm));
            let beams = (0..120)
                .map(|b| {
                    let angle = Angle::from_centidegrees(300 * b);
                    let a = pose.heading.to_radians() + angle.to_radians();
                    Beam {
                        angle,
                        range: match cast(boxes, x, y, a, f64::from(max_range_mm) + 1000.0) {
                            Some(r) if r >= 20.0 => Range::Hit(r.round() as u32),
                            _ => Range::NoReturn,
                        },
                    }
                })
                .collect();
            out.push(ScanRecord { pose, beams });
        }
    }
    out
}
