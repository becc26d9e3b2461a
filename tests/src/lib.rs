//! Cross-crate integration tests live in `tests/tests/`; this library holds what they share.

#![warn(missing_docs)]

use std::io::Write as _;

/// Prints a firmware run's report; asserts the firmware exited cleanly and streamed exactly what
/// the host replay of the same link streams.
pub fn assert_ran_identical(r: &host_sim::firmware::FirmwareReport) {
    host_sim::firmware::print_report(r);
    assert_eq!(
        r.exit_code,
        Some(0),
        "firmware exit status (log: {:?})",
        r.log
    );
    assert!(
        r.identical(),
        "the firmware's streamed map differs from the host replay's:\n{}",
        r.mismatches.join("\n")
    );
}

/// Whether the firmware can run here (toolchain and QEMU from `scripts/firmware-toolchain.sh`).
/// When it cannot, prints `SKIPPED test: why` to stderr and returns `false` — unless
/// `OGM_REQUIRE_FIRMWARE=1` (set by `scripts/test-all.sh`), when it panics with the reason, so
/// a machine that should run the firmware never passes by skipping.
pub fn firmware_available(test: &str) -> bool {
    let Some(why) = host_sim::firmware::toolchain_missing() else {
        return true;
    };
    let required = std::env::var("OGM_REQUIRE_FIRMWARE").is_ok_and(|v| v == "1");
    assert!(
        !required,
        "OGM_REQUIRE_FIRMWARE=1 but the firmware cannot be run: {why}"
    );
    // Written to stderr directly, not with `eprintln!`, so libtest does not swallow it.
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: {why} (set OGM_REQUIRE_FIRMWARE=1 to make this an error)"
    );
    false
}
