//! Lidar turns from the robot's own UART, placed by poses that arrive on their own.
//!
//! A spinning lidar measures while the robot moves: an LD06 sends a 12-point packet every
//! ~2.2 ms, one turn in 100 ms, each packet stamped with the sensor's millisecond clock; an
//! RPLIDAR A1 sends one 5-byte node every ~0.5 ms with no time at all.
//! [`Turns`] takes either (as batches of up to 12 points with one time) and the robot's
//! timestamped poses (odometry or a localiser, [`crate::wire::HostMsg::Pose`], at their own
//! rate) and hands out whole turns as ordinary scans: one pose, beams relative to it.
//!
//! * **Time.** The *lidar clock*, µs, is what poses are stamped in (every
//!   [`crate::wire::ScanReport::t_us`] tells a host where it stands). LD06: its timestamp (ms,
//!   wrapping at 30 000) unwrapped from the first packet read ([`Turns::push_packet`]).
//!   RPLIDAR: the count of nodes taken × the sample period ([`Turns::push_node`]), from 0 at
//!   the first node.
//! * **Placement.** A batch waits in a queue until a pose at or after its time has arrived,
//!   then gets the robot pose interpolated at its time ([`PoseTrack::at`]) moved to the
//!   sensor by the [`Mount`]. A batch older than every pose kept is dropped and counted.
//! * **Turns.** LD06: a packet whose start angle is smaller than the previous one's begins a
//!   new turn. RPLIDAR: the node with the protocol's start flag `S` does (it also closes the
//!   batch before it, so a batch never spans two turns). The finished turn goes out. The new
//!   turn's *reference pose* is its first batch's sensor pose.
//! * **Motion compensation.** Every point is moved into the reference frame ([`deskew`]): its
//!   endpoint stays exactly where it was measured, and its ray is cast from the reference
//!   origin (at most one turn's travel from the true one: 4 cm at 0.4 m/s, under a 5 cm cell).
//!   Batches taken at the reference pose itself (a robot standing still) pass unchanged, so a
//!   standing robot maps exactly what the same scan tunnelled by a host maps. The same beams
//!   at the same times give the same turns whichever lidar sent them.
//!
//! **Determinism.** What a turn contains and where it is placed depends only on the lidar
//! bytes and the poses, not on how the two streams interleave, as long as the queue never
//! overflows and no pose a waiting batch needs is forgotten: [`Turns::wants_packets`] and
//! [`Turns::wants_poses`] tell the reader when to hold a stream back (the firmware stops
//! reading that UART). The host replays the same bytes in any order and gets the same map.
//!
//! Fixed memory: [`QUEUE`] batches (~4 KiB) and [`POSES`] poses.

use crate::config::{LidarModel, PoseInput, RunConfig};
use crate::lidar::ld06::Packet;
use crate::lidar::pose_track::{Mount, PoseTrack, TrackError};
use crate::lidar::rplidar::Node;
use crate::types::angle::Angle;
use crate::types::geometry::Pose;
use crate::types::scan::{Beam, Range, ScanBuf};

/// Batches that can wait for their pose (~140 ms of LD06 data).
pub const QUEUE: usize = 64;
/// Poses kept for interpolation.
pub const POSES: usize = 32;
/// Points per batch: an LD06 packet's.
pub const BATCH: usize = crate::lidar::ld06::POINTS;
/// The LD06 timestamp wraps here, ms.
const WRAP_MS: u64 = 30_000;

/// What [`Turns`] counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TurnCounters {
    /// Batches taken in (LD06 packets, or runs of up to [`BATCH`] RPLIDAR nodes).
    pub packets: u32,
    /// Turns handed out.
    pub turns: u32,
    /// Batches dropped: older than every pose kept.
    pub packets_without_pose: u32,
    /// Batches dropped: the queue was full (the reader did not hold the lidar back).
    pub packets_overflowed: u32,
    /// Poses accepted.
    pub poses: u32,
    /// Poses rejected: not newer than the last one.
    pub poses_out_of_order: u32,
}

/// A finished turn, handed to the callback of [`Turns::push_pose`] / [`Turns::push_packet`] /
/// [`Turns::push_node`].
#[derive(Debug, PartialEq, Eq)]
pub struct Turn<'s> {
    /// Turn number (from 0).
    pub seq: u32,
    /// The sensor's pose at the turn's first batch: what the beams are relative to.
    pub pose: Pose,
    /// The first batch's time, µs of the lidar clock.
    pub t_us: u64,
    /// The beams, motion-compensated into `pose`'s frame.
    pub beams: &'s [Beam],
    /// Beams that did not fit the scan buffer.
    pub overflow: u32,
}

/// What the receiver of a finished [`Turn`] did with it.
///
/// A closure that returns `()` takes every turn (`From<()>`). One that returns
/// [`Taken::Held`] keeps the turn where it is: the batch that began the next turn stays at the
/// head of the queue, nothing of the next turn is placed, and the same turn is handed out
/// again, unchanged, at the next [`Turns::push_pose`], [`Turns::push_packet`],
/// [`Turns::push_node`] or [`Turns::retry`]. The firmware holds a turn this way while the host
/// sends back the stored tiles a window shift brought in (`RunConfig::window_hold`); the lidar
/// waits in the queue meanwhile ([`Turns::wants_packets`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Taken {
    /// The turn was used; the next one begins.
    Taken,
    /// Hand the same turn out again later.
    Held,
}

impl From<()> for Taken {
    fn from((): ()) -> Self {
        Taken::Taken
    }
}

/// How a batch tells where a turn begins.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mark {
    /// RPLIDAR: the batch begins with the start-flagged node. (First: `Flag(false)` is all
    /// zeros, so an empty [`Turns`] is too and its `static` stays in `.bss`, not in flash.)
    Flag(bool),
    /// LD06: the packet's start angle (centidegrees); a new turn when it is smaller than the
    /// previous placed packet's.
    Start(u16),
}

/// One measurement in the queue: the beam angle and the range in mm (0: no return).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Sample {
    angle: Angle,
    mm: u16,
}

/// Points taken together and placed by one pose: an LD06 packet, or up to [`BATCH`]
/// consecutive RPLIDAR nodes of one turn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Batch {
    /// When its first point was taken, µs of the lidar clock.
    t_us: u64,
    mark: Mark,
    len: u8,
    samples: [Sample; BATCH],
}

impl Batch {
    const EMPTY: Batch = Batch {
        t_us: 0,
        mark: Mark::Flag(false),
        len: 0,
        samples: [Sample {
            angle: Angle(0),
            mm: 0,
        }; BATCH],
    };

    fn of_packet(packet: &Packet, t_us: u64) -> Batch {
        let mut b = Batch {
            t_us,
            mark: Mark::Start(packet.start_cdeg),
            len: BATCH as u8,
            ..Batch::EMPTY
        };
        for (i, (s, p)) in b.samples.iter_mut().zip(&packet.points).enumerate() {
            *s = Sample {
                angle: crate::lidar::ld06::beam_angle(packet.angle_cdeg(i)),
                mm: p.distance_mm,
            };
        }
        b
    }

    fn beams(&self) -> impl Iterator<Item = Beam> + '_ {
        self.samples
            .iter()
            .take(usize::from(self.len))
            .map(|s| Beam {
                angle: s.angle,
                range: match s.mm {
                    0 => Range::NoReturn,
                    mm => Range::Hit(u32::from(mm)),
                },
            })
    }
}

/// Assembles turns; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct Turns {
    queue: heapless::Deque<Batch, QUEUE>,
    track: PoseTrack<POSES>,
    mount: Mount,
    fixed: bool,
    /// LD06: last raw timestamp and the unwrapped time, ms.
    clock: Option<(u16, u64)>,
    /// RPLIDAR: nodes taken, the sample period (µs), and the batch being filled.
    nodes: u64,
    sample_us: u32,
    filling: Batch,
    /// Time of the last packet placed.
    placed_us: Option<u64>,
    /// Start angle of the last packet placed.
    last_start: Option<u16>,
    /// The turn being filled: seq, reference pose, time.
    open: Option<(u32, Pose, u64)>,
    next_seq: u32,
    counters: TurnCounters,
}

impl Turns {
    /// Nothing received; the lidar sits at `mount` on the robot. `fixed`: no poses will come,
    /// the robot stands at the world origin ([`crate::config::PoseInput::Fixed`]).
    pub const fn new(mount: Mount, fixed: bool) -> Self {
        Turns {
            queue: heapless::Deque::new(),
            track: PoseTrack::new(0),
            mount,
            fixed,
            clock: None,
            nodes: 0,
            sample_us: 0,
            filling: Batch::EMPTY,
            placed_us: None,
            last_start: None,
            open: None,
            next_seq: 0,
            counters: TurnCounters {
                packets: 0,
                turns: 0,
                packets_without_pose: 0,
                packets_overflowed: 0,
                poses: 0,
                poses_out_of_order: 0,
            },
        }
    }

    /// Nothing received, the lidar mounted, its poses sourced and its nodes timed as `config`
    /// says ([`RunConfig::mount`], [`RunConfig::poses`], [`RunConfig::lidar`]).
    pub fn configured(config: &RunConfig) -> Self {
        let mut t = Turns::new(Mount::from(config.mount), config.poses == PoseInput::Fixed);
        if let LidarModel::Rplidar { sample_us } = config.lidar {
            t.sample_us = u32::from(sample_us);
        }
        t
    }

    /// The counters so far.
    pub fn counters(&self) -> TurnCounters {
        self.counters
    }

    /// Packets waiting for their pose.
    pub fn waiting(&self) -> usize {
        self.queue.len()
    }

    /// Whether the batches one more read can complete fit without dropping one (two: an
    /// RPLIDAR parser locking on hands out a few nodes at once, and a start flag among them
    /// closes a batch early): the reader holds the lidar back otherwise.
    pub fn wants_packets(&self) -> bool {
        self.queue.len() + 2 <= QUEUE
    }

    /// Poses the track takes before it has to forget one (then [`Turns::wants_poses`] decides
    /// pose by pose).
    pub fn pose_room(&self) -> usize {
        POSES.saturating_sub(self.track.len())
    }

    /// Whether one more pose can be taken without forgetting one a batch still to come may
    /// need: the oldest may go only if the next one is not after the earliest batch still to
    /// be placed (the first waiting, else the RPLIDAR nodes being collected, else the last
    /// placed). The reader holds the poses back otherwise.
    pub fn wants_poses(&self) -> bool {
        if self.track.len() < POSES {
            return true;
        }
        let filling = (self.filling.len > 0).then_some(self.filling.t_us);
        let next_packet = self
            .queue
            .front()
            .map(|q| q.t_us)
            .or(filling)
            .or(self.placed_us);
        match (self.track.second_oldest(), next_packet) {
            (Some(next), Some(t)) => next.t_us <= t,
            _ => false,
        }
    }

    /// A robot pose at `t_us` (lidar clock); places the packets it covers and hands out the
    /// turns they finish. A repeat of the newest pose is ignored.
    pub fn push_pose<const N: usize, T: Into<Taken>>(
        &mut self,
        t_us: u64,
        pose: Pose,
        scan: &mut ScanBuf<N>,
        mut f: impl FnMut(Turn<'_>) -> T,
    ) -> Result<(), TrackError> {
        if let Some(last) = self.track.latest() {
            if last.t_us == t_us && last.pose == pose {
                return Ok(());
            }
        }
        if let Err(e) = self.track.push(t_us, pose) {
            bump(&mut self.counters.poses_out_of_order);
            return Err(e);
        }
        bump(&mut self.counters.poses);
        self.drain(scan, &mut |t| f(t).into());
        Ok(())
    }

    /// A lidar packet; places it (and those before it) as soon as the poses cover it and hands
    /// out the turns that finish.
    pub fn push_packet<const N: usize, T: Into<Taken>>(
        &mut self,
        packet: &Packet,
        scan: &mut ScanBuf<N>,
        mut f: impl FnMut(Turn<'_>) -> T,
    ) {
        let raw = packet.timestamp_ms;
        let t_ms = match self.clock {
            None => u64::from(raw),
            Some((last, t)) => {
                let step = (u64::from(raw) + WRAP_MS - u64::from(last) % WRAP_MS) % WRAP_MS;
                t.saturating_add(step)
            }
        };
        self.clock = Some((raw, t_ms));
        self.enqueue(Batch::of_packet(packet, t_ms.saturating_mul(1000)));
        self.drain(scan, &mut |t| f(t).into());
    }

    /// An RPLIDAR node ([`crate::lidar::rplidar`]); it joins the batch being filled, which is queued
    /// when it holds [`BATCH`] nodes or when a start-flagged node begins the next turn. Hands
    /// out the turns that finish. The node's time is the nodes taken before it × the sample
    /// period of [`Turns::configured`]'s settings.
    pub fn push_node<const N: usize, T: Into<Taken>>(
        &mut self,
        node: &Node,
        scan: &mut ScanBuf<N>,
        mut f: impl FnMut(Turn<'_>) -> T,
    ) {
        let t_us = self.nodes.saturating_mul(u64::from(self.sample_us));
        self.nodes = self.nodes.saturating_add(1);
        if node.start && self.filling.len > 0 {
            self.flush();
        }
        let b = &mut self.filling;
        if b.len == 0 {
            b.t_us = t_us;
            b.mark = Mark::Flag(node.start);
        }
        let beam = node.beam();
        if let Some(s) = b.samples.get_mut(usize::from(b.len)) {
            *s = Sample {
                angle: beam.angle,
                mm: match beam.range {
                    // At most (65 535 + 2) / 4 = 16 384 mm.
                    Range::Hit(mm) => u16::try_from(mm).unwrap_or(u16::MAX),
                    Range::NoReturn => 0,
                },
            };
            b.len += 1;
        }
        if usize::from(b.len) >= BATCH {
            self.flush();
        }
        self.drain(scan, &mut |t| f(t).into());
    }

    /// Queues the batch being filled.
    fn flush(&mut self) {
        let b = core::mem::replace(&mut self.filling, Batch::EMPTY);
        self.enqueue(b);
    }

    fn enqueue(&mut self, batch: Batch) {
        bump(&mut self.counters.packets);
        if self.queue.is_full() {
            self.queue.pop_front();
            bump(&mut self.counters.packets_overflowed);
        }
        let _ = self.queue.push_back(batch);
    }

    /// Hands out a held turn again ([`Taken::Held`]) and places what waits behind it, as far as
    /// the poses allow; nothing happens without a held turn or a batch to place.
    pub fn retry<const N: usize, T: Into<Taken>>(
        &mut self,
        scan: &mut ScanBuf<N>,
        mut f: impl FnMut(Turn<'_>) -> T,
    ) {
        self.drain(scan, &mut |t| f(t).into());
    }

    /// Places every queued batch whose pose is known, in order, until a finished turn is held.
    /// Not inlined: every `push_*` calls it, and one copy of it is enough flash.
    #[inline(never)]
    fn drain<const N: usize>(
        &mut self,
        scan: &mut ScanBuf<N>,
        f: &mut dyn FnMut(Turn<'_>) -> Taken,
    ) {
        while let Some(q) = self.queue.front().copied() {
            let robot = if self.fixed {
                Pose::default()
            } else {
                match self.track.latest() {
                    Some(l) if l.t_us >= q.t_us => {}
                    _ => return, // wait for a pose at or after this packet
                }
                match self.track.at(q.t_us) {
                    Ok(p) => p,
                    Err(_) => {
                        // Older than every pose kept.
                        self.queue.pop_front();
                        bump(&mut self.counters.packets_without_pose);
                        continue;
                    }
                }
            };
            if self.place(&q, &self.mount.sensor_pose(&robot), scan, f) == Taken::Held {
                return; // the batch stays first in the queue, the turn in `scan`
            }
            self.queue.pop_front();
        }
    }

    /// Places `q` at `sensor`; [`Taken::Held`] (nothing changed) if it begins a new turn and
    /// the receiver holds the finished one.
    fn place<const N: usize>(
        &mut self,
        q: &Batch,
        sensor: &Pose,
        scan: &mut ScanBuf<N>,
        f: &mut dyn FnMut(Turn<'_>) -> Taken,
    ) -> Taken {
        let new_turn = match q.mark {
            Mark::Start(start) => self.last_start.is_none_or(|last| start < last),
            Mark::Flag(start) => start || self.open.is_none(),
        };
        if new_turn {
            if let Some((seq, pose, t_us)) = self.open {
                let turn = Turn {
                    seq,
                    pose,
                    t_us,
                    beams: scan.beams(),
                    overflow: scan.overflow(),
                };
                if f(turn) == Taken::Held {
                    return Taken::Held;
                }
                bump(&mut self.counters.turns);
            }
            scan.clear();
            self.open = Some((self.next_seq, *sensor, q.t_us));
            self.next_seq = self.next_seq.wrapping_add(1);
        }
        if let Mark::Start(start) = q.mark {
            self.last_start = Some(start);
        }
        self.placed_us = Some(q.t_us);
        let Some((_, reference, _)) = self.open else {
            return Taken::Taken;
        };
        for b in q.beams() {
            scan.push(deskew(b, sensor, &reference));
        }
        Taken::Taken
    }
}

fn bump(c: &mut u32) {
    *c = c.saturating_add(1);
}

/// `beam`, measured from the sensor pose `from`, as seen from `to`: the same endpoint, its
/// direction and range from `to` (range rounded to the nearest mm). A beam without a return
/// keeps its direction in the world (only its origin moves, by less than the robot travels in
/// one turn). `from == to` returns `beam` unchanged.
pub fn deskew(beam: Beam, from: &Pose, to: &Pose) -> Beam {
    if from == to {
        return beam;
    }
    match beam.range {
        Range::Hit(r) => {
            let (ex, ey) = from.beam_end(beam.angle, r);
            // Saturated at ±2^31 mm (poses 2 000 km apart are nonsense anyway), so the squares
            // sum below 2^63 and all of it stays in 64 bits.
            const LIM: i64 = 1 << 31;
            let dx = (ex - i64::from(to.x_mm)).clamp(-LIM, LIM);
            let dy = (ey - i64::from(to.y_mm)).clamp(-LIM, LIM);
            let r2 = dx.unsigned_abs().pow(2) + dy.unsigned_abs().pow(2);
            let range = u32::try_from(isqrt_round(r2)).unwrap_or(u32::MAX);
            Beam {
                angle: Angle::atan2(dy, dx).wrapping_sub(to.heading),
                range: Range::Hit(range),
            }
        }
        Range::NoReturn => Beam {
            angle: beam
                .angle
                .wrapping_add(from.heading.wrapping_sub(to.heading)),
            range: Range::NoReturn,
        },
    }
}

/// √v rounded to the nearest integer (digit by digit: no division; smaller in flash than
/// `u64::isqrt`).
fn isqrt_round(v: u64) -> u64 {
    let (mut rem, mut root) = (v, 0u64);
    let mut bit = 1u64 << 62;
    while bit > v {
        bit >>= 2;
    }
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    // root = ⌊√v⌋, rem = v − root²; round: (root + ½)² = root² + root + ¼.
    if rem > root {
        root + 1
    } else {
        root
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lidar::ld06::{Point, POINTS};

    fn pose(x: i32, y: i32, deg: f64) -> Pose {
        Pose::new(x, y, Angle::from_degrees(deg))
    }

    #[test]
    fn isqrt_rounds_to_nearest() {
        for v in 0u64..20_000 {
            let want = (v as f64).sqrt().round() as u64;
            assert_eq!(isqrt_round(v), want, "{v}");
        }
        for v in [(1u64 << 62) + 12_345, u64::MAX, 1 << 63, (1 << 32) - 1] {
            let r = isqrt_round(v) as u128;
            // ⌊√v⌋ or one above, whichever is nearer: (r − ½)² ≤ v < (r + ½)².
            let v4 = 4 * v as u128;
            assert!(
                (2 * r - 1).pow(2) <= v4 && v4 < (2 * r + 1).pow(2),
                "{v}: {r}"
            );
        }
    }

    /// f64 reference of [`deskew`]: endpoint from `from`, then direction and range from `to`.
    fn reference(b: Beam, from: &Pose, to: &Pose) -> (f64, f64) {
        let Range::Hit(r) = b.range else {
            unreachable!()
        };
        let a = from.heading.to_radians() + b.angle.to_radians();
        let ex = f64::from(from.x_mm) + f64::from(r) * a.cos();
        let ey = f64::from(from.y_mm) + f64::from(r) * a.sin();
        let (dx, dy) = (ex - f64::from(to.x_mm), ey - f64::from(to.y_mm));
        (dy.atan2(dx) - to.heading.to_radians(), dx.hypot(dy))
    }

    #[test]
    fn deskew_matches_f64() {
        let mut worst = (0.0f64, 0.0f64);
        for k in 0..2000u32 {
            let from = pose(
                (k * 37 % 900) as i32 - 450,
                (k * 91 % 700) as i32 - 350,
                f64::from(k * 7 % 360),
            );
            let to = pose(
                from.x_mm + (k % 61) as i32 - 30,
                from.y_mm - (k % 47) as i32 + 23,
                f64::from(k * 7 % 360) + f64::from(k % 11) - 5.0,
            );
            let b = Beam {
                angle: Angle((k * 4099 % 65536) as u16),
                range: Range::Hit(200 + k * 13 % 11_000),
            };
            let got = deskew(b, &from, &to);
            let (a, r) = reference(b, &from, &to);
            let Range::Hit(gr) = got.range else {
                panic!("{got:?}")
            };
            let da = Angle::from_radians(a).signed_diff(got.angle).unsigned_abs();
            let dr = (f64::from(gr) - r).abs();
            // Endpoint rounding (±0.5 mm per axis) plus the table atan2.
            let da_mm = f64::from(da) / 65536.0 * std::f64::consts::TAU * r;
            worst = (worst.0.max(da_mm), worst.1.max(dr));
        }
        assert!(worst.0 <= 1.5 && worst.1 <= 1.3, "{worst:?}");
        // Same pose: unchanged, bit for bit, with or without a return.
        let p = pose(10, -20, 33.0);
        for range in [Range::Hit(1234), Range::NoReturn] {
            let b = Beam {
                angle: Angle(777),
                range,
            };
            assert_eq!(deskew(b, &p, &p), b);
        }
        // No return: the world direction is kept.
        let b = Beam {
            angle: Angle(1000),
            range: Range::NoReturn,
        };
        let (from, to) = (pose(0, 0, 10.0), pose(30, 5, 12.0));
        let got = deskew(b, &from, &to);
        assert_eq!(
            to.heading.wrapping_add(got.angle),
            from.heading.wrapping_add(b.angle)
        );
    }

    /// One packet of 12 points at `range_mm`, starting at `start_cdeg`, 0.8° apart.
    fn packet(start_cdeg: u16, t_ms: u16, range_mm: u16) -> Packet {
        Packet {
            speed_dps: 3600,
            start_cdeg,
            end_cdeg: (start_cdeg + 880) % 36000,
            timestamp_ms: t_ms,
            points: [Point {
                distance_mm: range_mm,
                intensity: 200,
            }; POINTS],
        }
    }

    /// A pose (`true`, its time and pose) or a packet (`false`, its time and the packet).
    type Event = (bool, u64, Pose, Packet);
    /// A turn as the tests compare it.
    type Out = (u32, Pose, u64, Vec<Beam>);

    /// Feeds `events` (pose or packet, in the given order); returns the turns.
    fn run(events: &[Event], fixed: bool, mount: Mount) -> (Vec<Out>, TurnCounters) {
        let mut t = Turns::new(mount, fixed);
        let mut scan = ScanBuf::<1024>::new();
        let mut out = Vec::new();
        for (is_pose, t_us, p, pk) in events {
            let mut f =
                |turn: Turn<'_>| out.push((turn.seq, turn.pose, turn.t_us, turn.beams.to_vec()));
            if *is_pose {
                let _ = t.push_pose(*t_us, *p, &mut scan, &mut f);
            } else {
                t.push_packet(pk, &mut scan, &mut f);
            }
        }
        (out, t.counters())
    }

    /// A robot driving at 0.4 m/s along x while turning 20°/s; LD06 packets every 2 ms (50 a
    /// turn of 100 ms), poses every 30 ms.
    fn drive(turns: usize) -> (Vec<Event>, impl Fn(f64) -> Pose) {
        let truth = |t_s: f64| pose((400.0 * t_s) as i32, 0, 20.0 * t_s);
        let mut ev = Vec::new();
        let packets = turns * 50 + 1; // + the first of the next turn, which closes the last
        for k in 0..packets {
            let t_ms = 2 * k as u64;
            let start = ((k % 50) * 720) as u16;
            ev.push((
                false,
                t_ms * 1000,
                Pose::default(),
                packet(start, t_ms as u16, 2000),
            ));
        }
        let end_us = 2 * packets as u64 * 1000 + 30_000;
        let mut t_us = 0;
        while t_us <= end_us {
            let p = truth(t_us as f64 / 1e6);
            ev.push((true, t_us, p, Packet::default()));
            t_us += 30_000;
        }
        (ev, truth)
    }

    fn by_time(ev: &mut [Event]) {
        ev.sort_by_key(|e| (e.1, !e.0));
    }

    #[test]
    fn turns_are_placed_by_interpolated_poses_whatever_the_interleaving() {
        let (mut ev, truth) = drive(4);
        let mount = Mount {
            x_mm: 100,
            y_mm: -20,
            yaw: Angle::from_degrees(90.0),
        };
        by_time(&mut ev);
        let (a, c) = run(&ev, false, mount);
        assert_eq!(a.len(), 4, "{c:?}");
        assert_eq!(c.packets_without_pose + c.packets_overflowed, 0, "{c:?}");
        for (i, (seq, p, t_us, beams)) in a.iter().enumerate() {
            assert_eq!((*seq as usize, *t_us), (i, i as u64 * 100_000));
            assert_eq!(beams.len(), 50 * POINTS);
            // The reference pose is the true sensor pose at the turn's first packet (poses
            // interpolated linearly between 30 ms samples of a gentle arc: within 1 mm).
            let want = mount.sensor_pose(&truth(*t_us as f64 / 1e6));
            assert!(
                (p.x_mm - want.x_mm).abs() <= 1 && (p.y_mm - want.y_mm).abs() <= 1,
                "{p:?} {want:?}"
            );
            assert!(
                p.heading.signed_diff(want.heading).abs() <= 8,
                "{p:?} {want:?}"
            );
        }
        // Every endpoint lands where the true sensor pose at its packet's time put it: the
        // world point of packet k's first point.
        let (_, p0, _, beams) = &a[1];
        let k = 50 + 17; // packet 17 of turn 1
        let true_sensor = mount.sensor_pose(&truth(0.002 * k as f64));
        let ang = crate::lidar::ld06::beam_angle(17 * 720);
        let want = true_sensor.beam_end(ang, 2000);
        let got_b = beams[17 * POINTS];
        let Range::Hit(r) = got_b.range else { panic!() };
        let got = p0.beam_end(got_b.angle, r);
        assert!(
            (got.0 - want.0).abs() <= 3 && (got.1 - want.1).abs() <= 3,
            "{got:?} {want:?}"
        );
        // The same streams, interleaved differently (poses late, in bursts, or all packets
        // first as far as the queue allows): identical turns.
        let poses: Vec<_> = ev.iter().filter(|e| e.0).cloned().collect();
        let pkts: Vec<_> = ev.iter().filter(|e| !e.0).cloned().collect();
        for lag in [1usize, 5, 20, 45] {
            let mut mixed = Vec::new();
            let (mut i, mut j) = (0, 0);
            while i < pkts.len() || j < poses.len() {
                // Packets run `lag` packets ahead of the poses that cover them.
                let pose_due = poses.get(j).map(|p| p.1);
                let pkt_t = pkts.get(i).map(|p| p.1);
                let take_pkt = match (pkt_t, pose_due) {
                    (Some(tp), Some(tq)) => tp <= tq + 2000 * lag as u64,
                    (Some(_), None) => true,
                    _ => false,
                };
                if take_pkt {
                    mixed.push(pkts[i]);
                    i += 1;
                } else {
                    mixed.push(poses[j]);
                    j += 1;
                }
            }
            let (b, cb) = run(&mixed, false, mount);
            assert_eq!(a, b, "lag {lag}: {cb:?}");
        }
    }

    #[test]
    fn a_held_turn_comes_out_again_unchanged_and_nothing_behind_it_is_lost() {
        let (mut ev, _) = drive(4);
        by_time(&mut ev);
        let mount = Mount::default();
        let (want, _) = run(&ev, false, mount);
        // The receiver holds turn 1 each time it is offered until `release`, which comes
        // after every event (packets queue behind it, up to what the queue holds).
        let mut t = Turns::new(mount, false);
        let mut scan = ScanBuf::<1024>::new();
        let mut got: Vec<Out> = Vec::new();
        let mut offered = 0;
        let mut release = false;
        let mut f = |turn: Turn<'_>, release: bool, offered: &mut u32| {
            if turn.seq == 1 && !release {
                *offered += 1;
                return Taken::Held;
            }
            got.push((turn.seq, turn.pose, turn.t_us, turn.beams.to_vec()));
            Taken::Taken
        };
        let mut held_waiting = 0;
        for (k, (is_pose, t_us, p, pk)) in ev.iter().enumerate() {
            release = release || (offered > 0 && k >= 150);
            let r = release;
            if *is_pose {
                let _ = t.push_pose(*t_us, *p, &mut scan, |x| f(x, r, &mut offered));
            } else {
                t.push_packet(pk, &mut scan, |x| f(x, r, &mut offered));
            }
            if offered > 0 && !release {
                held_waiting = held_waiting.max(t.waiting());
            }
        }
        t.retry(&mut scan, |x| f(x, true, &mut offered));
        assert!(offered > 1, "offered {offered} times");
        assert!(held_waiting > 10, "{held_waiting} batches waited");
        assert_eq!(got, want);
        assert_eq!(t.counters().packets_overflowed, 0);
        // Nothing held: `retry` hands out nothing more.
        let n = got.len();
        t.retry(&mut scan, |x: Turn<'_>| {
            got.push((x.seq, x.pose, x.t_us, x.beams.to_vec()))
        });
        assert_eq!(got.len(), n);
    }

    #[test]
    fn standing_still_or_fixed_gives_the_scan_unchanged() {
        let mut ev = Vec::new();
        for k in 0..101u64 {
            let start = ((k % 50) * 720) as u16;
            ev.push((
                false,
                k * 2000,
                Pose::default(),
                packet(start, k as u16 * 2, 1500),
            ));
        }
        let (fixed, c) = run(&ev, true, Mount::default());
        assert_eq!((fixed.len(), c.poses), (2, 0));
        let want: Vec<Beam> = (0..50u16)
            .flat_map(|k| {
                let p = packet(k * 720, 0, 1500);
                (0..POINTS).filter_map(move |i| p.beam(i))
            })
            .collect();
        assert_eq!(fixed[0].3.len(), want.len());
        if let Some(i) = (0..want.len()).find(|&i| fixed[0].3[i] != want[i]) {
            panic!("beam {i}: {:?} vs {:?}", fixed[0].3[i], want[i]);
        }
        assert_eq!(fixed[0].1, Pose::default());
        // The same with a pose track that never moves.
        let still = pose(500, -300, 45.0);
        for k in 0..12 {
            ev.push((true, k * 20_000, still, Packet::default()));
        }
        by_time(&mut ev);
        let (tracked, _) = run(&ev, false, Mount::default());
        assert_eq!(tracked.len(), 2);
        assert_eq!(tracked[0].3.len(), want.len());
        if let Some(i) = (0..want.len()).find(|&i| tracked[0].3[i] != want[i]) {
            panic!("beam {i}: {:?} vs {:?}", tracked[0].3[i], want[i]);
        }
        assert_eq!(tracked[0].1, still);
    }

    #[test]
    fn timestamps_unwrap_and_stale_or_unplaced_packets_are_counted() {
        let mut t = Turns::new(Mount::default(), false);
        let mut scan = ScanBuf::<64>::new();
        let mut n = 0;
        // Packets at 29 998 ms and (wrapped) 2 ms: 4 ms apart, not −29 996.
        t.push_packet(&packet(0, 29_998, 1000), &mut scan, |_| n += 1);
        t.push_packet(&packet(720, 2, 1000), &mut scan, |_| n += 1);
        t.push_pose(29_999_000, pose(0, 0, 0.0), &mut scan, |_| n += 1)
            .unwrap();
        // The first is older than every pose: dropped; the second waits for a pose at 30 002.
        assert_eq!(t.counters().packets_without_pose, 1);
        assert_eq!(t.waiting(), 1);
        t.push_pose(30_002_000, pose(10, 0, 0.0), &mut scan, |_| n += 1)
            .unwrap();
        assert_eq!(t.waiting(), 0);
        assert_eq!(
            t.push_pose(30_001_000, pose(0, 0, 0.0), &mut scan, |_| ()),
            Err(TrackError::OutOfOrder)
        );
        // A repeat of the newest is no error.
        assert_eq!(
            t.push_pose(30_002_000, pose(10, 0, 0.0), &mut scan, |_| ()),
            Ok(())
        );
        assert_eq!(t.counters().poses_out_of_order, 1);
        assert_eq!(n, 0);
        // Without poses the queue fills; the reader is told, and beyond it packets are lost.
        for k in 0..QUEUE as u16 + 3 {
            assert_eq!(t.wants_packets(), k + 1 < QUEUE as u16);
            t.push_packet(&packet(1440, 100 + k, 1000), &mut scan, |_| ());
        }
        assert_eq!(t.counters().packets_overflowed, 3);
        // Poses far ahead of the lidar: the track fills and the reader is told to wait.
        let mut t = Turns::new(Mount::default(), false);
        t.push_packet(&packet(0, 0, 1000), &mut scan, |_| ());
        let mut k = 0u64;
        while t.wants_poses() {
            t.push_pose(k * 10_000, pose(0, 0, 0.0), &mut scan, |_| ())
                .unwrap();
            k += 1;
        }
        assert_eq!(k as usize, POSES);
    }

    /// The same beams at the same times, as LD06 packets and as RPLIDAR nodes (a turn of 360
    /// points 1° apart in 180 ms: an A1's 2 000 samples/s; 30 batches of 12, one every 6 ms),
    /// give the same turns, placed by the same poses of a moving robot.
    #[test]
    fn rplidar_nodes_give_the_turns_of_the_same_ld06_packets() {
        use crate::lidar::rplidar::Node;
        let mount = Mount {
            x_mm: 80,
            y_mm: 10,
            yaw: Angle::from_degrees(-90.0),
        };
        let truth = |t_us: u64| {
            let t = t_us as f64 / 1e6;
            pose((300.0 * t) as i32, (50.0 * t) as i32, 15.0 * t)
        };
        let range = |k: u64| ((1000 + (k * 37) % 3000) as u16, (k % 17 == 3));
        let config = RunConfig {
            lidar: LidarModel::Rplidar { sample_us: 500 },
            mount: crate::Pose {
                x_mm: mount.x_mm,
                y_mm: mount.y_mm,
                heading: mount.yaw,
            },
            ..RunConfig::PAPER
                .with_max_range_mm(8000)
                .with_budget(crate::config::Budget::Fixed { updates: 0 })
        };
        let (turns, per_turn) = (4u64, 30u64);
        let mut ld = Turns::configured(&RunConfig {
            lidar: LidarModel::Ld06,
            ..config
        });
        let mut rp = Turns::configured(&config);
        let (mut sa, mut sb) = (ScanBuf::<512>::new(), ScanBuf::<512>::new());
        let (mut a, mut b) = (Vec::<Out>::new(), Vec::<Out>::new());
        let mut next_pose = 0u64;
        for j in 0..=turns * per_turn {
            let t_us = j * 6000;
            // Poses every 20 ms, up to the batch's time (the queue holds the rest).
            while next_pose <= t_us + 20_000 {
                let p = truth(next_pose);
                let mut fa = |t: Turn<'_>| a.push((t.seq, t.pose, t.t_us, t.beams.to_vec()));
                ld.push_pose(next_pose, p, &mut sa, &mut fa).unwrap();
                let mut fb = |t: Turn<'_>| b.push((t.seq, t.pose, t.t_us, t.beams.to_vec()));
                rp.push_pose(next_pose, p, &mut sb, &mut fb).unwrap();
                next_pose += 20_000;
            }
            let start = ((j % per_turn) * 1200) as u16;
            let mut pk = packet(start, (t_us / 1000) as u16, 0);
            pk.end_cdeg = start + 1100;
            for i in 0..POINTS as u64 {
                let (mm, none) = range(j * 12 + i);
                pk.points[i as usize].distance_mm = if none { 0 } else { mm };
                let node = Node {
                    start: i == 0 && j % per_turn == 0,
                    quality: 47,
                    angle_q6: (((j % per_turn) * 12 + i) * 64) as u16,
                    distance_q2: if none { 0 } else { mm * 4 },
                };
                rp.push_node(&node, &mut sb, |t| {
                    b.push((t.seq, t.pose, t.t_us, t.beams.to_vec()))
                });
            }
            ld.push_packet(&pk, &mut sa, |t| {
                a.push((t.seq, t.pose, t.t_us, t.beams.to_vec()))
            });
        }
        assert_eq!(a.len(), turns as usize);
        assert_eq!(a[1].3.len(), 360);
        assert_ne!(a[1].1, a[2].1, "the robot moves");
        assert_eq!(a, b);
        assert_eq!(ld.counters(), rp.counters());
        // Poses as far ahead as the reader lets them run (`wants_poses`): the nodes being
        // collected hold them back too, so none is dropped and the turns are the same.
        let mut rp = Turns::configured(&config);
        let mut c = Vec::<Out>::new();
        let mut next_pose = 0u64;
        for j in 0..=turns * per_turn {
            for i in 0..POINTS as u64 {
                // Between any two nodes (a batch half collected, too).
                while rp.wants_poses() && next_pose <= (turns * per_turn + 1) * 6000 + 20_000 {
                    let mut fc = |t: Turn<'_>| c.push((t.seq, t.pose, t.t_us, t.beams.to_vec()));
                    rp.push_pose(next_pose, truth(next_pose), &mut sb, &mut fc)
                        .unwrap();
                    next_pose += 20_000;
                }
                let (mm, none) = range(j * 12 + i);
                let node = Node {
                    start: i == 0 && j % per_turn == 0,
                    quality: 47,
                    angle_q6: (((j % per_turn) * 12 + i) * 64) as u16,
                    distance_q2: if none { 0 } else { mm * 4 },
                };
                rp.push_node(&node, &mut sb, |t| {
                    c.push((t.seq, t.pose, t.t_us, t.beams.to_vec()))
                });
            }
        }
        assert_eq!(rp.counters().packets_without_pose, 0);
        assert_eq!(a, c);
        // A start flag in the middle of a batch closes it: the turn after it starts there.
        let mut t = Turns::configured(&RunConfig {
            poses: PoseInput::Fixed,
            ..config
        });
        let mut s = ScanBuf::<64>::new();
        let mut out = Vec::new();
        for k in 0..30u16 {
            let node = Node {
                start: k == 5 || k == 15,
                quality: 47,
                angle_q6: (k % 10) * 64,
                distance_q2: 4000,
            };
            t.push_node(&node, &mut s, |turn| out.push(turn.beams.len()));
        }
        // Nodes 0-4 (no start seen: a partial turn), then 5-14, handed out when the batch of
        // nodes 15-26 is placed; 27-29 are still being collected.
        assert_eq!(out, vec![5, 10]);
    }
}
