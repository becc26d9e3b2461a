//! Online mapping ("traditional OGM"): the log-odds grid in caller memory, integer rays,
//! inverse sensor models and the mapper that inserts a scan (hits win within a scan).
//! Imports [`crate::types`] and [`crate::error`] only.

pub mod grid;
pub mod mapper;
pub mod ray;
pub mod sensor_model;
pub mod shift;
