//! What `eval-log --odometry-drift` / `--truth-poses` ([`crate::eval::eval_odometry`]) reports:
//! `report.json`'s types and the Markdown tables (pose error per run, max F1 per map, the worst
//! ratios).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::eval::pose_error::{ratio, Rpe, RPE_DELTAS};
use crate::sim::track::VerdictCounts;

/// Max F1 of each map of one experiment.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ExperimentF1 {
    /// 1, 2 or 3.
    pub experiment: u8,
    /// Max F1 near the experiment's mapped cells (eval-log's figure), per method.
    pub near_mapped: BTreeMap<String, f64>,
    /// Max F1 over all cells the benchmark knows, per method.
    pub all: BTreeMap<String, f64>,
}

/// One trajectory's figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PosesResult {
    /// Relative pose error against the truth at 1, 10 and 100 scans.
    pub rpe: Vec<Rpe>,
    /// Absolute position error against the truth, m: mean and largest.
    pub position_error_m: (f64, f64),
    /// The maps made at these poses.
    pub maps: Vec<ExperimentF1>,
}

/// One odometry run (one seed, or the given log's odometry).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OdometryRun {
    /// The drift seed (`None`: `--truth-poses`).
    pub seed: Option<u64>,
    /// The odometry.
    pub odometry: PosesResult,
    /// The matched poses (`None` with `--no-match`).
    pub matched: Option<PosesResult>,
    /// How the matches went.
    pub verdicts: Option<VerdictCounts>,
}

impl OdometryRun {
    /// matched / odometry relative pose error at index `k` of [`crate::eval::pose_error::RPE_DELTAS`]:
    /// (translation, rotation); NaN without matching.
    pub fn ratios(&self, k: usize) -> (f64, f64) {
        let (Some(m), Some(o)) = (
            self.matched.as_ref().and_then(|m| m.rpe.get(k)),
            self.odometry.rpe.get(k),
        ) else {
            return (f64::NAN, f64::NAN);
        };
        (ratio(m.trans_m, o.trans_m), ratio(m.rot_deg, o.rot_deg))
    }
}

/// `DIR/report.json` of one log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OdometryReport {
    /// Log name.
    pub log: String,
    /// Where the truth came from: `the log's poses` or the `--truth-poses` file.
    pub truth: String,
    /// `--odometry-model` (with `--odometry-drift`).
    pub model: Option<String>,
    /// Scans.
    pub scans: usize,
    /// The maps made at the true poses.
    pub true_poses: Vec<ExperimentF1>,
    /// One run per seed.
    pub runs: Vec<OdometryRun>,
}

fn rpe_cell(r: Option<&Rpe>) -> String {
    r.map_or("—".into(), |r| {
        format!("{:.3} / {:.2}", r.trans_m, r.rot_deg)
    })
}

fn seed_cell(r: &OdometryRun) -> String {
    r.seed.map_or("—".into(), |s| s.to_string())
}

/// The pose-error table, the F1 table and the worst matched / odometry ratios.
pub fn tables(reports: &[OdometryReport]) -> String {
    let mut s = String::new();
    s.push_str("Relative pose error vs the truth, mean translation m / rotation ° (Kümmerle 2009), at 1 / 10 / 100 scans:\n\n");
    s.push_str("| log | model | seed | odometry Δ1 | matched Δ1 | odometry Δ10 | matched Δ10 | odometry Δ100 | matched Δ100 | matched/odometry t10 / r10 | t100 / r100 | verdicts T/A/R/U/F/N/W/C |\n");
    s.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for rep in reports {
        for r in &rep.runs {
            let m = r.matched.as_ref();
            let mut row = format!(
                "| {} | {} | {} |",
                rep.log,
                rep.model.as_deref().unwrap_or("given"),
                seed_cell(r)
            );
            for k in 0..RPE_DELTAS.len() {
                row.push_str(&format!(
                    " {} | {} |",
                    rpe_cell(r.odometry.rpe.get(k)),
                    rpe_cell(m.and_then(|m| m.rpe.get(k)))
                ));
            }
            let (t10, r10) = r.ratios(1);
            let (t100, r100) = r.ratios(2);
            row.push_str(&format!(
                " {t10:.3} / {r10:.3} | {t100:.3} / {r100:.3} | {} |\n",
                r.verdicts.map_or("—".into(), |v| v.short())
            ));
            s.push_str(&row);
        }
    }
    let ratios: Vec<[f64; 4]> = reports
        .iter()
        .flat_map(|rep| &rep.runs)
        .filter(|r| r.matched.is_some())
        .map(|r| {
            let (t10, r10) = r.ratios(1);
            let (t100, r100) = r.ratios(2);
            [t10, r10, t100, r100]
        })
        .collect();
    if !ratios.is_empty() {
        let worst = |k: usize| ratios.iter().map(|r| r[k]).fold(f64::NAN, f64::max);
        let mean = |k: usize| ratios.iter().map(|r| r[k]).sum::<f64>() / ratios.len() as f64;
        s.push_str(&format!(
            "\nmatched/odometry over {} runs: worst t10 {:.3} r10 {:.3} t100 {:.3} r100 {:.3}; mean t10 {:.3} r10 {:.3} t100 {:.3} r100 {:.3}\n",
            ratios.len(),
            worst(0),
            worst(1),
            worst(2),
            worst(3),
            mean(0),
            mean(1),
            mean(2),
            mean(3)
        ));
    }
    s.push_str("\nMax F1 near mapped cells against the benchmark of the true poses:\n\n");
    s.push_str("| log | model | seed | exp | method | true poses | odometry | matched |\n");
    s.push_str("|---|---|---|---|---|---|---|---|\n");
    let f1 = |maps: Option<&Vec<ExperimentF1>>, exp: u8, method: &str| -> String {
        maps.and_then(|v| v.iter().find(|e| e.experiment == exp))
            .and_then(|e| e.near_mapped.get(method))
            .map_or("—".into(), |f| format!("{f:.4}"))
    };
    for rep in reports {
        for r in &rep.runs {
            for e in &rep.true_poses {
                for method in e.near_mapped.keys() {
                    s.push_str(&format!(
                        "| {} | {} | {} | {} | {method} | {} | {} | {} |\n",
                        rep.log,
                        rep.model.as_deref().unwrap_or("given"),
                        seed_cell(r),
                        e.experiment,
                        f1(Some(&rep.true_poses), e.experiment, method),
                        f1(Some(&r.odometry.maps), e.experiment, method),
                        f1(r.matched.as_ref().map(|m| &m.maps), e.experiment, method),
                    ));
                }
            }
        }
    }
    s
}
