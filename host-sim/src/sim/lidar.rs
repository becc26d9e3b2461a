//! A synthetic 2-D lidar: one revolution per [`SimLidar::read_scan`], in the engine's own scan
//! type ([`ScanBuf`]). `host-sim firmware` encodes these scans as LD06 packets, so the firmware
//! reads them through its real lidar parser.
//!
//! Beams are cast exactly (Amanatides–Woo, f64) into the ground truth from the robot's pose; the
//! range to the boundary of the first cell that blocks the beam gets Gaussian noise (σ in cells,
//! paper: 3) and is reported in millimetres. A beam that hits nothing within the maximum range
//! (paper: 75 cells) — or whose noisy range reaches it — is reported as `Range::NoReturn`.

use ogm_core::{Angle, Beam, Pose, Range, ScanBuf};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

use ogm_field::world::World;

/// Lidar parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LidarConfig {
    /// Beams per revolution, evenly spaced over 360° starting at the robot's heading.
    pub beams: u16,
    /// Maximum range in cells (paper: 75).
    pub max_range_cells: f64,
    /// Range noise standard deviation in cells (paper: 3).
    pub sigma_cells: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        LidarConfig {
            beams: 360,
            max_range_cells: 75.0,
            sigma_cells: 3.0,
        }
    }
}

/// The simulated sensor. Set [`SimLidar::pose`] before each [`SimLidar::read_scan`].
pub struct SimLidar<'w> {
    world: &'w World,
    config: LidarConfig,
    rng: Xoshiro256PlusPlus,
    noise: Normal<f64>,
    /// Where the robot is (the lidar is at the robot's centre).
    pub pose: Pose,
}

impl<'w> SimLidar<'w> {
    /// A lidar in `world`, seeded.
    pub fn new(world: &'w World, config: LidarConfig, seed: u64) -> anyhow::Result<Self> {
        anyhow::ensure!(config.beams > 0, "lidar needs at least one beam");
        anyhow::ensure!(
            config.max_range_cells.is_finite() && config.max_range_cells > 0.0,
            "lidar max range must be positive"
        );
        let noise = Normal::new(0.0, config.sigma_cells.max(0.0))
            .map_err(|e| anyhow::anyhow!("bad lidar noise σ {}: {e}", config.sigma_cells))?;
        Ok(SimLidar {
            world,
            config,
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
            noise,
            pose: Pose::default(),
        })
    }

    /// Max range in millimetres.
    pub fn max_range_mm(&self) -> u32 {
        (self.config.max_range_cells * self.world.resolution_m * 1000.0).round() as u32
    }

    /// Noise-free range in cells from the pose along world direction `theta`, or `None` when
    /// nothing blocks the beam within `limit` cells.
    pub fn cast(&self, pose: &Pose, theta: f64, limit: f64) -> Option<f64> {
        let res_mm = self.world.resolution_m * 1000.0;
        let (ox, oy) = (
            self.world.origin_m.0 * 1000.0,
            self.world.origin_m.1 * 1000.0,
        );
        let x = (f64::from(pose.x_mm) - ox) / res_mm;
        let y = (f64::from(pose.y_mm) - oy) / res_mm;
        cast_ray(self.world, x, y, theta, limit)
    }
}

/// Amanatides–Woo traversal from (x, y) (in cell units) along `theta`; returns the distance (cells)
/// to the entry point of the first blocking cell, 0 if the start cell blocks.
pub fn cast_ray(world: &World, x: f64, y: f64, theta: f64, limit: f64) -> Option<f64> {
    let (dx, dy) = (theta.cos(), theta.sin());
    let (mut cx, mut cy) = (x.floor() as i64, y.floor() as i64);
    if world.blocks_beam(cx, cy) {
        return Some(0.0);
    }
    let step_x: i64 = if dx > 0.0 { 1 } else { -1 };
    let step_y: i64 = if dy > 0.0 { 1 } else { -1 };
    let t_delta_x = if dx != 0.0 {
        (1.0 / dx).abs()
    } else {
        f64::INFINITY
    };
    let t_delta_y = if dy != 0.0 {
        (1.0 / dy).abs()
    } else {
        f64::INFINITY
    };
    let mut t_max_x = if dx > 0.0 {
        ((cx + 1) as f64 - x) / dx
    } else if dx < 0.0 {
        (cx as f64 - x) / dx
    } else {
        f64::INFINITY
    };
    let mut t_max_y = if dy > 0.0 {
        ((cy + 1) as f64 - y) / dy
    } else if dy < 0.0 {
        (cy as f64 - y) / dy
    } else {
        f64::INFINITY
    };
    loop {
        let t = if t_max_x < t_max_y {
            cx += step_x;
            let t = t_max_x;
            t_max_x += t_delta_x;
            t
        } else {
            cy += step_y;
            let t = t_max_y;
            t_max_y += t_delta_y;
            t
        };
        if t > limit {
            return None;
        }
        if world.blocks_beam(cx, cy) {
            return Some(t);
        }
    }
}

impl SimLidar<'_> {
    /// One revolution from [`SimLidar::pose`] into `scan` (cleared first).
    pub fn read_scan<const N: usize>(&mut self, scan: &mut ScanBuf<N>) {
        scan.clear();
        let n = u32::from(self.config.beams);
        let res_mm = self.world.resolution_m * 1000.0;
        let max = self.config.max_range_cells;
        // Cast a little past max range so noise can bring a far wall inside it.
        let limit = max + 4.0 * self.config.sigma_cells;
        for i in 0..n {
            let angle = Angle(((u64::from(i) << 16) / u64::from(n)) as u16);
            let theta = self.pose.heading.wrapping_add(angle).to_radians();
            let range = match self.cast(&self.pose, theta, limit) {
                None => Range::NoReturn,
                Some(d) => {
                    let z = d + self.noise.sample(&mut self.rng);
                    if z >= max {
                        Range::NoReturn
                    } else {
                        Range::Hit((z.max(0.0) * res_mm).round() as u32)
                    }
                }
            };
            scan.push(Beam { angle, range });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_field::world::Truth;

    fn box_world() -> World {
        // 20x20 cells of 0.1 m, walls on the border.
        let (w, h) = (20usize, 20usize);
        let cells = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x == 0 || y == 0 || x == w - 1 || y == h - 1 {
                    Truth::Occupied
                } else {
                    Truth::Free
                }
            })
            .collect();
        World {
            width: w,
            height: h,
            resolution_m: 0.1,
            origin_m: (0.0, 0.0),
            cells,
        }
    }

    #[test]
    fn noise_free_ranges_hit_the_walls() {
        let w = box_world();
        // Centre of cell (10, 10) = (1.05 m, 1.05 m); the east wall's inner face is at x = 1.9 m.
        assert!((cast_ray(&w, 10.5, 10.5, 0.0, 100.0).unwrap() - 8.5).abs() < 1e-9);
        assert!(
            (cast_ray(&w, 10.5, 10.5, std::f64::consts::PI, 100.0).unwrap() - 9.5).abs() < 1e-9
        );
        let diag = cast_ray(&w, 10.5, 10.5, std::f64::consts::FRAC_PI_4, 100.0).unwrap();
        assert!((diag - 8.5 * 2f64.sqrt()).abs() < 1e-9);
        assert_eq!(cast_ray(&w, 10.5, 10.5, 0.0, 5.0), None);
        assert_eq!(cast_ray(&w, 0.5, 0.5, 0.0, 5.0), Some(0.0));
    }

    #[test]
    fn scans_are_seeded_and_max_range_is_no_return() {
        let w = box_world();
        let cfg = LidarConfig {
            beams: 90,
            max_range_cells: 9.0,
            sigma_cells: 0.5,
        };
        let pose = Pose {
            x_mm: 1050,
            y_mm: 1050,
            heading: Angle::ZERO,
        };
        let mut scans = Vec::new();
        for _ in 0..2 {
            let mut l = SimLidar::new(&w, cfg, 7).unwrap();
            l.pose = pose;
            let mut s: ScanBuf<128> = ScanBuf::new();
            l.read_scan(&mut s);
            scans.push(s.beams().to_vec());
        }
        assert_eq!(scans[0], scans[1]);
        assert_eq!(scans[0].len(), 90);
        // Diagonal beams (12 cells to the corner walls) are beyond 9 cells: no return.
        assert_eq!(scans[0][11].range, Range::NoReturn);
        match scans[0][0].range {
            Range::Hit(mm) => assert!((mm as f64 - 850.0).abs() < 250.0, "{mm}"),
            Range::NoReturn => panic!("east wall should be seen"),
        }
    }
}
