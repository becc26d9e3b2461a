//! A simple exploring robot with known poses that stops to scan (as in the paper: "the robot
//! only maps the environment when stopped").
//!
//! The robot plans on the ground truth's *navigable* cells (free, at least `robot_radius_m` from
//! anything that is not free), so every path is collision-free. It chooses where to go from what
//! its scans have *observed* so far (cells any measurement updated): the nearest navigable cell
//! that is still unobserved and at least `min_stop_separation_m` from every earlier stop. It drives
//! along the shortest 8-connected path, stopping to scan at the target or every `max_step_m`,
//! whichever comes first, and ends when no such cell is reachable or after `max_stops` scans.
//! Because only navigable cells are targets, the unobservable insides of walls never keep it
//! exploring, and the data stays sparse (one scan per room or so), as in the paper.

use std::collections::VecDeque;

use anyhow::{ensure, Context};
use ogm_core::{Angle, Beam, Pose};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

use ogm_field::world::{Truth, World};

/// Exploration parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExploreConfig {
    /// Robot radius (clearance kept from non-free cells), metres.
    pub robot_radius_m: f64,
    /// Longest drive between two scans, metres.
    pub max_step_m: f64,
    /// A target must be at least this far from every earlier stop, metres.
    pub min_stop_separation_m: f64,
    /// A target needs at least this many unobserved navigable cells within `cluster_radius_m`
    /// (so stray unobserved pockets behind furniture do not attract the robot).
    pub min_unobserved: usize,
    /// Radius of that neighbourhood (a square), metres.
    pub cluster_radius_m: f64,
    /// Hard bound on the number of scans.
    pub max_stops: usize,
    /// Scans per second while driving (the LD06 turns at 10 Hz); 0 = scan only when stopped,
    /// as in the paper.
    pub scan_rate_hz: f64,
    /// Driving speed, m/s (with `scan_rate_hz`).
    pub speed_m_s: f64,
    /// Keep going — patrolling to random navigable places once nothing is left to explore —
    /// until at least this many scans are taken (a long mission); 0 = stop when explored.
    pub min_scans: usize,
}

impl ExploreConfig {
    /// A robot that scans at `rate_hz` while driving at `speed_m_s`, for at least `scans` scans
    /// (and at most `scans` plus one path's worth).
    pub fn moving(rate_hz: f64, speed_m_s: f64, scans: usize) -> Self {
        ExploreConfig {
            scan_rate_hz: rate_hz,
            speed_m_s,
            min_scans: scans,
            max_stops: scans.max(1),
            ..ExploreConfig::default()
        }
    }

    fn moving_step_cells(&self, res: f64) -> Option<f64> {
        (self.scan_rate_hz > 0.0 && self.speed_m_s > 0.0)
            .then(|| self.speed_m_s / self.scan_rate_hz / res)
    }
}

impl Default for ExploreConfig {
    fn default() -> Self {
        ExploreConfig {
            robot_radius_m: 0.2,
            max_step_m: 2.5,
            min_stop_separation_m: 1.5,
            min_unobserved: 40,
            cluster_radius_m: 0.5,
            max_stops: 400,
            scan_rate_hz: 0.0,
            speed_m_s: 0.4,
            min_scans: 0,
        }
    }
}

/// One recorded scan: the pose it was taken at and its beams.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScanRecord {
    /// Known pose.
    pub pose: Pose,
    /// Beams as the sensor reported them.
    pub beams: Vec<Beam>,
}

/// Cells of `world` a robot of the given radius can stand on (chessboard-distance clearance).
pub fn navigable(world: &World, radius_cells: usize) -> Vec<bool> {
    let (w, h) = (world.width, world.height);
    let mut dist = vec![u32::MAX; w * h];
    let mut q = VecDeque::new();
    for (i, c) in world.cells.iter().enumerate() {
        if *c != Truth::Free {
            dist[i] = 0;
            q.push_back(i);
        }
    }
    // Map border counts as blocked too.
    for (i, d) in dist.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        if *d != 0 && (x == 0 || y == 0 || x == w - 1 || y == h - 1) {
            *d = 1;
            q.push_back(i);
        }
    }
    while let Some(i) = q.pop_front() {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        for (nx, ny) in neighbours8(x, y, w, h) {
            let j = ny * w + nx;
            if dist[j] > dist[i] + 1 {
                dist[j] = dist[i] + 1;
                q.push_back(j);
            }
        }
    }
    dist.iter().map(|&d| d as usize > radius_cells).collect()
}

fn neighbours8(x: i64, y: i64, w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> {
    const D: [(i64, i64); 8] = [
        (1, 0),
        (-1, 0),
        (0, 1),
        (0, -1),
        (1, 1),
        (1, -1),
        (-1, 1),
        (-1, -1),
    ];
    D.iter().filter_map(move |(dx, dy)| {
        let (nx, ny) = (x + dx, y + dy);
        (nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h)
            .then_some((nx as usize, ny as usize))
    })
}

/// Labels of the largest 8-connected component of `mask`.
fn largest_component(mask: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut label = vec![0u32; mask.len()];
    let (mut best, mut best_size, mut next) = (0u32, 0usize, 1u32);
    for s in 0..mask.len() {
        if !mask[s] || label[s] != 0 {
            continue;
        }
        let mut size = 0;
        let mut q = VecDeque::from([s]);
        label[s] = next;
        while let Some(i) = q.pop_front() {
            size += 1;
            for (nx, ny) in neighbours8((i % w) as i64, (i / w) as i64, w, h) {
                let j = ny * w + nx;
                if mask[j] && label[j] == 0 {
                    label[j] = next;
                    q.push_back(j);
                }
            }
        }
        if size > best_size {
            (best, best_size) = (next, size);
        }
        next += 1;
    }
    label.iter().map(|&l| l == best && best != 0).collect()
}

/// Runs an exploration. `scan_and_map(pose)` must take a scan at `pose`, integrate it into the
/// robot's map, and return the scan's beams plus the mask of cells observed so far.
///
/// With [`ExploreConfig::scan_rate_hz`] the robot also scans while it drives, every
/// `speed / rate` along its path (poses interpolated between cell centres, heading along the
/// path; one pose per scan — the sensor's own motion during a turn is not simulated), and with
/// [`ExploreConfig::min_scans`] it patrols to random navigable cells once everything is explored.
pub fn explore(
    world: &World,
    cfg: &ExploreConfig,
    seed: u64,
    mut scan_and_map: impl FnMut(&Pose) -> anyhow::Result<(Vec<Beam>, Vec<bool>)>,
) -> anyhow::Result<Vec<ScanRecord>> {
    let (w, h) = (world.width, world.height);
    let res = world.resolution_m;
    ensure!(res > 0.0, "world resolution must be positive");
    let radius = (cfg.robot_radius_m / res).ceil() as usize;
    let nav = largest_component(&navigable(world, radius), w, h);
    let starts: Vec<usize> = (0..w * h).filter(|&i| nav[i]).collect();
    ensure!(
        !starts.is_empty(),
        "the world has no free space where a robot of radius {} m fits",
        cfg.robot_radius_m
    );
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut cur = starts[rng.random_range(0..starts.len())];
    let mut heading = Angle(rng.random::<u16>());
    let sep = (cfg.min_stop_separation_m / res).powi(2);
    let max_step = (cfg.max_step_m / res).max(1.0);
    let mut stops: Vec<usize> = Vec::new();
    let mut records = Vec::new();
    let pose_of = |i: usize, heading: Angle| {
        let (x, y) = (i % w, i / w);
        Pose {
            x_mm: ((world.origin_m.0 + (x as f64 + 0.5) * res) * 1000.0).round() as i32,
            y_mm: ((world.origin_m.1 + (y as f64 + 0.5) * res) * 1000.0).round() as i32,
            heading,
        }
    };
    let moving = cfg.moving_step_cells(res);
    let limit = cfg.max_stops.max(cfg.min_scans);
    // Distance driven since the last scan while moving, cells.
    let mut since_scan = 0.0f64;
    let mut observed_now: Vec<bool> = vec![false; w * h];
    let mut first = true;
    while records.len() < limit {
        let pose = pose_of(cur, heading);
        let observed = if moving.is_none() || first {
            first = false;
            let (beams, observed) = scan_and_map(&pose).context("scanning")?;
            records.push(ScanRecord { pose, beams });
            observed_now.clone_from(&observed);
            observed
        } else {
            observed_now.clone()
        };
        ensure!(
            observed.len() == w * h,
            "observed mask has {} cells, world {}",
            observed.len(),
            w * h
        );
        stops.push(cur);
        // Unobserved navigable cells per neighbourhood, by a summed-area table.
        let r = (cfg.cluster_radius_m / res).ceil() as usize;
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            for x in 0..w {
                let v = u32::from(nav[y * w + x] && !observed[y * w + x]);
                sat[(y + 1) * (w + 1) + x + 1] =
                    v + sat[y * (w + 1) + x + 1] + sat[(y + 1) * (w + 1) + x]
                        - sat[y * (w + 1) + x];
            }
        }
        let unobserved_near = |i: usize| {
            let (x, y) = (i % w, i / w);
            let (x0, y0, x1, y1) = (
                x.saturating_sub(r),
                y.saturating_sub(r),
                (x + r + 1).min(w),
                (y + r + 1).min(h),
            );
            (sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
                - sat[y0 * (w + 1) + x1]
                - sat[y1 * (w + 1) + x0]) as usize
        };
        // BFS over navigable cells for the nearest target far enough from all stops.
        let mut parent = vec![usize::MAX; w * h];
        parent[cur] = cur;
        let mut q = VecDeque::from([cur]);
        let mut target = None;
        while let Some(i) = q.pop_front() {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let far_from_stops = stops.iter().all(|&s| {
                let (sx, sy) = ((s % w) as f64, (s / w) as f64);
                (sx - x).powi(2) + (sy - y).powi(2) >= sep
            });
            if !observed[i] && far_from_stops && unobserved_near(i) >= cfg.min_unobserved {
                target = Some(i);
                break;
            }
            for (nx, ny) in neighbours8(x as i64, y as i64, w, h) {
                let j = ny * w + nx;
                if nav[j] && parent[j] == usize::MAX {
                    parent[j] = i;
                    q.push_back(j);
                }
            }
        }
        let target = match target {
            Some(t) => t,
            // Explored: patrol to a random reachable cell for a long mission.
            None if records.len() < cfg.min_scans => {
                let reachable: Vec<usize> = (0..w * h)
                    .filter(|&i| parent[i] != usize::MAX && i != cur)
                    .collect();
                if reachable.is_empty() {
                    break;
                }
                reachable[rng.random_range(0..reachable.len())]
            }
            None => break,
        };
        // Path back from the target; drive at most `max_step` cells along it.
        let mut path = vec![target];
        while let Some(&last) = path.last() {
            if last == cur {
                break;
            }
            path.push(parent[last]);
        }
        path.reverse();
        if let Some(step) = moving {
            // Drive the whole path, scanning every `step` cells.
            for pair in path.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                let (ax, ay) = ((a % w) as f64, (a / w) as f64);
                let (bx, by) = ((b % w) as f64, (b / w) as f64);
                let d = (bx - ax).hypot(by - ay);
                heading = Angle::from_radians((by - ay).atan2(bx - ax));
                let mut t = step - since_scan;
                while t <= d && records.len() < limit {
                    let f = t / d;
                    let (x, y) = (ax + f * (bx - ax), ay + f * (by - ay));
                    let pose = Pose {
                        x_mm: ((world.origin_m.0 + (x + 0.5) * res) * 1000.0).round() as i32,
                        y_mm: ((world.origin_m.1 + (y + 0.5) * res) * 1000.0).round() as i32,
                        heading,
                    };
                    let (beams, observed) = scan_and_map(&pose).context("scanning")?;
                    records.push(ScanRecord { pose, beams });
                    observed_now = observed;
                    t += step;
                }
                since_scan = d - (t - step);
            }
            cur = target;
            continue;
        }
        let mut travelled = 0.0;
        let mut next = cur;
        for pair in path.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let diag = (a % w != b % w) && (a / w != b / w);
            let d = if diag { std::f64::consts::SQRT_2 } else { 1.0 };
            if travelled + d > max_step {
                break;
            }
            travelled += d;
            next = b;
        }
        let (dx, dy) = (
            (next % w) as f64 - (cur % w) as f64,
            (next / w) as f64 - (cur / w) as f64,
        );
        if dx != 0.0 || dy != 0.0 {
            heading = Angle::from_radians(dy.atan2(dx));
        }
        cur = next;
    }
    Ok(records)
}
