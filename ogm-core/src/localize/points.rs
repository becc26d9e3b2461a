//! A scan's hits as points in the robot frame, in sub-cells of the grid they will be matched
//! against, in caller memory.
//!
//! Which hits: those in `[min_range_mm, max_range_mm)` (no-returns carry no position), at least
//! `min_spacing_mm` (Chebyshev) from the last point kept, in beam order. If more remain than the
//! buffer holds, as many as it holds are kept, spread evenly over the candidates, so that the
//! points still cover the whole scan rather than its first beams.

use crate::localize::{MatchConfig, MAX_POINTS, MAX_POINT_SUB, SUB};
use crate::types::angle::Q30_ONE;
use crate::types::scan::{Beam, Range};

/// A point in the robot frame (x forward, y left), in 1/[`SUB`] cell. `repr(C)`: two `i32`s,
/// so a board may lend two words of idle `u32` scratch per point (the session's point buffer
/// shares the mapper's marks: [`crate::session::MarkWords`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanPoint {
    /// x, sub-cells.
    pub x: i32,
    /// y, sub-cells.
    pub y: i32,
}

/// What [`prepare_points`] did with a scan's beams.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PointStats {
    /// Points written (the first `kept` entries of the buffer).
    pub kept: usize,
    /// Hits within range and spacing (before thinning to the buffer's capacity).
    pub candidates: usize,
    /// Beams without a usable hit (no return, out of range, beyond [`MAX_POINT_SUB`]).
    pub unusable: usize,
    /// Hits skipped for being closer than `min_spacing_mm` to the previous point.
    pub crowded: usize,
}

/// One hit as a point in sub-cells of `cell_mm` cells, or `None` if it is out of range.
#[inline]
fn point_of(beam: &Beam, cell_mm: u32, cfg: &MatchConfig) -> Option<ScanPoint> {
    let Range::Hit(r) = beam.range else {
        return None;
    };
    if r < cfg.min_range_mm || r >= cfg.max_range_mm {
        return None;
    }
    let r = r.saturating_add(u32::from(cfg.hit_offset_mm));
    // Range in sub-cells; `cell_mm ≥ 1` (a geometry's cells are never empty, `max` makes sure).
    let q = if r < 1 << 23 {
        // r · 256 < 2^31: a 32-bit division (a 64-bit one is a library call on the M4).
        i64::from((r << 8) / cell_mm.max(1))
    } else {
        (i64::from(r) * i64::from(SUB)) / i64::from(cell_mm.max(1))
    };
    if q >= MAX_POINT_SUB {
        return None;
    }
    let (c, s) = beam.angle.cos_sin_q30();
    // |q| < 2^24, |c| ≤ 2^30: the products fit easily; round to nearest.
    let half = i64::from(Q30_ONE) / 2;
    let x = (q * i64::from(c) + half) >> 30;
    let y = (q * i64::from(s) + half) >> 30;
    Some(ScanPoint {
        x: x as i32,
        y: y as i32,
    })
}

/// Runs the range and spacing filters over `beams`, calling `keep` for each candidate point.
fn candidates(
    beams: &[Beam],
    cell_mm: u32,
    cfg: &MatchConfig,
    stats: &mut PointStats,
    mut keep: impl FnMut(ScanPoint),
) {
    let spacing = (i64::from(cfg.min_spacing_mm) * i64::from(SUB)) / i64::from(cell_mm.max(1));
    let mut last: Option<ScanPoint> = None;
    for beam in beams {
        let Some(p) = point_of(beam, cell_mm, cfg) else {
            stats.unusable += 1;
            continue;
        };
        if let Some(l) = last {
            let d = (i64::from(p.x) - i64::from(l.x))
                .abs()
                .max((i64::from(p.y) - i64::from(l.y)).abs());
            if d < spacing {
                stats.crowded += 1;
                continue;
            }
        }
        last = Some(p);
        stats.candidates += 1;
        keep(p);
    }
}

/// Turns `beams` into points for grids of `cell_mm` cells, written to the front of `out` (at
/// most [`MAX_POINTS`]). Work: two passes over the beams when they do not all fit, else one.
pub fn prepare_points(
    beams: &[Beam],
    cell_mm: u32,
    cfg: &MatchConfig,
    out: &mut [ScanPoint],
) -> PointStats {
    let cap = out.len().min(MAX_POINTS);
    let mut stats = PointStats::default();
    let mut kept = 0usize;
    candidates(beams, cell_mm, cfg, &mut stats, |p| {
        if let Some(slot) = out.get_mut(kept) {
            if kept < cap {
                *slot = p;
                kept += 1;
            }
        }
    });
    if stats.candidates > cap && cap > 0 {
        // Too many: keep `cap` candidates spread evenly (the `i`-th is kept when
        // ⌊(i+1)·cap/candidates⌋ steps up), not the first `cap`.
        let total = stats.candidates as u64;
        let mut again = PointStats::default();
        let (mut i, mut k) = (0u64, 0usize);
        candidates(beams, cell_mm, cfg, &mut again, |p| {
            let step_up = ((i + 1) * cap as u64) / total > (i * cap as u64) / total;
            if step_up && k < cap {
                if let Some(slot) = out.get_mut(k) {
                    *slot = p;
                    k += 1;
                }
            }
            i += 1;
        });
        kept = k;
    }
    stats.kept = kept;
    stats
}
