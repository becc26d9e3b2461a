//! `host-sim`: the std side of the project — worlds, robot motion, synthetic lidar, metrics,
//! evaluation reports, plots, prior training and map I/O. Everything that maps calls `ogm-core`;
//! nothing here re-implements it.
#![warn(missing_docs)]

pub mod baselines;
pub mod bench_insert;
pub mod carmen;
pub mod demo;
pub mod eval;
pub mod eval_log;
pub mod explore;
pub mod firmware;
pub mod l25;
pub mod lidar;
pub mod link;
pub mod listen;
pub mod live;
pub mod map_export;
pub mod metrics;
pub mod noise;
pub mod prior;
pub mod progress;
pub mod recording;
pub mod render;
pub mod report;
pub mod robot;
pub mod sampling;
pub mod sim;
pub mod world;
