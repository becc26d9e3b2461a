//! A `host-sim firmware` run: the world, the simulated run and the robot's input, the
//! firmware in QEMU (or the host alone), the comparison and the report; the command.

use std::time::Duration;

use anyhow::{bail, ensure, Context};
use ogm_core::config::{LidarModel, RunConfig};
use ogm_core::wire::ScanReport;
use ogm_field::stream::{decode_file, DeviceEvent};
use ogm_firmware::sizes::MPS2_AN386 as FW;

use super::accuracy::{accuracy, Online};
use super::args::{FirmwareArgs, LidarArg, PatternArg};
use super::compare::{compare, noise_report, Checker};
use super::groups::{decode_captured, Groups};
use super::input::{corrupt, encode_run_idle};
use super::odometry::{with_odometry, OdometryReport};
use super::qemu::{
    build_elf, build_elf_with, check_elf, repo_root, run_qemu, toolchain_missing, LidarLine,
    QemuRun,
};
use super::replay::replay_fixed;
use super::report::{figures, print_report, AnytimePoint, FirmwareReport, RobotReport};
use super::setup::{firmware_world, idle_periods_us, run_config, sim_config};
use crate::sim::simulate;

/// Runs `host-sim firmware` (see the module docs).
pub fn run(args: &FirmwareArgs) -> anyhow::Result<FirmwareReport> {
    ensure!(
        args.robot || (args.lidar == LidarArg::Ld06 && args.pattern.is_none()),
        "--lidar and --pattern describe the lidar on the robot's own UART: add --robot"
    );
    if args.robot {
        return run_robot(args);
    }
    let root = repo_root();
    let qemu_dir = root.join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let world = firmware_world(args)?;
    ensure!(
        world.width <= usize::from(FW.width) && world.height <= usize::from(FW.height),
        "world is {}x{} cells, the firmware's grid {}x{}",
        world.width,
        world.height,
        FW.width,
        FW.height
    );
    let sim = simulate(&world, &sim_config(args), args.seed)?;
    let mut scans = sim.scans.clone();
    if let Some(n) = args.max_scans {
        scans.truncate(n);
    }
    if let Some(n) = args.soak_scans {
        ensure!(
            !scans.is_empty(),
            "the simulated run has no scans to soak with"
        );
        scans = scans.iter().cycle().take(n).cloned().collect();
    }
    let config = run_config(&world, args, sim.mapper_config.max_range_mm);
    let idle_us = idle_periods_us(&args.idle)?;
    // What the robot is told: the true poses, or drifting odometry along them.
    let sent = match &args.odometry_noise {
        Some(o) => with_odometry(&scans, o, args.seed),
        None => scans.clone(),
    };
    let mut input = encode_run_idle(&config, &sent, args.garbage, args.repeat_frames, &idle_us)?;
    let corrupted = corrupt(&mut input.bytes, args.noise_ppm, args.seed);
    let mut report = FirmwareReport {
        config: Some(config),
        scans_sent: input.scans,
        input_bytes: input.bytes.len(),
        garbage_bytes: input.garbage_bytes,
        ..FirmwareReport::default()
    };
    let mut updates_used: Vec<u32> = Vec::new();
    let mut idle_used: Vec<u32> = Vec::new();
    if !args.host_only {
        let elf = match &args.elf {
            Some(e) => e.clone(),
            None => build_elf(&qemu_dir.join("host-sim-build.log"))?,
        };
        let log = (!args.verbose).then(|| qemu_dir.join("host-sim-firmware.log"));
        let QemuRun {
            stream,
            status,
            secs,
            ..
        } = run_qemu(
            &elf,
            &input.bytes,
            None,
            Duration::from_secs(args.timeout),
            log.as_deref(),
        )?;
        report.log = log.clone();
        report.qemu_seconds = secs;
        report.exit_code = status.and_then(|s| s.code());
        if let Some(out) = &args.out {
            std::fs::create_dir_all(out)?;
            std::fs::write(out.join("stream.bin"), &stream)?;
            std::fs::write(out.join("input.bin"), &input.bytes)?;
        }
        let (events, ds) = decode_captured(&stream);
        (
            report.stream_bytes,
            report.stream_frames,
            report.stream_bad_frames,
        ) = (ds.bytes, ds.frames, ds.bad_frames);
        let groups = Groups::of(&events);
        report.read_stream(&groups, &events);
        let mut checker = Checker::default();
        if report.exit_code != Some(0) {
            checker.fail(format!(
                "firmware exit status {:?} (log: {})",
                report.exit_code,
                log.as_ref()
                    .map_or("stdout".into(), |l| l.display().to_string())
            ));
        }
        match compare(&input.bytes, &[], &groups, &mut checker) {
            Ok(()) => {}
            Err(e) => checker.fail(format!("{e:#}")),
        }
        if args.noise_ppm > 0 {
            match noise_report(&input, &corrupted, &groups) {
                Ok(n) => {
                    if !n.surviving_replay_identical {
                        checker.fail(
                            "a replay of only the intact packets and frames gives another map"
                                .into(),
                        );
                    }
                    report.noise = Some(n);
                }
                Err(e) => checker.fail(format!("surviving-packets replay: {e:#}")),
            }
        }
        report.mismatches = checker.mismatches;
        report.checks = checker.checks;
        let mut seqs: Vec<&u32> = groups.scans.keys().collect();
        seqs.sort();
        if let Some(o) = &args.odometry_noise {
            let reports: Vec<ScanReport> = seqs.iter().map(|s| groups.scans[s].report).collect();
            report.odometry = Some(OdometryReport::of(o, args.seed, &scans, &sent, &reports));
        }
        updates_used = seqs
            .iter()
            .map(|s| groups.scans[s].report.sampler_updates)
            .collect();
        idle_used = (0..idle_us.len() as u32)
            .map(|s| groups.idles.get(&s).map_or(0, |r| r.sampler_updates))
            .collect();
    }
    if args.host_only {
        // No firmware to report its update counts: the fixed number per scan, if given.
        if let Some(n) = args.fixed_updates {
            updates_used = vec![n; input.scans];
            // Idle at the same rate: `n` updates per 10 Hz scan period.
            idle_used = idle_us
                .iter()
                .map(|&us| (u64::from(n) * u64::from(us) / 100_000).min(u64::from(u32::MAX)) as u32)
                .collect();
        }
    }
    if args.accuracy {
        let online = (!updates_used.is_empty()).then_some(Online {
            input: &input.bytes,
            scan_updates: &updates_used,
            idle_updates: &idle_used,
            idle_marks: &args.idle,
        });
        report.accuracy = Some(accuracy(args, &config, &world, &sim, &scans, online)?);
    }
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out)?;
        let json = serde_json::to_string_pretty(&report)?;
        std::fs::write(out.join("report.json"), json + "\n")?;
        if let Some(a) = report.accuracy.as_ref().filter(|a| !a.anytime.is_empty()) {
            let pts = |f: fn(&AnytimePoint) -> f64| -> Vec<(f64, f64)> {
                a.anytime
                    .iter()
                    .map(|p| (f64::from(p.scans), f(p)))
                    .collect()
            };
            crate::eval::render::anytime_svg(
                out.join("anytime.svg"),
                &[
                    ("online marginals (firmware)", pts(|p| p.online)),
                    ("log-odds map", pts(|p| p.log_odds)),
                ],
                &format!("Online map quality, seed {}", args.seed),
            )?;
        }
    }
    Ok(report)
}

/// The firmware in QEMU on given settings and scans (tunnelled with their poses, a fixed
/// budget in `config` makes every figure repeatable), checked against the host replay like
/// [`run`]; returns the report and the firmware's decoded stream (a rolling window's tiles,
/// `Window` messages, ...). `None` for the report's QEMU part when the toolchain is missing is
/// the caller's concern ([`toolchain_missing`]).
pub fn run_scans(
    config: &RunConfig,
    scans: &[crate::sim::explore::ScanRecord],
    timeout: Duration,
) -> anyhow::Result<(FirmwareReport, Vec<DeviceEvent>)> {
    let qemu_dir = repo_root().join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let input = encode_run_idle(config, scans, false, 1, &[])?;
    let elf = build_elf(&qemu_dir.join("host-sim-build.log"))?;
    let log = qemu_dir.join("host-sim-firmware.log");
    let QemuRun {
        stream,
        status,
        secs,
        ..
    } = run_qemu(&elf, &input.bytes, None, timeout, Some(&log))?;
    let (events, ds) = decode_captured(&stream);
    let groups = Groups::of(&events);
    let mut report = FirmwareReport {
        config: Some(*config),
        scans_sent: input.scans,
        input_bytes: input.bytes.len(),
        log: Some(log),
        qemu_seconds: secs,
        exit_code: status.and_then(|s| s.code()),
        stream_bytes: ds.bytes,
        stream_frames: ds.frames,
        stream_bad_frames: ds.bad_frames,
        hello: groups.hello.clone(),
        tiles: groups.all_tiles.len() as u64,
        device_errors: groups.errors,
        counters: groups.final_counters,
        sampler: groups.final_sampler,
        done: groups.done,
        ..FirmwareReport::default()
    };
    let mut checker = Checker::default();
    if let Err(e) = compare(&input.bytes, &[], &groups, &mut checker) {
        checker.fail(format!("{e:#}"));
    }
    if let Some(h) = &groups.hello {
        report.figures = figures(&groups, h);
    }
    report.mismatches = checker.mismatches;
    report.checks = checker.checks;
    Ok((report, events))
}

/// `--robot`: the robot loop in QEMU (see [`FirmwareArgs::robot`]).
fn run_robot(args: &FirmwareArgs) -> anyhow::Result<FirmwareReport> {
    ensure!(
        !args.accuracy
            && args.idle.is_empty()
            && args.noise_ppm == 0
            && !args.garbage
            && args.soak_scans.is_none()
            && args.repeat_frames <= 1,
        "--robot runs the robot loop only: no --accuracy, --idle, --noise-ppm, --garbage, \
         --soak-scans or --repeat-frames with it"
    );
    let world = firmware_world(args)?;
    let moving = FirmwareArgs {
        moving: true,
        ..args.clone()
    };
    let sim_cfg = sim_config(&moving);
    let sim = simulate(&world, &sim_cfg, args.seed)?;
    let mut poses: Vec<ogm_core::Pose> = sim.scans.iter().map(|s| s.pose).collect();
    if let Some(n) = args.max_scans {
        // `n` turns, and the pose where the next one begins.
        poses.truncate(n + 1);
    }
    let config = RunConfig {
        mount: ogm_core::Pose {
            x_mm: ROBOT_MOUNT_X_MM,
            y_mm: 0,
            heading: ogm_core::Angle(0),
        },
        lidar: args.lidar.model(),
        ..run_config(&world, args, sim.mapper_config.max_range_mm)
    };
    let pattern = match args.pattern {
        None => super::robot::ScanPattern::of(&config.lidar),
        Some(PatternArg::Ld06) => super::robot::ScanPattern::LD06,
        Some(PatternArg::A1) => super::robot::ScanPattern::A1,
    };
    let input = super::robot::robot_input(
        &world,
        &poses,
        &config,
        pattern,
        sim_cfg.lidar.sigma_cells,
        super::robot::POSE_PERIOD_US,
        args.seed,
    )?;
    run_input(args, &config, &input).map(|(r, _)| r)
}

/// A robot run's two serial lines (`input`, made for `config`) through the firmware in QEMU,
/// checked bit-exact against the host replay (or, with `--host-only`, the replay alone); the
/// report and the captured map stream.
pub(super) fn run_input(
    args: &FirmwareArgs,
    config: &RunConfig,
    input: &super::robot::RobotInput,
) -> anyhow::Result<(FirmwareReport, Vec<u8>)> {
    let root = repo_root();
    let qemu_dir = root.join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let link: Vec<u8> = [&input.link[..], &input.finish[..]].concat();
    if args.host_only {
        // The firmware's application on the host, on the same two byte streams, with a fixed
        // number of sampler updates per turn.
        let n = args.fixed_updates.unwrap_or(0);
        let (stream, events) = replay_fixed(&link, &input.lidar, n)?;
        let groups = Groups::of(&events);
        return Ok((robot_report(config, input, &link, &groups, &events), stream));
    }
    let (elf, log) = robot_firmware(args, &qemu_dir)?;
    let line = LidarLine {
        bytes: &input.lidar,
        schedule: &input.schedule,
        finish: &input.finish,
        last_turn: input.turns.saturating_sub(1),
        answers: matches!(config.lidar, LidarModel::Rplidar { .. })
            .then_some(ogm_core::lidar::rplidar::REQ_SCAN),
    };
    let run = run_qemu(
        &elf,
        &input.link,
        Some(line),
        Duration::from_secs(args.timeout),
        log.as_deref(),
    )?;
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out)?;
        std::fs::write(out.join("stream.bin"), &run.stream)?;
        std::fs::write(out.join("input.bin"), &link)?;
        std::fs::write(out.join("lidar.bin"), &input.lidar)?;
    }
    // What an RPLIDAR must hear before it scans: STOP, then SCAN; an LD06 nothing.
    let want: &[u8] = match config.lidar {
        LidarModel::Rplidar { .. } => &[
            ogm_core::lidar::rplidar::REQ_STOP,
            ogm_core::lidar::rplidar::REQ_SCAN,
        ]
        .concat(),
        LidarModel::Ld06 => &[],
    };
    let report = checked_robot_report(config, input, &link, &run, log, |checker| {
        checker.eq(
            || "bytes the firmware sent the lidar".into(),
            &run.heard.as_slice(),
            &want,
        );
    });
    Ok((report, run.stream))
}

/// The firmware ELF a robot run uses (`--elf`, else built with the lidar's features; the build
/// log in `qemu_dir`) and where QEMU's log goes (`None` with `--verbose`: stdout).
pub(super) fn robot_firmware(
    args: &FirmwareArgs,
    qemu_dir: &std::path::Path,
) -> anyhow::Result<(std::path::PathBuf, Option<std::path::PathBuf>)> {
    let elf = match &args.elf {
        Some(e) => e.clone(),
        None => build_elf_with(&qemu_dir.join("host-sim-build.log"), args.lidar.features())?,
    };
    Ok((
        elf,
        (!args.verbose).then(|| qemu_dir.join("host-sim-firmware.log")),
    ))
}

/// The report of a robot run in QEMU (`run`, its log at `log`): its stream decoded and checked
/// message for message against the host replay of `link` (the link as the host sent it) and
/// `input`'s lidar bytes, its exit status checked, `more` checks added.
pub(super) fn checked_robot_report(
    config: &RunConfig,
    input: &super::robot::RobotInput,
    link: &[u8],
    run: &QemuRun,
    log: Option<std::path::PathBuf>,
    more: impl FnOnce(&mut Checker),
) -> FirmwareReport {
    let (events, ds) = decode_captured(&run.stream);
    let groups = Groups::of(&events);
    let mut checker = Checker::default();
    let exit_code = run.status.and_then(|s| s.code());
    if exit_code != Some(0) {
        checker.fail(format!(
            "firmware exit status {exit_code:?} (log: {})",
            log.as_ref()
                .map_or("stdout".into(), |l| l.display().to_string())
        ));
    }
    if let Err(e) = compare(link, &input.lidar, &groups, &mut checker) {
        checker.fail(format!("{e:#}"));
    }
    more(&mut checker);
    let r = robot_report(config, input, link, &groups, &events);
    FirmwareReport {
        stream_bytes: ds.bytes,
        stream_frames: ds.frames,
        stream_bad_frames: ds.bad_frames,
        exit_code,
        qemu_seconds: run.secs,
        mismatches: checker.mismatches,
        checks: checker.checks,
        log,
        ..r
    }
}

/// The LD06 sits this far ahead of the robot's centre in `--robot` runs, mm.
pub const ROBOT_MOUNT_X_MM: i32 = 60;

/// What a `--robot` run's stream says: the turns and how well they were placed.
pub(super) fn robot_report(
    config: &RunConfig,
    input: &super::robot::RobotInput,
    link: &[u8],
    groups: &Groups,
    events: &[DeviceEvent],
) -> FirmwareReport {
    let mut reports: Vec<ScanReport> = groups.scans.values().map(|g| g.report).collect();
    reports.sort_by_key(|r| r.seq);
    let (pos, head) = super::robot::pose_errors(&reports, input, config);
    let mut report = FirmwareReport {
        config: Some(*config),
        scans_sent: input.turns as usize,
        input_bytes: link.len() + input.lidar.len(),
        robot: Some(RobotReport {
            turns_sent: input.turns,
            lidar_bytes: input.lidar.len(),
            poses_sent: input.poses,
            pose_period_us: super::robot::POSE_PERIOD_US,
            turns_mapped: reports.len(),
            max_position_error_mm: pos,
            max_heading_error_deg: head,
        }),
        ..FirmwareReport::default()
    };
    report.read_stream(groups, events);
    report
}

/// The CLI entry point.
pub fn cli(args: &FirmwareArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.decode {
        let events = decode_file(path)?;
        let g = Groups::of(&events);
        if let Some(h) = &g.hello {
            println!("{h:?}");
            let f = figures(&g, h);
            println!("{}", serde_json::to_string_pretty(&f)?);
        }
        println!(
            "{} scans, {} tiles, {} errors, done: {:?}",
            g.scans.len(),
            g.all_tiles.len(),
            g.errors,
            g.done
        );
        // The latest counters (the final ones, else the last scan's): what a cut-off run saw.
        let last = g.final_counters.or_else(|| {
            let seq = g.scans.keys().max()?;
            g.scans.get(seq)?.counters
        });
        if let Some(c) = last {
            println!("counters: {c:?}");
        }
        ensure!(
            g.done.is_some(),
            "{}: truncated map stream: {} frames but no Done message",
            path.display(),
            events.len()
        );
        return Ok(());
    }
    if let Some(log) = &args.log {
        ensure!(
            !args.robot && !args.accuracy && args.map.is_none() && args.soak_scans.is_none(),
            "--log sends the log's scans: no --robot, --accuracy, --map or --soak-scans with it"
        );
        if let Some(elf) = &args.elf {
            check_elf(elf)?;
        }
        if !args.host_only {
            if let Some(why) = toolchain_missing() {
                bail!("{why}");
            }
        }
        let r = super::log_run::run_log(args, log, args.experiment)?;
        print_report(&r.firmware);
        println!(
            "{}: robot's grid covers {:.1} % of the benchmark's mapped cells; F1 near mapped {}",
            log.display(),
            100.0 * r.coverage,
            r.near_mapped
                .iter()
                .map(|(m, s)| format!("{m} {:.4}", s.max_f1))
                .collect::<Vec<_>>()
                .join(", ")
        );
        if !args.host_only && !r.firmware.identical() {
            bail!("the firmware's map differs from the host's");
        }
        let rb = r.firmware.robot.as_ref().context("no robot report")?;
        ensure!(
            rb.turns_mapped == rb.turns_sent as usize,
            "{} of {} turns were mapped",
            rb.turns_mapped,
            rb.turns_sent
        );
        return Ok(());
    }
    if args.host_only && !args.accuracy && !args.robot {
        bail!("--host-only only makes sense with --accuracy, --robot or --log");
    }
    // Bad input files first, each with a one-line error naming it (before the toolchain check).
    if let Some(elf) = &args.elf {
        check_elf(elf)?;
    }
    if args.map.is_some() {
        firmware_world(args)?;
    }
    if !args.host_only {
        if let Some(why) = toolchain_missing() {
            bail!("{why}");
        }
    }
    let r = run(args)?;
    print_report(&r);
    if !args.host_only && !r.identical() {
        bail!("the firmware's map differs from the host's");
    }
    if let Some(rb) = &r.robot {
        ensure!(
            rb.turns_mapped == rb.turns_sent as usize,
            "{} of {} turns were mapped",
            rb.turns_mapped,
            rb.turns_sent
        );
    }
    Ok(())
}
