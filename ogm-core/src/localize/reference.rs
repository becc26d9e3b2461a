//! The matcher in `f64` (feature `reference`): the same points, pyramid, Gauss–Newton steps,
//! prior, window, budget, probes and verdict as [`crate::localize::match_scan`], with real
//! arithmetic in place of the fixed point (and the heading unrounded). The tests compare the two;
//! the fixed-point code may differ by its roundings only (a sub-cell, a fraction of an angle unit
//! per step).

use crate::localize::field::MapView;
use crate::localize::matcher::{lever_of, Verdict};
use crate::localize::points::ScanPoint;
use crate::localize::{MatchConfig, MAX_LEVEL, MAX_POINTS, SUB};
use crate::types::geometry::Pose;
use crate::types::scan::{Beam, Range};

/// A match's outcome in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefResult {
    /// x, mm.
    pub x_mm: f64,
    /// y, mm.
    pub y_mm: f64,
    /// Heading, radians (the prediction's plus the correction, not wrapped).
    pub heading_rad: f64,
    /// As [`crate::localize::MatchResult::verdict`].
    pub verdict: Verdict,
    /// As [`crate::localize::Quality`], shares as fractions.
    pub quality: RefQuality,
    /// Gauss–Newton passes run.
    pub passes: u16,
}

/// [`crate::localize::Quality`] in `f64`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RefQuality {
    /// Points on occupied cells.
    pub matched: u32,
    /// Σ map value (1 per point on a fully occupied cell).
    pub score: f64,
    /// Share of the score lost along the weakest direction.
    pub drop_weak: f64,
    /// Share lost along the strongest direction.
    pub drop_strong: f64,
    /// Weakest direction, radians (an axis).
    pub weak_axis_rad: f64,
    /// Share lost by the turn probe.
    pub drop_turn: f64,
    /// Share of the last pass's points that had a distribution.
    pub overlap: f64,
    /// Share of the points deep in observed free space.
    pub contradicted: f64,
}

/// A beam's hit as a point in cells of `cell_mm` (robot frame), with the same range test as
/// [`crate::localize::prepare_points`] (spacing aside).
pub fn point_f64(beam: &Beam, cell_mm: u32, cfg: &MatchConfig) -> Option<(f64, f64)> {
    let Range::Hit(r) = beam.range else {
        return None;
    };
    if r < cfg.min_range_mm || r >= cfg.max_range_mm {
        return None;
    }
    let r = f64::from(r) + f64::from(cfg.hit_offset_mm);
    let q = r / f64::from(cell_mm.max(1));
    let a = beam.angle.to_radians();
    Some((q * libm::cos(a), q * libm::sin(a)))
}

struct RefField<'a> {
    cells: &'a [crate::types::fixed::LogOdds],
    w: i64,
    h: i64,
    floor: f64,
    span: f64,
}

impl RefField<'_> {
    fn value(&self, raw: i16) -> f64 {
        ((f64::from(raw) - self.floor) / self.span).clamp(0.0, 1.0)
    }

    fn raw(&self, x: i64, y: i64) -> Option<i16> {
        if x < 0 || y < 0 || x >= self.w || y >= self.h {
            return None;
        }
        self.cells.get((y * self.w + x) as usize).map(|l| l.0)
    }

    /// The cell of (x, y) and those two and four cells farther along the beam direction
    /// (rx, ry) (cells, along its dominant axis) all inside and at or below `free`.
    fn see_through(&self, x: f64, y: f64, rx: f64, ry: f64, free: i16) -> bool {
        let m = libm::fabs(rx).max(libm::fabs(ry)).max(1.0 / 256.0);
        let (sx, sy) = (2.0 * rx / m, 2.0 * ry / m);
        [0.0, 1.0, 2.0].iter().all(|k| {
            let (cx, cy) = (
                libm::floor(x + k * sx) as i64,
                libm::floor(y + k * sy) as i64,
            );
            self.raw(cx, cy).is_some_and(|l| l <= free)
        })
    }

    fn nearest(&self, x: f64, y: f64) -> f64 {
        self.raw(libm::floor(x) as i64, libm::floor(y) as i64)
            .map_or(0.0, |r| self.value(r))
    }

    /// Max-pooled level cell (i, j) of size n; `None` if any of it is outside the grid.
    fn pooled(&self, i: i64, j: i64, n: i64) -> Option<i16> {
        let mut m = i16::MIN;
        for y in j * n..(j + 1) * n {
            for x in i * n..(i + 1) * n {
                m = m.max(self.raw(x, y)?);
            }
        }
        Some(m)
    }

    /// The window's distribution at (x, y) grid cells: point → centroid (level cells) and the
    /// Cauchy-weighted inverse covariance (per level cell²), as `field::Field::near`.
    fn near(&self, x: f64, y: f64, level: u8, p: &RefNear) -> Option<[f64; 5]> {
        let n = 1i64 << level;
        let (u, v) = (x / n as f64, y / n as f64);
        let (i, j) = (libm::floor(u) as i64, libm::floor(v) as i64);
        let r = i64::from(p.radius);
        let (mut s0, mut s1x, mut s1y, mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for cj in j - r..=j + r {
            for ci in i - r..=i + r {
                let w = self.value(self.pooled(ci, cj, n)?);
                let (ex, ey) = (ci as f64 + 0.5 - u, cj as f64 + 0.5 - v);
                s0 += w;
                s1x += w * ex;
                s1y += w * ey;
                sxx += w * ex * ex;
                sxy += w * ex * ey;
                syy += w * ey * ey;
            }
        }
        if s0 < 0.5 {
            return None;
        }
        let (mx, my) = (s1x / s0, s1y / s0);
        let cxx = sxx / s0 - mx * mx + p.reg;
        let cyy = syy / s0 - my * my + p.reg;
        let cxy = sxy / s0 - mx * my;
        let det = cxx * cyy - cxy * cxy;
        if det.partial_cmp(&0.0) != Some(core::cmp::Ordering::Greater) {
            return None;
        }
        let (oxx, oxy, oyy) = (cyy / det, -cxy / det, cxx / det);
        let d2 = mx * (oxx * mx + oxy * my) + my * (oxy * mx + oyy * my);
        let w = p.cauchy / (p.cauchy + d2);
        Some([mx, my, w * oxx, w * oxy, w * oyy])
    }
}

/// [`RefField::near`]'s settings.
struct RefNear {
    radius: u8,
    reg: f64,
    cauchy: f64,
}

fn solve3(h: &[[f64; 3]; 3], b: &[f64; 3]) -> Option<[f64; 3]> {
    let [[a00, a01, a02], [_, a11, a12], [_, _, a22]] = *h;
    let c00 = a11 * a22 - a12 * a12;
    let c01 = a02 * a12 - a01 * a22;
    let c02 = a01 * a12 - a02 * a11;
    let c11 = a00 * a22 - a02 * a02;
    let c12 = a01 * a02 - a00 * a12;
    let c22 = a00 * a11 - a01 * a01;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    if !(det > 0.0 && a00 > 0.0 && c22 > 0.0) {
        return None;
    }
    Some([
        (c00 * b[0] + c01 * b[1] + c02 * b[2]) / det,
        (c01 * b[0] + c11 * b[1] + c12 * b[2]) / det,
        (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det,
    ])
}

/// [`crate::localize::match_scan`] in `f64`.
pub fn match_scan_f64(
    map: &MapView<'_>,
    points: &[ScanPoint],
    predicted: &Pose,
    cfg: &MatchConfig,
) -> RefResult {
    let points = points.get(..points.len().min(MAX_POINTS)).unwrap_or(&[]);
    let n = points.len();
    let mut out = RefResult {
        x_mm: f64::from(predicted.x_mm),
        y_mm: f64::from(predicted.y_mm),
        heading_rad: predicted.heading.to_radians(),
        verdict: Verdict::TooFewPoints,
        quality: RefQuality::default(),
        passes: 0,
    };
    if cfg.validate().is_err() || n < usize::from(cfg.min_points).max(1) {
        return out;
    }
    let g = map.geometry();
    let cell = f64::from(g.cell_mm().max(1));
    let (ox, oy) = g.origin_mm();
    let x0 = (f64::from(predicted.x_mm) - f64::from(ox)) / cell;
    let y0 = (f64::from(predicted.y_mm) - f64::from(oy)) / cell;
    let sub = f64::from(SUB);
    if libm::fabs(x0) * sub > (1u64 << 27) as f64 || libm::fabs(y0) * sub > (1u64 << 27) as f64 {
        out.verdict = Verdict::NoOverlap;
        return out;
    }
    let field = RefField {
        cells: map.cells(),
        w: i64::from(g.width()),
        h: i64::from(g.height()),
        floor: f64::from(cfg.floor.0),
        span: (f64::from(cfg.occupied.0) - f64::from(cfg.floor.0)).max(1.0),
    };
    let pts = |i: &ScanPoint| (f64::from(i.x) / sub, f64::from(i.y) / sub);
    let th0 = predicted.heading.to_radians();
    let lever = lever_of(points);
    let win = (f64::from(cfg.max_shift_mm) / cell).min((1u64 << 26) as f64 / sub);
    let win_th = f64::from(cfg.max_turn.0.min(32767)) / 65536.0 * core::f64::consts::TAU;

    let (mut dx, mut dy) = (0.0f64, 0.0f64);
    // The heading search is discrete and exact: shared with the fixed-point matcher.
    let mut dth = f64::from(crate::localize::matcher::heading_search(
        map, points, predicted, cfg,
    )) / (256.0 * 65536.0)
        * core::f64::consts::TAU;
    let mut at_edge = false;
    let mut overlap = 0.0f64;
    let mut reads = cfg.search_reads(n);
    let budget = if cfg.budget_reads == 0 {
        u64::MAX
    } else {
        u64::from(cfg.budget_reads)
    };
    let mut np = RefNear {
        radius: cfg.radius_at(0),
        reg: f64::from(cfg.reg_q8) / 256.0 + 1.0 / 12.0,
        cauchy: f64::from(cfg.cauchy_q8) / 256.0,
    };
    'levels: for level in (0..=cfg.levels.min(MAX_LEVEL)).rev() {
        let lever_k = lever.saturating_sub(u32::from(level));
        let scale = f64::from(1u32 << level); // cells per level cell
        let lev = f64::from(1u32 << lever_k);
        let cost = cfg.pass_reads(level, n);
        np.radius = cfg.radius_at(level);
        // A coarse pass leaves room for one pass at the grid's level: a match the budget cuts
        // short still ends on the grid (the coarse levels only bring it into reach).
        let reserve = if level > 0 { cfg.pass_reads(0, n) } else { 0 };
        for _ in 0..cfg.iterations {
            if reads + cost + reserve > budget {
                if level > 0 {
                    continue 'levels;
                }
                break 'levels;
            }
            reads += cost;
            out.passes += 1;
            let (s, c) = (libm::sin(th0 + dth), libm::cos(th0 + dth));
            let (mut h, mut b, mut used) = ([[0.0f64; 3]; 3], [0.0f64; 3], 0u32);
            for p in points.iter().step_by(cfg.stride_at(level)) {
                let (px, py) = pts(p);
                let (rx, ry) = (px * c - py * s, px * s + py * c);
                let Some([mx, my, oxx, oxy, oyy]) =
                    field.near(x0 + dx + rx, y0 + dy + ry, level, &np)
                else {
                    continue;
                };
                used += 1;
                // Rotation column of the Jacobian, level cells at the lever.
                let (jx, jy) = (-ry / scale / lev, rx / scale / lev);
                // H += JᵀΩJ, b += JᵀΩμ with J = [[1, 0, jx], [0, 1, jy]].
                let (ojx, ojy) = (oxx * jx + oxy * jy, oxy * jx + oyy * jy);
                let (omx, omy) = (oxx * mx + oxy * my, oxy * mx + oyy * my);
                let add = [
                    [oxx, oxy, ojx],
                    [oxy, oyy, ojy],
                    [ojx, ojy, jx * ojx + jy * ojy],
                ];
                for (hr, ar) in h.iter_mut().zip(add) {
                    for (hv, av) in hr.iter_mut().zip(ar) {
                        *hv += av;
                    }
                }
                for (bv, av) in b.iter_mut().zip([omx, omy, jx * omx + jy * omy]) {
                    *bv += av;
                }
            }
            overlap = f64::from(used) / n.div_ceil(cfg.stride_at(level)).max(1) as f64;
            if used == 0 {
                break;
            }
            let lt = f64::from(used) * f64::from(cfg.prior_trans_q8) / 256.0 * scale * scale;
            let lr = f64::from(used) * f64::from(cfg.prior_rot) / (lev * lev);
            let lam = [lt, lt, lr];
            let off = [dx / scale, dy / scale, dth * lev];
            for (i, ((hr, bv), (l, o))) in h
                .iter_mut()
                .zip(b.iter_mut())
                .zip(lam.iter().zip(off))
                .enumerate()
            {
                if let Some(d) = hr.get_mut(i) {
                    *d += l;
                }
                *bv -= l * o;
            }
            let Some(step) = solve3(&h, &b) else {
                break;
            };
            let step = step.map(|v| v.clamp(-1.0, 1.0));
            let next = (
                dx + step[0] * scale,
                dy + step[1] * scale,
                dth + step[2] / lev,
            );
            let clamped = (
                next.0.clamp(-win, win),
                next.1.clamp(-win, win),
                next.2.clamp(-win_th, win_th),
            );
            at_edge = clamped != next;
            (dx, dy, dth) = clamped;
            if step.iter().all(|v| libm::fabs(*v) < 1.0 / 16.0) {
                break;
            }
        }
    }
    out.x_mm = f64::from(predicted.x_mm) + dx * cell;
    out.y_mm = f64::from(predicted.y_mm) + dy * cell;
    out.heading_rad = th0 + dth;

    // Probes.
    let d = (f64::from(cfg.probe_mm) / cell).max(1.0 / sub);
    let e = d / core::f64::consts::SQRT_2;
    let offs = [
        (d, 0.0),
        (-d, 0.0),
        (0.0, d),
        (0.0, -d),
        (e, e),
        (-e, -e),
        (-e, e),
        (e, -e),
    ];
    let place = |th: f64| {
        let (s, c) = (libm::sin(th), libm::cos(th));
        move |p: &ScanPoint| {
            let (px, py) = pts(p);
            (x0 + dx + px * c - py * s, y0 + dy + px * s + py * c)
        }
    };
    let (s_fin, c_fin) = (libm::sin(th0 + dth), libm::cos(th0 + dth));
    let at = place(th0 + dth);
    let (mut score, mut matched, mut moved) = (0.0f64, 0u32, [0.0f64; 8]);
    let mut contradicted = 0u32;
    for p in points {
        let (x, y) = at(p);
        let (px, py) = pts(p);
        let (rx, ry) = (px * c_fin - py * s_fin, px * s_fin + py * c_fin);
        contradicted += u32::from(field.see_through(x, y, rx, ry, cfg.free.0));
        let m = field.nearest(x, y);
        score += m;
        matched += u32::from(m >= 0.5);
        for (acc, (ox, oy)) in moved.iter_mut().zip(offs) {
            *acc += field.nearest(x + ox, y + oy);
        }
    }
    let turn = (d / f64::from(1u32 << lever)).max(core::f64::consts::TAU / 65536.0);
    let mut turned = 0.0;
    for sign in [1.0, -1.0] {
        let at = place(th0 + dth + sign * turn);
        for p in points {
            let (x, y) = at(p);
            turned += field.nearest(x, y);
        }
    }
    let [xp, xm, yp, ym, dp, dm, ap, am] = moved;
    let (lx, ly) = (score - (xp + xm) / 2.0, score - (yp + ym) / 2.0);
    let (ld, la) = (score - (dp + dm) / 2.0, score - (ap + am) / 2.0);
    let (a, bb, c) = (lx, (ld - la) / 2.0, ly);
    let mid = (a + c) / 2.0;
    let rad = libm::sqrt(((a - c) / 2.0) * ((a - c) / 2.0) + bb * bb);
    let share = |v: f64| {
        if score > 0.0 {
            (v.max(0.0) / score).min(1.0)
        } else {
            0.0
        }
    };
    out.quality = RefQuality {
        matched,
        score,
        drop_weak: share(mid - rad),
        drop_strong: share(mid + rad),
        weak_axis_rad: 0.5 * libm::atan2(2.0 * bb, a - c) + core::f64::consts::FRAC_PI_2,
        drop_turn: share(score - turned / 2.0),
        overlap,
        contradicted: f64::from(contradicted) / n.max(1) as f64,
    };
    let q = &out.quality;
    let permille = |v: f64| (v * 1000.0) as u16;
    out.verdict = if permille(q.overlap) < cfg.min_overlap_permille || q.score <= 0.0 {
        Verdict::NoOverlap
    } else if at_edge {
        Verdict::OutOfWindow
    } else if permille(q.contradicted) > cfg.max_contradicted_permille {
        Verdict::Contradicted
    } else if permille(q.drop_turn) < cfg.min_turn_drop_permille
        && permille(q.drop_weak) < cfg.min_drop_permille
    {
        Verdict::Unconstrained
    } else if permille(q.drop_turn) < cfg.min_turn_drop_permille {
        Verdict::AmbiguousRotation
    } else if permille(q.drop_weak) < cfg.min_drop_permille {
        Verdict::Ambiguous {
            weak_axis: crate::types::angle::Angle::from_radians(q.weak_axis_rad),
        }
    } else {
        Verdict::Trusted
    };
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::localize::field::{Field, NearParams, Ramp};
    use crate::types::fixed::LogOdds;
    use crate::types::geometry::GridGeometry;

    /// The fixed-point window distribution against the f64 one at many positions and levels.
    #[test]
    fn near_agrees() {
        let g = GridGeometry::new(60, 50, 50, 0, 0).unwrap();
        // Walls: a slanted line and a box, with noise-free log-odds.
        let cells: Vec<LogOdds> = (0..g.len())
            .map(|i| {
                let (x, y) = ((i % 60) as i32, (i / 60) as i32);
                let on_line = (2 * x - 3 * y + 10).abs() <= 2;
                let on_box = (x == 40 || x == 50) && (10..30).contains(&y);
                LogOdds(if on_line || on_box { 3000 } else { -2000 })
            })
            .collect();
        let map = MapView::new(&cells, g).unwrap();
        let cfg = MatchConfig::default();
        let f = Field::new(&map, Ramp::new(cfg.floor, cfg.occupied));
        let (mut n, mut worst) = (0, [0.0f64; 5]);
        for level in 0..=1u8 {
            for radius in 1..=3u8 {
                let np = NearParams {
                    radius,
                    reg: (i32::from(cfg.reg_q8) << 4) + 4096 / 12,
                    cauchy: i32::from(cfg.cauchy_q8) << 4,
                };
                let rn = RefNear {
                    radius,
                    reg: f64::from(cfg.reg_q8) / 256.0 + 1.0 / 12.0,
                    cauchy: f64::from(cfg.cauchy_q8) / 256.0,
                };
                let r = RefField {
                    cells: &cells,
                    w: 60,
                    h: 50,
                    floor: f64::from(cfg.floor.0),
                    span: f64::from(cfg.occupied.0 - cfg.floor.0),
                };
                for i in 0..3000 {
                    let gx = (i * 37) % (60 * 256);
                    let gy = (i * 91) % (50 * 256);
                    let a = f.near(gx, gy, level, &np);
                    let b = r.near(f64::from(gx) / 256.0, f64::from(gy) / 256.0, level, &rn);
                    assert_eq!(a.is_some(), b.is_some(), "{gx} {gy} {level} {radius}");
                    if let (Some(a), Some(b)) = (a, b) {
                        n += 1;
                        let got = [
                            f64::from(a.mx) / 256.0,
                            f64::from(a.my) / 256.0,
                            f64::from(a.oxx) / 4096.0,
                            f64::from(a.oxy) / 4096.0,
                            f64::from(a.oyy) / 4096.0,
                        ];
                        for (w, (g, e)) in worst.iter_mut().zip(got.iter().zip(b)) {
                            *w = w.max((g - e).abs());
                        }
                    }
                }
            }
        }
        assert!(n > 1000, "{n} distributions compared");
        // Centroid to 1/128 cell, inverse covariance to 1 %  of its scale (≤ 1/reg ≈ 1.7).
        assert!(
            worst[0] < 1.0 / 128.0 && worst[1] < 1.0 / 128.0,
            "{worst:?}"
        );
        assert!(
            worst[2] < 0.02 && worst[3] < 0.02 && worst[4] < 0.02,
            "{worst:?}"
        );
    }
}
