//! The vocabulary every layer shares: binary angles, fixed-point log-odds, integer poses and the
//! world ↔ cell transform, and a scan's beams. Imports nothing else of the crate but [`crate::error`].

pub mod angle;
pub mod fixed;
pub mod geometry;
pub mod scan;
