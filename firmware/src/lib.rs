//! The robot's application, board-independent and `no_std`: what every board's binary runs and
//! what the host replays byte for byte to check it (`host-sim firmware`).
//!
//! * [`app`] — the link (LD06 packets + host frames, `ogm_core::lidar::link`), the mapping engine
//!   (`ogm_core::session::Session`) under a per-scan sampler budget, and the postcard map stream
//!   (`ogm_core::wire`);
//! * [`platform`] — what it needs from a board: a clock, the stack's high-water mark;
//! * [`selftest`] — a synthetic room through the same code when no host is on the link.
//!
//! The boards (`src/board/`, one binary per board feature) own the hardware, every `unsafe`
//! and the static memory. See docs/firmware.md (build, run, RAM layout, figures) and
//! docs/wire.md (the stream).
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

#[macro_use]
mod fmt;

pub mod app;
#[cfg(feature = "bench-match")]
pub mod bench_match;
pub mod platform;
pub mod selftest;
pub mod sizes;

pub use app::{App, Fed, Memory};
pub use platform::{LidarPort, Platform, StackUsage, Work};
