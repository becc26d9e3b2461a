//! nRF52840-DK (PCA10056): nRF52840, Cortex-M4F at 64 MHz, 1 MiB flash, 256 KiB RAM
//! (`memory.x` as it is: no SoftDevice, no bootloader). Built, not yet run on hardware: see
//! docs/firmware.md, "nRF52840-DK".
//!
//! * **Host link**: UARTE0 on the DK's interface MCU (J-Link virtual COM port over the same USB
//!   cable that flashes it): P0.08 RXD, P0.06 TXD, 921 600 baud. Map stream out, settings and
//!   poses in.
//! * **Lidar**: UARTE1 on [`LIDAR_RX_PIN`] (P1.01, a pin no DK peripheral uses), at the
//!   settings' lidar's rate. LD06 (230 400 baud): its `Tx` wire to P1.01, `PWM` to GND (internal
//!   speed control), `P5V`/`GND` to the DK's 5 V and GND; receive only. With the `rplidar`
//!   feature the UARTE also transmits on [`LIDAR_TX_PIN`] (P1.02): an RPLIDAR A1 (115 200 baud)
//!   has `TX` to P1.01, `RX` to P1.02 (the firmware sends it `SCAN`), `MOTOCTL` to 5 V (motor
//!   on), `VCC`/`GND` to 5 V and GND.
//! * Both UARTs are embassy-nrf `BufferedUarte`s: the UARTE's EasyDMA receives into a ring
//!   buffer while the sampler runs, a TIMER counts the bytes through PPI, overruns are reported
//!   as errors (the application counts them). The application polls them through
//!   `embedded_io` ([`Uart`], [`LidarUart`]); no executor is needed.
//! * **Timer**: the DWT cycle counter, 64 MHz (wraps every 67 s; the application uses
//!   `wrapping_sub`).
//! * **defmt** over RTT (`defmt-rtt`; `probe-rs run` shows it), panics through `panic-probe`,
//!   [`exit`] = a breakpoint when a debugger is attached, else a reset.

use super::StaticBuf;
use core::sync::atomic::AtomicBool;
use defmt_rtt as _; // the global defmt logger
#[cfg(not(feature = "rplidar"))]
use embassy_nrf::buffered_uarte::BufferedUarteRx;
use embassy_nrf::buffered_uarte::{self, BufferedUarte};
use embassy_nrf::{bind_interrupts, peripherals, uarte};
use ogm_firmware::sizes::BoardSizes;
use panic_probe as _;

/// Name logged at boot and sent in `Hello`.
pub const BOARD_NAME: &str = "nRF52840-DK";

/// CPU clock = DWT cycle counter, Hz.
pub const TICK_HZ: u32 = 64_000_000;

/// The pin the lidar's transmit wire goes to.
pub const LIDAR_RX_PIN: &str = "P1.01";
/// The pin the lidar's receive wire goes to (an RPLIDAR's requests; `rplidar` feature).
pub const LIDAR_TX_PIN: &str = "P1.02";

const LIDAR_BAUD: uarte::Baudrate = uarte::Baudrate::Baud230400;
const LINK_BAUD: uarte::Baudrate = uarte::Baudrate::Baud921600;

bind_interrupts!(struct Irqs {
    UARTE0 => buffered_uarte::InterruptHandler<peripherals::UARTE0>;
    UARTE1 => buffered_uarte::InterruptHandler<peripherals::UARTE1>;
});

// Receive/transmit rings (EasyDMA reads and writes RAM only, so they are statics in RAM). The
// lidar's 4 KiB is ~180 ms of an LD06, longer than the main loop ever leaves it.
static LIDAR_RX: StaticBuf<[u8; 4096]> = StaticBuf::new([0; 4096]);
#[cfg(feature = "rplidar")]
static LIDAR_TX: StaticBuf<[u8; 16]> = StaticBuf::new([0; 16]);
static LINK_RX: StaticBuf<[u8; 1024]> = StaticBuf::new([0; 1024]);
static LINK_TX: StaticBuf<[u8; 1024]> = StaticBuf::new([0; 1024]);

/// The board's peripherals, handed out once ([`super::Board::take`]).
pub struct Nrf52840Dk {
    /// UARTE1: the range sensor.
    pub lidar: LidarUart,
    /// UARTE0 (the DK's USB virtual COM port): the host link.
    pub link: Uart,
    /// The DWT cycle counter.
    pub timer: Timer,
}

impl super::Board for Nrf52840Dk {
    const NAME: &'static str = BOARD_NAME;
    const SIZES: BoardSizes = ogm_firmware::sizes::NRF52840;
    type Link = Uart;
    type Lidar = LidarUart;
    type Clock = Timer;

    /// Initialises the board: clocks (64 MHz crystal), both UARTs, the cycle counter. `None`
    /// if called before.
    fn take() -> Option<Self> {
        static TAKEN: AtomicBool = AtomicBool::new(false);
        if super::test_and_set(&TAKEN) {
            return None;
        }
        let mut core = cortex_m::Peripherals::take()?;
        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
        let mut config = embassy_nrf::config::Config::default();
        // UART timing from the crystal, not the ±1.5 % RC oscillator.
        config.hfclk_source = embassy_nrf::config::HfclkSource::ExternalXtal;
        let p = embassy_nrf::init(config);
        let (lidar_rx, link_rx, link_tx) = (LIDAR_RX.take()?, LINK_RX.take()?, LINK_TX.take()?);
        let mut c = uarte::Config::default();
        c.baudrate = LINK_BAUD;
        let link = BufferedUarte::new(
            p.UARTE0,
            p.TIMER0,
            p.PPI_CH0,
            p.PPI_CH1,
            p.PPI_GROUP0,
            p.P0_08,
            p.P0_06,
            Irqs,
            c,
            link_rx,
            link_tx,
        );
        let mut c = uarte::Config::default();
        c.baudrate = LIDAR_BAUD;
        #[cfg(not(feature = "rplidar"))]
        let lidar = LidarUart(BufferedUarteRx::new(
            p.UARTE1,
            p.TIMER1,
            p.PPI_CH2,
            p.PPI_CH3,
            p.PPI_GROUP1,
            Irqs,
            p.P1_01,
            c,
            lidar_rx,
        ));
        #[cfg(feature = "rplidar")]
        let lidar = Uart(BufferedUarte::new(
            p.UARTE1,
            p.TIMER1,
            p.PPI_CH2,
            p.PPI_CH3,
            p.PPI_GROUP1,
            p.P1_01,
            p.P1_02,
            Irqs,
            c,
            lidar_rx,
            LIDAR_TX.take()?,
        ));
        Some(Nrf52840Dk {
            lidar,
            link: Uart(link),
            timer: Timer,
        })
    }

    fn parts(&mut self) -> (&mut Self::Link, &mut Self::Lidar, &mut Self::Clock) {
        (&mut self.link, &mut self.lidar, &mut self.timer)
    }

    fn exit(code: i32) -> ! {
        exit(code)
    }
}

/// Ends the program: a breakpoint for an attached debugger (`probe-rs run` then exits), else a
/// system reset (a robot starts over). `code` is logged first.
pub fn exit(code: i32) -> ! {
    defmt::info!("exit {=i32}", code);
    if cortex_m::peripheral::DCB::is_debugger_attached() {
        cortex_m::asm::bkpt();
    }
    cortex_m::peripheral::SCB::sys_reset()
}

/// The host link: a `BufferedUarte` as blocking `embedded_io` (reads wait for at least one
/// byte, writes for room in the transmit ring).
pub struct Uart(BufferedUarte<'static>);

/// The lidar's UARTE, receive only (an LD06 is never written to), as blocking `embedded_io`.
#[cfg(not(feature = "rplidar"))]
pub struct LidarUart(BufferedUarteRx<'static>);

/// The lidar's UARTE, both ways (an RPLIDAR is sent its requests): the link's type.
#[cfg(feature = "rplidar")]
pub type LidarUart = Uart;

/// UART errors: the UARTE's receive ring overflowed.
pub type UartError = buffered_uarte::Error;

impl embedded_io::ErrorType for Uart {
    type Error = UartError;
}

#[cfg(not(feature = "rplidar"))]
impl embedded_io::ErrorType for LidarUart {
    type Error = UartError;
}

impl embedded_io::Read for Uart {
    #[inline(never)] // one copy of the driver's future, not one per caller (flash)
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, UartError> {
        embassy_futures::block_on(self.0.read(buf))
    }
}

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, UartError> {
        embedded_io::ReadReady::read_ready(&mut self.0)
    }
}

impl embedded_io::Write for Uart {
    #[inline(never)] // one copy of the driver's future, not one per caller (flash)
    fn write(&mut self, buf: &[u8]) -> Result<usize, UartError> {
        embassy_futures::block_on(self.0.write(buf))
    }

    #[inline(never)] // one copy of the driver's future, not one per caller (flash)
    fn flush(&mut self) -> Result<(), UartError> {
        embassy_futures::block_on(self.0.flush())
    }
}

#[cfg(not(feature = "rplidar"))]
impl embedded_io::Read for LidarUart {
    #[inline(never)] // one copy of the driver's future, not one per caller (flash)
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, UartError> {
        embassy_futures::block_on(self.0.read(buf))
    }
}

#[cfg(not(feature = "rplidar"))]
impl embedded_io::ReadReady for LidarUart {
    fn read_ready(&mut self) -> Result<bool, UartError> {
        embedded_io::ReadReady::read_ready(&mut self.0)
    }
}

/// No transmit pin: nothing to send to an LD06 (the application writes to the lidar only for an
/// RPLIDAR, whose settings an image without the `rplidar` feature refuses).
#[cfg(not(feature = "rplidar"))]
impl embedded_io::Write for LidarUart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, UartError> {
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), UartError> {
        Ok(())
    }
}

#[cfg(not(feature = "rplidar"))]
impl ogm_firmware::LidarPort for LidarUart {
    fn set_baud(&mut self, baud: u32) {
        // The receive half cannot change its rate; an LD06 talks at the rate it was built
        // with. Anything else is refused before this.
        let _ = baud;
    }
}

#[cfg(feature = "rplidar")]
impl ogm_firmware::LidarPort for Uart {
    fn set_baud(&mut self, baud: u32) {
        use uarte::Baudrate as B;
        self.0.set_baudrate(match baud {
            115_200 => B::Baud115200,
            _ => B::Baud230400,
        });
    }
}

/// The DWT cycle counter as the application's clock ([`TICK_HZ`]).
pub struct Timer;

impl Timer {
    /// Cycles since boot (modulo 2³²).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        cortex_m::peripheral::DWT::cycle_count()
    }

    /// Nanoseconds in `ticks` (15.625 ns per cycle).
    pub const fn ticks_to_ns(ticks: u32) -> u64 {
        ticks as u64 * 1_000 / 64
    }
}

super::platform!(Timer);

/// Microseconds since boot (wraps after 67 s), for defmt timestamps.
pub fn uptime_us() -> u32 {
    cortex_m::peripheral::DWT::cycle_count() / (TICK_HZ / 1_000_000)
}

defmt::timestamp!("{=u32:us}", uptime_us());
