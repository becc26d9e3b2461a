//! Runs `ogm_core::sampler::gibbs` on a recorded dataset, with host-sized (or firmware-sized) buffers:
//! the paper's Table I/II variants and the robot's own sampler. `gibbs_l9_border` is always the
//! firmware's default mode (`RunConfig::ROBOT`: per-cell evidence, the evidence's configuration
//! as a candidate, averaged draws); `gibbs_l9_border_rays` is the paper's (the forward model
//! over every stored ray, sample counts), `gibbs_l9_border_hybrid` the robot's sampler with
//! the rays still in the store plus the evidence of what it dropped; `gibbs_l9_border_mean` the
//! robot's sampler read out as the mean of every counted sweep instead of its moving average. `gibbs_l25` (Table I's
//! "L = 25, data-driven prior") does not fit `ogm_core::sampler::gibbs`'s 16-bit patch words and runs on
//! the host-only sampler of [`l25`] instead.
//!
//! Layers: [`config`] (settings) < [`dataset`] (a dataset's rays and evidence map) < [`l25`] (the
//! host-only L = 25 sampler) < [`variant`] (which sampler) < `run` ([`run_sampler`],
//! [`Prepared`]).

pub mod config;
pub mod dataset;
pub mod l25;
mod run;
pub mod variant;

pub use config::{Bounds, SamplingConfig};
pub use dataset::evidence_map;
pub use run::{run_sampler, Prepared, SamplerOutput};
pub use variant::Variant;
