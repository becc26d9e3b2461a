//! What a `host-sim firmware` run reports ([`FirmwareReport`]) and how it is printed.

use std::collections::BTreeMap;
use std::path::PathBuf;

use ogm_core::config::RunConfig;
use ogm_core::wire::{Counters, Done, SamplerReport};
use ogm_field::stream::{DeviceEvent, OwnedHello};
use serde::Serialize;

use super::groups::Groups;
use crate::eval::metrics::Summary;

/// The outcome of one `host-sim firmware` run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FirmwareReport {
    /// The firmware's boot message.
    pub hello: Option<OwnedHello>,
    /// Settings sent.
    pub config: Option<RunConfig>,
    /// Scans sent.
    pub scans_sent: usize,
    /// Bytes sent to the robot (garbage included).
    pub input_bytes: usize,
    /// Garbage bytes mixed in.
    pub garbage_bytes: usize,
    /// Map-stream bytes received.
    pub stream_bytes: u64,
    /// Map-stream frames (and bad ones).
    pub stream_frames: u64,
    /// Bad frames in the stream.
    pub stream_bad_frames: u64,
    /// Tiles received.
    pub tiles: u64,
    /// Error messages the firmware sent.
    pub device_errors: usize,
    /// The firmware's final counters.
    pub counters: Option<Counters>,
    /// The firmware's final sampler statistics.
    pub sampler: Option<SamplerReport>,
    /// The firmware's `Done`.
    pub done: Option<Done>,
    /// QEMU's exit status (the firmware's exit code).
    pub exit_code: Option<i32>,
    /// Wall-clock seconds in QEMU.
    pub qemu_seconds: f64,
    /// Instruction counts.
    pub figures: Figures,
    /// Differences between the firmware and the host replay (empty = identical).
    pub mismatches: Vec<String>,
    /// Comparisons made (reports, tiles, cells).
    pub checks: u64,
    /// Drifting odometry sent (`--odometry-noise`): its error and the corrected poses' error
    /// against the truth.
    pub odometry: Option<super::odometry::OdometryReport>,
    /// Accuracy of the firmware's bounds vs the unbounded host configuration (`--accuracy`).
    pub accuracy: Option<Accuracy>,
    /// Where QEMU's log went.
    pub log: Option<PathBuf>,
    /// `Hello` messages received (1 = the firmware never reset).
    pub hellos: usize,
    /// What `--noise-ppm` did to the input.
    pub noise: Option<NoiseReport>,
    /// `--robot`: the two serial lines and how well the turns were placed.
    pub robot: Option<RobotReport>,
}

impl FirmwareReport {
    /// Whether the firmware's map equals the host's, cell for cell (and it ran to the end).
    pub fn identical(&self) -> bool {
        self.mismatches.is_empty() && self.done.is_some() && self.checks > 0
    }

    /// Fills in what the robot's map stream says (`events`, grouped as `groups`): its `Hello`
    /// and how many it sent, tiles, errors, the final counters and sampler report, `Done`, and
    /// the instruction figures.
    pub(super) fn read_stream(&mut self, groups: &Groups, events: &[DeviceEvent]) {
        self.hello = groups.hello.clone();
        self.hellos = events
            .iter()
            .filter(|e| matches!(e, DeviceEvent::Hello(_)))
            .count();
        self.tiles = groups.all_tiles.len() as u64;
        self.device_errors = groups.errors;
        self.counters = groups.final_counters;
        self.sampler = groups.final_sampler;
        self.done = groups.done;
        if let Some(h) = &groups.hello {
            self.figures = figures(groups, h);
        }
    }
}

/// Instruction counts (QEMU `-icount shift=0`: 1 ns of board time = 1 instruction).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Figures {
    /// Scans processed.
    pub scans: u32,
    /// Mean beams per scan.
    pub beams_per_scan: f64,
    /// Mean cells updated per scan.
    pub cells_per_scan: f64,
    /// `insert_and_seed` (log-odds update, seeding, ray store, first-occupied refresh):
    /// instructions per scan (mean).
    pub insert_per_scan: f64,
    /// … the largest.
    pub insert_per_scan_max: u64,
    /// … per updated cell.
    pub insert_per_cell: f64,
    /// The largest per-scan step plus sampling after it (`insert_ticks + store_ticks +
    /// sampler_ticks`), instructions: under a time budget, at most the period plus the
    /// sampler's last call past it.
    pub cycle_per_scan_max: u64,
    /// Ray store add + first-occupied refresh, per scan, when the firmware times it separately
    /// (older firmware; 0 since both are part of `insert_and_seed`, i.e. of `insert_per_scan`).
    pub store_per_scan: f64,
    /// The scan matcher (pose correction): instructions per scan (mean; 0 with correction off).
    pub match_per_scan: f64,
    /// … the largest.
    pub match_per_scan_max: u64,
    /// Sampler patch updates in total.
    pub sampler_updates: u64,
    /// Sampler updates per scan (mean).
    pub updates_per_scan: f64,
    /// Instructions per sampled patch (amortised: tile visits' ray gathering included).
    pub per_patch: f64,
    /// Stack high-water mark of the mapping loop, bytes.
    pub stack_used: u32,
    /// Stack high-water mark while the settings were applied (building the sampler), bytes.
    pub stack_config: u32,
    /// Stack size, bytes.
    pub stack_size: u32,
}

/// `--robot`: what the lidar's UART and the link carried, and the placement error of the turns
/// the firmware mapped against the simulator's true sensor pose at each turn's time.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RobotReport {
    /// Turns the lidar sent (complete ones).
    pub turns_sent: u32,
    /// Lidar bytes.
    pub lidar_bytes: usize,
    /// Pose messages sent.
    pub poses_sent: usize,
    /// Pose period, µs.
    pub pose_period_us: u64,
    /// Turns the firmware reported.
    pub turns_mapped: usize,
    /// Largest position error of a turn's pose, mm.
    pub max_position_error_mm: f64,
    /// Largest heading error of a turn's pose, degrees.
    pub max_heading_error_deg: f64,
}

/// `--noise-ppm`: the damage done to the robot's input.
#[derive(Clone, Debug, Default, Serialize)]
pub struct NoiseReport {
    /// Bytes corrupted.
    pub corrupted_bytes: usize,
    /// LD06 packets sent / of which damaged (at least one corrupted byte).
    pub packets: usize,
    /// …
    pub damaged_packets: usize,
    /// Host frames sent (repeats included) / of which damaged.
    pub frames: usize,
    /// …
    pub damaged_frames: usize,
    /// Damaged packets that still pass the LD06's checks (header and 8-bit CRC: one damaged
    /// packet in 256 does), so the firmware rightly accepts them.
    pub undetected_packets: usize,
    /// Packets and frames the firmware can accept before the first intact `Finish` (it stops
    /// reading there): the intact ones, and for packets also the undetectably damaged ones.
    pub intact_packets_before_finish: usize,
    /// …
    pub intact_frames_before_finish: usize,
    /// Points of the rejected damaged packets inside scans whose framing arrived (the ones the
    /// firmware must report lost).
    pub points_in_damaged_packets: u64,
    /// Whether a host replay of only the packets and frames the firmware can accept (intact,
    /// or damaged past detection) gives its final map (log-odds, marginal counts, sample), cell
    /// for cell.
    pub surviving_replay_identical: bool,
}

/// `--accuracy`: metrics of the maps of the same runs.
#[derive(Clone, Debug, Serialize)]
pub struct Accuracy {
    /// Worlds pooled.
    pub runs: u32,
    /// Scans per world.
    pub scans: Vec<usize>,
    /// All cells with known truth: `traditional` (Hähnel's textbook log-odds map),
    /// `traditional_noise_matched` (the robot's own log-odds map, when its free update is
    /// scaled), `offline_firmware_sizes`, `offline_unbounded` (and `online_*` after a QEMU
    /// run).
    pub methods: BTreeMap<String, Summary>,
    /// Cells within 10 cells of a mapped cell.
    pub methods_near_mapped: BTreeMap<String, Summary>,
    /// Rays that did not fit the per-tile list, summed over the runs (offline, firmware sizes).
    pub local_overflow_firmware: u64,
    /// … unbounded (0 by construction).
    pub local_overflow_unbounded: u64,
    /// Tile visits, summed (offline, firmware sizes).
    pub tile_visits: u64,
    /// Ray-store thinnings (firmware sizes), summed.
    pub thinnings: u32,
    /// Max F1 (all cells) of the on-board marginals and of the log-odds map as the scans come
    /// in (first world; at most ~200 points).
    pub anytime: Vec<AnytimePoint>,
}

/// One point of the anytime curve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AnytimePoint {
    /// Scans inserted.
    pub scans: u32,
    /// Max F1 of the sampler's marginals.
    pub online: f64,
    /// Max F1 of the log-odds map.
    pub log_odds: f64,
}

/// The figures from the firmware's reports.
pub(super) fn figures(g: &Groups, hello: &OwnedHello) -> Figures {
    let ns_per_tick = 1e9 / f64::from(hello.tick_hz.max(1));
    let mut f = Figures::default();
    let (mut beams, mut cells, mut insert, mut store, mut sampler, mut updates) =
        (0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
    let mut matching = 0u64;
    for s in g.scans.values() {
        let r = &s.report;
        f.scans += 1;
        beams += u64::from(r.beams);
        cells += u64::from(r.mapper.cells_hit + r.mapper.cells_freed);
        insert += u64::from(r.insert_ticks);
        store += u64::from(r.store_ticks);
        sampler += u64::from(r.sampler_ticks);
        updates += u64::from(r.sampler_updates);
        f.insert_per_scan_max = f
            .insert_per_scan_max
            .max((f64::from(r.insert_ticks) * ns_per_tick) as u64);
        matching += u64::from(r.match_ticks);
        f.match_per_scan_max = f
            .match_per_scan_max
            .max((f64::from(r.match_ticks) * ns_per_tick) as u64);
        let cycle =
            u64::from(r.insert_ticks) + u64::from(r.store_ticks) + u64::from(r.sampler_ticks);
        f.cycle_per_scan_max = f
            .cycle_per_scan_max
            .max((cycle as f64 * ns_per_tick) as u64);
    }
    let n = f64::from(f.scans.max(1));
    f.beams_per_scan = beams as f64 / n;
    f.cells_per_scan = cells as f64 / n;
    f.insert_per_scan = insert as f64 * ns_per_tick / n;
    f.insert_per_cell = insert as f64 * ns_per_tick / cells.max(1) as f64;
    f.store_per_scan = store as f64 * ns_per_tick / n;
    f.match_per_scan = matching as f64 * ns_per_tick / n;
    f.sampler_updates = updates;
    f.updates_per_scan = updates as f64 / n;
    f.per_patch = sampler as f64 * ns_per_tick / updates.max(1) as f64;
    if let Some(d) = &g.done {
        (f.stack_used, f.stack_config, f.stack_size) = (d.stack_used, d.stack_config, d.stack_size);
    }
    f
}

/// Prints a report.
pub fn print_report(r: &FirmwareReport) {
    if let Some(h) = &r.hello {
        println!(
            "firmware: {} on {}; grid {}x{}, {} rays, {} scans, {} local rays, {} beams/scan",
            h.firmware,
            h.board,
            h.width,
            h.height,
            h.ray_capacity,
            h.scan_capacity,
            h.local_capacity,
            h.max_beams
        );
    }
    if r.exit_code.is_some() || r.stream_bytes > 0 {
        println!(
            "link: {} scans, {} bytes in ({} garbage); stream {} bytes, {} frames ({} bad), {} tiles, {} error reports; QEMU {:.1} s, exit {:?}",
            r.scans_sent, r.input_bytes, r.garbage_bytes, r.stream_bytes, r.stream_frames,
            r.stream_bad_frames, r.tiles, r.device_errors, r.qemu_seconds, r.exit_code
        );
    }
    if let Some(c) = &r.counters {
        println!("counters: {c:?}");
    }
    if let Some(o) = &r.odometry {
        let e = |p: &super::odometry::PoseErrors| {
            format!(
                "{:.3} / {:.3} m, {:.2} / {:.2} deg",
                p.mean_m, p.max_m, p.mean_deg, p.max_deg
            )
        };
        println!(
            "odometry {} (seed {}): sent {}; mapped at {} (mean / max vs the truth); {} scans corrected, {} cannot tell",
            o.model,
            o.seed,
            e(&o.odometry),
            e(&o.corrected),
            o.matched,
            o.cannot_tell
        );
    }
    if let Some(rb) = &r.robot {
        println!(
            "robot loop: {} turns on the lidar UART ({} bytes), {} poses on the link every {} ms; {} turns mapped, placed within {:.1} mm and {:.2} deg of the true sensor pose",
            rb.turns_sent,
            rb.lidar_bytes,
            rb.poses_sent,
            rb.pose_period_us / 1000,
            rb.turns_mapped,
            rb.max_position_error_mm,
            rb.max_heading_error_deg
        );
    }
    if let Some(n) = &r.noise {
        println!(
            "noise: {} bytes corrupted; {} of {} LD06 packets ({} of them past the 8-bit CRC) and {} of {} frames damaged; {} points in rejected packets of framed scans; replay of the acceptable packets alone {}",
            n.corrupted_bytes, n.damaged_packets, n.packets, n.undetected_packets, n.damaged_frames, n.frames,
            n.points_in_damaged_packets,
            if n.surviving_replay_identical { "identical" } else { "DIFFERENT" }
        );
    }
    if r.hellos > 1 {
        println!("the firmware reset: {} Hello messages", r.hellos);
    }
    if let Some(s) = &r.sampler {
        println!("sampler: {s:?}");
    }
    let f = &r.figures;
    if f.scans > 0 {
        println!(
            "instructions (qemu -icount shift=0): insert+seed+store+refresh per updated cell {:.1}, per scan {:.0} (max {}, {:.0} beams, {:.0} cells; separate store+refresh {:.0}/scan); per sampled patch {:.0} ({} updates, {:.0}/scan); stack {} B (mapping loop) / {} B (building the sampler) of {} B",
            f.insert_per_cell, f.insert_per_scan, f.insert_per_scan_max, f.beams_per_scan,
            f.cells_per_scan, f.store_per_scan, f.per_patch, f.sampler_updates,
            f.updates_per_scan, f.stack_used, f.stack_config, f.stack_size
        );
        if f.match_per_scan > 0.0 {
            println!(
                "scan matcher (pose correction): {:.0} instructions per scan (max {})",
                f.match_per_scan, f.match_per_scan_max
            );
        }
    }
    if let Some(a) = &r.accuracy {
        println!("accuracy, L = 9 + border (all cells | near mapped cells): max F1, max precision; online_*: first world only");
        for (k, v) in &a.methods {
            let n = &a.methods_near_mapped[k];
            println!(
                "  {k:<28} {:.4} {:.4} | {:.4} {:.4}",
                v.max_f1, v.max_precision, n.max_f1, n.max_precision
            );
        }
        println!(
            "  {} world(s), {:?} scans; offline local-list overflow: firmware sizes {} / unbounded {}; ray-store thinnings {}",
            a.runs, a.scans, a.local_overflow_firmware, a.local_overflow_unbounded, a.thinnings
        );
    }
    if r.exit_code.is_some() {
        if r.identical() {
            println!(
                "IDENTICAL: the streamed map equals ogm-core on the host, cell for cell ({} checks)",
                r.checks
            );
        } else {
            println!("DIFFERENT ({} checks):", r.checks);
            for m in &r.mismatches {
                println!("  {m}");
            }
            if let Some(l) = &r.log {
                println!("QEMU log: {}", l.display());
            }
        }
    }
}
