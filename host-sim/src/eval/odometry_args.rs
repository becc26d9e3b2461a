//! `eval-log`'s odometry options (what [`crate::eval::eval_odometry`] runs).

use std::path::PathBuf;

use anyhow::bail;
use ogm_core::localize::odometry::OdometryModel;

/// eval-log's odometry options.
#[derive(clap::Args, Clone, Debug)]
pub struct OdometryArgs {
    /// Drift the log's poses (the truth) into wheel odometry with these seeds (comma-separated,
    /// one run each), map on the odometry with and without scan matching, and score the maps
    /// against the benchmark of the true poses.
    #[arg(long, value_delimiter = ',', conflicts_with = "truth_poses")]
    pub odometry_drift: Vec<u64>,
    /// With --odometry-drift: `issue39` (issue 39's mild model: 1 % of the distance, 2 % of the
    /// turn, 0.11°/m heading bias) or `cheap` (an uncalibrated small robot;
    /// `ogm_core::localize::odometry::OdometryModel::CHEAP_ROBOT`).
    #[arg(long, default_value = "issue39")]
    pub odometry_model: String,
    /// A log whose poses are the truth for the given log's scans (whose own poses are then the
    /// odometry); same number of scans.
    #[arg(long)]
    pub truth_poses: Option<PathBuf>,
    /// With --odometry-drift / --truth-poses: do not track; report odometry only.
    #[arg(long)]
    pub no_match: bool,
}

impl Default for OdometryArgs {
    /// Off (the log's poses are used as they are).
    fn default() -> Self {
        OdometryArgs {
            odometry_drift: Vec::new(),
            odometry_model: "issue39".into(),
            truth_poses: None,
            no_match: false,
        }
    }
}

impl OdometryArgs {
    /// Whether an odometry evaluation was asked for.
    pub fn is_active(&self) -> bool {
        !self.odometry_drift.is_empty() || self.truth_poses.is_some()
    }

    /// The model `--odometry-model` names.
    pub fn model(&self) -> anyhow::Result<OdometryModel> {
        model_named(&self.odometry_model)
    }
}

/// The odometry model of a name: `issue39` or `cheap`.
pub fn model_named(name: &str) -> anyhow::Result<OdometryModel> {
    Ok(match name {
        "issue39" => OdometryModel::ISSUE_39,
        "cheap" => OdometryModel::CHEAP_ROBOT,
        other => bail!("--odometry-model `{other}`: expected issue39 or cheap"),
    })
}
