//! The evaluation report (`report.json`) shared by `demo`, `eval-sim` and `eval-log`.
//!
//! Shape: `{"methods": {"<name>": {max_f1, max_precision, threshold_at_max_f1,
//! precision_at_max_f1, recall_at_max_f1, cells_evaluated}}, "datasets": N, ...}`. Method names:
//! `traditional`, `gibbs_l1`, `gibbs_l9`, `gibbs_l9_border`, `mh`, `mh_heatmap`, `bp_sum`,
//! `bp_max`, `dd`.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::eval::metrics::Summary;

/// Per-map information in a report.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MapInfo {
    /// Name (file stem or "default").
    pub name: String,
    /// Cells wide.
    pub width: usize,
    /// Cells tall.
    pub height: usize,
    /// Cell size in metres.
    pub resolution_m: f64,
    /// Datasets simulated on it.
    pub runs: u32,
    /// Mean scans per dataset.
    pub mean_scans: f64,
}

/// A whole report.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Report {
    /// Pooled metrics per method over all cells with known ground truth.
    pub methods: BTreeMap<String, Summary>,
    /// The same restricted to cells within `restricted_radius_cells` of a cell some measurement
    /// mapped (the paper's hardware metric).
    pub methods_near_mapped: BTreeMap<String, Summary>,
    /// Radius (cells) of the restricted metric.
    pub restricted_radius_cells: f64,
    /// Number of datasets pooled.
    pub datasets: usize,
    /// The maps.
    pub maps: Vec<MapInfo>,
    /// Free-form settings (lidar, robot, sampler) for reproducibility.
    pub settings: serde_json::Value,
    /// Wall-clock seconds per method (summed over datasets).
    pub seconds: BTreeMap<String, f64>,
}

impl Report {
    /// Writes the report as pretty JSON.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let json = serde_json::to_string_pretty(self)?;
        std::fs::write(path, json + "\n").with_context(|| format!("writing {}", path.display()))
    }

    /// A table of the methods for the terminal.
    pub fn table(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!(
            "{:<22} {:>8} {:>9} {:>9} {:>9} {:>9} | {:>8}\n",
            "method", "max F1", "max prec", "thr@F1", "prec@F1", "rec@F1", "F1 near"
        ));
        for (name, m) in &self.methods {
            let near = self
                .methods_near_mapped
                .get(name)
                .map(|n| n.max_f1)
                .unwrap_or(f64::NAN);
            s.push_str(&format!(
                "{:<22} {:>8.4} {:>9.4} {:>9.3} {:>9.4} {:>9.4} | {:>8.4}\n",
                name,
                m.max_f1,
                m.max_precision,
                m.threshold_at_max_f1,
                m.precision_at_max_f1,
                m.recall_at_max_f1,
                near
            ));
        }
        s
    }
}
