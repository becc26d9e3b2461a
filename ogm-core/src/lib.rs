//! # ogm-core
//!
//! Occupancy grid mapping for microcontrollers: `no_std`, no allocator, fixed point.
//! [`Session`] is the one way in: built from a [`RunConfig`] over caller memory of [`Sizes`],
//! it inserts scans ([`Session::insert`]) and improves the map between them ([`Session::step`]).
//!
//! ## Layers, bottom up (a layer imports only those below it)
//! * [`types`] — binary angles, `i16` log-odds in units of ln(4)/1024, integer poses, the
//!   world ↔ cell transform, a scan's beams; and [`error`], the crate's one error type;
//! * [`config`] — the run's settings as plain data ([`RunConfig`]), what the host sends;
//! * [`wire`] — the host link's frames and messages and the map stream's tile codec;
//! * [`map`] — online log-odds mapping: grid, rays, inverse sensor models, the mapper;
//! * [`sampler`] — the patch prior, forward model, ray store and the patch Gibbs sampler;
//! * [`localize`] — scan-to-map matching: odometry pose + scan → corrected pose and a verdict;
//! * [`lidar`] — LD06 and RPLIDAR parsers, the robot's receive link, turns and pose tracking:
//!   the one way scans and poses enter (bytes in, sans-IO; [`lidar::source`] says why);
//! * [`session`] — the engine: mapper, ray store and sampler behind `insert` / `step`;
//! * [`mod@reference`] — f64 reference implementations for tests (feature `reference`).
//!
//! ## Panics
//! Nothing in this crate panics on input values. Slices are accessed with `get`, arithmetic on
//! input-dependent values saturates or is bounded (each module says how), and bad parameters are
//! reported through [`Error`]. The crate denies `unwrap`, `expect`, `panic!` and slice indexing
//! outside tests.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]
#![forbid(unsafe_code)]
// The docs link to feature-gated items (`reference`, `Owned`): those links resolve with the
// features on, and the default build's docs are checked with warnings denied
// (scripts/test-all.sh); a build without the features would only report the gated links.
#![cfg_attr(
    not(all(feature = "reference", feature = "alloc")),
    allow(rustdoc::broken_intra_doc_links)
)]
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

pub mod error;
pub mod types;

pub mod config;
pub mod wire;

pub mod map;
pub mod sampler;

pub mod localize;

pub mod lidar;

pub mod session;

#[cfg(feature = "reference")]
pub mod reference;

pub use config::RunConfig;
pub use error::{Error, Result};
pub use map::grid::LogOddsGrid;
pub use map::mapper::{Mapper, MapperConfig, ScanStats};
pub use session::{Inserted, Session, SessionError, Sizes};
pub use types::angle::Angle;
pub use types::fixed::{Clamp, LogOdds};
pub use types::geometry::{CellCoord, GridGeometry, Pose};
pub use types::scan::{Beam, Range, ScanBuf};
