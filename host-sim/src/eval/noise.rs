//! The range sensor's noise, estimated from the data itself rather than hand-set: the forward
//! model's σ and outlier rate, and through σ the weight of free evidence
//! (`ogm_core::config::noise::free_evidence_q8`).
//!
//! For every hit of a sample of the scans, look along the beam within ±[`WINDOW_CELLS`] of the
//! measured range for the cell the log-odds map (built from the same scans) believes most
//! occupied; the residual is the measured range minus that cell's distance along the beam.
//! Walls are where many beams agree, so the residuals of a sensor with Gaussian noise σ spread
//! like N(0, σ²) plus the half-cell quantisation; outliers (glass, people, beams grazing a
//! corner) land anywhere. σ = 1.4826 · MAD of the residuals (robust to those outliers), minus
//! the quantisation in quadrature; the outlier rate is the share of hits more than 3σ from the
//! median or with no occupied cell in the window.

use ogm_core::{Beam, GridGeometry, LogOdds, Pose, Range};
use serde::{Deserialize, Serialize};

use crate::sim::explore::ScanRecord;

/// Half-width of the search window along a beam, cells.
pub const WINDOW_CELLS: f64 = 12.0;

/// At most this many hits are examined (scans are sampled evenly).
pub const MAX_HITS: usize = 200_000;

/// The estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NoiseEstimate {
    /// Range noise standard deviation, cells.
    pub sigma_cells: f64,
    /// Share of hits that are outliers.
    pub outlier_rate: f64,
    /// Hits examined.
    pub hits: usize,
}

/// Estimates the noise of the scans `scans` from `map`, their log-odds map over `g` built with
/// `mapper` (whose occupied increment is taken back out of each beam's own end cell); `None` if
/// fewer than 100 hits have an occupied cell near them.
pub fn estimate(
    g: &GridGeometry,
    mapper: &ogm_core::MapperConfig,
    scans: &[ScanRecord],
    map: &[LogOdds],
) -> Option<NoiseEstimate> {
    let occ_increment = i32::from(mapper.model.occ_increment().raw());
    let cell = f64::from(g.cell_mm());
    let hits_total: usize = scans
        .iter()
        .map(|s| {
            s.beams
                .iter()
                .filter(|b| matches!(b.range, Range::Hit(_)))
                .count()
        })
        .sum();
    let stride = hits_total.div_ceil(MAX_HITS).max(1);
    let mut residuals = Vec::new();
    let mut missing = 0usize;
    let mut k = 0usize;
    for s in scans {
        for b in &s.beams {
            let Range::Hit(mm) = b.range else { continue };
            k += 1;
            if k % stride != 0 {
                continue;
            }
            match residual(g, map, occ_increment, &s.pose, b, f64::from(mm) / cell) {
                Some(r) => residuals.push(r),
                None => missing += 1,
            }
        }
    }
    if residuals.len() < 100 {
        return None;
    }
    residuals.sort_by(f64::total_cmp);
    let median = residuals[residuals.len() / 2];
    let mut dev: Vec<f64> = residuals.iter().map(|r| (r - median).abs()).collect();
    dev.sort_by(f64::total_cmp);
    let mad = dev[dev.len() / 2];
    // The search quantises a residual to half a cell (uniform: variance 1/48), and a wall cell
    // is one cell deep (uniform over it: 1/12).
    let quant = 1.0 / 48.0 + 1.0 / 12.0;
    let sigma = ((1.4826 * mad).powi(2) - quant).max(0.0).sqrt().max(0.05);
    let far = residuals
        .iter()
        .filter(|r| (*r - median).abs() > 3.0 * sigma.max(0.5))
        .count();
    let n = residuals.len() + missing;
    Some(NoiseEstimate {
        sigma_cells: sigma,
        outlier_rate: (far + missing) as f64 / n as f64,
        hits: n,
    })
}

/// Measured range (cells) minus the distance of the most occupied cell within the window.
fn residual(
    g: &GridGeometry,
    map: &[LogOdds],
    occ_increment: i32,
    pose: &Pose,
    b: &Beam,
    z: f64,
) -> Option<f64> {
    let cell = f64::from(g.cell_mm());
    let (ox, oy) = (
        f64::from(g.origin_mm().0) / cell,
        f64::from(g.origin_mm().1) / cell,
    );
    let (px, py) = (
        f64::from(pose.x_mm) / cell - ox,
        f64::from(pose.y_mm) / cell - oy,
    );
    let th = pose.heading.wrapping_add(b.angle).to_radians();
    let (c, s) = (th.cos(), th.sin());
    let (w, h) = (i64::from(g.width()), i64::from(g.height()));
    let mut best: Option<(i32, f64)> = None;
    let end = ((px + z * c).floor() as i64, (py + z * s).floor() as i64);
    let mut t = (z - WINDOW_CELLS).max(0.5);
    while t <= z + WINDOW_CELLS {
        let (x, y) = ((px + t * c).floor() as i64, (py + t * s).floor() as i64);
        if (0..w).contains(&x) && (0..h).contains(&y) {
            let mut l = i32::from(map[(y * w + x) as usize].raw());
            if (x, y) == end {
                // Leave this beam's own hit out: it would pull the estimate to itself.
                l -= occ_increment;
            }
            // Most occupied; on ties the one nearest the measurement.
            let better = match best {
                None => l > 0,
                Some((bl, bt)) => l > bl || (l == bl && (t - z).abs() < (bt - z).abs()),
            };
            if better {
                best = Some((l, t));
            }
        }
        t += 0.5;
    }
    best.map(|(_, t)| z - t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimConfig};

    #[test]
    fn recovers_the_simulated_lidars_noise() {
        let world = crate::sim::generate::generate(
            &crate::sim::generate::GenParams {
                width: 200,
                height: 200,
                ..Default::default()
            },
            3,
        );
        for sigma in [0.5, 1.5, 3.0] {
            let mut cfg = SimConfig::default();
            cfg.lidar.sigma_cells = sigma;
            let run = simulate(&world, &cfg, 3).unwrap();
            let e = estimate(&run.geometry, &run.mapper_config, &run.scans, &run.map).unwrap();
            eprintln!("σ = {sigma}: estimated {e:?}");
            assert!(
                (e.sigma_cells - sigma).abs() < 0.35 * sigma + 0.3,
                "σ = {sigma}: estimated {e:?}"
            );
        }
    }
}
