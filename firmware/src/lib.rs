//! The robot's application, board-independent and `no_std`: what every board's binary runs and
//! what the host replays byte for byte to check it (`host-sim firmware`).
//!
//! Layers, top down (a module imports only those below it):
//! * [`run`] — boot (a host, the stored settings or the self-test) and the main loop over the
//!   host link and the lidar's UART;
//! * [`selftest`] — a synthetic room through the same code when no host is on the link;
//! * [`app`] — the link (LD06 or RPLIDAR bytes + host frames, `ogm_core::lidar`), the mapping
//!   engine (`ogm_core::session::Session`) under a per-scan sampler budget, and the postcard map
//!   stream (`ogm_core::wire`);
//! * [`platform`] — what it needs from a board: a clock, the stack's high-water mark;
//!   [`sizes`] — every board's buffer sizes.
//!
//! The boards (`src/board/`, one binary per board feature) own the hardware, every `unsafe`
//! and the static memory. See docs/firmware.md (build, run, RAM layout, figures) and
//! docs/wire.md (the stream).
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

// The log macros: ogm-core's one shim (`ogm_core::__log`), at this crate's `defmt` feature (the
// boards'; the host's replay builds without it and logs nothing).
macro_rules! info {
    ($($t:tt)*) => { ::ogm_core::__log!(info, $($t)*) };
}
macro_rules! warn {
    ($($t:tt)*) => { ::ogm_core::__log!(warn, $($t)*) };
}
macro_rules! error {
    ($($t:tt)*) => { ::ogm_core::__log!(error, $($t)*) };
}

pub mod app;
#[cfg(feature = "bench-match")]
pub mod bench_match;
pub mod platform;
pub mod run;
pub mod selftest;
pub mod sizes;

pub use app::{App, Fed, Memory};
pub use platform::{LidarPort, Platform, StackUsage, Work};
pub use run::run;
