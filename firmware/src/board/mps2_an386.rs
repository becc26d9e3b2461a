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
//! * defmt goes out over semihosting (`defmt-semihosting`), the program ends with a semihosting
//!   `SYS_EXIT` (QEMU exits with that status). Run QEMU with
//!   `-semihosting-config enable=on,target=native`.

use super::Reg;
use core::sync::atomic::{AtomicBool, Ordering};
use defmt_semihosting as _; // the global defmt logger

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

/// The board's peripherals, handed out once.
pub struct Board {
    /// UART0: the range sensor.
    pub lidar: Uart,
    /// UART1: the host link (map stream out, poses in).
    pub link: Uart,
    /// Timer 0, free-running.
    pub timer: Timer,
    /// Cortex-M core peripherals.
    pub core: cortex_m::Peripherals,
}

impl Board {
    /// Initialises the board: both UARTs enabled (TX and RX), timer 0 running. `None` if called
    /// before (peripherals have a single owner).
    pub fn take() -> Option<Board> {
        static TAKEN: AtomicBool = AtomicBool::new(false);
        if TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        let core = cortex_m::Peripherals::take()?;
        // SAFETY: these are the CMSDK UART0/UART1/timer0 register blocks of mps2-an386, and the
        // `TAKEN` guard makes this the only place that ever creates drivers for them.
        let (lidar, link, timer) = unsafe {
            (
                Uart::new(UART0_BASE, LIDAR_BAUD),
                Uart::new(UART1_BASE, LINK_BAUD),
                Timer::new(TIMER0_BASE),
            )
        };
        Some(Board {
            lidar,
            link,
            timer,
            core,
        })
    }
}

/// Ends the program: semihosting `SYS_EXIT` with `code` (QEMU exits with status `code`; 0 = ok).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

// ---------------------------------------------------------------------------------------------
// CMSDK APB UART

/// DATA: write = transmit a byte, read = the received byte (clears RXFULL).
const UART_DATA: usize = 0x00;
/// STATE: b0 TXFULL, b1 RXFULL, b2 TX overrun, b3 RX overrun (write 1 to clear overruns).
const UART_STATE: usize = 0x04;
/// CTRL: b0 TX_EN, b1 RX_EN (interrupt enables above, unused: polling).
const UART_CTRL: usize = 0x08;
/// BAUDDIV: SYSCLK / baud, at least 16.
const UART_BAUDDIV: usize = 0x10;

const STATE_TXFULL: u32 = 1 << 0;
const STATE_RXFULL: u32 = 1 << 1;
const STATE_RX_OVERRUN: u32 = 1 << 3;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;

/// A CMSDK APB UART, polled. One-byte TX and RX buffers; QEMU holds host input back while RXFULL
/// is set, so polling loses nothing there (a real UART at 230400 baud would need an interrupt or
/// DMA ring buffer: see [`UartError::Overrun`]).
pub struct Uart {
    data: Reg,
    state: Reg,
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

impl Uart {
    /// # Safety
    /// `base` must be the register block of a CMSDK APB UART that no other code uses.
    unsafe fn new(base: usize, baud: u32) -> Self {
        // SAFETY: caller's contract; the offsets are the CMSDK UART register map.
        let (data, state, ctrl, bauddiv) = unsafe {
            (
                Reg::at(base + UART_DATA),
                Reg::at(base + UART_STATE),
                Reg::at(base + UART_CTRL),
                Reg::at(base + UART_BAUDDIV),
            )
        };
        bauddiv.write((SYSCLK_HZ / baud).max(16));
        ctrl.write(CTRL_TX_EN | CTRL_RX_EN);
        // QEMU's CMSDK UART asks its character backend for input only when DATA is read (that
        // read calls `qemu_chr_fe_accept_input`); enabling RX alone does not. A backend that
        // was polled while RX was still disabled at reset (a socket that connected before the
        // guest ran) would otherwise never deliver a byte. On hardware this read just
        // discards a stale byte.
        let _ = data.read();
        Uart { data, state }
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
        if self.state.read() & STATE_RXFULL != 0 {
            Some(self.data.read() as u8)
        } else {
            None
        }
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

impl embedded_io::ErrorType for Uart {
    type Error = UartError;
}

impl embedded_io::Read for Uart {
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

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, UartError> {
        Ok(self.state.read() & STATE_RXFULL != 0)
    }
}

impl embedded_io::Write for Uart {
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

impl embedded_io::WriteReady for Uart {
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

/// The application's view of this board: its name, the timer, the painted stack.
impl ogm_firmware::Platform for Timer {
    const NAME: &'static str = BOARD_NAME;
    const TICK_HZ: u32 = TICK_HZ;

    #[inline(always)]
    fn now(&self) -> u32 {
        Timer::now(self)
    }

    fn stack_usage(&self) -> ogm_firmware::StackUsage {
        super::stack_usage()
    }

    fn repaint_stack(&mut self) {
        super::repaint_stack();
    }
}

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
// Faults

/// A hard fault (bad address, undefined instruction, …): log where and exit with status 3, so a
/// QEMU run fails instead of spinning until its timeout.
#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!(
        "HardFault: pc={=u32:#010x} lr={=u32:#010x} xpsr={=u32:#010x}",
        frame.pc(),
        frame.lr(),
        frame.xpsr()
    );
    exit(3)
}

/// Any interrupt without a handler: log it and exit with status 4.
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    defmt::error!("unhandled exception/interrupt {=i16}", irqn);
    exit(4)
}
