//! The robot loop in simulation: what a real robot's two serial lines carry.
//!
//! * **Lidar UART**: LD06 packets only, as the sensor sends them while the robot drives —
//!   10 turns a second, 38 packets of 12 points a turn (456 points, 0.79° apart: the LD06's
//!   4 500 points/s), each packet stamped with the
//!   sensor's millisecond clock and measured from where the sensor *is at that packet's time*
//!   (the simulator's trajectory, moved by the lidar's mounting), with the simulator's range
//!   noise.
//! * **Link**: the settings, then the robot's pose at its own rate (odometry at 25 Hz,
//!   stamped in the lidar's clock), and `Finish` once the device has reported the last turn.
//!
//! The trajectory passes through the simulated mission's scan poses, one every 100 ms, in
//! straight lines ([`Trajectory`]); the device must place every turn at the interpolated pose,
//! which [`pose_errors`] checks against the truth.

use std::ops::Range;

use anyhow::ensure;
use ogm_core::ld06::{self, Packet, Point, POINTS};
use ogm_core::wire::{HostMsg, RunConfig, ScanReport, WirePose};
use ogm_core::{Angle, Pose};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::lidar::cast_ray;
use crate::link::host_frame;
use crate::world::World;

/// Turn period, µs (LD06: 10 Hz).
pub const TURN_US: u64 = 100_000;
/// Packets per turn (12 points each: 456 points, `ogm_firmware::sizes::MPS2_AN386.max_beams`).
pub const PACKETS_PER_TURN: u64 = 38;
/// Default pose period, µs (25 Hz odometry: not a multiple of the packet period).
pub const POSE_PERIOD_US: u64 = 40_000;

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
    pub fn sensor_at(&self, mount: &WirePose, t_us: u64) -> (f64, f64, f64) {
        let (x, y, h) = self.at(t_us);
        let (c, s) = (h.cos(), h.sin());
        let (mx, my) = (f64::from(mount.x_mm), f64::from(mount.y_mm));
        (
            x + mx * c - my * s,
            y + mx * s + my * c,
            h + Angle(mount.heading).to_radians(),
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

/// The lidar bytes and pose messages of a robot driving through `poses` (one every 100 ms) in
/// `world`, with `config`'s mounting and range, the simulator's range noise `sigma_cells`,
/// poses every `pose_period_us`.
pub fn robot_input(
    world: &World,
    poses: &[Pose],
    config: &RunConfig,
    sigma_cells: f64,
    pose_period_us: u64,
    seed: u64,
) -> anyhow::Result<RobotInput> {
    ensure!(poses.len() >= 2, "a robot run needs at least two poses");
    ensure!(pose_period_us > 0, "the pose period must be positive");
    let trajectory = Trajectory::through(poses, TURN_US);
    let turns = (poses.len() - 1) as u64;
    let res_mm = world.resolution_m * 1000.0;
    let (ox, oy) = (world.origin_m.0 * 1000.0, world.origin_m.1 * 1000.0);
    let max_cells = f64::from(config.max_range_mm) / res_mm;
    ensure!(
        config.max_range_mm < u32::from(u16::MAX),
        "the LD06 reports ranges below 65.5 m"
    );
    let noise = Normal::new(0.0, sigma_cells.max(0.0))?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut lidar = Vec::new();
    // (time µs, line, bytes) of every packet and pose, merged into `schedule` below.
    let mut timed: Vec<(u64, Line, Range<usize>)> = Vec::new();
    // Every packet of `turns` turns, and the first of the next (it closes the last).
    for k in 0..=turns * PACKETS_PER_TURN {
        let (turn, j) = (k / PACKETS_PER_TURN, k % PACKETS_PER_TURN);
        let t_ms = turn * TURN_US / 1000 + j * TURN_US / 1000 / PACKETS_PER_TURN;
        // The packet's first and last point: 1/38 of a turn per packet, 1/456 per point.
        let start = (j * 36_000 / PACKETS_PER_TURN) as u16;
        let end = ((j * 36_000 + 33_000) / PACKETS_PER_TURN) as u16;
        let mut packet = Packet {
            speed_dps: 3600,
            start_cdeg: start,
            end_cdeg: end,
            timestamp_ms: (t_ms % 30_000) as u16,
            points: [Point::default(); POINTS],
        };
        let (sx, sy, sh) = trajectory.sensor_at(&config.mount, t_ms * 1000);
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
                        intensity: 200,
                    }
                }
            };
        }
        let at = lidar.len();
        lidar.extend_from_slice(&packet.to_bytes());
        timed.push((t_ms * 1000, Line::Lidar, at..lidar.len()));
    }
    let mut link = host_frame(&HostMsg::Config(*config));
    let mut schedule = vec![(Line::Link, 0..link.len())];
    // Poses from 0 until one at or after the last packet's time.
    let last_packet_us = turns * TURN_US;
    let mut t = 0;
    let mut sent = 0;
    loop {
        let at = link.len();
        link.extend(host_frame(&HostMsg::Pose {
            t_us: t,
            pose: WirePose::from(trajectory.pose_at(t)),
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
/// time.
pub fn pose_errors(reports: &[ScanReport], input: &RobotInput, config: &RunConfig) -> (f64, f64) {
    let (mut pos, mut head) = (0.0f64, 0.0f64);
    for r in reports {
        let want = input.trajectory.sensor_at(&config.mount, r.t_us);
        let got = Pose::from(r.pose);
        pos = pos.max((f64::from(got.x_mm) - want.0).hypot(f64::from(got.y_mm) - want.1));
        let dh = (got.heading.to_radians() - want.2).rem_euclid(std::f64::consts::TAU);
        head = head.max(dh.min(std::f64::consts::TAU - dh).to_degrees());
    }
    (pos, head)
}
