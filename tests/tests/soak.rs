//! Soak: long runs with no overflow, no oscillation of the map and flat memory.
//!
//! * **Host** ([`host_soak`]): the firmware's per-scan step on its engine
//!   (`ogm_core::session::Session`: `insert` = `pipeline::insert_and_seed`, then `step`, with the
//!   firmware's buffer sizes and `u8` marginal counts) on the scans of a simulated 12.8 m run,
//!   cycled. Checks at every cycle: log-odds within the clamp; once warmed up a cell's value at
//!   the end of a cycle either equals the previous cycle's or creeps towards the clamp, always
//!   the same way, and fewer cells move each cycle (the same scans again; with the robot's
//!   noise-matched free update, −564 against +1024, a cell's net increment per cycle can be as
//!   small as 4 LSB, so reaching the clamp can take thousands of cycles); samples ≤ 255 and counts ≤ samples + 1 (a sweep
//!   counts cell by cell); the ray store within its capacity; counters never run backwards (no
//!   wrap-around); and **no heap allocation at
//!   all** while scans are processed (a counting global allocator, per thread), so memory is
//!   flat by construction. The default suite runs 2 040 scans; the ≥ 100 000-scan run is
//!   `cargo test -p ogm-tests --release --test soak -- --ignored host_soak_100k`.
//! * **Firmware in QEMU** ([`firmware_soak`]): the same cycled run through the firmware, once
//!   short and once long (both compared with the host cell for cell); the stack high-water mark
//!   of the mapping loop at the end of the long run equals the short run's, i.e. it did not
//!   move after the first scans. 40 / 160 scans in the default suite (the scan store's 128 slots
//!   and the ray store both thin); `… -- --ignored firmware_soak_long` runs 40 / 1 000.
//!   Skipped without QEMU unless `OGM_REQUIRE_FIRMWARE=1`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Write as _;

use host_sim::firmware::{
    firmware_world, print_report, run, run_config, FirmwareArgs, FIRMWARE_SIZES,
};
use host_sim::sim::{simulate, SimConfig};
use ogm_core::config::Budget;
use ogm_core::session::{Owned, Session};
use ogm_tests::firmware_available;

/// Counts this thread's heap allocations (libtest runs tests on several threads).
struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count_one() {
    let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
}

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

// SAFETY: forwards to the system allocator unchanged; the counter is a const-initialised
// thread-local `Cell` (no allocation, no destructor).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        System.alloc(layout)
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count_one();
        System.alloc_zeroed(layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        System.realloc(ptr, layout, new_size)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Sampler updates after each scan.
const UPDATES: u32 = 64;

/// What a host soak saw.
#[derive(Debug)]
struct SoakReport {
    scans: usize,
    allocations_while_mapping: u64,
    saturated_cells: usize,
    samples: u32,
    thinnings: u32,
}

fn host_soak(total: usize) -> SoakReport {
    let args = FirmwareArgs::default();
    let world = firmware_world(&args).expect("world");
    let sim = simulate(&world, &SimConfig::default(), args.seed).expect("simulated run");
    let cycle = sim.scans.len();
    assert!(cycle > 10, "{cycle} scans");
    // The hybrid data term: rays in the bounded store (which must thin) and the evidence.
    let config = run_config(
        &world,
        &FirmwareArgs {
            fixed_updates: Some(UPDATES),
            sampler: host_sim::firmware::SamplerArgs {
                data: Some(ogm_core::config::DataTerm::Hybrid),
                ..Default::default()
            },
            ..args
        },
        sim.mapper_config.max_range_mm,
    );
    assert_eq!(config.budget, Budget::Fixed { updates: UPDATES });
    let mut r = Session::new(config, Owned::<u8>::buffers(&FIRMWARE_SIZES)).expect("session");
    let clamp = config.mapper_config().expect("valid config").clamp;
    let warm_up = 20 * cycle;
    let mut previous: Option<Vec<i16>> = None;
    let mut direction = vec![0i8; r.log_odds().len()];
    let mut last_moved = usize::MAX;
    let mut allocs = 0u64;
    let mut last = r.sampler_report();
    for k in 0..total {
        let s = &sim.scans[k % cycle];
        let before = allocations();
        let inserted = r.insert(&s.pose, &s.beams);
        assert_eq!(r.step(UPDATES), UPDATES);
        allocs += allocations() - before;
        assert!(inserted.is_ok(), "scan {k} rejected");
        if (k + 1) % cycle != 0 {
            continue;
        }
        // End of a cycle.
        let map: Vec<i16> = r.log_odds().iter().map(|l| l.raw()).collect();
        assert!(
            map.iter()
                .all(|&v| (clamp.min().raw()..=clamp.max().raw()).contains(&v)),
            "log-odds outside the clamp after scan {k}"
        );
        if k >= warm_up {
            if let Some(p) = &previous {
                // The same scans again: a cell's end-of-cycle value either stays (the textbook
                // increments, ±1024, reach the clamp within a few cycles) or, with the robot's
                // noise-matched free update (−564), creeps towards the clamp by its net
                // increment per cycle (as little as 4 LSB: up to thousands of cycles) — but
                // always the same way. Never back and forth.
                let mut moved = 0;
                for (i, (a, b)) in p.iter().zip(&map).enumerate() {
                    let d = (b - a).signum() as i8;
                    if d != 0 {
                        moved += 1;
                        assert!(
                            direction[i] == 0 || direction[i] == d,
                            "cell {i} turned back in cycle {}",
                            k / cycle
                        );
                        direction[i] = d;
                    }
                }
                assert!(
                    moved <= last_moved,
                    "{moved} cells moved in cycle {}, {last_moved} before",
                    k / cycle
                );
                last_moved = moved;
            }
        }
        previous = Some(map);
        let g = r.gibbs();
        assert!(g.samples() <= 255, "{} samples in u8 counts", g.samples());
        // Counts accumulate cell by cell during a sweep and `samples` moves at its end, so a
        // cell can be one ahead mid-sweep.
        let cells = r.log_odds().len();
        assert!((0..cells).all(|i| g.count(i) <= (g.samples() + 1).min(255)));
        let rep = r.sampler_report();
        assert!(rep.store.scans as usize <= FIRMWARE_SIZES.scans);
        assert!(rep.store.rays as usize <= FIRMWARE_SIZES.rays);
        // Counters only grow (saturating where they are `u32`; `u64` ones cannot wrap here).
        assert!(rep.updates >= last.updates && rep.store.rays_added >= last.store.rays_added);
        assert!(rep.store.scans_added >= last.store.scans_added);
        assert_eq!(rep.updates, (k as u64 + 1) * u64::from(UPDATES));
        last = rep;
    }
    let saturated = previous.as_ref().map_or(0, |m| {
        m.iter()
            .filter(|&&v| v == clamp.min().raw() || v == clamp.max().raw())
            .count()
    });
    SoakReport {
        scans: total,
        allocations_while_mapping: allocs,
        saturated_cells: saturated,
        samples: last.samples,
        thinnings: last.store.thinnings,
    }
}

fn check_host(r: &SoakReport) {
    let _ = writeln!(std::io::stderr(), "host soak: {r:?}");
    assert_eq!(r.allocations_while_mapping, 0, "the mapping step allocated");
    assert!(r.saturated_cells > 1000, "{r:?}");
    assert!(r.samples > 0 && r.thinnings > 0, "{r:?}");
}

#[test]
fn host_soak_short() {
    // 60 cycles of the 34-scan run: 20 to warm up, 40 checked for oscillation.
    let r = host_soak(60 * 34);
    check_host(&r);
}

#[test]
#[ignore = "long: ~100 000 scans; cargo test -p ogm-tests --release --test soak -- --ignored host_soak_100k"]
fn host_soak_100k() {
    let r = host_soak(2942 * 34); // 100 028 scans
    assert!(r.scans >= 100_000);
    check_host(&r);
}

/// The firmware (`elf`) on `scans` cycled scans.
fn firmware_run(elf: &std::path::Path, scans: usize) -> host_sim::firmware::FirmwareReport {
    let args = FirmwareArgs {
        seed: 2,
        elf: Some(elf.to_path_buf()),
        soak_scans: Some(scans),
        fixed_updates: Some(200),
        timeout: 600,
        ..FirmwareArgs::default()
    };
    let r = run(&args).expect("host-sim firmware run");
    print_report(&r);
    assert_eq!(r.exit_code, Some(0), "exit status (log: {:?})", r.log);
    assert!(
        r.identical(),
        "{scans} scans: the streamed map differs from the host's:\n{}",
        r.mismatches.join("\n")
    );
    let c = r.counters.expect("counters");
    assert_eq!(c.scans as usize, scans);
    assert_eq!(c.errors, 0);
    assert_eq!(r.hellos, 1);
    r
}

fn firmware_soak(short: usize, long: usize) {
    // One build for both runs, so they compare the same code.
    let log = host_sim::firmware::repo_root().join("firmware/target/qemu/soak-build.log");
    std::fs::create_dir_all(log.parent().unwrap()).unwrap();
    let elf = host_sim::firmware::build_elf(&log).expect("firmware build");
    let a = firmware_run(&elf, short);
    let b = firmware_run(&elf, long);
    let (da, db) = (a.done.expect("Done"), b.done.expect("Done"));
    let _ = writeln!(
        std::io::stderr(),
        "firmware soak: stack high-water mark {} B after {short} scans, {} B after {long} scans (of {} B)",
        da.stack_used,
        db.stack_used,
        db.stack_size
    );
    // The receive interrupts stack their frame wherever the main loop happens to be, so the
    // high-water mark may differ by up to one interrupt (its exception frame with the FPU
    // context, 104 B, plus the handler's, well under 256 B); anything growing with the
    // mission would show as more.
    const INTERRUPT_FRAME: u32 = 256;
    assert!(
        db.stack_used.abs_diff(da.stack_used) <= INTERRUPT_FRAME,
        "the stack high-water mark moved between {short} and {long} scans: {} -> {} B",
        da.stack_used,
        db.stack_used
    );
    assert!(da.stack_config.abs_diff(db.stack_config) <= INTERRUPT_FRAME);
    let s = b.sampler.expect("sampler report");
    // The robot's data term is the per-cell evidence: it keeps no rays, so nothing grows
    // with the mission (the ray store's thinning is soaked on the host, `host_soak_short`).
    assert_eq!(
        (s.store.scans_added, s.store.rays_added, s.store.rays),
        (0, 0, 0),
        "{s:?}"
    );
    assert_eq!(s.updates, long as u64 * 200);
}

#[test]
fn firmware_soak_short() {
    if firmware_available("firmware_soak_short") {
        firmware_soak(40, 160);
    }
}

#[test]
#[ignore = "long: ~4 min of QEMU; cargo test -p ogm-tests --release --test soak -- --ignored firmware_soak_long"]
fn firmware_soak_long() {
    if firmware_available("firmware_soak_long") {
        firmware_soak(40, 1000);
    }
}
