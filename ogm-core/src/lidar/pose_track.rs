//! Poses that arrive on their own: a short history of timestamped robot poses (from odometry
//! or a localiser, at their own rate), interpolated to the time of each lidar packet, and the
//! lidar's mounting on the robot.
//!
//! A spinning lidar measures while the robot moves (LD06: one turn in 100 ms, a packet every
//! ~2.2 ms), so each packet is placed at the robot's pose *at its own time*, not at one pose
//! per scan. [`PoseTrack`] keeps the last `N` poses (fixed memory) and answers
//! [`PoseTrack::at`] by linear interpolation of position and shortest-arc interpolation of
//! heading between the two poses around that time; [`Mount::sensor_pose`] then moves the robot
//! pose to the sensor's.
//!
//! Integer arithmetic throughout (i64 intermediates: no overflow for any `i32` position and
//! `u64` time); tested against an f64 reference.

use crate::types::angle::{Angle, Q30_ONE};
use crate::types::geometry::Pose;

/// Why a pose could not be added or given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TrackError {
    /// A pose not newer than the last one (dropped: poses must come in time order).
    OutOfOrder,
    /// No pose yet.
    Empty,
    /// The time is before the oldest pose kept.
    TooOld,
    /// The time is after the newest pose by more than the allowed extrapolation.
    TooNew,
}

impl core::fmt::Display for TrackError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            TrackError::OutOfOrder => "pose older than the last one",
            TrackError::Empty => "no pose yet",
            TrackError::TooOld => "time before the oldest pose kept",
            TrackError::TooNew => "time after the newest pose (beyond the extrapolation limit)",
        })
    }
}

impl core::error::Error for TrackError {}

/// A robot pose and when it was valid (µs of a clock shared with the lidar's timestamps).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StampedPose {
    /// Time, µs.
    pub t_us: u64,
    /// The pose.
    pub pose: Pose,
}

/// The last `N` poses, in time order.
#[derive(Clone, Debug)]
pub struct PoseTrack<const N: usize> {
    ring: heapless::Deque<StampedPose, N>,
    hold_us: u64,
}

impl<const N: usize> PoseTrack<N> {
    /// An empty track that holds the newest pose for up to `hold_us` after its time (a lidar
    /// packet may arrive before the pose that follows it; beyond that, [`TrackError::TooNew`]).
    pub const fn new(hold_us: u64) -> Self {
        PoseTrack {
            ring: heapless::Deque::new(),
            hold_us,
        }
    }

    /// Adds a pose newer than every pose so far; the oldest is forgotten when `N` are kept.
    pub fn push(&mut self, t_us: u64, pose: Pose) -> Result<(), TrackError> {
        if self.ring.back().is_some_and(|b| b.t_us >= t_us) {
            return Err(TrackError::OutOfOrder);
        }
        if self.ring.is_full() {
            self.ring.pop_front();
        }
        // Cannot fail: there is room now (N ≥ 1; with N = 0 nothing is ever kept).
        let _ = self.ring.push_back(StampedPose { t_us, pose });
        Ok(())
    }

    /// The newest pose.
    pub fn latest(&self) -> Option<StampedPose> {
        self.ring.back().copied()
    }

    /// The second-oldest pose kept (the oldest once the oldest is forgotten).
    pub fn second_oldest(&self) -> Option<StampedPose> {
        self.ring.iter().nth(1).copied()
    }

    /// Poses kept.
    pub fn len(&self) -> usize {
        self.ring.len()
    }

    /// Whether no pose is kept.
    pub fn is_empty(&self) -> bool {
        self.ring.is_empty()
    }

    /// Forgets every pose (e.g. after the localiser relocalised).
    pub fn clear(&mut self) {
        self.ring.clear();
    }

    /// The robot's pose at `t_us`: interpolated between the poses around it, the newest one
    /// for up to `hold_us` after it.
    pub fn at(&self, t_us: u64) -> Result<Pose, TrackError> {
        let (first, last) = match (self.ring.front(), self.ring.back()) {
            (Some(f), Some(l)) => (*f, *l),
            _ => return Err(TrackError::Empty),
        };
        if t_us < first.t_us {
            return Err(TrackError::TooOld);
        }
        if t_us >= last.t_us {
            return if t_us - last.t_us <= self.hold_us {
                Ok(last.pose)
            } else {
                Err(TrackError::TooNew)
            };
        }
        // first.t ≤ t < last.t: some consecutive pair brackets it (N is small: a linear scan).
        let mut prev = first;
        for s in self.ring.iter().skip(1) {
            if t_us < s.t_us {
                return Ok(interpolate(&prev, s, t_us));
            }
            prev = *s;
        }
        Ok(last.pose)
    }
}

/// The pose at `t` on the straight line from `a` to `b` (`a.t ≤ t < b.t`), heading along the
/// shorter arc; rounded to the nearest mm and angle unit.
pub fn interpolate(a: &StampedPose, b: &StampedPose, t_us: u64) -> Pose {
    let span = b.t_us.saturating_sub(a.t_us).max(1);
    let dt = t_us.saturating_sub(a.t_us).min(span);
    // `dt / span` in Q30, in 64-bit arithmetic (no 128-bit division on a 32-bit MCU): both
    // scaled down first so that `span < 2^34` (poses more than 4.8 h apart lose sub-µs
    // resolution, nothing else).
    let shift = (64 - span.leading_zeros()).saturating_sub(34);
    let (dt, span) = (dt >> shift, (span >> shift).max(1));
    let f = ((dt << 30) / span) as i64; // ≤ 2^30
                                        // |q − p| < 2^32 and f ≤ 2^30: the product fits an i64.
    let lerp = |p: i32, q: i32| -> i32 {
        let d = i64::from(q) - i64::from(p);
        let v = i64::from(p) + ((d * f + (1 << 29)) >> 30);
        v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
    };
    let dh = i64::from(b.pose.heading.signed_diff(a.pose.heading));
    let turn = ((dh * f + (1 << 29)) >> 30) as i16;
    Pose {
        x_mm: lerp(a.pose.x_mm, b.pose.x_mm),
        y_mm: lerp(a.pose.y_mm, b.pose.y_mm),
        heading: a.pose.heading.wrapping_add(Angle(turn as u16)),
    }
}

/// Where the lidar sits on the robot: its origin in the robot's frame (x forward, y left, mm)
/// and its zero direction relative to the robot's heading.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Mount {
    /// Forward offset, mm.
    pub x_mm: i32,
    /// Leftward offset, mm.
    pub y_mm: i32,
    /// The sensor's 0° relative to the robot's heading.
    pub yaw: Angle,
}

impl From<Pose> for Mount {
    /// A mount given as a pose in the robot's frame ([`crate::RunConfig::mount`]).
    fn from(p: Pose) -> Self {
        Mount {
            x_mm: p.x_mm,
            y_mm: p.y_mm,
            yaw: p.heading,
        }
    }
}

impl Mount {
    /// The lidar at the robot's origin, facing its heading.
    pub const ZERO: Mount = Mount {
        x_mm: 0,
        y_mm: 0,
        yaw: Angle(0),
    };

    /// The sensor's pose in the world when the robot is at `robot` (rounded to the nearest mm;
    /// saturating at the `i32` range).
    pub fn sensor_pose(&self, robot: &Pose) -> Pose {
        let (c, s) = robot.heading.cos_sin_q30();
        let (c, s) = (i64::from(c), i64::from(s));
        let (mx, my) = (i64::from(self.x_mm), i64::from(self.y_mm));
        let half = i64::from(Q30_ONE) / 2;
        let dx = (mx * c - my * s + half) >> 30;
        let dy = (mx * s + my * c + half) >> 30;
        let sat = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        Pose {
            x_mm: sat(i64::from(robot.x_mm) + dx),
            y_mm: sat(i64::from(robot.y_mm) + dy),
            heading: robot.heading.wrapping_add(self.yaw),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: i32, y: i32, h: u16) -> Pose {
        Pose::new(x, y, Angle(h))
    }

    /// f64 reference of [`interpolate`] + [`Mount::sensor_pose`].
    fn reference(a: &StampedPose, b: &StampedPose, t: u64, m: &Mount) -> (f64, f64, f64) {
        let f = (t - a.t_us) as f64 / (b.t_us - a.t_us) as f64;
        let x = f64::from(a.pose.x_mm) + f * f64::from(b.pose.x_mm - a.pose.x_mm);
        let y = f64::from(a.pose.y_mm) + f * f64::from(b.pose.y_mm - a.pose.y_mm);
        let mut dh = f64::from(b.pose.heading.0) - f64::from(a.pose.heading.0);
        if dh > 32768.0 {
            dh -= 65536.0;
        } else if dh < -32768.0 {
            dh += 65536.0;
        }
        let h = (f64::from(a.pose.heading.0) + f * dh).rem_euclid(65536.0);
        let th = h / 65536.0 * std::f64::consts::TAU;
        let sx = x + f64::from(m.x_mm) * th.cos() - f64::from(m.y_mm) * th.sin();
        let sy = y + f64::from(m.x_mm) * th.sin() + f64::from(m.y_mm) * th.cos();
        (sx, sy, (h + f64::from(m.yaw.0)).rem_euclid(65536.0))
    }

    #[test]
    fn interpolation_and_mounting_match_the_f64_reference() {
        let mut seed = 0x1234_5678_9abc_def0u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..20_000 {
            let t0 = next() % 1_000_000_000;
            let a = StampedPose {
                t_us: t0,
                pose: pose(
                    (next() % 200_000) as i32 - 100_000,
                    (next() % 200_000) as i32 - 100_000,
                    next() as u16,
                ),
            };
            let b = StampedPose {
                t_us: t0 + 1 + next() % 200_000,
                pose: pose(
                    a.pose.x_mm + (next() % 2001) as i32 - 1000,
                    a.pose.y_mm + (next() % 2001) as i32 - 1000,
                    next() as u16,
                ),
            };
            let t = a.t_us + next() % (b.t_us - a.t_us);
            let m = Mount {
                x_mm: (next() % 601) as i32 - 300,
                y_mm: (next() % 601) as i32 - 300,
                yaw: Angle(next() as u16),
            };
            let got = m.sensor_pose(&interpolate(&a, &b, t));
            let (rx, ry, rh) = reference(&a, &b, t, &m);
            assert!((f64::from(got.x_mm) - rx).abs() <= 1.5, "{got:?} vs {rx}");
            assert!((f64::from(got.y_mm) - ry).abs() <= 1.5, "{got:?} vs {ry}");
            let dh = (f64::from(got.heading.0) - rh).rem_euclid(65536.0);
            assert!(dh.min(65536.0 - dh) <= 1.0, "{got:?} vs {rh}");
        }
    }

    #[test]
    fn a_track_answers_inside_its_window_and_says_why_outside() {
        let mut tr: PoseTrack<4> = PoseTrack::new(50_000);
        assert_eq!(tr.at(0), Err(TrackError::Empty));
        for k in 0..6u64 {
            tr.push(1_000 + 100_000 * k, pose(1000 * k as i32, 0, 0))
                .unwrap();
        }
        assert_eq!(tr.len(), 4);
        // Oldest kept: k = 2 at t = 201 000.
        assert_eq!(tr.at(200_999), Err(TrackError::TooOld));
        assert_eq!(tr.at(201_000).unwrap().x_mm, 2000);
        assert_eq!(tr.at(251_000).unwrap().x_mm, 2500);
        assert_eq!(tr.at(475_999).unwrap().x_mm, 4750);
        assert_eq!(tr.at(501_000).unwrap().x_mm, 5000);
        assert_eq!(tr.at(551_000).unwrap().x_mm, 5000); // held
        assert_eq!(tr.at(551_001), Err(TrackError::TooNew));
        assert_eq!(tr.push(501_000, pose(0, 0, 0)), Err(TrackError::OutOfOrder));
        assert_eq!(tr.latest().map(|s| s.t_us), Some(501_000));
    }

    #[test]
    fn heading_takes_the_short_way_round() {
        let a = StampedPose {
            t_us: 0,
            pose: pose(0, 0, 65_000),
        };
        let b = StampedPose {
            t_us: 100,
            pose: pose(0, 0, 500),
        };
        // 65 000 → 500 is +1 036 units across 0, not −64 500.
        assert_eq!(interpolate(&a, &b, 50).heading, Angle(65_518));
    }

    #[test]
    fn a_circle_sampled_at_20_hz_is_followed_to_within_its_chord() {
        // The robot drives a 2 m radius circle at 0.5 m/s; poses at 20 Hz, queries at the LD06
        // packet rate. The interpolated position is on the chord: off by at most the sagitta.
        let (r, v) = (2000.0f64, 500.0f64);
        let at = |t: f64| {
            let th = v * t / r;
            let h = ((th + std::f64::consts::FRAC_PI_2) / std::f64::consts::TAU * 65536.0)
                .rem_euclid(65536.0);
            (r * th.cos(), r * th.sin(), h)
        };
        let mut tr: PoseTrack<8> = PoseTrack::new(0);
        let mut worst = 0.0f64;
        for k in 0..200u64 {
            let t = k * 50_000;
            let (x, y, h) = at(t as f64 / 1e6);
            tr.push(
                t,
                pose(x.round() as i32, y.round() as i32, h.round() as u16),
            )
            .unwrap();
            for q in 0..23u64 {
                let tq = t.saturating_sub(50_000) + q * 2_170;
                if k == 0 || tq > t {
                    continue;
                }
                let p = tr.at(tq).unwrap();
                let (x, y, _) = at(tq as f64 / 1e6);
                worst = worst.max((f64::from(p.x_mm) - x).hypot(f64::from(p.y_mm) - y));
            }
        }
        // Sagitta of a 25 mm chord on a 2 m circle: 0.04 mm; plus rounding.
        assert!(worst <= 1.5, "worst position error {worst} mm");
    }
}
