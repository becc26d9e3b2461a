//! A noisy UART: the firmware in QEMU with 1 % of the bytes it receives corrupted (each XORed
//! with a random non-zero byte; host frames sent three times, see `ogm_core::lidar::link`). Only the
//! damaged LD06 packets and frames may be lost, and every loss must be counted in the stream's
//! statistics; the streamed map must equal the host replay of the same bytes *and* a host replay
//! of only the packets and frames that arrived intact; no reset, no panic. The LD06's own check
//! is an 8-bit CRC, so about one damaged packet in 256 passes it: the robot cannot tell such a
//! packet from an intact one, and the test counts it with the intact ones (and bounds how many
//! there are).
//!
//! Needs the firmware toolchain and QEMU like `firmware_qemu.rs` (skipped without them unless
//! `OGM_REQUIRE_FIRMWARE=1`). Runtime: ~15 s after the firmware build.

use host_sim::firmware::{print_report, run, FirmwareArgs};
use ogm_tests::firmware_available;

#[test]
fn one_percent_of_corrupted_uart_bytes_loses_only_the_damaged_packets() {
    if !firmware_available("one_percent_of_corrupted_uart_bytes_loses_only_the_damaged_packets") {
        return;
    }
    let args = FirmwareArgs {
        seed: 3,
        max_scans: Some(24),
        noise_ppm: 10_000,
        repeat_frames: 3,
        timeout: 120,
        ..FirmwareArgs::default()
    };
    let r = run(&args).expect("host-sim firmware run");
    print_report(&r);
    // No panic, no fault, no hang; no reset (one Hello); it ran to the end (Done).
    assert_eq!(r.exit_code, Some(0), "exit status (log: {:?})", r.log);
    assert_eq!(r.hellos, 1, "the firmware reset");
    assert!(r.done.is_some(), "no Done");
    // The same bytes through ogm-core on the host: identical, cell for cell.
    assert!(
        r.identical(),
        "the streamed map differs from the host's:\n{}",
        r.mismatches.join("\n")
    );
    let n = r.noise.as_ref().expect("noise report");
    let c = r.counters.expect("final counters");
    // 1 % of the bytes; with 47-byte packets that damages about a third of them.
    assert_eq!(n.corrupted_bytes, r.input_bytes.div_ceil(100));
    assert!(n.damaged_packets > 100 && n.damaged_frames > 5, "{n:?}");
    // Damaged packets the LD06's CRC-8 cannot catch: about 1 in 256.
    assert!(
        n.undetected_packets <= 1 + n.damaged_packets / 64,
        "{} of {} damaged packets passed the CRC",
        n.undetected_packets,
        n.damaged_packets
    );
    // Only the damaged packets and frames are lost: every intact one was accepted …
    assert_eq!(c.link.ld06_packets as usize, n.intact_packets_before_finish);
    assert_eq!(c.link.frames as usize, n.intact_frames_before_finish);
    // … every scan survived (its framing arrived in at least one copy), the points of the
    // damaged packets are exactly what is reported lost, and nothing else went astray.
    assert_eq!(c.scans as usize, r.scans_sent);
    assert_eq!(u64::from(c.link.points_lost), n.points_in_damaged_packets);
    assert_eq!(c.link.points_outside_scan, 0);
    assert_eq!(c.link.scan_seq_errors, 0);
    assert_eq!(c.beams_overflowed, 0);
    // The losses are counted as errors of the right kinds.
    assert!(c.link.ld06_crc_errors + c.link.ld06_bad_headers + c.link.ld06_truncated > 0);
    assert!(c.link.frame_errors + c.link.frames_too_long > 0);
    assert!(c.errors > 0 && r.device_errors > 0);
    // And the map is the one the surviving packets alone make.
    assert!(n.surviving_replay_identical, "{n:?}");
}
