//! # ogm-core
//!
//! Occupancy grid mapping for microcontrollers: `no_std`, no allocator, fixed point.
//!
//! * [`fixed`] — `i16` log-odds in units of ln(4)/1024, so the papers' Hähnel model is exact;
//! * [`geometry`], [`angle`] — integer poses, binary angles, world ↔ cell transforms;
//! * [`ray`] — Bresenham traversal in closed form, with exact clipping;
//! * [`sensor_model`] — inverse sensor models (Hähnel ray model, the lecture's α/β cone);
//! * [`mapper`] — online log-odds updates ("traditional OGM"), hits win within a scan;
//! * [`hal`] — the traits through which scans and poses enter (firmware and simulator alike);
//! * [`pipeline`] — the loop step both call;
//! * [`session`] — the engine: mapper, ray store and sampler behind `insert` / `step`;
//! * [`wire`] — the host link's messages and the map stream's tile codec;
//! * [`reference`] — f64 reference implementations for tests (feature `reference`).
//!
//! ## Panics
//! Nothing in this crate panics on input values. Slices are accessed with `get`, arithmetic on
//! input-dependent values saturates or is bounded (each module says how), and bad parameters are
//! reported through [`Error`]. The crate denies `unwrap`, `expect`, `panic!` and slice indexing
//! outside tests.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]
#![forbid(unsafe_code)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing
    )
)]

#[cfg(feature = "alloc")]
extern crate alloc;

#[macro_use]
mod fmt;

pub mod angle;
pub mod error;
pub mod fixed;
pub mod forward_model;
pub mod geometry;
pub mod gibbs;
pub mod grid;
pub mod hal;
pub mod ld06;
pub mod link;
pub mod mapper;
pub mod patch;
pub mod pipeline;
pub mod pose_track;
pub mod prior;
mod prior_table;
pub mod ray;
pub mod ray_store;
#[cfg(feature = "reference")]
pub mod reference;
pub mod rplidar;
pub mod sensor_model;
pub mod session;
pub mod turn;
pub mod wire;

pub use angle::Angle;
pub use error::{Error, Result};
pub use fixed::{Clamp, LogOdds};
pub use geometry::{CellCoord, GridGeometry, Pose};
pub use grid::LogOddsGrid;
pub use hal::{Beam, PoseSource, Range, RangeSensor, ScanBuf};
pub use mapper::{Mapper, MapperConfig, ScanStats};
