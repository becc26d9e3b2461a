//! The researcher's: the evaluations and everything they compare, score and draw.
//!
//! * commands — [`demo`], [`eval_sim`] (`eval-sim`), [`eval_log`] (`eval-log`),
//!   [`baselines::fig2`] (`exact-1d`), [`bench_insert`] (`bench-insert`), [`prior`]
//!   (`train-prior`, `prior-stats`);
//! * the methods — [`sampling`] (the Gibbs sampler variants on a recorded dataset, the host-only
//!   L = 25 sampler) and [`baselines`] (the source papers' other inference methods);
//! * scoring and output — [`metrics`], [`render`], [`report`], [`noise`] (the range noise
//!   estimated from a log), [`perturb`] (a log made noisier or sparser, seeded), [`progress`],
//!   [`pose_error`] (relative pose error of a trajectory);
//! * wheel odometry and scan matching on logs — [`eval_odometry`] (`eval-log --odometry-drift`,
//!   `--truth-poses`), its [`odometry_args`] and [`odometry_report`]; [`log_setup`] (a log's grid, mapper,
//!   experiments and traditional map) and [`log_maps`] (the benchmark and the methods' maps)
//!   are what every eval-log variant and `export` share.
//!
//! Built on the simulator ([`crate::sim`]); nothing here depends on the firmware developer's
//! [`crate::firmware`].

pub mod baselines;
pub mod bench_insert;
pub mod demo;
pub mod eval_log;
pub mod eval_odometry;
pub mod eval_sim;
pub mod log_maps;
pub mod log_setup;
pub mod metrics;
pub mod noise;
pub mod odometry_args;
pub mod odometry_report;
pub mod perturb;
pub mod pose_error;
pub mod prior;
pub mod progress;
pub mod render;
pub mod report;
pub mod sampling;
