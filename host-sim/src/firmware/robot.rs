//! The robot loop in simulation: what a real robot's two serial lines carry.
//!
//! * **Lidar UART**: what the sensor sends while the robot drives, turn after turn, each point
//!   measured from where the sensor *is at its batch's time* (the simulator's trajectory, moved
//!   by the lidar's mounting), with the simulator's range noise:
//!   * LD06 ([`ScanPattern::LD06`]): 10 turns a second, 38 packets of 12 points a turn (456
//!     points, 0.79° apart: the LD06's 4 500 points/s), each packet stamped with the sensor's
//!     millisecond clock;
//!   * RPLIDAR A1 ([`ScanPattern::A1`]): the `SCAN` response descriptor, then 5-byte nodes,
//!     360 a turn 1° apart at 2 000 samples/s (5.6 turns a second), the first of each turn
//!     flagged `S`. The robot times them by their count (`LidarModel::Rplidar`).
//!
//!   The same pattern in either format carries the same beams at the same times, which is how
//!   a test shows the two lidars map alike.
//! * **Link**: the settings, then the robot's pose at its own rate (odometry at 25 Hz,
//!   stamped in the lidar's clock), and `Finish` once the device has reported the last turn.
//!
//! The trajectory passes through the simulated mission's scan poses, one per turn, in
//! straight lines ([`Trajectory`]); the device must place every turn at the interpolated pose,
//! which [`pose_errors`] checks against the truth.

use std::ops::Range;

use anyhow::ensure;
use ogm_core::config::{LidarModel, RunConfig};
use ogm_core::lidar::ld06::{self, Packet, Point, POINTS};
use ogm_core::lidar::rplidar::{self, Node};
use ogm_core::wire::{HostMsg, ScanReport};
use ogm_core::{Angle, Pose};
use ogm_field::stream::host_frame;
use ogm_field::world::World;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::sim::lidar::cast_ray;

/// Turn period of the LD06, µs (10 Hz).
pub const TURN_US: u64 = 100_000;
/// LD06 packets per turn (12 points each: 456, `ogm_firmware::sizes::MPS2_AN386.max_beams`).
pub const PACKETS_PER_TURN: u64 = 38;
/// Default pose period, µs (25 Hz odometry: not a multiple of the packet period).
pub const POSE_PERIOD_US: u64 = 40_000;

/// How a simulated lidar turns: its period and its points, taken in batches of 12 (an LD06
/// packet; for an RPLIDAR, 12 consecutive nodes measured from one pose).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScanPattern {
    /// Turn period, µs.
    pub turn_us: u64,
    /// Batches of 12 points per turn.
    pub batches: u64,
}

impl ScanPattern {
    /// The LD06: 100 ms, 456 points.
    pub const LD06: ScanPattern = ScanPattern {
        turn_us: TURN_US,
        batches: PACKETS_PER_TURN,
    };
    /// The RPLIDAR A1 in standard scan mode: 360 points 1° apart at 2 000 samples/s (500 µs
    /// apart, `LidarModel::Rplidar { sample_us: 500 }`): 180 ms a turn.
    pub const A1: ScanPattern = ScanPattern {
        turn_us: 180_000,
        batches: 30,
    };

    /// Points per turn.
    pub const fn points(&self) -> u64 {
        self.batches * POINTS as u64
    }

    /// The sensor's own pattern.
    pub fn of(lidar: &LidarModel) -> ScanPattern {
        match lidar {
            LidarModel::Rplidar { .. } => ScanPattern::A1,
            _ => ScanPattern::LD06,
        }
    }
}

/// The robot's true path: straight lines between poses at known times.
#[derive(Clone, Debug)]
pub struct Trajectory {
    knots: Vec<(u64, Pose)>,
}

impl Trajectory {
    /// Through `poses`, one every `period_us` from time 0.
    pub fn through(poses: &[Pose], period_us: u64) -> Self {
        Trajectory {
            knots: poses
                .iter()
                .enumerate()
                .map(|(k, p)| (k as u64 * period_us, *p))
                .collect(),
        }
    }

    /// Through `knots` (time µs, pose), in time order.
    pub fn from_knots(knots: Vec<(u64, Pose)>) -> Self {
        Trajectory { knots }
    }

    /// Where the robot is at `t_us` (held at the ends), in f64: (x mm, y mm, heading rad).
    pub fn at(&self, t_us: u64) -> (f64, f64, f64) {
        let i = self.knots.partition_point(|(t, _)| *t <= t_us);
        let (a, b) = match (
            i.checked_sub(1).and_then(|j| self.knots.get(j)),
            self.knots.get(i),
        ) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) => (a, a),
            (None, Some(b)) => (b, b),
            (None, None) => return (0.0, 0.0, 0.0),
        };
        let f = if b.0 > a.0 {
            (t_us - a.0) as f64 / (b.0 - a.0) as f64
        } else {
            0.0
        };
        let lerp = |p: i32, q: i32| f64::from(p) + f * (f64::from(q) - f64::from(p));
        let dh = f64::from(b.1.heading.signed_diff(a.1.heading)) / 65536.0 * std::f64::consts::TAU;
        (
            lerp(a.1.x_mm, b.1.x_mm),
            lerp(a.1.y_mm, b.1.y_mm),
            a.1.heading.to_radians() + f * dh,
        )
    }

    /// Where a lidar mounted at `mount` (`RunConfig::mount`: x forward, y left, mm; its 0°
    /// relative to the heading) is at `t_us`, in f64: (x mm, y mm, heading rad).
    pub fn sensor_at(&self, mount: &Pose, t_us: u64) -> (f64, f64, f64) {
        let (x, y, h) = self.at(t_us);
        let (c, s) = (h.cos(), h.sin());
        let (mx, my) = (f64::from(mount.x_mm), f64::from(mount.y_mm));
        (
            x + mx * c - my * s,
            y + mx * s + my * c,
            h + mount.heading.to_radians(),
        )
    }

    /// [`Trajectory::at`] rounded to a pose.
    pub fn pose_at(&self, t_us: u64) -> Pose {
        let (x, y, h) = self.at(t_us);
        Pose::new(x.round() as i32, y.round() as i32, Angle::from_radians(h))
    }

    /// Time of the last knot, µs.
    pub fn end_us(&self) -> u64 {
        self.knots.last().map_or(0, |k| k.0)
    }
}

/// The two serial lines of a simulated robot run.
#[derive(Clone, Debug)]
pub struct RobotInput {
    /// The link up to (not including) `Finish`: settings, then poses.
    pub link: Vec<u8>,
    /// The `Finish` frame, sent once the last turn is reported.
    pub finish: Vec<u8>,
    /// The lidar's bytes.
    pub lidar: Vec<u8>,
    /// Turns the device can complete (the lidar sends the first packet of one more).
    pub turns: u32,
    /// Poses sent.
    pub poses: usize,
    /// The truth.
    pub trajectory: Trajectory,
    /// The order a robot's two lines carry these bytes in: byte ranges of `link` and `lidar`,
    /// by the time they describe (settings first; a packet before a pose of the same time).
    /// A real robot's lines run in step like this; a test that writes each line on its own
    /// lets one run seconds ahead, which no robot does.
    pub schedule: Vec<(Line, Range<usize>)>,
}

/// One of the robot's two serial lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Line {
    /// The host link (settings, poses).
    Link,
    /// The lidar's own UART.
    Lidar,
}

/// The lidar bytes and pose messages of a robot driving through `poses` (one per turn of
/// `pattern`) in `world`, with `config`'s lidar, mounting and range, the simulator's range noise
/// `sigma_cells`, poses every `pose_period_us`.
pub fn robot_input(
    world: &World,
    poses: &[Pose],
    config: &RunConfig,
    pattern: ScanPattern,
    sigma_cells: f64,
    pose_period_us: u64,
    seed: u64,
) -> anyhow::Result<RobotInput> {
    ensure!(poses.len() >= 2, "a robot run needs at least two poses");
    ensure!(pose_period_us > 0, "the pose period must be positive");
    ensure!(
        pattern.batches > 0 && pattern.turn_us % 1000 == 0,
        "a scan pattern needs batches and a turn of whole milliseconds"
    );
    // Batches start on whole milliseconds (the LD06's clock).
    let turn_ms = pattern.turn_us / 1000;
    if let LidarModel::Rplidar { sample_us } = config.lidar {
        ensure!(
            turn_ms % pattern.batches == 0
                && u64::from(sample_us) * pattern.points() == pattern.turn_us,
            "the RPLIDAR's sample period ({sample_us} µs) must be the pattern's point period \
             ({} µs), in batches of whole ms: the robot times nodes by their count",
            pattern.turn_us as f64 / pattern.points() as f64
        );
    }
    let trajectory = Trajectory::through(poses, pattern.turn_us);
    let turns = (poses.len() - 1) as u64;
    let res_mm = world.resolution_m * 1000.0;
    let (ox, oy) = (world.origin_m.0 * 1000.0, world.origin_m.1 * 1000.0);
    let max_cells = f64::from(config.max_range_mm) / res_mm;
    let max_mm = match config.lidar {
        LidarModel::Rplidar { .. } => rplidar::MAX_RANGE_MM,
        _ => u32::from(u16::MAX) - 1,
    };
    ensure!(
        config.max_range_mm <= max_mm,
        "the lidar reports ranges up to {max_mm} mm, below the settings' maximum range"
    );
    let noise = Normal::new(0.0, sigma_cells.max(0.0))?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut lidar = Vec::new();
    if let LidarModel::Rplidar { .. } = config.lidar {
        // The answer to the `SCAN` the robot sends once configured.
        lidar.extend_from_slice(&rplidar::SCAN_DESCRIPTOR);
    }
    // (time µs, line, bytes) of every batch and pose, merged into `schedule` below.
    let mut timed: Vec<(u64, Line, Range<usize>)> = Vec::new();
    // Every batch of `turns` turns, and the first of the next (it closes the last).
    let per_turn = pattern.batches;
    for k in 0..=turns * per_turn {
        let (turn, j) = (k / per_turn, k % per_turn);
        let t_ms = turn * turn_ms + j * turn_ms / per_turn;
        let t_us = t_ms * 1000;
        // The batch's first and last point: 1/batches of a turn per batch, 1/points per point.
        let start = (j * 36_000 / per_turn) as u16;
        let end = ((j * 36_000 + 33_000) / per_turn) as u16;
        let mut packet = Packet {
            speed_dps: (360_000_000 / pattern.turn_us) as u16,
            start_cdeg: start,
            end_cdeg: end,
            timestamp_ms: (t_ms % 30_000) as u16,
            points: [Point::default(); POINTS],
        };
        let (sx, sy, sh) = trajectory.sensor_at(&config.mount, t_us);
        for i in 0..POINTS {
            // Along the angle the device will give the point.
            let dir = sh + ld06::beam_angle(packet.angle_cdeg(i)).to_radians();
            let (cx, cy) = ((sx - ox) / res_mm, (sy - oy) / res_mm);
            let limit = max_cells + 4.0 * sigma_cells;
            packet.points[i] = match cast_ray(world, cx, cy, dir, limit) {
                None => Point::default(),
                Some(d) => {
                    let z = d + noise.sample(&mut rng);
                    let mm = (z.max(0.0) * res_mm).round();
                    Point {
                        distance_mm: if z >= max_cells {
                            0
                        } else {
                            mm.max(1.0) as u16
                        },
                        intensity: ld06::HIT_INTENSITY,
                    }
                }
            };
        }
        let at = lidar.len();
        match config.lidar {
            LidarModel::Rplidar { .. } => {
                for i in 0..POINTS {
                    let Some(beam) = packet.beam(i) else { continue };
                    let node = Node::from_beam(&beam, j == 0 && i == 0);
                    lidar.extend_from_slice(&node.to_bytes());
                }
            }
            _ => lidar.extend_from_slice(&packet.to_bytes()),
        }
        timed.push((t_us, Line::Lidar, at..lidar.len()));
    }
    let mut link = host_frame(&HostMsg::Config(*config));
    let mut schedule = vec![(Line::Link, 0..link.len())];
    // Poses from 0 until one at or after the last batch's time.
    let last_packet_us = turns * pattern.turn_us;
    let mut t = 0;
    let mut sent = 0;
    loop {
        let at = link.len();
        link.extend(host_frame(&HostMsg::Pose {
            t_us: t,
            pose: trajectory.pose_at(t),
        }));
        timed.push((t, Line::Link, at..link.len()));
        sent += 1;
        if t >= last_packet_us {
            break;
        }
        t += pose_period_us;
    }
    // At equal times the packet first: it waits for a pose at or after its own time.
    timed.sort_by_key(|(t, line, _)| (*t, *line == Line::Link));
    schedule.extend(timed.into_iter().map(|(_, line, r)| (line, r)));
    Ok(RobotInput {
        link,
        finish: host_frame(&HostMsg::Finish),
        lidar,
        turns: turns as u32,
        poses: sent,
        trajectory,
        schedule,
    })
}

/// How far the device's turn poses are from the truth: the largest position error (mm) and
/// heading error (degrees) over `reports`, each against the true sensor pose at the turn's
/// time. The turn's pose as placed by the pose messages (`ScanReport::odometry`), not the pose
/// it was mapped at after the scan matcher's correction (`pose`): this checks the placement.
pub fn pose_errors(reports: &[ScanReport], input: &RobotInput, config: &RunConfig) -> (f64, f64) {
    let (mut pos, mut head) = (0.0f64, 0.0f64);
    for r in reports {
        let want = input.trajectory.sensor_at(&config.mount, r.t_us);
        let got = r.odometry;
        pos = pos.max((f64::from(got.x_mm) - want.0).hypot(f64::from(got.y_mm) - want.1));
        let dh = (got.heading.to_radians() - want.2).rem_euclid(std::f64::consts::TAU);
        head = head.max(dh.min(std::f64::consts::TAU - dh).to_degrees());
    }
    (pos, head)
}
