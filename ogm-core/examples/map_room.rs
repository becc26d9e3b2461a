//! The engine's common path: scans of a 6 m square room `insert`ed, the map improved by `step`.
use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::{Angle, Beam, Pose, Range};
/// A synthetic lidar: 360 beams from (x, y) mm in a room with walls at ±3 m.
fn scan(x: f64, y: f64) -> Vec<Beam> {
    let wall = |p: f64, d: f64| (3000f64.copysign(d) - p) / d; // parallel: +inf
    let mut beams = Vec::new();
    for d in 0..360u32 {
        let (angle, a) = (Angle::from_centidegrees(100 * d), f64::from(d).to_radians());
        let range = Range::Hit(wall(x, a.cos()).min(wall(y, a.sin())) as u32);
        beams.push(Beam { angle, range });
    }
    beams
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let config = RunConfig::ROBOT
        .with_origin_mm(-3200, -3200)
        .with_max_range_mm(8000)
        .with_budget(Budget::Fixed { updates: 5000 });
    let mut map = Session::new(config, Owned::<u8>::buffers(&Sizes::grid(128, 128)))?;
    for k in 0..5 {
        let (x_mm, y_mm) = (600 * k - 1200, 400 * k - 1500);
        let beams = scan(x_mm.into(), y_mm.into());
        let inserted = map.insert(&Pose::new(x_mm, y_mm, Angle(0)), &beams)?;
        let (hit, updates) = (inserted.stats.cells_hit, map.step(5000)); // step: improve the map
        println!("({x_mm}, {y_mm}) mm: {hit} cells hit, {updates} sampler updates");
    }
    let cell = |i: usize| match (map.log_odds()[i].raw(), map.marginal(i)) {
        (0, _) => ' ', // never observed: unknown
        (_, Some(p)) if p > 0.5 => '#',
        _ => '.',
    };
    for row in (4..128).step_by(4).rev() {
        let line: String = (0..128).step_by(2).map(|c| cell(row * 128 + c)).collect();
        println!("{line}");
    }
    Ok(())
}
