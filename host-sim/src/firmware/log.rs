//! A real laser log through the robot's own lidar UART (`host-sim firmware --log FILE`).
//!
//! Each of the log's scans becomes one LD06 turn, its pose two pose messages: the robot stands
//! at the scan's pose for the turn (100 ms), then drives to the next pose in the next 100 ms, in
//! which the lidar sends nothing. The device places every packet at the pose interpolated at its
//! time, which during a turn is the scan's pose exactly, so the turn it assembles is the log's
//! scan.
//!
//! * **Angles.** The LD06 reports angles in 0.01° steps, clockwise, 12 evenly spaced points a
//!   packet. The scan's beams are sorted clockwise and packed 12 at a time. A 180° scanner's
//!   beams would run through the LD06's 0° and split the turn, so the lidar is "mounted"
//!   ([`RunConfig::mount`]) turned by the quarter turn that puts the widest gap between the
//!   beams at 0°. A quarter turn is exact both in 0.01° and in ogm-core's binary angles, so a
//!   beam at a whole multiple of 0.01° (every shared log's: 0.5° and 1° steps) arrives at
//!   exactly its logged angle; others are rounded, and counted ([`LogEncoding::inexact_angles`]).
//! * **Padding.** A turn whose beams are not a multiple of 12 is padded with points continuing
//!   its spacing at [`PAD_MM`], closer than the settings' minimum range [`MIN_RANGE_MM`]: the
//!   mapper drops them (counted in the scan report's `beams_dropped`), so they change nothing.
//! * **Ranges.** A no-return is the LD06's 0; a hit is its millimetres, at most 65 535 (a hit at
//!   or beyond the mapping range frees up to it like a no-return, so with a range cap below
//!   65.5 m this changes nothing); a 0 mm hit, which the LD06 cannot send, is sent as
//!   [`PAD_MM`] and so dropped. Both are counted.

use std::ops::Range;

use anyhow::ensure;
use ogm_core::config::{LidarModel, RunConfig};
use ogm_core::lidar::ld06::{self, Packet, Point, POINTS};
use ogm_core::wire::HostMsg;
use ogm_core::{Angle, Pose};
use ogm_field::stream::host_frame;
use serde::Serialize;

use super::robot::{Line, RobotInput, Trajectory, TURN_US};
use crate::sim::explore::ScanRecord;

/// Range of a padding point, mm: below [`MIN_RANGE_MM`], so the mapper drops it.
pub const PAD_MM: u16 = 1;
/// The minimum range a log run's settings need (see [`PAD_MM`]).
pub const MIN_RANGE_MM: u32 = 2;

/// How a log's scans were sent as LD06 turns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LogEncoding {
    /// The lidar's mounting turn, degrees (0, 90, 180 or 270).
    pub mount_deg: u16,
    /// Turns sent (one per scan).
    pub turns: usize,
    /// The log's beams sent.
    pub beams: u64,
    /// Padding points sent (dropped by the mapper).
    pub padding_points: u64,
    /// Beams whose angle the LD06 could not carry exactly (off the 0.01° grid, or not evenly
    /// spaced within their packet).
    pub inexact_angles: u64,
    /// Hits sent at another range: beyond 65 535 mm, or 0 mm (sent as [`PAD_MM`]).
    pub clipped_ranges: u64,
}

/// The quarter turn to mount the lidar at so that no scan of `scans` crosses the LD06's 0°:
/// the one that leaves the widest gap between the clockwise-first and -last beams.
pub fn mount_heading(scans: &[ScanRecord]) -> Angle {
    // (gap, its smaller side from 0°): the gap, then the mount that centres it on 0°.
    let mut best = ((0u32, 0u32), Angle(0));
    for q in 0..4u16 {
        let mount = Angle(q << 14);
        let (mut lo, mut hi) = (u32::MAX, 0u32);
        for b in scans.iter().flat_map(|s| &s.beams) {
            let t = u32::from(ld06::theta_cdeg(b.angle.wrapping_sub(mount)));
            lo = lo.min(t);
            hi = hi.max(t);
        }
        let score = if lo > hi {
            (36_000, 18_000)
        } else {
            (lo + 36_000 - hi, lo.min(36_000 - hi))
        };
        if score > best.0 {
            best = (score, mount);
        }
    }
    best.1
}

/// The settings a log run needs on top of `base`: the lidar an LD06 mounted at `mount`
/// ([`mount_heading`]) on the robot's centre, and the minimum range that drops the padding.
pub fn log_config(base: RunConfig, mount: Angle) -> RunConfig {
    RunConfig {
        mount: Pose {
            x_mm: 0,
            y_mm: 0,
            heading: mount,
        },
        lidar: LidarModel::Ld06,
        min_range_mm: base.min_range_mm.max(MIN_RANGE_MM),
        ..base
    }
}

/// The two serial lines of a robot replaying `scans` with `config` (from [`log_config`]).
pub fn log_input(
    scans: &[ScanRecord],
    config: &RunConfig,
) -> anyhow::Result<(RobotInput, LogEncoding)> {
    ensure!(!scans.is_empty(), "the log has no scans");
    ensure!(
        config.lidar == LidarModel::Ld06
            && config.mount.x_mm == 0
            && config.mount.y_mm == 0
            && config.mount.heading.0 & 0x3fff == 0
            && config.min_range_mm > u32::from(PAD_MM),
        "a log run needs the settings of log_config (an LD06 on the robot's centre turned by \
         a quarter turn, minimum range above {PAD_MM} mm)"
    );
    let mount = config.mount.heading;
    let mut enc = LogEncoding {
        mount_deg: (u32::from(mount.0) * 360 / 65_536) as u16,
        turns: scans.len(),
        ..LogEncoding::default()
    };
    // Turn k stands at its pose over [2kT, 2kT + T); the robot drives to the next in the next T.
    let turn_ms = TURN_US / 1000;
    let mut knots = Vec::with_capacity(2 * scans.len() + 1);
    let mut lidar = Vec::new();
    let mut timed: Vec<(u64, Line, Range<usize>)> = Vec::new();
    for (k, scan) in scans.iter().enumerate() {
        let t0_ms = 2 * k as u64 * turn_ms;
        knots.push((t0_ms * 1000, scan.pose));
        knots.push(((t0_ms + turn_ms) * 1000, scan.pose));
        let packets = turn_packets(scan, mount, &mut enc);
        let n = packets.len() as u64;
        for (j, mut packet) in packets.into_iter().enumerate() {
            let t_ms = t0_ms + j as u64 * turn_ms / n.max(1);
            packet.timestamp_ms = (t_ms % 30_000) as u16;
            let at = lidar.len();
            lidar.extend_from_slice(&packet.to_bytes());
            timed.push((t_ms * 1000, Line::Lidar, at..lidar.len()));
        }
    }
    // The first packet of one more turn closes the last (the device ends a turn when the next
    // begins); that turn is never completed.
    let end_ms = 2 * scans.len() as u64 * turn_ms;
    if let Some(last) = scans.last() {
        knots.push((end_ms * 1000, last.pose));
        let mut closing = turn_packets(last, mount, &mut LogEncoding::default());
        if let Some(p) = closing.first_mut() {
            p.timestamp_ms = (end_ms % 30_000) as u16;
            let at = lidar.len();
            lidar.extend_from_slice(&p.to_bytes());
            timed.push((end_ms * 1000, Line::Lidar, at..lidar.len()));
        }
    }
    let mut link = host_frame(&HostMsg::Config(*config));
    let mut schedule = vec![(Line::Link, 0..link.len())];
    for &(t_us, pose) in &knots {
        let at = link.len();
        link.extend(host_frame(&HostMsg::Pose { t_us, pose }));
        timed.push((t_us, Line::Link, at..link.len()));
    }
    // At equal times the packet first: it waits for a pose at or after its own time.
    timed.sort_by_key(|(t, line, _)| (*t, *line == Line::Link));
    schedule.extend(timed.into_iter().map(|(_, line, r)| (line, r)));
    Ok((
        RobotInput {
            link,
            finish: host_frame(&HostMsg::Finish),
            lidar,
            turns: u32::try_from(scans.len()).unwrap_or(u32::MAX),
            poses: knots.len(),
            trajectory: Trajectory::from_knots(knots),
            schedule,
        },
        enc,
    ))
}

/// The beams of `scan` as the firmware's turn holds them, and the sensor's pose: relative to
/// the lidar mounted at `mount`, clockwise, with the padding (dropped by the mapper): what an
/// unbounded host map of the same scans inserts.
pub fn firmware_scan(scan: &ScanRecord, mount: Angle) -> (Pose, Vec<ogm_core::Beam>) {
    let beams = turn_packets(scan, mount, &mut LogEncoding::default())
        .iter()
        .flat_map(|p| (0..POINTS).filter_map(|i| p.beam(i)))
        .collect();
    let sensor = Pose {
        heading: scan.pose.heading.wrapping_add(mount),
        ..scan.pose
    };
    (sensor, beams)
}

/// One scan as LD06 packets (timestamps left at 0), counting into `enc`.
fn turn_packets(scan: &ScanRecord, mount: Angle, enc: &mut LogEncoding) -> Vec<Packet> {
    // (LD06 angle, distance, the angle the beam must arrive at) clockwise.
    let mut points: Vec<(u16, u16, Angle)> = scan
        .beams
        .iter()
        .map(|b| {
            let sensor = b.angle.wrapping_sub(mount);
            let theta = ld06::theta_cdeg(sensor);
            let mm = match b.range {
                ogm_core::Range::NoReturn => 0,
                ogm_core::Range::Hit(mm) => match u16::try_from(mm) {
                    Ok(0) => {
                        enc.clipped_ranges += 1;
                        PAD_MM
                    }
                    Ok(mm) => mm,
                    Err(_) => {
                        enc.clipped_ranges += 1;
                        u16::MAX
                    }
                },
            };
            (theta, mm, sensor)
        })
        .collect();
    points.sort_by_key(|p| p.0);
    enc.beams += points.len() as u64;
    // The padding continues the scan's spacing (its smallest step; 1° for a lone beam).
    let step = points
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .filter(|d| *d > 0)
        .min()
        .unwrap_or(100);
    let turn_cdeg = 36_000u32;
    points
        .chunks(POINTS)
        .map(|chunk| {
            let mut angles = [0u16; POINTS];
            let mut pts = [Point::default(); POINTS];
            for i in 0..POINTS {
                let (theta, mm) = match chunk.get(i) {
                    Some(p) => (p.0, p.1),
                    None => {
                        enc.padding_points += 1;
                        let prev = u32::from(angles[i - 1]);
                        (((prev + u32::from(step)) % turn_cdeg) as u16, PAD_MM)
                    }
                };
                angles[i] = theta;
                pts[i] = Point {
                    distance_mm: mm,
                    intensity: if mm == 0 { 0 } else { ld06::HIT_INTENSITY },
                };
            }
            let packet = Packet {
                speed_dps: (360_000_000 / TURN_US) as u16,
                start_cdeg: angles[0],
                end_cdeg: angles[POINTS - 1],
                timestamp_ms: 0,
                points: pts,
            };
            // The device interpolates the points' angles between the first and the last.
            for (i, p) in chunk.iter().enumerate() {
                if ld06::beam_angle(packet.angle_cdeg(i)) != p.2 {
                    enc.inexact_angles += 1;
                }
            }
            packet
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use ogm_core::config::Budget;
    use ogm_core::lidar::ld06::Ld06Parser;
    use ogm_core::session::{Owned, Session};
    use ogm_core::{Beam, Range};

    use super::super::replay::{replay, FIRMWARE_SIZES};
    use super::*;

    /// `n` beams from −90° in `step_deg` steps, from `pose` inside the box ±(2.4 m, 1.7 m)
    /// (its walls at the ranges an exact scanner measures; beyond 6 m no return).
    fn room_scan(pose: Pose, n: usize, step_deg: f64) -> ScanRecord {
        let (px, py) = (f64::from(pose.x_mm), f64::from(pose.y_mm));
        let beams = (0..n)
            .map(|i| {
                let angle = Angle::from_radians((-90.0 + i as f64 * step_deg).to_radians());
                let phi = pose.heading.wrapping_add(angle).to_radians();
                let (c, s) = (phi.cos(), phi.sin());
                let tx = if c > 1e-9 {
                    (2400.0 - px) / c
                } else if c < -1e-9 {
                    (-2400.0 - px) / c
                } else {
                    f64::INFINITY
                };
                let ty = if s > 1e-9 {
                    (1700.0 - py) / s
                } else if s < -1e-9 {
                    (-1700.0 - py) / s
                } else {
                    f64::INFINITY
                };
                let t = tx.min(ty);
                let range = if t < 6000.0 {
                    Range::Hit(t.round() as u32)
                } else {
                    Range::NoReturn
                };
                Beam { angle, range }
            })
            .collect();
        ScanRecord { pose, beams }
    }

    fn scans(n: usize, step_deg: f64) -> Vec<ScanRecord> {
        [
            (0, 0, 0),
            (300, -200, 20),
            (-700, 400, 95),
            (1200, 900, 200),
            (-1500, -1000, 300),
        ]
        .into_iter()
        .map(|(x, y, deg)| {
            let pose = Pose::new(x, y, Angle::from_radians(f64::from(deg).to_radians()));
            room_scan(pose, n, step_deg)
        })
        .collect()
    }

    fn config(mount: Angle) -> RunConfig {
        log_config(
            RunConfig::ROBOT
                .with_origin_mm(-6400, -6400)
                .with_max_range_mm(8000)
                .with_budget(Budget::Fixed { updates: 0 }),
            mount,
        )
    }

    #[test]
    fn a_front_scanner_is_mounted_backwards_and_its_beams_arrive_as_logged() {
        for (n, step, pad) in [(181, 1.0, 11), (180, 1.0, 0), (361, 0.5, 11), (360, 0.5, 0)] {
            let log = scans(n, step);
            let mount = mount_heading(&log);
            assert_eq!(mount, Angle(0x8000), "{n} beams");
            let (input, enc) = log_input(&log, &config(mount)).unwrap();
            assert_eq!(enc.inexact_angles, 0, "{n} beams");
            assert_eq!(enc.padding_points, pad * log.len() as u64, "{n} beams");
            assert_eq!(enc.beams, (n * log.len()) as u64);
            // The lidar's bytes, parsed: each turn's points are the scan's beams (and padding).
            let mut got: Vec<Beam> = Vec::new();
            Ld06Parser::new().feed(&input.lidar, |p| {
                let p = p.unwrap();
                got.extend((0..POINTS).filter_map(|i| p.beam(i)));
            });
            let per_turn = n.div_ceil(POINTS) * POINTS;
            assert_eq!(got.len(), per_turn * log.len() + POINTS, "{n} beams");
            for (k, scan) in log.iter().enumerate() {
                let turn = &got[k * per_turn..(k + 1) * per_turn];
                for b in &scan.beams {
                    let want = Beam {
                        angle: b.angle.wrapping_sub(mount),
                        range: b.range,
                    };
                    assert!(
                        turn.contains(&want),
                        "{n} beams: {b:?} not sent in turn {k}"
                    );
                }
            }
        }
    }

    /// The firmware's own application (on the host), fed the log's LD06 bytes and poses,
    /// maps exactly what inserting the logged scans at their poses maps.
    #[test]
    fn the_firmware_maps_a_log_as_a_direct_insert_does() {
        for (n, step) in [(181, 1.0), (361, 0.5)] {
            let log = scans(n, step);
            let cfg = config(mount_heading(&log));
            let (input, _) = log_input(&log, &cfg).unwrap();
            let link = [&input.link[..], &input.finish[..]].concat();
            let fw = replay::<u8, _>(
                &link,
                &input.lidar,
                FIRMWARE_SIZES,
                |_| Some(0),
                |_, _| {},
                |m, _| m.map(|m| m.log_odds().to_vec()),
            )
            .unwrap()
            .unwrap();
            let mut direct = Session::new(cfg, Owned::<u8>::buffers(&FIRMWARE_SIZES)).unwrap();
            for s in &log {
                // The scan as the LD06 delivers it: from the sensor's pose, clockwise (the
                // mapper's result depends on the beams' order in a few cells).
                let m = cfg.mount.heading;
                let sensor = Pose {
                    heading: s.pose.heading.wrapping_add(m),
                    ..s.pose
                };
                let mut beams: Vec<Beam> = s
                    .beams
                    .iter()
                    .map(|b| Beam {
                        angle: b.angle.wrapping_sub(m),
                        range: b.range,
                    })
                    .collect();
                beams.sort_by_key(|b| ld06::theta_cdeg(b.angle));
                direct.insert(&sensor, &beams).unwrap();
            }
            let want = direct.log_odds();
            assert!(
                want.iter().filter(|l| l.raw() > 0).count() > 200,
                "{n} beams"
            );
            let differ = fw.iter().zip(want).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{n} beams: {differ} cells differ");
        }
    }
}
