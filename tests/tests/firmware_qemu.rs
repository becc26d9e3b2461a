//! The firmware in QEMU (mps2-an386, `-icount shift=0`) on a simulated run: the map it streams
//! over the link must equal ogm-core on the host, cell for cell (`host-sim firmware`).
//!
//! Needs the firmware toolchain and QEMU (`bash scripts/firmware-toolchain.sh`, which
//! `scripts/test-all.sh` runs first). Without them the test is skipped with a message — unless
//! `OGM_REQUIRE_FIRMWARE=1`, when it fails. Runtime: ~10 s after the firmware build.

use host_sim::firmware::{print_report, run, FirmwareArgs};

#[test]
fn firmware_in_qemu_streams_the_hosts_map() {
    if !ogm_tests::firmware_available("firmware_in_qemu_streams_the_hosts_map") {
        return;
    }
    let args = FirmwareArgs {
        seed: 3,
        // The default time budget (6.4 ms of board time per scan): the firmware decides how
        // many sampler updates fit and reports them; the host replays exactly those.
        garbage: true,
        max_scans: Some(24),
        timeout: 120,
        ..FirmwareArgs::default()
    };
    let r = run(&args).expect("host-sim firmware run");
    print_report(&r);
    assert_eq!(
        r.exit_code,
        Some(0),
        "firmware exit status (log: {:?})",
        r.log
    );
    assert!(
        r.identical(),
        "the firmware's streamed map differs from the host's:\n{}",
        r.mismatches.join("\n")
    );
    assert!(r.checks > 3 * 65_536, "too few comparisons: {}", r.checks);
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
    // The sampler ran within its budget and produced marginals.
    let s = r.sampler.expect("final sampler report");
    assert!(s.updates > 0 && s.samples > 0, "{s:?}");
    let d = r.done.expect("Done");
    assert!(d.stack_used > 0 && d.stack_used < d.stack_size, "{d:?}");
}
