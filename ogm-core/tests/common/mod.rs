//! Synthetic worlds for the localisation tests: walls as segments, an exact lidar over them.

use ogm_core::{Angle, Beam, Pose, Range};

/// A wall from (x0, y0) to (x1, y1), mm.
pub type Seg = (f64, f64, f64, f64);

/// A synthetic lidar: `n` beams over a full turn from `pose` (mm, mm, rad), range `max_mm`,
/// exact.
pub fn scan(world: &[Seg], pose: (f64, f64, f64), n: u32, max_mm: f64) -> Vec<Beam> {
    let (px, py, th) = pose;
    (0..n)
        .map(|i| {
            let a = f64::from(i) / f64::from(n) * std::f64::consts::TAU;
            let (dx, dy) = ((th + a).cos(), (th + a).sin());
            let mut best = f64::INFINITY;
            for &(x0, y0, x1, y1) in world {
                let (ex, ey) = (x1 - x0, y1 - y0);
                let den = dx * ey - dy * ex;
                if den.abs() < 1e-12 {
                    continue;
                }
                let t = ((x0 - px) * ey - (y0 - py) * ex) / den;
                let u = ((x0 - px) * dy - (y0 - py) * dx) / den;
                if t > 0.0 && (0.0..=1.0).contains(&u) {
                    best = best.min(t);
                }
            }
            let range = if best < max_mm {
                Range::Hit(best.round() as u32)
            } else {
                Range::NoReturn
            };
            Beam {
                angle: Angle::from_radians(a),
                range,
            }
        })
        .collect()
}

/// The pose (mm, mm, rad) on the robot's integer grid.
pub fn pose_of(p: (f64, f64, f64)) -> Pose {
    Pose::new(
        p.0.round() as i32,
        p.1.round() as i32,
        Angle::from_radians(p.2),
    )
}
