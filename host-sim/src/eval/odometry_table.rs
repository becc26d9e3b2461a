//! The Markdown tables of `eval-log --odometry-drift` / `--truth-poses`
//! ([`crate::eval::eval_odometry`]): pose error per run, max F1 per map, the worst ratios.

use crate::eval::eval_odometry::{ExperimentF1, OdometryReport, OdometryRun};
use crate::eval::pose_error::{Rpe, RPE_DELTAS};

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
