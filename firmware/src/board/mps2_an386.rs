//! QEMU `mps2-an386`: Arm MPS2 FPGA board with the AN386 Cortex-M4 image, 25 MHz system clock.
//!
//! * Memory: 4 MiB at 0x0000_0000 (code) and 4 MiB at 0x2000_0000 (SRAM); `memory.x` (an
//!   nRF52840-sized layout) fits inside both.
//! * UARTs: CMSDK APB UART i is QEMU's i-th `-serial`: UART0 0x4000_4000 (→ `lidar`),
//!   UART1 0x4000_5000 (→ `link`).
//! * Timers: CMSDK APB timer 0 at 0x4000_0000 (→ `timer`), a 32-bit down counter at 25 MHz.
//!   Under `qemu -icount shift=0,sleep=off` virtual time advances 1 ns per guest instruction, so
//!   one tick is exactly 40 instructions (not real cycles: QEMU models no pipeline, no wait
//!   states). DWT CYCCNT does not count in QEMU.
//! * defmt goes out over semihosting stdout ([`log`]), the program ends with a semihosting
//!   `SYS_EXIT` (QEMU exits with that status). Run QEMU with
//!   `-semihosting-config enable=on,target=native`.

use super::{Reg, RxRing};
use core::sync::atomic::{AtomicBool, Ordering};
use ogm_firmware::sizes::BoardSizes;

/// Name logged at boot.
pub const BOARD_NAME: &str = "mps2-an386 (QEMU)";

/// System clock = timer clock, Hz.
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Ticks per second of [`Timer::now`].
pub const TICK_HZ: u32 = SYSCLK_HZ;

const UART0_BASE: usize = 0x4000_4000;
const UART1_BASE: usize = 0x4000_5000;
const TIMER0_BASE: usize = 0x4000_0000;

/// Baud rates the board configures (QEMU ignores the rate; a real link would not).
const LIDAR_BAUD: u32 = 230_400;
const LINK_BAUD: u32 = 921_600;

/// The board's peripherals, handed out once ([`super::Board::take`]).
pub struct Mps2An386 {
    /// UART0: the range sensor.
    pub lidar: Uart<LIDAR_RX_RING>,
    /// UART1: the host link (map stream out, poses in).
    pub link: Uart<LINK_RX_RING>,
    /// Timer 0, free-running.
    pub timer: Timer,
    /// Cortex-M core peripherals.
    pub core: cortex_m::Peripherals,
}

impl super::Board for Mps2An386 {
    const NAME: &'static str = BOARD_NAME;
    const SIZES: BoardSizes = ogm_firmware::sizes::MPS2_AN386;
    type Link = Uart<LINK_RX_RING>;
    type Lidar = Uart<LIDAR_RX_RING>;
    type Clock = Timer;

    /// Initialises the board: both UARTs enabled (TX and RX), timer 0 running. `None` if called
    /// before (peripherals have a single owner).
    fn take() -> Option<Self> {
        static TAKEN: AtomicBool = AtomicBool::new(false);
        if super::test_and_set(&TAKEN) {
            return None;
        }
        let core = cortex_m::Peripherals::take()?;
        // SAFETY: these are the CMSDK UART0/UART1/timer0 register blocks of mps2-an386 with
        // their receive interrupts, and the `TAKEN` guard makes this the only place that ever
        // creates drivers for them.
        let (lidar, link, timer) = unsafe {
            (
                Uart::new(Irq::Uart0Rx, &LIDAR_RX, LIDAR_BAUD),
                Uart::new(Irq::Uart1Rx, &LINK_RX, LINK_BAUD),
                Timer::new(TIMER0_BASE),
            )
        };
        for irq in [Irq::Uart0Rx, Irq::Uart1Rx] {
            // SAFETY: unmasking can break a critical section only if the handler shares state
            // with one; the receive handlers touch their ring (lock-free) and their UART's
            // registers, whose one read-modify-write in thread mode (`Uart::resume`) runs with
            // interrupts off.
            unsafe { cortex_m::peripheral::NVIC::unmask(irq) };
            // Bytes that arrived before the unmask are taken now.
            cortex_m::peripheral::NVIC::pend(irq);
        }
        Some(Mps2An386 {
            lidar,
            link,
            timer,
            core,
        })
    }

    fn parts(&mut self) -> (&mut Self::Link, &mut Self::Lidar, &mut Self::Clock) {
        (&mut self.link, &mut self.lidar, &mut self.timer)
    }

    fn exit(code: i32) -> ! {
        exit(code)
    }
}

/// Ends the program: semihosting `SYS_EXIT` with `code` (QEMU exits with status `code`; 0 = ok).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

// ---------------------------------------------------------------------------------------------
// defmt over semihosting

/// The global defmt logger: frames to the host over semihosting stdout, one frame at a time
/// with interrupts off. What `defmt-semihosting` does, written here so that no byte goes
/// through `semihosting`'s `write_all`: its range-checked slicing and panic message keep
/// `core::fmt` (~2.3 KiB of flash) in the image.
mod log {
    use core::cell::UnsafeCell;
    use core::sync::atomic::{AtomicBool, Ordering};
    use semihosting::io::Write as _;

    #[defmt::global_logger]
    struct Logger;

    /// The logger's state; only touched between `acquire` and `release`.
    struct State {
        taken: AtomicBool,
        /// Interrupts were enabled when `acquire` disabled them.
        interrupts_were_on: AtomicBool,
        encoder: UnsafeCell<defmt::Encoder>,
        out: UnsafeCell<Option<semihosting::io::Stdout>>,
    }

    // SAFETY: the cells are only accessed by the holder of `taken`, with interrupts disabled
    // on this single-core part, so no two contexts ever access them at once.
    unsafe impl Sync for State {}

    static STATE: State = State {
        taken: AtomicBool::new(false),
        interrupts_were_on: AtomicBool::new(false),
        encoder: UnsafeCell::new(defmt::Encoder::new()),
        out: UnsafeCell::new(None),
    };

    /// Writes all of `bytes` to semihosting stdout; gives up on an error or a zero write (a
    /// log frame lost, never a panic).
    fn put(out: &mut Option<semihosting::io::Stdout>, mut bytes: &[u8]) {
        let Some(h) = out else { return };
        while !bytes.is_empty() {
            match h.write(bytes) {
                Ok(n) if n > 0 => match bytes.get(n..) {
                    Some(rest) => bytes = rest,
                    None => return,
                },
                _ => return,
            }
        }
    }

    // SAFETY (the trait's contract): defmt calls `write`/`flush`/`release` only between an
    // `acquire` and its `release`, which is what the cells' accesses below rely on.
    unsafe impl defmt::Logger for Logger {
        fn acquire() {
            let was_on = cortex_m::register::primask::read().is_active();
            cortex_m::interrupt::disable();
            // Interrupts are off: a load and a store are enough (and thumbv6m has no swap).
            if STATE.taken.load(Ordering::Relaxed) {
                panic!("defmt logger taken reentrantly");
            }
            STATE.taken.store(true, Ordering::Relaxed);
            STATE.interrupts_were_on.store(was_on, Ordering::Relaxed);
            // SAFETY: `taken` is ours and interrupts are off: nothing else accesses the cells.
            unsafe {
                let out = &mut *STATE.out.get();
                if out.is_none() {
                    *out = semihosting::io::stdout().ok();
                }
                (*STATE.encoder.get()).start_frame(|b| put(out, b));
            }
        }

        unsafe fn flush() {}

        unsafe fn release() {
            // SAFETY: called after `acquire` (the trait's contract): the cells are ours.
            unsafe {
                let out = &mut *STATE.out.get();
                (*STATE.encoder.get()).end_frame(|b| put(out, b));
            }
            STATE.taken.store(false, Ordering::Relaxed);
            if STATE.interrupts_were_on.load(Ordering::Relaxed) {
                // SAFETY: restores the state `acquire` found; the frame is complete.
                unsafe { cortex_m::interrupt::enable() };
            }
        }

        unsafe fn write(bytes: &[u8]) {
            // SAFETY: called after `acquire` (the trait's contract): the cells are ours.
            unsafe {
                let out = &mut *STATE.out.get();
                (*STATE.encoder.get()).write(bytes, |b| put(out, b));
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// CMSDK APB UART

/// DATA: write = transmit a byte, read = the received byte (clears RXFULL).
const UART_DATA: usize = 0x00;
/// STATE: b0 TXFULL, b1 RXFULL, b2 TX overrun, b3 RX overrun (write 1 to clear overruns).
const UART_STATE: usize = 0x04;
/// CTRL: b0 TX_EN, b1 RX_EN, b2 TX interrupt enable, b3 RX interrupt enable.
const UART_CTRL: usize = 0x08;
/// INTSTATUS on reads, INTCLEAR on writes: b0 TX, b1 RX, b2 TX overrun, b3 RX overrun.
const UART_INTCLEAR: usize = 0x0C;
/// BAUDDIV: SYSCLK / baud, at least 16.
const UART_BAUDDIV: usize = 0x10;

const STATE_TXFULL: u32 = 1 << 0;
const STATE_RXFULL: u32 = 1 << 1;
const STATE_RX_OVERRUN: u32 = 1 << 3;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INTEN: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;

/// Receive ring of the lidar's UART: 4 KiB is ~180 ms of an LD06 at 230 400 baud, longer than
/// the main loop ever leaves it (a scan's insertion and its tiles on the link).
pub const LIDAR_RX_RING: usize = 4096;
/// Receive ring of the host link (settings and 25 Hz poses: a few hundred bytes per second).
pub const LINK_RX_RING: usize = 1024;

/// A UART's receive side as its interrupt sees it. All zero at reset, so it lives in `.bss`
/// (a non-zero field would put the whole ring's initial value into flash).
struct RxLine<const N: usize> {
    ring: RxRing<N>,
    /// The handler found the ring full and turned its interrupt off (the byte stays in DATA:
    /// QEMU then holds the rest back, hardware counts an overrun); the reader turns it on again.
    paused: AtomicBool,
}

impl<const N: usize> RxLine<N> {
    const fn new() -> Self {
        RxLine {
            ring: RxRing::new(),
            paused: AtomicBool::new(false),
        }
    }

    /// The receive interrupt `irq`: moves what its UART holds into the ring; when the ring is
    /// full, leaves the byte in DATA and pauses (the reader resumes it).
    fn on_interrupt(&self, irq: Irq) {
        let (data, state, ctrl, intclear) = uart_regs(irq);
        intclear.write(INT_RX);
        while state.read() & STATE_RXFULL != 0 {
            if !self.ring.has_room() {
                ctrl.write(ctrl.read() & !CTRL_RX_INTEN);
                self.paused.store(true, Ordering::Release);
                return;
            }
            // Cannot fail: there is room, and only this handler pushes.
            let _ = self.ring.push(data.read() as u8);
        }
    }
}

/// DATA, STATE, CTRL and INTCLEAR of the UART whose receive interrupt is `irq` (safe: the
/// address can only be one of this board's two UART blocks).
fn uart_regs(irq: Irq) -> (Reg, Reg, Reg, Reg) {
    let base = irq.base();
    // SAFETY: `base` is UART0's or UART1's CMSDK register block; the offsets are its registers.
    unsafe {
        (
            Reg::at(base + UART_DATA),
            Reg::at(base + UART_STATE),
            Reg::at(base + UART_CTRL),
            Reg::at(base + UART_INTCLEAR),
        )
    }
}

static LIDAR_RX: RxLine<LIDAR_RX_RING> = RxLine::new();
static LINK_RX: RxLine<LINK_RX_RING> = RxLine::new();

/// The receive interrupts of UART0 and UART1 (mps2-an386: UART i's RX is IRQ 2·i, TX 2·i + 1).
#[derive(Clone, Copy)]
enum Irq {
    Uart0Rx = 0,
    Uart1Rx = 2,
}

impl Irq {
    /// The register block of the UART this interrupt belongs to.
    const fn base(self) -> usize {
        match self {
            Irq::Uart0Rx => UART0_BASE,
            Irq::Uart1Rx => UART1_BASE,
        }
    }
}

// SAFETY: the numbers are the board's interrupt lines (QEMU hw/arm/mps2.c: `uartirq[] = {0, 2,
// ...}` are the RX lines), all below the NVIC's line count.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// A CMSDK APB UART: receive by interrupt into a ring ([`RxRing`]), so no byte is lost while the
/// main loop maps or samples; transmit polled. When the ring fills, the interrupt pauses (the
/// byte waits in DATA) until the reader has made room: under QEMU nothing is lost then, on
/// hardware the UART counts an overrun ([`UartError::Overrun`]).
pub struct Uart<const N: usize> {
    data: Reg,
    state: Reg,
    ctrl: Reg,
    line: &'static RxLine<N>,
    irq: Irq,
}

/// UART errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum UartError {
    /// A received byte was lost because the previous one had not been read (never happens under
    /// QEMU). The flag is cleared when reported.
    Overrun,
}

impl core::fmt::Display for UartError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("UART receive overrun")
    }
}

impl core::error::Error for UartError {}

impl embedded_io::Error for UartError {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::Other
    }
}

impl<const N: usize> Uart<N> {
    /// # Safety
    /// No other driver may use `irq`'s UART, and `line` must be the ring its receive interrupt
    /// fills (see `DefaultHandler`).
    unsafe fn new(irq: Irq, line: &'static RxLine<N>, baud: u32) -> Self {
        let (data, state, ctrl, _) = uart_regs(irq);
        // SAFETY: BAUDDIV is a register of the same CMSDK UART block.
        let bauddiv = unsafe { Reg::at(irq.base() + UART_BAUDDIV) };
        bauddiv.write((SYSCLK_HZ / baud).max(16));
        ctrl.write(CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INTEN);
        // QEMU's CMSDK UART asks its character backend for input only when DATA is read (that
        // read calls `qemu_chr_fe_accept_input`); enabling RX alone does not. A backend that
        // was polled while RX was still disabled at reset (a socket that connected before the
        // guest ran) would otherwise never deliver a byte. On hardware this read just
        // discards a stale byte.
        let _ = data.read();
        Uart {
            data,
            state,
            ctrl,
            line,
            irq,
        }
    }

    /// Transmits one byte, waiting while the transmit buffer is full.
    #[inline]
    pub fn write_byte(&mut self, byte: u8) {
        while self.state.read() & STATE_TXFULL != 0 {}
        self.data.write(u32::from(byte));
    }

    /// The next received byte if one is waiting (never blocks).
    #[inline]
    pub fn try_read_byte(&mut self) -> Option<u8> {
        let byte = self.line.ring.pop()?;
        if self.line.paused.load(Ordering::Acquire) {
            self.resume();
        }
        Some(byte)
    }

    /// The ring has room again: the receive interrupt back on, and taken once now for the byte
    /// that waited in DATA (enabling it does not raise it again).
    #[cold]
    fn resume(&mut self) {
        cortex_m::interrupt::free(|_| {
            self.line.paused.store(false, Ordering::Release);
            self.ctrl.write(self.ctrl.read() | CTRL_RX_INTEN);
        });
        cortex_m::peripheral::NVIC::pend(self.irq);
    }

    /// Waits for the next received byte.
    pub fn read_byte(&mut self) -> u8 {
        loop {
            if let Some(b) = self.try_read_byte() {
                return b;
            }
        }
    }

    fn take_overrun(&mut self) -> Result<(), UartError> {
        if self.state.read() & STATE_RX_OVERRUN != 0 {
            self.state.write(STATE_RX_OVERRUN);
            Err(UartError::Overrun)
        } else {
            Ok(())
        }
    }
}

impl<const N: usize> embedded_io::ErrorType for Uart<N> {
    type Error = UartError;
}

impl<const N: usize> embedded_io::Read for Uart<N> {
    /// Blocks until at least one byte is there, then returns what is available without waiting.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, UartError> {
        let Some((first, rest)) = buf.split_first_mut() else {
            return Ok(0);
        };
        *first = self.read_byte();
        let mut n = 1;
        for slot in rest {
            match self.try_read_byte() {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        self.take_overrun()?;
        Ok(n)
    }
}

impl<const N: usize> embedded_io::ReadReady for Uart<N> {
    fn read_ready(&mut self) -> Result<bool, UartError> {
        Ok(!self.line.ring.is_empty())
    }
}

impl<const N: usize> embedded_io::Write for Uart<N> {
    /// Blocking: transmits the whole buffer.
    fn write(&mut self, buf: &[u8]) -> Result<usize, UartError> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    /// Waits until the transmit buffer has been handed on.
    fn flush(&mut self) -> Result<(), UartError> {
        while self.state.read() & STATE_TXFULL != 0 {}
        Ok(())
    }
}

impl<const N: usize> ogm_firmware::LidarPort for Uart<N> {
    fn set_baud(&mut self, baud: u32) {
        // SAFETY: BAUDDIV is a register of this driver's own CMSDK UART block (`Uart::new`).
        let bauddiv = unsafe { Reg::at(self.irq.base() + UART_BAUDDIV) };
        bauddiv.write((SYSCLK_HZ / baud.max(1)).max(16));
    }
}

impl<const N: usize> embedded_io::WriteReady for Uart<N> {
    fn write_ready(&mut self) -> Result<bool, UartError> {
        Ok(self.state.read() & STATE_TXFULL == 0)
    }
}

// ---------------------------------------------------------------------------------------------
// CMSDK APB timer

/// CTRL: b0 enable, b1 external enable, b2 external clock, b3 interrupt enable.
const TIMER_CTRL: usize = 0x00;
/// VALUE: current count (counts down at SYSCLK).
const TIMER_VALUE: usize = 0x04;
/// RELOAD: loaded into VALUE when it reaches 0.
const TIMER_RELOAD: usize = 0x08;
const TIMER_CTRL_EN: u32 = 1 << 0;

/// Timer 0 as a free-running 32-bit up-counter of [`TICK_HZ`] ticks (wraps every ~171.8 s;
/// use `wrapping_sub` for durations).
pub struct Timer {
    value: Reg,
}

impl Timer {
    /// # Safety
    /// `base` must be the register block of a CMSDK APB timer that no other code uses.
    unsafe fn new(base: usize) -> Self {
        // SAFETY: caller's contract; the offsets are the CMSDK timer register map.
        let (ctrl, value, reload) = unsafe {
            (
                Reg::at(base + TIMER_CTRL),
                Reg::at(base + TIMER_VALUE),
                Reg::at(base + TIMER_RELOAD),
            )
        };
        ctrl.write(0);
        reload.write(u32::MAX);
        value.write(u32::MAX);
        ctrl.write(TIMER_CTRL_EN);
        Timer { value }
    }

    /// Ticks since the timer was started (modulo 2³²).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        !self.value.read()
    }

    /// Nanoseconds in `ticks` (40 ns per tick; = guest instructions under `-icount shift=0`).
    pub const fn ticks_to_ns(ticks: u32) -> u64 {
        ticks as u64 * (1_000_000_000 / SYSCLK_HZ) as u64
    }
}

super::platform!(Timer);

impl embedded_hal::delay::DelayNs for Timer {
    fn delay_ns(&mut self, ns: u32) {
        let ticks = (u64::from(ns) * u64::from(TICK_HZ)).div_ceil(1_000_000_000) as u32;
        let start = self.now();
        while self.now().wrapping_sub(start) < ticks {}
    }
}

/// Microseconds since timer 0 was started (0 before `Board::take`), for defmt timestamps.
/// Reads the timer's registers only, which has no side effects, so it is safe alongside the
/// `Timer` owner.
pub fn uptime_us() -> u32 {
    // SAFETY: timer 0's CTRL and VALUE registers; reading them has no side effects.
    let (ctrl, value) = unsafe {
        (
            Reg::at(TIMER0_BASE + TIMER_CTRL),
            Reg::at(TIMER0_BASE + TIMER_VALUE),
        )
    };
    if ctrl.read() & TIMER_CTRL_EN == 0 {
        return 0;
    }
    !value.read() / (TICK_HZ / 1_000_000)
}

defmt::timestamp!("{=u32:us}", uptime_us());

// ---------------------------------------------------------------------------------------------
// Interrupts (the hard fault handler is shared: board/mod.rs)

/// Every interrupt comes here (this board has no peripheral-access crate, so no vector table
/// of named handlers): the UARTs' receive interrupts go to their rings; anything else is logged
/// and ends the program with status 4.
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        0 => LIDAR_RX.on_interrupt(Irq::Uart0Rx),
        2 => LINK_RX.on_interrupt(Irq::Uart1Rx),
        _ => {
            defmt::error!("unhandled exception/interrupt {=i16}", irqn);
            exit(4)
        }
    }
}
