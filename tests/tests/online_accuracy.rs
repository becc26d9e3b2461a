//! The product's promise, as a behaviour test: the map the firmware's sampler keeps online (in
//! QEMU) beats the log-odds map it is built from. The firmware runs 10 000 sampler updates after
//! each scan — a little less than what the default time budget of 6.4 ms of board time buys on
//! this run (11 043 at 490 instructions per patch) — as a fixed count: under the time budget the
//! count depends on where the link's receive interrupts land in a scan's window, which follows
//! the host's load (docs/results.md), while a fixed count makes max F1 exactly repeatable, so
//! fixed margins can be asserted; this is not a timing test.
//!
//! Seed 1: 34 scans of the generated 12.8 m building, then half a second of board time standing
//! still. Figures at the time of writing (`host-sim firmware --seed 1 --accuracy --idle 0.5
//! --fixed-updates 10000`): log-odds 0.7195; online after the last scan 0.8201, after 0.5 s idle
//! 0.8351.
//!
//! A long mission (1 000 scans taken while driving, the σ = 3-cell simulated lidar) runs the same
//! firmware application on the host with a fixed number of sampler updates per scan (no QEMU):
//! there the robot's sampler must beat both the textbook log-odds map and its own noise-matched
//! one (`host-sim firmware --seed 1 --mission-scans 1000 --accuracy --host-only
//! --fixed-updates 6000`: 0.677 vs 0.523 and 0.649).

use host_sim::firmware::{print_report, run, FirmwareArgs};

#[test]
fn online_marginals_beat_the_log_odds_map() {
    if !ogm_tests::firmware_available("online_marginals_beat_the_log_odds_map") {
        return;
    }
    let r = run(&FirmwareArgs {
        seed: 1,
        accuracy: true,
        idle: vec![0.5],
        fixed_updates: Some(10_000),
        timeout: 240,
        ..FirmwareArgs::default()
    })
    .expect("host-sim firmware run");
    print_report(&r);
    assert!(r.identical(), "{}", r.mismatches.join("\n"));
    let a = r.accuracy.expect("accuracy");
    let f1 = |m: &str| a.methods.get(m).map(|s| s.max_f1).expect(m);
    let (trad, online, idle) = (
        f1("traditional"),
        f1("online_firmware_sizes"),
        f1("online_idle_0.5s"),
    );
    eprintln!("log-odds {trad:.4}, online {online:.4}, after 0.5 s idle {idle:.4}");
    assert!(online >= trad + 0.09, "online {online} vs log-odds {trad}");
    assert!(
        idle >= trad + 0.10,
        "after idling {idle} vs log-odds {trad}"
    );
    // The anytime curve: the sampler is ahead of the log-odds map from early on.
    let late: Vec<_> = a.anytime.iter().filter(|p| p.scans >= 10).collect();
    assert!(!late.is_empty());
    assert!(
        late.iter().all(|p| p.online > p.log_odds),
        "{:?}",
        a.anytime
    );
}

#[test]
fn long_missions_beat_both_log_odds_maps() {
    let r = run(&FirmwareArgs {
        seed: 1,
        mission_scans: Some(1000),
        accuracy: true,
        host_only: true,
        fixed_updates: Some(6000),
        ..FirmwareArgs::default()
    })
    .expect("host-sim firmware --host-only run");
    let a = r.accuracy.expect("accuracy");
    let f1 = |m: &str| a.methods.get(m).map(|s| s.max_f1).expect(m);
    let (textbook, own, online, offline) = (
        f1("traditional"),
        f1("traditional_noise_matched"),
        f1("online_firmware_sizes"),
        f1("offline_firmware_sizes"),
    );
    eprintln!(
        "log-odds {textbook:.4} (noise-matched {own:.4}), online {online:.4}, offline {offline:.4}"
    );
    assert!(
        online >= textbook + 0.10,
        "online {online} vs log-odds {textbook}"
    );
    // The robot's own map is the face band's (σ = 3 cells), itself 0.21 above the textbook
    // map on this mission (0.7312 against 0.5231); the sampler still adds 0.012 to it.
    assert!(
        online >= own + 0.01,
        "online {online} vs the robot's log-odds {own}"
    );
    assert!(
        (online - offline).abs() <= 0.02,
        "online {online} vs offline {offline}"
    );
}
