//! ogm-firmware: online occupancy grid mapping with a patch Gibbs sampler on a Cortex-M4F. The
//! binary of one board: its hardware and memory around the board-independent application
//! (the `ogm_firmware` library, `src/lib.rs`, which the host replays to check it).
//!
//! * `board/` — everything that knows a hardware address, behind the `board::Board` trait (QEMU
//!   mps2-an386, nRF52840-DK; one cargo feature each): UARTs, clock, defmt transport, exit,
//!   faults;
//! * `memory` — every large buffer, as `static`s in `.bss` (the board's sizes, from
//!   `ogm_firmware::sizes`).
//!
//! See docs/firmware.md (build, run, RAM layout, figures) and docs/wire.md (the stream).
#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[allow(unsafe_code)] // all hardware access (and all `unsafe`) lives in here
mod board;

mod memory;

use board::{Board, Selected};
use defmt::info;

/// `cortex_m::asm::delay` argument used to check the tick ↔ instruction relation at boot.
#[cfg(feature = "mps2-an386")]
const CALIBRATION_CYCLES: u32 = 1_000_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(mut board) = Selected::take() else {
        defmt::panic!("Board::take called twice");
    };
    info!(
        "boot: ogm-firmware {=str} on {=str}",
        env!("CARGO_PKG_VERSION"),
        Selected::NAME
    );

    #[cfg(feature = "mps2-an386")]
    calibrate(board.parts().2);

    let Some(memory) = memory::take() else {
        defmt::panic!("buffers taken twice");
    };
    info!(
        "memory: {=usize} B grid, {=usize} B counts, {=usize} rays, {=usize} scans, {=usize} local rays, {=usize} beams/scan",
        core::mem::size_of::<[ogm_core::LogOdds; memory::CELLS]>(),
        memory::CELLS,
        memory::RAYS,
        memory::SCANS,
        memory::LOCAL_RAYS,
        ogm_firmware::app::MAX_BEAMS
    );
    let (link, lidar, clock) = board.parts();
    // `FIRMWARE_FEATURES=bench-match`: the matcher's benchmark instead of the application.
    #[cfg(feature = "bench-match")]
    let code = {
        let _ = (link, lidar);
        let mut memory = memory;
        let b = &mut memory.buffers;
        ogm_firmware::bench_match::run(&mut b.grid[..], b.marks.as_mut(), b.width, b.height, clock)
    };
    #[cfg(not(feature = "bench-match"))]
    let code = ogm_firmware::run(memory, link, lidar, clock);
    let stack = board::stack_usage();
    info!(
        "stack: {=u32} of {=u32} bytes used since the settings were applied (high-water mark)",
        stack.used, stack.size
    );
    info!("exit {=i32}", code);
    Selected::exit(code)
}

/// QEMU's instruction clock: the timer against a delay loop of known length.
#[cfg(feature = "mps2-an386")]
fn calibrate(timer: &board::Timer) {
    // `asm::delay(n)` runs exactly 2·(n + 1) instructions (a `subs; bne` loop, n + 1 times).
    // Under QEMU with `-icount shift=0` every instruction is 1 ns, i.e. 1/40 tick, so the
    // measured time must come out at 1000 ps per instruction (±1 tick); without icount the ticks
    // are host wall-clock time and the ratio is meaningless.
    let t0 = timer.now();
    cortex_m::asm::delay(CALIBRATION_CYCLES);
    let cal_ns = board::Timer::ticks_to_ns(timer.now().wrapping_sub(t0));
    let cal_insns = 2 * (u64::from(CALIBRATION_CYCLES) + 1);
    info!(
        "timer: {=u64} instructions took {=u64} ns = {=u64} ps per instruction (1000 under -icount shift=0)",
        cal_insns,
        cal_ns,
        (cal_ns * 1000 + cal_insns / 2) / cal_insns
    );
}

/// Logs the panic with defmt and exits with status 101 (like a Rust test that panicked), so a
/// QEMU run fails fast instead of hanging until its timeout. Only static panic messages and the
/// location are logged: formatting arbitrary messages would pull `core::fmt` (~3.5 KiB of
/// flash) into the image, and ogm-core does not panic on input anyway.
#[cfg(feature = "mps2-an386")]
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    use core::sync::atomic::AtomicBool;
    use defmt::error;
    static PANICKING: AtomicBool = AtomicBool::new(false);
    if !board::test_and_set(&PANICKING) {
        let msg = info.message().as_str().unwrap_or("(formatted message)");
        match info.location() {
            Some(l) => error!("panic: {=str} at {=str}:{=u32}", msg, l.file(), l.line()),
            None => error!("panic: {=str}", msg),
        }
    }
    Selected::exit(101)
}
