//! A host online while the robot maps, sending stored tiles back down the link (issue 38):
//! [`OnlineHost`] keeps the building from the stream (`ogm_field::stream::BuildingMap`) and
//! answers every `Window` that brings stored tiles back into the window with their `Restore`
//! parts, as `listen` does.
//!
//! Through QEMU this must stay bit-exact with the host replay, so the host paces the input
//! (`qemu::run_qemu_paced`): it writes the bytes that let the firmware map scan `s + 1` only
//! once scan `s` is reported and its answers are written. Host-tunnelled scans: scan `s + 1`'s
//! frames wait for report `s`. The robot loop: a turn is mapped when a pose at or after the
//! next turn's first packet arrives (`ogm_core::lidar::turn`), so each pose waits for the
//! report of the turn before the one it can complete. The answers then sit at one place in the
//! link, whatever the timing, and the replay of the link as sent gives the same map.

use std::time::Duration;

use anyhow::Context;
use ogm_core::config::RunConfig;
use ogm_core::lidar::ld06::Ld06Parser;
use ogm_core::wire::HostMsg;
use ogm_field::stream::{host_frame, BuildingMap, DeviceEvent, StreamDecoder};

use super::args::FirmwareArgs;
use super::compare::{compare, Checker};
use super::groups::{decode_captured, Groups};
use super::input::scan_packets;
use super::qemu::{build_elf, repo_root, run_qemu_paced, Answer, Paced, Step};
use super::replay::{replay_fixed, HostMemory, HostPlatform, FIRMWARE_SIZES};
use super::report::FirmwareReport;
use super::robot::{Line, RobotInput};
use super::run::{checked_robot_report, robot_firmware, robot_report};
use crate::sim::explore::ScanRecord;

/// The host's side: the building as streamed, and whether it sends stored tiles back.
pub struct OnlineHost {
    building: Option<BuildingMap>,
    restore: bool,
    /// `Restore` parts sent.
    pub parts_sent: u64,
}

impl OnlineHost {
    /// A host that sends stored tiles back (`restore`) or only listens.
    pub fn new(restore: bool) -> Self {
        OnlineHost {
            building: None,
            restore,
            parts_sent: 0,
        }
    }

    /// Takes one event of the robot's stream; returns the frames to send back: for a `Window`
    /// that shifted, the `Restore` parts of the stored tiles it brings back into the window
    /// and `Resume`, at once (a robot with `RunConfig::window_hold` waits for them).
    pub fn answer(&mut self, e: &DeviceEvent) -> Answer {
        match e {
            DeviceEvent::Hello(h) => {
                self.building = Some(BuildingMap::new(
                    usize::from(h.width),
                    usize::from(h.height),
                    usize::from(h.tile_edge),
                ));
            }
            DeviceEvent::Tile(t) => {
                if let Some(b) = &mut self.building {
                    let _ = b.apply(t);
                }
            }
            DeviceEvent::Window(w) => {
                if let Some(b) = &mut self.building {
                    let shifted = w.shifts > b.window().map_or(0, |p| p.shifts);
                    b.note_window(*w);
                    if self.restore && shifted {
                        let tiles = b.entered().to_vec();
                        let msgs = b.restore_msgs(&tiles);
                        self.parts_sent += msgs.len() as u64;
                        let mut bytes: Vec<u8> = msgs.iter().flat_map(host_frame).collect();
                        bytes.extend(host_frame(&HostMsg::Resume));
                        return Answer { bytes, now: true };
                    }
                }
            }
            _ => {}
        }
        Answer::default()
    }

    /// The building as the host holds it.
    pub fn building(&self) -> Option<&BuildingMap> {
        self.building.as_ref()
    }
}

/// Host-tunnelled scans as paced steps: `Config`; each scan (`ScanStart`, its LD06 packets,
/// `ScanEnd`) after the report of the one before; `Finish` after the last report.
pub(super) fn scan_steps(
    config: &RunConfig,
    scans: &[ScanRecord],
) -> anyhow::Result<(Vec<u8>, Vec<Step>)> {
    let mut link = host_frame(&HostMsg::Config(*config));
    let mut steps = vec![Step {
        line: Line::Link,
        bytes: 0..link.len(),
        after: None,
    }];
    let mut ts = 0u16;
    for (k, s) in scans.iter().enumerate() {
        let seq = u32::try_from(k)?;
        let at = link.len();
        link.extend(host_frame(&HostMsg::ScanStart { seq, pose: s.pose }));
        link.extend(scan_packets(&s.beams, &mut ts)?);
        link.extend(host_frame(&HostMsg::ScanEnd {
            seq,
            points: u32::try_from(s.beams.len())?,
        }));
        steps.push(Step {
            line: Line::Link,
            bytes: at..link.len(),
            after: seq.checked_sub(1),
        });
    }
    let at = link.len();
    link.extend(host_frame(&HostMsg::Finish));
    steps.push(Step {
        line: Line::Link,
        bytes: at..link.len(),
        after: u32::try_from(scans.len())?.checked_sub(1),
    });
    Ok((link, steps))
}

/// A robot loop's schedule (LD06 turns) as paced steps over `link ++ finish`: each link item
/// (a pose) after the report of turn `L − 2`, `L` the last turn whose first packet was written
/// (the pose can complete turn `L − 1`); `Finish` after the last turn's report.
pub(super) fn robot_steps(input: &RobotInput) -> Vec<Step> {
    let mut steps = Vec::with_capacity(input.schedule.len() + 1);
    let (mut started, mut last_start) = (0u32, None::<u16>);
    let mut parser = Ld06Parser::new();
    for (line, r) in &input.schedule {
        if *line == Line::Lidar {
            parser.feed(input.lidar.get(r.clone()).unwrap_or(&[]), |p| {
                if let Ok(p) = p {
                    // A new turn: the start angle falls (as `Turns` tells).
                    if last_start.is_none_or(|l| p.start_cdeg < l) {
                        started += 1;
                    }
                    last_start = Some(p.start_cdeg);
                }
            });
        }
        steps.push(Step {
            line: *line,
            bytes: r.clone(),
            after: (*line == Line::Link)
                .then(|| started.checked_sub(3))
                .flatten(),
        });
    }
    let n = input.link.len();
    steps.push(Step {
        line: Line::Link,
        bytes: n..n + input.finish.len(),
        after: Some(input.turns.saturating_sub(1)),
    });
    steps
}

/// The paced steps run on the host: the firmware's application fed step by step, the host
/// answering each report before the next step that waits for it. Returns the link as sent.
pub(super) fn host_link(
    link: &[u8],
    lidar: &[u8],
    steps: &[Step],
    host: &mut OnlineHost,
    updates: u32,
) -> Vec<u8> {
    let mut memory = HostMemory::<u8>::new();
    let mut app = memory.app(&FIRMWARE_SIZES);
    let mut platform = HostPlatform {
        updates: |_| Some(updates),
        missing: None,
    };
    let (mut out, mut read, mut sent) = (Vec::new(), 0usize, Vec::new());
    app.hello(&mut out, &platform);
    let mut decoder = StreamDecoder::new();
    let mut answers: Vec<(u32, Vec<u8>)> = Vec::new();
    let mut answer = Vec::new();
    for step in steps {
        // Everything streamed so far, through the host; answers due at once are fed at once
        // (and what they make the robot stream is read in turn).
        while read < out.len() {
            let mut now = Vec::new();
            for e in decoder.push(&out[read..]).into_iter().flatten() {
                let a = host.answer(&e);
                answer.extend(a.bytes);
                if a.now {
                    now.append(&mut answer);
                }
                if let DeviceEvent::Scan(r) = e {
                    answers.push((r.seq, std::mem::take(&mut answer)));
                }
            }
            read = out.len();
            sent.extend_from_slice(&now);
            app.feed(&now, &mut out, &mut platform);
        }
        if let Some(s) = step.after {
            // The answers to every report up to `s`, in order, as the paced writer sends them.
            let due = answers.iter().take_while(|(seq, _)| *seq <= s).count();
            let feed: Vec<u8> = answers.drain(..due).flat_map(|(_, b)| b).collect();
            sent.extend_from_slice(&feed);
            app.feed(&feed, &mut out, &mut platform);
        }
        let Some(bytes) = (match step.line {
            Line::Link => link.get(step.bytes.clone()),
            Line::Lidar => lidar.get(step.bytes.clone()),
        }) else {
            continue;
        };
        match step.line {
            Line::Link => {
                sent.extend_from_slice(bytes);
                app.feed(bytes, &mut out, &mut platform);
            }
            Line::Lidar => {
                app.feed_lidar(bytes, &mut out, &mut platform);
            }
        }
    }
    sent
}

/// Host-tunnelled scans through the firmware in QEMU with an online host (sending stored tiles
/// back if `restore`), paced; checked bit-exact against the host replay of the link as sent.
/// Returns the report, the decoded stream and the host.
pub fn run_scans_online(
    config: &RunConfig,
    scans: &[ScanRecord],
    timeout: Duration,
    restore: bool,
) -> anyhow::Result<(FirmwareReport, Vec<DeviceEvent>, OnlineHost)> {
    let qemu_dir = repo_root().join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let (link, steps) = scan_steps(config, scans)?;
    let elf = build_elf(&qemu_dir.join("host-sim-build.log"))?;
    let log = qemu_dir.join("host-sim-firmware.log");
    let mut host = OnlineHost::new(restore);
    let (run, sent) = run_qemu_paced(
        &elf,
        Paced {
            link: &link,
            lidar: None,
            steps: &steps,
            answers: None,
            host: Some(Box::new(|e: &DeviceEvent| host.answer(e))),
        },
        timeout,
        Some(&log),
    )?;
    let (events, ds) = decode_captured(&run.stream);
    let groups = Groups::of(&events);
    let mut report = FirmwareReport {
        config: Some(*config),
        scans_sent: scans.len(),
        input_bytes: sent.len(),
        log: Some(log),
        qemu_seconds: run.secs,
        exit_code: run.status.and_then(|s| s.code()),
        stream_bytes: ds.bytes,
        stream_frames: ds.frames,
        stream_bad_frames: ds.bad_frames,
        ..FirmwareReport::default()
    };
    report.read_stream(&groups, &events);
    let mut checker = Checker::default();
    if let Err(e) = compare(&sent, &[], &groups, &mut checker) {
        checker.fail(format!("{e:#}"));
    }
    report.mismatches = checker.mismatches;
    report.checks = checker.checks;
    Ok((report, events, host))
}

/// Scans sent as a robot sends them — LD06 turns on the lidar's UART, their poses on the link
/// (`host-sim firmware --log`'s encoding, [`super::log::log_input`]) — through the firmware in
/// QEMU with an online host (sending stored tiles back if `restore`), paced; checked bit-exact
/// against the host replay of the link as sent. `config` gets the lidar's mount from the
/// scans. Returns the report, the decoded stream, the host and the settings as sent.
pub fn run_turns_online(
    config: &RunConfig,
    scans: &[ScanRecord],
    timeout: Duration,
    restore: bool,
) -> anyhow::Result<(FirmwareReport, Vec<DeviceEvent>, OnlineHost, RunConfig)> {
    let config = super::log::log_config(*config, super::log::mount_heading(scans));
    let (input, _) = super::log::log_input(scans, &config)?;
    let qemu_dir = repo_root().join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let elf = build_elf(&qemu_dir.join("host-sim-build.log"))?;
    let log = qemu_dir.join("host-sim-firmware.log");
    let mut host = OnlineHost::new(restore);
    let (run, sent) = robot_paced(&elf, &input, &mut host, timeout, Some(&log))?;
    let report = checked_robot_report(&config, &input, &sent, &run, Some(log), |_| ());
    let (events, _) = decode_captured(&run.stream);
    Ok((report, events, host, config))
}

/// A robot loop's two serial lines (`input`) written to the firmware `elf` in QEMU, paced on
/// its turn reports, `host` answering its stream; QEMU's run and the link as sent.
fn robot_paced(
    elf: &std::path::Path,
    input: &RobotInput,
    host: &mut OnlineHost,
    timeout: Duration,
    log: Option<&std::path::Path>,
) -> anyhow::Result<(super::qemu::QemuRun, Vec<u8>)> {
    let link: Vec<u8> = [&input.link[..], &input.finish[..]].concat();
    let steps = robot_steps(input);
    run_qemu_paced(
        elf,
        Paced {
            link: &link,
            lidar: Some(&input.lidar),
            steps: &steps,
            answers: None,
            host: Some(Box::new(|e: &DeviceEvent| host.answer(e))),
        },
        timeout,
        log,
    )
    .context("the firmware in QEMU")
}

/// A robot run's two serial lines through the firmware in QEMU with an online host (sending
/// stored tiles back if `restore`), paced; checked bit-exact against the host replay of the
/// link as sent (or, with `--host-only`, that replay alone, paced on the host). Returns the
/// report, the captured stream and the link as sent (with `Finish`).
pub(super) fn run_input_online(
    args: &FirmwareArgs,
    config: &RunConfig,
    input: &RobotInput,
    restore: bool,
) -> anyhow::Result<(FirmwareReport, Vec<u8>, Vec<u8>)> {
    let mut host = OnlineHost::new(restore);
    if args.host_only {
        let link: Vec<u8> = [&input.link[..], &input.finish[..]].concat();
        let steps = robot_steps(input);
        let n = args.fixed_updates.unwrap_or(0);
        let sent = host_link(&link, &input.lidar, &steps, &mut host, n);
        // The stream is the plain replay's of the link as sent (the paced run above only
        // placed the answers).
        let (stream, events) = replay_fixed(&sent, &input.lidar, n)?;
        let groups = Groups::of(&events);
        let r = robot_report(config, input, &sent, &groups, &events);
        return Ok((r, stream, sent));
    }
    let qemu_dir = repo_root().join("firmware/target/qemu");
    std::fs::create_dir_all(&qemu_dir)?;
    let (elf, log) = robot_firmware(args, &qemu_dir)?;
    let timeout = Duration::from_secs(args.timeout);
    let (run, sent) = robot_paced(&elf, input, &mut host, timeout, log.as_deref())?;
    let report = checked_robot_report(config, input, &sent, &run, log, |_| ());
    Ok((report, run.stream, sent))
}

#[cfg(test)]
mod tests {
    use ogm_core::config::Budget;
    use ogm_core::session::{Owned, Session, Sizes};
    use ogm_core::wire::WindowReport;
    use ogm_field::stream::BuildingMap;

    use super::super::log::{firmware_scan, log_config, log_input, mount_heading};
    use super::*;
    use crate::sim::boxes;

    /// The robot loop (lidar on its own UART, poses on the link) paced on the host with an
    /// online host (sending tiles back if `restore`, the robot holding shifting turns if
    /// `hold`), scans every `spacing` m on a path east and back west through a 30 m building,
    /// so the west region leaves the window and comes back. Returns the robot's last `Window`,
    /// the `Restore` parts sent, and the cells where the stitched replay of the link as sent
    /// differs from an unbounded map of the same scans.
    fn paced(spacing: f64, restore: bool, hold: bool) -> (WindowReport, u64, usize) {
        let scans = boxes::scans(
            &boxes::building(14_000.0, 30, false),
            &[(6.4, 6.4), (24.0, 7.0), (5.0, 7.4)],
            spacing,
            3000,
        );
        // The poses as sent (`host-sim firmware --log`'s default): without tiles sent back a
        // matcher would see a different map than the unbounded one's and place scans apart.
        let base = RunConfig::ROBOT
            .with_max_range_mm(3000)
            .with_window_margin_cells(112)
            .with_window_hold(hold)
            .with_budget(Budget::Fixed { updates: 20 })
            .with_correction(ogm_core::config::PoseCorrection::Off);
        let config = log_config(base, mount_heading(&scans));
        let (input, _) = log_input(&scans, &config).unwrap();
        let steps = robot_steps(&input);
        let link = [&input.link[..], &input.finish[..]].concat();
        let mut host = OnlineHost::new(restore);
        let sent = host_link(&link, &input.lidar, &steps, &mut host, 20);
        assert_eq!(
            sent.len() > link.len(),
            restore,
            "answers only with restore"
        );
        let (_, events) = replay_fixed(&sent, &input.lidar, 20).unwrap();
        let hello = super::super::groups::Groups::of(&events).hello;
        let b = BuildingMap::stitch(hello.as_ref().expect("a Hello"), &events);
        let w = *b.window().expect("a final Window");
        assert_eq!(
            (b.tiles_bad_size(), b.tiles_refused()),
            (0, 0),
            "every tile applies"
        );
        // The unbounded map of the same scans, as the firmware's turns hold them.
        let (x0, y0, gw, gh) = (-128i32, -128i32, 896u16, 544u16);
        let mut s = Session::new(
            config
                .with_window_margin_cells(0)
                .with_origin_mm(x0 * 50, y0 * 50),
            Owned::<u8>::buffers(&Sizes::grid(gw, gh)),
        )
        .unwrap();
        for scan in &scans {
            let (pose, beams) = firmware_scan(scan, config.mount.heading);
            s.insert(&pose, &beams).unwrap();
        }
        let r = b.render();
        let (rw, rh) = (r.map.width as i64, r.map.height as i64);
        let mut differ = 0;
        for (i, l) in s.log_odds().iter().enumerate() {
            let bx = i64::from(x0) + (i % usize::from(gw)) as i64 - r.x0;
            let by = i64::from(y0) + (i / usize::from(gw)) as i64 - r.y0;
            let got = if (0..rw).contains(&bx) && (0..rh).contains(&by) {
                r.map.log_odds[(by * rw + bx) as usize]
            } else {
                0
            };
            differ += usize::from(got != l.0);
        }
        (w, host.parts_sent, differ)
    }

    /// Scans 0.3 m apart (within the margin rule): tiles sent back make the stitched map
    /// exact, held turns or not; without them the host's merge is off where a clamp was hit.
    #[test]
    fn the_paced_robot_loop_gets_its_tiles_back_before_it_maps_there() {
        for hold in [false, true] {
            let (w, parts, differ) = paced(0.3, true, hold);
            assert!(w.shifts >= 4, "{w:?}");
            assert_eq!((w.restore_refused, w.beams_clipped), (0, 0), "{w:?}");
            assert!(w.tiles_restored > 10, "{w:?}");
            assert_eq!(parts, 12 * u64::from(w.tiles_restored));
            assert_eq!(w.turns_held, if hold { w.shifts } else { 0 }, "{w:?}");
            assert_eq!(w.holds_unanswered, 0, "{w:?}");
            assert_eq!(differ, 0, "hold {hold}");
        }
        let (w, _, differ) = paced(0.3, false, false);
        assert_eq!((w.tiles_restored, w.restore_refused), (0, 0), "{w:?}");
        assert!((1..200).contains(&differ), "{differ}");
    }

    /// Scans 4 m apart, farther than the margin allows (112 − 61 = 51 cells = 2.55 m): the
    /// turn that shifts reaches tiles that just entered. Mapped at once, it makes the robot
    /// refuse them when they come back; held until the host has sent them (`window_hold`),
    /// the stitched map is exact.
    #[test]
    fn a_turn_held_for_the_hosts_tiles_maps_steps_longer_than_the_margin_exactly() {
        let (w, _, differ) = paced(4.0, true, false);
        assert!(w.restore_refused > 0, "{w:?}");
        assert!(differ > 100, "{differ}");
        let (w, parts, differ) = paced(4.0, true, true);
        assert!(w.shifts >= 4 && w.tiles_restored > 10, "{w:?}");
        assert_eq!((w.restore_refused, w.beams_clipped), (0, 0), "{w:?}");
        assert_eq!((w.turns_held, w.holds_unanswered), (w.shifts, 0), "{w:?}");
        assert_eq!(parts, 12 * u64::from(w.tiles_restored));
        assert_eq!(differ, 0);
    }
}
