//! The classification of a scan into per-cell updates ([`classify_scan`]): the f64 reference's
//! and the cone model's, and what the beam model's insertion is tested against.

use super::band::Band;
use super::marks::{mark_chunk, marks_len, Marks, BRANCH_FREE_MARKING, CHUNK};
use super::rays::{beam_extent, Rays};
use super::{MapperConfig, ScanStats};
use crate::error::{Error, Result};
use crate::map::sensor_model::InverseModelKind;
use crate::types::angle::Angle;
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::Beam;

/// Classifies one scan into per-cell updates, calling `sink(index, update)` at most once per
/// cell, hits first. `marks` must hold at least `marks_len(geometry.len())` zeroed words and is
/// left zeroed. The f64 reference's classification, and the fixed-point mapper's for the cone
/// model (its beam model makes the same updates in `insert_beam_model`).
pub fn classify_scan(
    geometry: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    mut sink: impl FnMut(usize, CellUpdate),
) -> Result<ScanStats> {
    if marks.len() < marks_len(geometry.len()) {
        return Err(Error::BufferSize {
            expected: marks_len(geometry.len()),
            actual: marks.len(),
        });
    }
    match cfg.model.kind() {
        InverseModelKind::Beam | InverseModelKind::FaceBand { .. } => {
            Ok(classify_beam(geometry, cfg, pose, beams, marks, &mut sink))
        }
        InverseModelKind::Cone { alpha_mm, beta } => {
            classify_cone(geometry, cfg, pose, beams, alpha_mm, beta, &mut sink)
        }
    }
}

/// The update a cell receives from a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellUpdate {
    /// Occupied (`l_occ − l₀`).
    Hit,
    /// Free (`l_free − l₀`).
    Free,
    /// In a reading's face band ([`InverseModelKind::FaceBand`]), this many eighths of σ past
    /// the reading (from −[`crate::map::sensor_model::FACE_BAND_REACH_EIGHTHS`] to
    /// [`crate::map::sensor_model::FACE_BAND_FAR_EIGHTHS`], past the reach only with a far edge):
    /// `Φ(t)·(l_occ − l₀) + (1 − Φ(t))·(l_free − l₀)`.
    Face(i8),
}

fn classify_beam(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    sink: &mut impl FnMut(usize, CellUpdate),
) -> ScanStats {
    let mut stats = ScanStats::default();
    let mut marks = Marks::new(marks);
    let rays = Rays::new(g, pose);
    let (width, height) = (g.width(), g.height());
    let band = Band::of(cfg);
    // Pass 1: hits (the end cell, or the face band).
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            stats.beams_dropped += 1;
            continue;
        };
        stats.beams_used += 1;
        match band {
            _ if !hit => {}
            None => {
                if let Some(i) = g.index(rays.end(range, beam.angle)) {
                    if Marks::first_touch(marks.words, i) {
                        marks.cover(i, i);
                        stats.cells_hit += 1;
                        sink(i, CellUpdate::Hit);
                    }
                }
            }
            Some(b) => {
                let Some(face) = rays.band(b, range, beam.angle, None) else {
                    continue;
                };
                let words = &mut *marks.words;
                face.ray.for_each_index(face.steps, width, |k, i| {
                    if Marks::first_touch(words, i) {
                        stats.cells_hit += 1;
                        sink(i, CellUpdate::Face(face.eighths(k)));
                    }
                });
                marks.cover_rows(rays.origin, face.end, width, height);
            }
        }
    }
    // Pass 2: free space up to (not including) each hit's end cell or band, or through max
    // range.
    let mut freed = 0u32;
    let mut chunk = [0u32; CHUNK];
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            continue;
        };
        let traced = Band::traced(band, range, hit);
        let end = rays.end(traced, beam.angle);
        let Some((ray, mut steps)) = rays.in_grid(end) else {
            continue;
        };
        if let (Some(b), true) = (band, hit) {
            // The band was updated in pass 1; free only what lies before it.
            match b.first_step(range, traced, ray.steps()).checked_sub(1) {
                Some(last) if last >= steps.first => steps.last = steps.last.min(last),
                _ => continue,
            }
        } else if hit && steps.last == ray.steps() {
            // A hit's end cell is not freed (it was hit in pass 1).
            if steps.last == 0 || steps.first == steps.last {
                continue;
            }
            steps.last -= 1;
        }
        match ray.index_walk(steps, width) {
            Some(mut walk) => {
                // Mark a chunk of the ray, then update the cells it touched first: the marking
                // loop keeps its whole state in registers (a fused loop spilled on a Cortex-M4).
                while walk.left() > 0 {
                    let n = mark_chunk::<BRANCH_FREE_MARKING>(&mut walk, marks.words, &mut chunk);
                    for &i in chunk.get(..n).unwrap_or_default() {
                        sink(i as usize, CellUpdate::Free);
                    }
                    freed += n as u32;
                }
            }
            None => {
                let words = &mut *marks.words;
                ray.for_each_index(steps, width, |_, i| {
                    if Marks::first_touch(words, i) {
                        freed += 1;
                        sink(i, CellUpdate::Free);
                    }
                });
            }
        }
        marks.cover_rows(rays.origin, end, width, height);
    }
    stats.cells_freed = freed;
    stats
}

/// The lecture's α/β model, cell by cell over the square around the pose that the sensor can
/// reach (`r_max + α/2`).
fn classify_cone(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    alpha_mm: u32,
    beta: Angle,
    sink: &mut impl FnMut(usize, CellUpdate),
) -> Result<ScanStats> {
    if !beams
        .windows(2)
        .all(|w| matches!(w, [a, b] if a.angle.0 <= b.angle.0))
    {
        return Err(Error::UnsortedScan);
    }
    let mut stats = ScanStats::default();
    for b in beams {
        match beam_extent(cfg, b) {
            Some(_) => stats.beams_used += 1,
            None => stats.beams_dropped += 1,
        }
    }
    if beams.is_empty() {
        return Ok(stats);
    }
    let half_alpha = i64::from(alpha_mm / 2);
    let half_beta = i32::from(beta.0 / 2);
    let r_max = i64::from(cfg.max_range_mm);
    let reach = r_max + half_alpha;
    let lo = g.cell_of_point(i64::from(pose.x_mm) - reach, i64::from(pose.y_mm) - reach);
    let hi = g.cell_of_point(i64::from(pose.x_mm) + reach, i64::from(pose.y_mm) + reach);
    let (x0, x1) = (lo.x.max(0), hi.x.min(i32::from(g.width()) - 1));
    let (y0, y1) = (lo.y.max(0), hi.y.min(i32::from(g.height()) - 1));
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            let c = CellCoord { x: cx, y: cy };
            let (mx, my) = g.cell_center_mm(c);
            let (dx, dy) = (mx - i64::from(pose.x_mm), my - i64::from(pose.y_mm));
            let r2 = (dx * dx + dy * dy) as u64;
            if r2 > (reach * reach) as u64 {
                continue;
            }
            let r = r2.isqrt() as i64;
            let phi = Angle::atan2(dy, dx).wrapping_sub(pose.heading);
            let Some(beam) = nearest_beam(beams, phi) else {
                continue;
            };
            if i32::from(phi.signed_diff(beam.angle)).abs() > half_beta {
                continue;
            }
            let Some((range, hit)) = beam_extent(cfg, beam) else {
                continue;
            };
            let rk = i64::from(range);
            if r > r_max.min(rk + half_alpha) {
                continue;
            }
            let Some(i) = g.index(c) else { continue };
            if hit && (r - rk).abs() < half_alpha {
                stats.cells_hit += 1;
                sink(i, CellUpdate::Hit);
            } else if r <= rk {
                stats.cells_freed += 1;
                sink(i, CellUpdate::Free);
            }
        }
    }
    Ok(stats)
}

/// The beam closest in angle to `phi` (wrapping), in a slice sorted by angle.
fn nearest_beam(beams: &[Beam], phi: Angle) -> Option<&Beam> {
    let k = beams.partition_point(|b| b.angle.0 < phi.0);
    let after = beams.get(k).or(beams.first());
    let before = k.checked_sub(1).and_then(|j| beams.get(j)).or(beams.last());
    match (before, after) {
        (Some(a), Some(b)) => {
            let da = i32::from(phi.signed_diff(a.angle)).abs();
            let db = i32::from(phi.signed_diff(b.angle)).abs();
            Some(if da <= db { a } else { b })
        }
        (a, b) => a.or(b),
    }
}

#[cfg(test)]
mod tests {
    use super::super::strategies::{beams, geometry, mm};
    use super::*;
    use crate::map::ray::Ray;
    use crate::types::scan::Range;
    use proptest::prelude::*;
    use std::collections::HashSet;

    /// The mapper's beam classification as it was written first: `GridGeometry`'s i64
    /// conversions, the all-i128 clip, `cell_at` step by step, a hash set for the marks.
    fn classify_reference(
        g: &GridGeometry,
        cfg: &MapperConfig,
        pose: &Pose,
        beams: &[Beam],
    ) -> (Vec<(usize, CellUpdate)>, ScanStats) {
        let (mut calls, mut stats, mut seen) = (Vec::new(), ScanStats::default(), HashSet::new());
        let origin = g.cell_of_pose(pose);
        let end_cell = |range: u32, angle: Angle| {
            let (x, y) = pose.beam_end(angle, range);
            g.cell_of_point(x, y)
        };
        for beam in beams {
            match beam_extent(cfg, beam) {
                None => stats.beams_dropped += 1,
                Some((range, hit)) => {
                    stats.beams_used += 1;
                    if let Some(i) = hit.then(|| g.index(end_cell(range, beam.angle))).flatten() {
                        if seen.insert(i) {
                            stats.cells_hit += 1;
                            calls.push((i, CellUpdate::Hit));
                        }
                    }
                }
            }
        }
        for beam in beams {
            let Some((range, hit)) = beam_extent(cfg, beam) else {
                continue;
            };
            let ray = Ray::new(origin, end_cell(range, beam.angle));
            let Some(mut steps) = ray.clip_reference(g.width(), g.height()) else {
                continue;
            };
            if hit && steps.last == ray.steps() {
                if steps.last == 0 || steps.first == steps.last {
                    continue;
                }
                steps.last -= 1;
            }
            for s in steps.first..=steps.last {
                let i = g.index(ray.cell_at_reference(s)).unwrap();
                if seen.insert(i) {
                    stats.cells_freed += 1;
                    calls.push((i, CellUpdate::Free));
                }
            }
        }
        (calls, stats)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// `classify_scan` (beam model) makes exactly the calls, in exactly the order, of the
        /// straightforward reference, and leaves the marks zeroed.
        #[test]
        fn classification_matches_reference(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                            beams in beams(), max_range in 1u32..10_000, min_range in 0u32..300) {
            let mut cfg = MapperConfig::new(max_range.max(min_range + 1));
            cfg.min_range_mm = min_range;
            let pose = Pose { x_mm: x, y_mm: y, heading: Angle(heading) };
            let mut marks = vec![0u32; marks_len(g.len()) + 1];
            let mut calls = Vec::new();
            let stats = classify_scan(&g, &cfg, &pose, &beams, &mut marks, |i, u| calls.push((i, u))).unwrap();
            let (want_calls, want_stats) = classify_reference(&g, &cfg, &pose, &beams);
            prop_assert_eq!(stats, want_stats);
            prop_assert_eq!(calls, want_calls);
            prop_assert!(marks.iter().all(|&w| w == 0));
        }
    }

    /// Rays so long that the walk falls back to 64-bit state: 1 mm cells, a pose near the far
    /// end of the i32 range, a range of 4·10⁹ mm.
    #[test]
    fn very_long_rays_match_reference() {
        let g = GridGeometry::new(40, 30, 1, 0, 0).unwrap();
        let mut cfg = MapperConfig::new(u32::MAX);
        cfg.min_range_mm = 0;
        let beams: Vec<Beam> = (0..64u16)
            .map(|k| Beam {
                angle: Angle(k.wrapping_mul(1021)),
                range: Range::Hit(4_000_000_000),
            })
            .collect();
        for pose in [
            Pose {
                x_mm: -2_000_000_000,
                y_mm: 15,
                heading: Angle(0),
            },
            Pose {
                x_mm: 20,
                y_mm: 2_000_000_000,
                heading: Angle(49_152),
            },
            Pose {
                x_mm: 10,
                y_mm: 10,
                heading: Angle(77),
            },
        ] {
            let mut marks = vec![0u32; marks_len(g.len())];
            let mut calls = Vec::new();
            let stats = classify_scan(&g, &cfg, &pose, &beams, &mut marks, |i, u| {
                calls.push((i, u))
            })
            .unwrap();
            let (want_calls, want_stats) = classify_reference(&g, &cfg, &pose, &beams);
            assert!(stats.cells_freed > 20, "{stats:?}");
            assert_eq!(stats, want_stats);
            assert_eq!(calls, want_calls);
            assert!(marks.iter().all(|&w| w == 0));
        }
    }
}
