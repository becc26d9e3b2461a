//! What a run is made of: its world, its simulation and the settings sent to the robot.

use anyhow::{ensure, Context};
use ogm_core::config::{Budget, RunConfig};
use ogm_field::world::{load_world, World};
use ogm_firmware::sizes::MPS2_AN386 as FW;

use super::args::FirmwareArgs;
use crate::sim::generate::{generate, GenParams};
use crate::sim::SimConfig;

/// The simulation of a run: the paper's robot that scans when stopped, or with `--moving` /
/// `--mission-scans` one that scans at the LD06's rate while it drives.
pub fn sim_config(args: &FirmwareArgs) -> SimConfig {
    let mut cfg = SimConfig::default();
    if args.moving || args.mission_scans.is_some() {
        cfg.explore =
            crate::sim::explore::ExploreConfig::moving(10.0, 0.4, args.mission_scans.unwrap_or(0));
        if args.mission_scans.is_none() {
            cfg.explore.max_stops = SimConfig::default().explore.max_stops * 25;
        }
        // 4 500 points/s at 10 Hz, rounded up to whole 12-point LD06 packets.
        cfg.lidar.beams = 456;
    }
    if let Some(sigma) = args.sigma_cells {
        cfg.lidar.sigma_cells = sigma;
    }
    cfg
}

/// The world of a run: `--map` (5 cm, cropped to the firmware grid) or a generated building.
pub fn firmware_world(args: &FirmwareArgs) -> anyhow::Result<World> {
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    Ok(match &args.map {
        Some(p) => load_world(p, None)
            .with_context(|| format!("loading {}", p.display()))?
            .resample(crate::eval::eval_sim::EVAL_RESOLUTION_M)
            .crop(0, 0, w, h),
        None => generate(
            &GenParams {
                width: w,
                height: h,
                ..GenParams::default()
            },
            args.seed,
        ),
    })
}

/// The settings sent to the robot for `world`.
pub fn run_config(world: &World, args: &FirmwareArgs, max_range_mm: u32) -> RunConfig {
    let budget = match args.fixed_updates {
        Some(updates) => Budget::Fixed { updates },
        None => Budget::Time {
            period_us: args.period_us,
            max_updates: args.max_updates,
        },
    };
    let origin = (
        (world.origin_m.0 * 1000.0).round() as i32,
        (world.origin_m.1 * 1000.0).round() as i32,
    );
    // The robot's settings made for the simulated sensor when it is not the paper's (no
    // outliers: the simulated lidar has none).
    let sensor = args
        .sigma_cells
        .and_then(|s| RunConfig::ROBOT.with_sensor(s, 0.0).ok());
    let robot = sensor
        .unwrap_or(RunConfig::ROBOT)
        .with_origin_mm(origin.0, origin.1)
        .with_max_range_mm(max_range_mm)
        .with_seed(args.seed)
        .with_budget(budget);
    // The simulator knows the true poses: sent as they are, they need no correction (matching
    // exact poses costs online F1, docs/firmware.md "Pose correction"); drifting odometry
    // (`--odometry-noise`) gets the robot's own default.
    let robot = match (args.correction, &args.odometry_noise) {
        (Some(c), _) => robot.with_correction(c.setting()),
        (None, None) => robot.with_correction(ogm_core::config::PoseCorrection::Off),
        (None, Some(_)) => robot,
    };
    let robot = match args.robot_odometry {
        Some(o) => robot.with_odometry_noise(o.setting()),
        None => robot,
    };
    args.sampler.apply(RunConfig {
        cell_mm: (world.resolution_m * 1000.0).round() as u32,
        tiles_per_scan: args.tiles_per_scan,
        count_tiles_per_scan: args.count_tiles_per_scan,
        visit_sweeps: args.visit_sweeps.unwrap_or(robot.visit_sweeps),
        ..robot
    })
}

/// The idle periods (µs) between the cumulative marks `secs` (increasing, positive).
pub(super) fn idle_periods_us(secs: &[f64]) -> anyhow::Result<Vec<u32>> {
    let mut prev = 0.0;
    let mut out = Vec::new();
    for &s in secs {
        ensure!(
            s.is_finite() && s > prev && s <= 600.0,
            "--idle: marks must increase, from above 0 to at most 600 s (got {secs:?})"
        );
        out.push(((s - prev) * 1e6).round() as u32);
        prev = s;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::firmware::args::RobotOdometryArg;
    use crate::firmware::odometry::parse_odometry;
    use ogm_core::config::{OdometryNoise, PoseCorrection};

    /// `--odometry-noise` alone leaves the robot its own (cheap) odometry settings and turns
    /// correction on; `--robot-odometry` tells it the model's.
    #[test]
    fn robot_odometry_reaches_the_settings() {
        let mut args = FirmwareArgs {
            odometry_noise: Some(parse_odometry("issue39").unwrap()),
            ..FirmwareArgs::default()
        };
        let world = firmware_world(&args).unwrap();
        let own = run_config(&world, &args, 10_000);
        assert_eq!(own.odometry, OdometryNoise::CHEAP_ROBOT);
        assert_eq!(own.correction, PoseCorrection::Match);
        args.robot_odometry = Some(RobotOdometryArg::Issue39);
        let told = run_config(&world, &args, 10_000);
        assert_eq!(told.odometry, OdometryNoise::ISSUE_39);
        assert_eq!(told, own.with_odometry_noise(OdometryNoise::ISSUE_39));
    }
}
