//! Boards: everything that knows a hardware address lives under this module.
//!
//! The application (`main.rs`) sees a board only through the [`Board`] trait, implemented by
//! the board [`Selected`] by the cargo feature:
//!
//! * [`Board::take`] → `Option<Self>` (once): the hardware initialised;
//! * [`Board::parts`]: the application's three parts —
//!   * the host link (`Board::Link`: map stream out, settings and poses in),
//!   * the range sensor's UART (`Board::Lidar`: LD06, 230400 baud, sensor → MCU),
//!   * the clock (`Board::Clock`, an `ogm_firmware::Platform`: free-running ticks, stack use);
//!
//!   the UARTs are blocking `embedded_io::{Read, ReadReady, Write}` over receive rings that an
//!   interrupt (mps2-an386) or EasyDMA (nRF52840) fills while the sampler runs;
//! * [`Board::SIZES`]: its buffer sizes (`ogm_firmware::sizes`, one entry per board), which
//!   `memory.rs` allocates and the application reports in `Hello`;
//! * [`Board::exit`]: end the program (QEMU: semihosting exit; the DK: breakpoint or reset);
//! * besides the trait, each board module installs the defmt global logger and timestamp.
//!
//! Adding a board = one more cargo feature, one more module here implementing [`Board`], its
//! entry in `ogm_firmware::sizes` and its `memory.x`. Board-independent Cortex-M helpers
//! ([`StaticBuf`], [`stack_usage`]) live in this file.
//!
//! # `unsafe`
//! The crate denies `unsafe_code` everywhere except under `board`. Every `unsafe` block here says
//! why it is sound; the public API is safe.
//!
//! The board API is wider than what today's `main.rs` uses (the LD06 driver, the map stream and
//! the timestamps need the rest), hence the `allow(dead_code)` here.
#![allow(dead_code)]

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The application's view of a board (`ogm_firmware::Platform`), the same on every board: its
/// `BOARD_NAME`, its clock `$timer` (whose inherent `now` counts `TICK_HZ` per second) and the
/// painted stack. Invoked in each board module, whose names it takes.
macro_rules! platform {
    ($timer:ty) => {
        impl ogm_firmware::Platform for $timer {
            const NAME: &'static str = BOARD_NAME;
            const TICK_HZ: u32 = TICK_HZ;

            #[inline(always)]
            fn now(&self) -> u32 {
                <$timer>::now(self)
            }

            fn stack_usage(&self) -> ogm_firmware::StackUsage {
                super::stack_usage()
            }

            fn repaint_stack(&mut self) {
                super::repaint_stack();
            }
        }
    };
}
use platform;

#[cfg(feature = "mps2-an386")]
mod mps2_an386;
#[cfg(feature = "mps2-an386")]
#[allow(unused_imports)]
pub use mps2_an386::{uptime_us, Mps2An386 as Selected, Timer, Uart, UartError, TICK_HZ};

#[cfg(feature = "nrf52840")]
mod nrf52840;
#[cfg(feature = "nrf52840")]
#[allow(unused_imports)]
pub use nrf52840::{uptime_us, Nrf52840Dk as Selected, Timer, Uart, UartError, TICK_HZ};

/// What a board gives the application: the seam between `main.rs` and the hardware (module
/// docs). Every method is called once, by `main`.
pub trait Board: Sized {
    /// Board name, logged at boot.
    const NAME: &'static str;
    /// Its buffer sizes (`ogm_firmware::sizes`).
    const SIZES: ogm_firmware::sizes::BoardSizes;
    /// The host link: map stream out, settings and poses in.
    type Link: embedded_io::Read + embedded_io::ReadReady + embedded_io::Write;
    /// The range sensor's UART (an LD06 only sends; an RPLIDAR is sent its requests).
    type Lidar: ogm_firmware::LidarPort;
    /// The free-running clock, and what else the application asks of the board.
    type Clock: ogm_firmware::Platform;

    /// Initialises the hardware; `None` if called before (peripherals have one owner).
    fn take() -> Option<Self>;

    /// The host link, the lidar's UART and the clock.
    fn parts(&mut self) -> (&mut Self::Link, &mut Self::Lidar, &mut Self::Clock);

    /// Ends the program with status `code` (0 = ok).
    fn exit(code: i32) -> !;
}

#[cfg(not(any(feature = "mps2-an386", feature = "nrf52840")))]
compile_error!("select a board feature (`mps2-an386`, the default, or `nrf52840`)");
#[cfg(all(feature = "mps2-an386", feature = "nrf52840"))]
compile_error!("select exactly one board feature: add `--no-default-features` for `nrf52840`");

/// A memory-mapped 32-bit register, accessed with volatile loads and stores.
///
/// Creating one is `unsafe` (the address must really be a device register); using it is safe,
/// because a volatile access to a valid MMIO address cannot violate Rust's memory model. Owning
/// peripheral structs (UART, timer) are handed out once by `Board::take`, so two drivers never
/// fight over the same register.
#[derive(Clone, Copy)]
pub(crate) struct Reg(*mut u32);

impl Reg {
    /// # Safety
    /// `addr` must be a 4-byte-aligned memory-mapped register that is valid for volatile 32-bit
    /// reads and writes for the rest of the program, and not ordinary memory that Rust code also
    /// accesses.
    pub(crate) const unsafe fn at(addr: usize) -> Self {
        Reg(addr as *mut u32)
    }

    /// Volatile read.
    #[inline(always)]
    pub(crate) fn read(self) -> u32 {
        // SAFETY: `Reg::at`'s contract: a valid, aligned MMIO register.
        unsafe { self.0.read_volatile() }
    }

    /// Volatile write.
    #[inline(always)]
    pub(crate) fn write(self, value: u32) {
        // SAFETY: `Reg::at`'s contract: a valid, aligned MMIO register.
        unsafe { self.0.write_volatile(value) }
    }
}

/// Sets `flag` and returns whether it was already set: `AtomicBool::swap` without the
/// compare-and-swap instructions thumbv6m (Cortex-M0/M0+) lacks, by a critical section.
pub fn test_and_set(flag: &AtomicBool) -> bool {
    cortex_m::interrupt::free(|_| {
        let was = flag.load(Ordering::Relaxed);
        flag.store(true, Ordering::Relaxed);
        was
    })
}

/// A hard fault (bad address, undefined instruction, …), on every board: log where and end the
/// program with status 3 ([`exit`]: QEMU then fails fast instead of spinning until its timeout;
/// the nRF52840 stops at a breakpoint under a debugger, else resets).
#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!(
        "HardFault: pc={=u32:#010x} lr={=u32:#010x} xpsr={=u32:#010x}",
        frame.pc(),
        frame.lr(),
        frame.xpsr()
    );
    <Selected as Board>::exit(3)
}

/// A `static` buffer that is handed out at most once as `&'static mut T`: for the big map arrays,
/// which must neither live on the stack nor be built on it (`cortex_m::singleton!` constructs its
/// value on the stack first, which a 128 KiB grid would overflow).
///
/// Initialise it with a `const` value; an all-zero value (e.g. `[LogOdds::ZERO; N]`) lands in
/// `.bss`, costs no flash and is zeroed by the runtime before `main`.
pub struct StaticBuf<T> {
    taken: AtomicBool,
    value: UnsafeCell<T>,
}

// SAFETY: the only access to `value` is through `take`, which hands out one `&mut T` ever
// (guarded by `test_and_set`), so sharing the `StaticBuf` between contexts is sound as long as
// the `&mut T` itself may move to another context (`T: Send`).
unsafe impl<T: Send> Sync for StaticBuf<T> {}

impl<T> StaticBuf<T> {
    /// A buffer holding `value`.
    pub const fn new(value: T) -> Self {
        StaticBuf {
            taken: AtomicBool::new(false),
            value: UnsafeCell::new(value),
        }
    }

    /// The buffer, the first time; `None` afterwards.
    // `&self -> &mut T` is sound here: the atomic flag makes the `&mut` unique (as in static_cell).
    #[allow(clippy::mut_from_ref)]
    pub fn take(&'static self) -> Option<&'static mut T> {
        if test_and_set(&self.taken) {
            return None;
        }
        // SAFETY: `test_and_set` above returns `false` exactly once, so this is the only reference
        // to `value` that is ever created.
        Some(unsafe { &mut *self.value.get() })
    }
}

/// The mapper's marks, which also hold the session's scan-matcher points between inserts
/// (`ogm_core::session::MarkWords`): one `static` of `W` words, seen as `W / 2` points when the
/// session asks. No RAM of its own for the points (4 KiB that the nRF52840 does not have).
pub struct SharedMarks<const W: usize>(pub &'static mut [u32; W]);

impl<const W: usize> AsRef<[u32]> for SharedMarks<W> {
    fn as_ref(&self) -> &[u32] {
        &self.0[..]
    }
}

impl<const W: usize> AsMut<[u32]> for SharedMarks<W> {
    fn as_mut(&mut self) -> &mut [u32] {
        &mut self.0[..]
    }
}

impl<const W: usize> ogm_core::session::MarkWords for SharedMarks<W> {
    fn points(&mut self) -> &mut [ogm_core::localize::ScanPoint] {
        let words: &mut [u32; W] = self.0;
        // SAFETY: `ScanPoint` is `repr(C)` of two `i32`s: size 8, alignment 4, every bit
        // pattern valid; `u32` has alignment 4, so the words' start is aligned for it, and
        // `W / 2` points cover at most the `W` words. The returned slice reborrows `self`
        // mutably, so the words cannot be used as words while it lives; what is written there
        // is plain data the mapper reads as words (the session zeroes it again before an
        // insert).
        unsafe {
            core::slice::from_raw_parts_mut(
                words.as_mut_ptr().cast::<ogm_core::localize::ScanPoint>(),
                W / 2,
            )
        }
    }
}

// The cast above relies on this layout.
const _: () = assert!(
    core::mem::size_of::<ogm_core::localize::ScanPoint>() == 8
        && core::mem::align_of::<ogm_core::localize::ScanPoint>() <= 4
);

/// A `static` slot for a value that has no `const` constructor (the mapping state, built from
/// the host's settings at run time): uninitialised in `.bss` (no flash, unlike a `StaticBuf`
/// of `Option<T>`, whose `None` is not all zero bytes and so lands in `.data`), written once.
pub struct StaticSlot<T> {
    taken: AtomicBool,
    value: UnsafeCell<core::mem::MaybeUninit<T>>,
}

// SAFETY: as for `StaticBuf`: `put` hands out at most one `&mut T`, ever.
unsafe impl<T: Send> Sync for StaticSlot<T> {}

impl<T> StaticSlot<T> {
    /// An empty slot.
    pub const fn new() -> Self {
        StaticSlot {
            taken: AtomicBool::new(false),
            value: UnsafeCell::new(core::mem::MaybeUninit::uninit()),
        }
    }

    /// Fills the slot with `make()`, the first time (`make` is not called afterwards:
    /// `None`). Taking a constructor rather than a value lets the compiler build a large value
    /// in place instead of on the stack first.
    // `&self -> &mut T` is sound here: the atomic flag makes the `&mut` unique.
    #[allow(clippy::mut_from_ref)]
    pub fn put_with(&'static self, make: impl FnOnce() -> T) -> Option<&'static mut T> {
        if test_and_set(&self.taken) {
            return None;
        }
        // SAFETY: `test_and_set` above returns `false` exactly once, so this is the only reference
        // to the slot that is ever created; `write` initialises it before it is returned.
        Some(unsafe { (*self.value.get()).write(make()) })
    }
}

/// A `static` array of a type without a `const` constructor (the ogm-core buffer element types
/// may grow fields; this needs only `Default`): uninitialised in `.bss`, filled element by
/// element on first use (never built on the stack), handed out once.
pub struct StaticArray<T, const N: usize> {
    taken: AtomicBool,
    value: UnsafeCell<core::mem::MaybeUninit<[T; N]>>,
}

// SAFETY: as for `StaticBuf`: `take_filled` hands out at most one `&mut`, ever.
unsafe impl<T: Send, const N: usize> Sync for StaticArray<T, N> {}

impl<T, const N: usize> StaticArray<T, N> {
    /// An unfilled array.
    pub const fn new() -> Self {
        StaticArray {
            taken: AtomicBool::new(false),
            value: UnsafeCell::new(core::mem::MaybeUninit::uninit()),
        }
    }

    /// The array with every element set to `fill()`, the first time; `None` afterwards.
    // `&self -> &mut T` is sound here: the atomic flag makes the `&mut` unique.
    #[allow(clippy::mut_from_ref)]
    pub fn take_filled(&'static self, fill: impl Fn() -> T) -> Option<&'static mut [T; N]> {
        if test_and_set(&self.taken) {
            return None;
        }
        let first = self.value.get().cast::<T>();
        for i in 0..N {
            // SAFETY: `MaybeUninit<[T; N]>` has the layout of `[T; N]`, so element `i < N` is
            // in bounds; nothing else can access the array (`test_and_set` above returns `false` once), and
            // `write` does not read or drop the uninitialised old value.
            unsafe { first.add(i).write(fill()) };
        }
        // SAFETY: all N elements were initialised above; this is the only reference.
        Some(unsafe { &mut *self.value.get().cast::<[T; N]>() })
    }
}

/// A single-producer single-consumer byte ring for a UART's receive side: the UART's receive
/// interrupt pushes, the main loop pops. `N` is a power of two (checked at compile time), so
/// the free-running indices wrap correctly and a slot is `index % N`.
///
/// Lock-free on any Cortex-M (atomic loads and stores only, no read-modify-write, so thumbv6m
/// too): the producer owns `head` and the slots from `head` on, the consumer owns `tail`; each
/// publishes with a release store what the other reads with an acquire load.
pub struct RxRing<const N: usize> {
    buf: UnsafeCell<[u8; N]>,
    /// Bytes pushed, ever (mod 2^32): written by the producer only.
    head: AtomicUsize,
    /// Bytes popped, ever: written by the consumer only.
    tail: AtomicUsize,
}

// SAFETY: one producer (the interrupt handler) and one consumer (the main loop) share the ring
// through the atomics: a slot is written only while it is outside `[tail, head)` and read only
// while inside it, so the two never access the same byte at once.
unsafe impl<const N: usize> Sync for RxRing<N> {}

impl<const N: usize> RxRing<N> {
    const POWER_OF_TWO: () = assert!(N.is_power_of_two());

    /// An empty ring.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::POWER_OF_TWO;
        RxRing {
            buf: UnsafeCell::new([0; N]),
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
        }
    }

    /// Producer side (the receive interrupt only): stores `byte`; `false` if the ring is full.
    pub fn push(&self, byte: u8) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        if head.wrapping_sub(self.tail.load(Ordering::Acquire)) >= N {
            return false;
        }
        // SAFETY: `head % N < N` is in the buffer, and the slot is outside `[tail, head)`, so
        // the consumer does not read it until the release store below publishes it.
        unsafe { self.buf.get().cast::<u8>().add(head % N).write(byte) };
        self.head.store(head.wrapping_add(1), Ordering::Release);
        true
    }

    /// Consumer side (the main loop only): the oldest byte, if any.
    pub fn pop(&self) -> Option<u8> {
        let tail = self.tail.load(Ordering::Relaxed);
        if self.head.load(Ordering::Acquire) == tail {
            return None;
        }
        // SAFETY: `tail % N < N`, and the slot is inside `[tail, head)`: published by the
        // producer (acquire above), which does not write it again until `tail` moves past it.
        let byte = unsafe { self.buf.get().cast::<u8>().add(tail % N).read() };
        self.tail.store(tail.wrapping_add(1), Ordering::Release);
        Some(byte)
    }

    /// Producer side: whether one more byte fits.
    pub fn has_room(&self) -> bool {
        let used = self.head.load(Ordering::Relaxed);
        used.wrapping_sub(self.tail.load(Ordering::Acquire)) < N
    }

    /// Whether no byte is waiting.
    pub fn is_empty(&self) -> bool {
        self.head.load(Ordering::Acquire) == self.tail.load(Ordering::Relaxed)
    }
}

// Stack size and high-water mark (`ogm_firmware::StackUsage`), from cortex-m-rt's `paint-stack`
// feature: the runtime fills `[_stack_end, _stack_start)` (from the end of `.bss`/`.uninit` to
// the top of RAM) with `0xCCCC_CCCC` before `main`; the lowest word that no longer holds the
// paint is the deepest the stack has reached. (A word that happened to be written with exactly
// the paint value would under-count by one word; irrelevant in practice.)
pub use ogm_firmware::StackUsage;

extern "C" {
    // Linker-script symbols (cortex-m-rt's link.x); only their addresses are used.
    static _stack_end: u32;
    static _stack_start: u32;
}

/// Room [`repaint_stack`] leaves below the stack pointer for an interrupt handler's frame.
const REPAINT_MARGIN: usize = 1024;

/// Paints the unused part of the stack again (everything more than [`REPAINT_MARGIN`] bytes
/// below the current stack pointer), so that [`stack_usage`] afterwards reports the high-water mark from here on:
/// e.g. of the mapping loop, without the one-off peak of building the sampler.
pub fn repaint_stack() {
    let lo = core::ptr::addr_of!(_stack_end) as usize;
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = lo;
    while p + REPAINT_MARGIN < sp {
        // SAFETY: `[lo, sp - REPAINT_MARGIN)` is stack RAM below the current stack pointer: no
        // live frame is there (the AAPCS has no red zone, and a receive interrupt taken during
        // this loop stacks less than the margin below `sp`: its exception frame, 104 bytes with
        // the FPU context, plus a handler of a few dozen), so painting it is harmless.
        unsafe { (p as *mut u32).write_volatile(cortex_m_rt::STACK_PAINT_VALUE) };
        p += 4;
    }
}

/// The stack's size and high-water mark (see [`StackUsage`] above).
pub fn stack_usage() -> StackUsage {
    let lo = core::ptr::addr_of!(_stack_end) as usize;
    let hi = core::ptr::addr_of!(_stack_start) as usize;
    let mut p = lo;
    while p < hi {
        // SAFETY: `[lo, hi)` is RAM owned by the stack (linker script); words below the current
        // stack pointer hold only the paint or dead stack frames, and a volatile read of them
        // has no side effects. Words above it belong to live frames, which we only read.
        let word = unsafe { (p as *const u32).read_volatile() };
        if word != cortex_m_rt::STACK_PAINT_VALUE {
            break;
        }
        p += 4;
    }
    StackUsage {
        size: (hi - lo) as u32,
        used: (hi - p) as u32,
    }
}
