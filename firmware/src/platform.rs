//! What the application needs from the hardware it runs on: a clock, a name, the stack's
//! high-water mark. Each board implements [`Platform`]; the host's replay implements it too,
//! and there also fixes how many sampler updates each scan gets (the counts the firmware
//! reported), which is the only thing on the device that depends on timing.

/// Stack size and high-water mark (bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StackUsage {
    /// Bytes between the end of static RAM and the top of RAM.
    pub size: u32,
    /// Bytes of it used so far (high-water mark).
    pub used: u32,
}

/// Sampler work: after scan `seq`, or in idle period `seq`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Work {
    /// The updates after a scan.
    Scan(u32),
    /// The updates of an idle period.
    Idle(u32),
}

/// A board (or a host running the application).
pub trait Platform {
    /// Board name, reported in `Hello`.
    const NAME: &'static str;
    /// Ticks per second of [`Platform::now`].
    const TICK_HZ: u32;

    /// A free-running tick counter (wraps; durations use `wrapping_sub`).
    fn now(&self) -> u32;

    /// The stack's size and high-water mark; zeros where unknown.
    fn stack_usage(&self) -> StackUsage {
        StackUsage::default()
    }

    /// Restarts the high-water mark from here (see [`Platform::stack_usage`]).
    fn repaint_stack(&mut self) {}

    /// How many sampler updates `work` gets, if the platform fixes it; `None` (every board):
    /// as many as the run's budget allows on [`Platform::now`].
    fn fixed_updates(&mut self, work: Work) -> Option<u32> {
        let _ = work;
        None
    }

    /// Ticks in `us` microseconds, at most `u32::MAX` (a duration compared with the
    /// `wrapping_sub` of two [`Platform::now`] readings).
    fn ticks_in_us(us: u64) -> u32 {
        (us.saturating_mul(u64::from(Self::TICK_HZ)) / 1_000_000).min(u64::from(u32::MAX)) as u32
    }

    /// Nanoseconds in `ticks`.
    fn ticks_to_ns(ticks: u64) -> u64 {
        ticks * u64::from(1_000_000_000 / Self::TICK_HZ.max(1))
    }
}

/// The range sensor's UART as the application uses it: bytes in, requests out (an RPLIDAR is
/// commanded), and the baud rate the settings' lidar talks at
/// ([`ogm_core::config::LidarModel::baud`]).
pub trait LidarPort: embedded_io::Read + embedded_io::ReadReady + embedded_io::Write {
    /// Switches the UART to `baud` (bytes received before it may be garbled: the parsers
    /// resynchronise).
    fn set_baud(&mut self, baud: u32);
}
