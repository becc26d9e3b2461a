//! The firmware in QEMU (mps2-an386, `-icount shift=0`) on a simulated run: the map it streams
//! over the link must equal ogm-core on the host, cell for cell (`host-sim firmware`).
//!
//! Needs the firmware toolchain and QEMU (`bash scripts/firmware-toolchain.sh`, which
//! `scripts/test-all.sh` runs first). Without them the test is skipped with a message — unless
//! `OGM_REQUIRE_FIRMWARE=1`, when it fails. Runtime: ~10 s after the firmware build.

use host_sim::firmware::{run, FirmwareArgs, FirmwareReport};

/// Runs `args` in QEMU (`None`: skipped, without the firmware toolchain) and checks what every
/// run must show: a clean exit, and a streamed map equal to the host's over more than three
/// whole maps of comparisons.
fn run_bit_exact(test: &str, args: &FirmwareArgs) -> Option<FirmwareReport> {
    if !ogm_tests::firmware_available(test) {
        return None;
    }
    let r = run(args).expect("host-sim firmware run");
    ogm_tests::assert_ran_identical(&r);
    assert!(r.checks > 3 * 65_536, "too few comparisons: {}", r.checks);
    Some(r)
}

#[test]
fn firmware_in_qemu_streams_the_hosts_map() {
    let args = FirmwareArgs {
        seed: 3,
        // The default time budget (6.4 ms of board time per scan): the firmware decides how
        // many sampler updates fit and reports them; the host replays exactly those.
        garbage: true,
        max_scans: Some(24),
        timeout: 120,
        ..FirmwareArgs::default()
    };
    let Some(r) = run_bit_exact("firmware_in_qemu_streams_the_hosts_map", &args) else {
        return;
    };
    let c = r.counters.expect("final counters");
    assert_eq!(c.scans as usize, r.scans_sent);
    // The garbage on the link was skipped and counted, and cost no lidar point.
    assert!(r.garbage_bytes > 0 && c.link.garbage_bytes > 0);
    assert!(
        c.link.frame_errors
            + c.link.frames_too_long
            + c.link.ld06_crc_errors
            + c.link.ld06_truncated
            > 0
    );
    assert_eq!(c.link.points_lost, 0);
    assert_eq!(c.beams_overflowed, 0);
    // The sampler ran within its budget and produced marginals: no scan's step and sampling
    // took more than the period (6.4 ms = 6.4 M instructions under icount) plus 1 % (the
    // sampler's last call past it: each call asks for half of the time left).
    let s = r.sampler.expect("final sampler report");
    assert!(s.updates > 0 && s.samples > 0, "{s:?}");
    let period = u64::from(args.period_us) * 1_000;
    eprintln!(
        "longest scan cycle: {} instructions for a period of {period}",
        r.figures.cycle_per_scan_max
    );
    assert!(
        r.figures.cycle_per_scan_max > 0 && r.figures.cycle_per_scan_max <= period + period / 100,
        "a scan took {} instructions for a period of {period}",
        r.figures.cycle_per_scan_max
    );
    let d = r.done.expect("Done");
    assert!(d.stack_used > 0 && d.stack_used < d.stack_size, "{d:?}");
}

/// The robot loop in QEMU (issue 13): simulated LD06 bytes on UART0 at 10 turns/s while the
/// robot drives, timestamped poses on the link (UART1) at 25 Hz, two sockets written by their
/// own threads. Every turn the firmware maps from its own lidar UART must be placed at the
/// simulator's true sensor pose, and its streamed map must equal the firmware's library run on
/// the host over the same two byte streams, cell for cell.
#[test]
fn the_robot_loop_in_qemu_maps_its_lidar_uart_like_the_host() {
    let args = FirmwareArgs {
        seed: 2,
        robot: true,
        max_scans: Some(30),
        timeout: 120,
        ..FirmwareArgs::default()
    };
    let Some(r) = run_bit_exact(
        "the_robot_loop_in_qemu_maps_its_lidar_uart_like_the_host",
        &args,
    ) else {
        return;
    };
    let robot = r.robot.expect("robot report");
    assert_eq!(robot.turns_mapped, robot.turns_sent as usize, "{robot:?}");
    assert!(robot.turns_sent >= 30, "{robot:?}");
    assert!(
        robot.max_position_error_mm < 25.0,
        "turns placed {} mm from the truth",
        robot.max_position_error_mm
    );
    // Everything either line carried was read and used: no packet without a pose, none
    // dropped, no pose out of order.
    let c = r.counters.expect("final counters");
    assert_eq!(c.lidar.turns, robot.turns_sent, "{c:?}");
    assert_eq!(
        c.lidar.bad_packets + c.lidar.packets_without_pose,
        0,
        "{c:?}"
    );
    assert_eq!(
        c.lidar.packets_overflowed + c.lidar.poses_out_of_order,
        0,
        "{c:?}"
    );
    assert_eq!(c.lidar.poses as usize, robot.poses_sent, "{c:?}");
}

/// RPLIDAR on the robot's UART (issue 14): the firmware built with its `rplidar` feature, set
/// to an RPLIDAR A1 by the settings, sends the sensor `SCAN` and maps the simulated nodes (a
/// `SCAN` descriptor, then 5-byte nodes, 360 a turn, no timestamps: the robot times them by
/// their count). The same scans sent as LD06 packets (`--pattern a1`: the same beams at the
/// same times) to the default image give the same map: the same log-odds grid and, with the
/// same sampler updates per turn, the same marginals. Both runs are bit-exact with the host.
#[test]
fn an_rplidar_maps_in_qemu_what_the_same_scans_as_ld06_packets_map() {
    let test = "an_rplidar_maps_in_qemu_what_the_same_scans_as_ld06_packets_map";
    let base = FirmwareArgs {
        seed: 4,
        robot: true,
        max_scans: Some(16),
        fixed_updates: Some(3000),
        timeout: 120,
        ..FirmwareArgs::default()
    };
    let rplidar = FirmwareArgs {
        lidar: host_sim::firmware::LidarArg::Rplidar,
        ..base.clone()
    };
    let ld06 = FirmwareArgs {
        pattern: Some(host_sim::firmware::PatternArg::A1),
        ..base
    };
    let (Some(a), Some(b)) = (run_bit_exact(test, &rplidar), run_bit_exact(test, &ld06)) else {
        return;
    };
    for r in [&a, &b] {
        let robot = r.robot.as_ref().expect("robot report");
        assert_eq!(robot.turns_mapped, robot.turns_sent as usize, "{robot:?}");
        let c = r.counters.expect("final counters");
        assert_eq!(
            c.lidar.bad_packets + c.lidar.packets_without_pose + c.lidar.packets_overflowed,
            0,
            "{c:?}"
        );
    }
    let (da, db) = (a.done.expect("Done"), b.done.expect("Done"));
    assert_eq!(da.scans, 16);
    assert_eq!(
        (da.scans, da.grid_fnv, da.counts_fnv),
        (db.scans, db.grid_fnv, db.counts_fnv)
    );
}
