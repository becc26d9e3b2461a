//! The matcher: Gauss–Newton on the pyramid, then the quality probes and the verdict (see the
//! [module docs](crate::localize)).
//!
//! The state is the correction relative to the prediction: `dx`, `dy` in sub-cells and `dth` in
//! 1/256 angle unit. Working on the correction keeps the numbers small whatever the pose (the
//! window bounds it), and the prior and the window are then tests on the state itself.

use crate::localize::field::{Cell, Field, MapView, NearParams, Ramp, ONE};
use crate::localize::points::ScanPoint;
use crate::localize::solve::{eigen2, solve3};
use crate::localize::{MatchConfig, MAX_LEVEL, MAX_POINTS, SUB};
use crate::types::angle::Angle;
use crate::types::geometry::Pose;

/// How far a prediction may lie from the grid's origin, in sub-cells, before the match gives up
/// (no point can reach the grid from there). Keeps every position in `i32`: a position is at most
/// this plus the window plus a point's reach (2²⁴), far below 2³¹.
const MAX_POSE_SUB: i64 = 1 << 27;

/// Largest window, in sub-cells (the window is clamped to it).
const MAX_WINDOW_SUB: i64 = 1 << 26;

/// `2^24 / 2π · 2^16`: radians (Q-anything) → 1/256 angle units, with a 16-bit shift.
const Q8_UNITS_PER_RAD_Q16: i64 = 683_565_276;

/// `2π · 2^16`: 1/256 angle units → radians, with a 32-bit shift.
const TWO_PI_Q16: i64 = 411_775;

/// Levers (the rotation's scale `2^s` cells) are kept in `0..=MAX_LEVER`.
const MAX_LEVER: u32 = 14;

/// Rotation Jacobians (Q8 level cells at the lever) are clamped to this magnitude (points
/// absurdly far for their lever): with inverse covariances below 2^14 (Q12) and at most
/// [`MAX_POINTS`] points, every sum of the normal equations stays below 2⁶⁰.
const J_LIM: i64 = 1 << 15;

/// Whether a match can be trusted, and if not, why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// The map constrains every direction and the rotation: use the corrected pose.
    Trusted,
    /// One direction of translation is not constrained (a corridor, a single wall): the pose
    /// along `weak_axis` (world frame, an axis: ± half a turn) is the prediction's, pulled there by
    /// the prior; across it the match is good.
    Ambiguous {
        /// The direction the map leaves open.
        weak_axis: Angle,
    },
    /// The rotation is not constrained (e.g. a round room, or a few points in one spot).
    AmbiguousRotation,
    /// Neither the rotation nor one direction of translation is constrained: whatever the match
    /// did, the map cannot tell (e.g. a far-off prediction where a few points graze a wall).
    Unconstrained,
    /// Fewer usable points than [`MatchConfig::min_points`] (a lidar that sees nothing).
    TooFewPoints,
    /// Too few points have occupied cells near them ([`MatchConfig::min_overlap_permille`]), or
    /// none lands on a cell above the map's floor: a new area, or a prediction far off the map.
    /// A map of one or two scans is enough (its cells may all be below ½: a match against it is
    /// what keeps the error of a new map's first turns out of the map).
    NoOverlap,
    /// The correction reached the edge of the search window: odometry jumped, or the match ran
    /// away.
    OutOfWindow,
    /// Too many points lie where the map has seen through (free space behind the hit): the pose
    /// is wrong (odometry jumped beyond the match's reach) or the world changed.
    Contradicted,
}

impl Verdict {
    /// Whether the map constrained every direction and the rotation.
    pub fn is_trusted(&self) -> bool {
        matches!(self, Verdict::Trusted)
    }

    /// Whether the corrected pose should be used: trusted, or ambiguous — then the prior has kept
    /// the open direction (or the rotation) where odometry put it, and the rest is corrected.
    /// Not when the matcher cannot tell at all (too few points, no overlap, out of window).
    pub fn is_usable(&self) -> bool {
        matches!(
            self,
            Verdict::Trusted | Verdict::Ambiguous { .. } | Verdict::AmbiguousRotation
        )
    }
}

/// How good the match is, at the final pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Quality {
    /// Points matched.
    pub points: u16,
    /// Points on occupied cells (map value ≥ ½, nearest cell).
    pub matched: u16,
    /// Σ map value over the points (nearest cell, Q15: [`field::ONE`](crate::localize::field::ONE)
    /// per point on a fully occupied cell).
    pub score: u32,
    /// Share of the score (‰) lost by moving the points `probe_mm` along the weakest direction.
    pub drop_weak: u16,
    /// The same along the strongest direction.
    pub drop_strong: u16,
    /// The weakest direction (world frame, an axis).
    pub weak_axis: Angle,
    /// Share of the score (‰) lost by turning the points by the probe angle.
    pub drop_turn: u16,
    /// Share (‰) of the points of the last Gauss–Newton pass that had occupied cells within the
    /// window: how much of the scan the map explains.
    pub overlap: u16,
    /// Share (‰) of the points the map has seen through (their cell and the cells behind them
    /// along the beam observed free): how much of the scan the map contradicts.
    pub contradicted: u16,
}

/// Work a call did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Work {
    /// Cell reads (the bound of each pass it ran, plus the probes).
    pub reads: u32,
    /// Gauss–Newton passes.
    pub passes: u16,
    /// The coarsest level the match ran (it may have been cut short by the budget).
    pub finest_level: u8,
}

/// A match's outcome.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MatchResult {
    /// Where the matcher ended (the prediction if it never started).
    pub pose: Pose,
    /// The prediction it started from.
    pub predicted: Pose,
    /// Whether `pose` can be trusted.
    pub verdict: Verdict,
    /// The measures the verdict rests on.
    pub quality: Quality,
    /// The work done.
    pub work: Work,
}

impl MatchResult {
    /// The pose to map with: the corrected one if [`Verdict::is_usable`], else the prediction.
    ///
    /// Why ambiguous matches are used: measured on the shared logs, falling back to odometry
    /// for them (~20 % of the scans) costs more than it saves — the prior already holds the open
    /// direction at the prediction (NOTES-39.md).
    pub fn accepted(&self) -> Pose {
        if self.verdict.is_usable() {
            self.pose
        } else {
            self.predicted
        }
    }
}

/// The Gauss–Newton normal equations of one pass.
#[derive(Clone, Copy, Debug, Default)]
struct Normal {
    h: [[i64; 3]; 3],
    b: [i64; 3],
    used: u32,
}

/// The running correction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct State {
    dx: i32,
    dy: i32,
    /// 1/256 angle unit.
    dth: i32,
}

/// Everything a pass needs that does not change during the match.
struct Frame<'a> {
    field: Field<'a>,
    points: &'a [ScanPoint],
    /// The prediction in sub-cells of the grid.
    gx0: i32,
    gy0: i32,
    /// The prediction's heading, 1/256 angle unit (2^24 per turn).
    th0: u32,
    /// `log2` of the rotation's lever, cells.
    lever: u32,
}

impl Frame<'_> {
    /// The heading of a state, rounded to an angle unit.
    fn heading(&self, s: &State) -> Angle {
        let q = self.th0.wrapping_add(s.dth as u32).wrapping_add(128);
        Angle(((q >> 8) & 0xFFFF) as u16)
    }

    /// Position (sub-cells) and rotation (Q30) of a state.
    fn transform(&self, s: &State) -> (i32, i32, i64, i64) {
        let (c, sn) = self.heading(s).cos_sin_q30();
        (
            self.gx0 + s.dx,
            self.gy0 + s.dy,
            i64::from(c),
            i64::from(sn),
        )
    }

    /// One pass at `level` over every `stride`-th point: the normal equations in Q28 (the
    /// translation's Jacobian is the identity, 256 in Q8; the rotation's is the point's lever
    /// `(−ry, rx) / 2^lever_k` in Q8 level cells, for `φ = θ · 2^lever_k` level cells).
    fn pass(&self, s: &State, level: u8, stride: usize, lever_k: u32, np: &NearParams) -> Normal {
        let (tx, ty, c, sn) = self.transform(s);
        let k = u32::from(level);
        let mut n = Normal::default();
        let (mut h00, mut h01, mut h02, mut h11, mut h12, mut h22) = (0i64, 0, 0, 0, 0, 0);
        let (mut b0, mut b1, mut b2) = (0i64, 0, 0);
        for p in self.points.iter().step_by(stride.max(1)) {
            let (px, py) = (i64::from(p.x), i64::from(p.y));
            // |p| < 2^24 and |c|, |s| ≤ 2^30: the rotated point is below 2^25 in magnitude.
            let rx = ((px * c - py * sn) >> 30) as i32;
            let ry = ((px * sn + py * c) >> 30) as i32;
            let at = Cell::of(tx + rx, ty + ry, level);
            let win = self.field.window(at.i, at.j, level, np);
            let Some(nd) = win.map(|w| w.near(&at, np)) else {
                continue;
            };
            n.used += 1;
            let lim = J_LIM as i32;
            let jx = i64::from(((-(ry >> k)) >> lever_k).clamp(-lim, lim));
            let jy = i64::from(((rx >> k) >> lever_k).clamp(-lim, lim));
            let (oxx, oxy, oyy) = (i64::from(nd.oxx), i64::from(nd.oxy), i64::from(nd.oyy));
            let (mx, my) = (i64::from(nd.mx), i64::from(nd.my));
            // Ω·j and Ω·μ, Q20.
            let (ojx, ojy) = (oxx * jx + oxy * jy, oxy * jx + oyy * jy);
            let (omx, omy) = (oxx * mx + oxy * my, oxy * mx + oyy * my);
            h00 += oxx << 16;
            h01 += oxy << 16;
            h11 += oyy << 16;
            h02 += ojx << 8;
            h12 += ojy << 8;
            h22 += jx * ojx + jy * ojy;
            b0 += omx << 8;
            b1 += omy << 8;
            b2 += jx * omx + jy * omy;
        }
        n.h = [[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]];
        n.b = [b0, b1, b2];
        n
    }
}

/// Rotation offset (1/256 angle unit) as `φ` in Q8 level cells for a lever of `2^lever_k`.
fn phi_q8(dth: i32, lever_k: u32) -> i64 {
    (i64::from(dth) * TWO_PI_Q16) >> (32 - lever_k.min(31))
}

/// `φ` (Q8 level cells) back to 1/256 angle units.
fn dth_of_phi(phi_q8: i64, lever_k: u32) -> i64 {
    (phi_q8 * Q8_UNITS_PER_RAD_Q16) >> (16 + lever_k)
}

/// The prior's information at a level, Q28 per level cell² (translation) and per level cell² of
/// `φ` (rotation), for `used` points: the config's per-point figures scaled to the level.
fn prior_weights(cfg: &MatchConfig, used: u32, level: u8, lever_k: u32) -> (i64, i64) {
    let used = i64::from(used);
    // Per fine cell² (Q8) → per level cell² (×4^k) → Q28.
    let t = (used * i64::from(cfg.prior_trans_q8)) << (20 + 2 * u32::from(level.min(MAX_LEVEL)));
    // Per rad² → per (φ level cell)² = per rad² / 4^lever_k → Q28.
    let r = ((used * i64::from(cfg.prior_rot)) << 28) >> (2 * lever_k.min(MAX_LEVER));
    (t, r)
}

/// `log2` of the points' mean Chebyshev distance in cells (at least 0): the rotation's lever.
pub(crate) fn lever_of(points: &[ScanPoint]) -> u32 {
    if points.is_empty() {
        return 0;
    }
    let sum: i64 = points
        .iter()
        .map(|p| i64::from(p.x).abs().max(i64::from(p.y).abs()))
        .sum();
    let mean_cells = (sum / points.len() as i64) / i64::from(SUB);
    if mean_cells <= 1 {
        0
    } else {
        (63 - mean_cells.leading_zeros()).min(MAX_LEVER)
    }
}

/// Matches `points` (from [`crate::localize::prepare_points`] for this grid's cell size)
/// against `map`, starting from `predicted`. Never panics; reads at most
/// [`MatchConfig::max_reads`] cells. An invalid `cfg` ([`MatchConfig::validate`]) gives
/// [`Verdict::TooFewPoints`] without reading the map.
pub fn match_scan(
    map: &MapView<'_>,
    points: &[ScanPoint],
    predicted: &Pose,
    cfg: &MatchConfig,
) -> MatchResult {
    let points = points.get(..points.len().min(MAX_POINTS)).unwrap_or(&[]);
    let n = points.len();
    let mut out = MatchResult {
        pose: *predicted,
        predicted: *predicted,
        verdict: Verdict::TooFewPoints,
        quality: Quality {
            points: n.min(usize::from(u16::MAX)) as u16,
            ..Quality::default()
        },
        work: Work::default(),
    };
    if cfg.validate().is_err() || n < usize::from(cfg.min_points).max(1) {
        return out;
    }
    let g = map.geometry();
    let cell = i64::from(g.cell_mm().max(1));
    let (ox, oy) = g.origin_mm();
    let to_sub = |mm: i64| (mm * i64::from(SUB)).div_euclid(cell);
    let gx0 = to_sub(i64::from(predicted.x_mm) - i64::from(ox));
    let gy0 = to_sub(i64::from(predicted.y_mm) - i64::from(oy));
    if gx0.abs() > MAX_POSE_SUB || gy0.abs() > MAX_POSE_SUB {
        out.verdict = Verdict::NoOverlap;
        return out;
    }
    let frame = Frame {
        field: Field::new(map, Ramp::new(cfg.floor, cfg.occupied)),
        points,
        gx0: gx0 as i32,
        gy0: gy0 as i32,
        th0: u32::from(predicted.heading.0) << 8,
        lever: lever_of(points),
    };
    let win = to_sub(i64::from(cfg.max_shift_mm)).min(MAX_WINDOW_SUB) as i32;
    let win_th = i32::from(cfg.max_turn.0.min(32767)) << 8;

    // Gauss–Newton, coarse to fine.
    let mut np = NearParams {
        radius: cfg.radius,
        reg: (i32::from(cfg.reg_q8) << 4) + 4096 / 12,
        cauchy: i32::from(cfg.cauchy_q8) << 4,
    };
    let mut s = State::default();
    if cfg.search_reads(n) > 0 {
        s.dth = turn_search(&frame, cfg, win_th);
    }
    let mut at_edge = false;
    let mut reads = cfg.search_reads(n);
    let budget = if cfg.budget_reads == 0 {
        u64::MAX
    } else {
        u64::from(cfg.budget_reads)
    };
    'levels: for level in (0..=cfg.levels.min(MAX_LEVEL)).rev() {
        let lever_k = frame.lever.saturating_sub(u32::from(level));
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
            out.work.passes = out.work.passes.saturating_add(1);
            out.work.finest_level = level;
            let ne = frame.pass(&s, level, cfg.stride_at(level), lever_k, &np);
            let evaluated = n.div_ceil(cfg.stride_at(level)).max(1) as u64;
            out.quality.overlap = (u64::from(ne.used) * 1000 / evaluated).min(1000) as u16;
            if ne.used == 0 {
                break;
            }
            let Some(step) = gn_step(&ne, &s, level, lever_k, cfg) else {
                break;
            };
            let k = u32::from(level);
            let next = State {
                dx: s.dx.saturating_add((step[0] as i32) << k),
                dy: s.dy.saturating_add((step[1] as i32) << k),
                dth: s.dth.saturating_add(dth_of_phi(step[2], lever_k) as i32),
            };
            let clamped = State {
                dx: next.dx.clamp(-win, win),
                dy: next.dy.clamp(-win, win),
                dth: next.dth.clamp(-win_th, win_th),
            };
            at_edge = clamped != next;
            s = clamped;
            // Converged at this level: the step moved less than 1/16 of a level cell.
            if step.iter().all(|v| v.abs() < i64::from(SUB) / 16) {
                break;
            }
        }
    }
    out.work.reads = reads.min(u64::from(u32::MAX)) as u32;

    // The corrected pose.
    let mm = |sub: i32| (i64::from(sub) * cell).div_euclid(i64::from(SUB));
    let sat = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
    out.pose = Pose {
        x_mm: sat(i64::from(predicted.x_mm) + mm(s.dx)),
        y_mm: sat(i64::from(predicted.y_mm) + mm(s.dy)),
        heading: frame.heading(&s),
    };

    // Quality probes and verdict.
    let probe = to_sub(i64::from(cfg.probe_mm)).clamp(1, MAX_WINDOW_SUB) as i32;
    out.quality = Quality {
        overlap: out.quality.overlap,
        ..probe_quality(&frame, &s, probe, cfg.free.0)
    };
    out.work.reads = out
        .work
        .reads
        .saturating_add(MatchConfig::probe_reads(n) as u32);
    out.verdict = verdict(&out.quality, at_edge, cfg);
    out
}

/// The heading search step, 1/256 angle unit: the turn that moves a point at the lever
/// distance (`2^lever` cells) by one cell, `2^−lever` rad, at least one angle unit.
pub(crate) fn turn_step(lever: u32) -> i32 {
    // 2^−lever rad is 256 >> lever in Q8 rad; Q8 rad × the constant >> 16 is 1/256 units.
    ((Q8_UNITS_PER_RAD_Q16 >> (8 + lever.min(MAX_LEVER))) as i32).max(256)
}

/// The heading search ([`MatchConfig::turn_search`]): the correction of the heading (1/256
/// angle unit, within `±win_th`) whose points score best on the grid max-pooled 2 × 2, the
/// prediction's translation kept; 0 (the prediction) unless another heading scores higher.
fn turn_search(frame: &Frame<'_>, cfg: &MatchConfig, win_th: i32) -> i32 {
    let step = turn_step(frame.lever);
    let stride = cfg.stride_at(1);
    let k = i32::from(cfg.turn_search);
    let (mut best, mut best_score) = (0i32, -1i64);
    // From the prediction outwards, alternating sides: a tie keeps the smaller turn.
    for i in 0..=2 * k {
        let j = if i % 2 == 1 { (i + 1) / 2 } else { -(i / 2) };
        let dth = j.saturating_mul(step);
        if dth.abs() > win_th {
            continue;
        }
        let (tx, ty, c, sn) = frame.transform(&State {
            dth,
            ..State::default()
        });
        let mut score = 0i64;
        for p in frame.points.iter().step_by(stride) {
            let (px, py) = (i64::from(p.x), i64::from(p.y));
            let gx = tx + ((px * c - py * sn) >> 30) as i32;
            let gy = ty + ((px * sn + py * c) >> 30) as i32;
            score += i64::from(frame.field.pooled(gx, gy));
        }
        if score > best_score {
            (best, best_score) = (dth, score);
        }
    }
    best
}

/// The heading search of [`match_scan`] on its own, for the `f64` reference (which shares it:
/// the search is discrete, its arithmetic is exact): the heading correction in 1/256 angle
/// unit, 0 if the search is off or the prediction is too far from the grid.
#[cfg(feature = "reference")]
pub(crate) fn heading_search(
    map: &MapView<'_>,
    points: &[ScanPoint],
    predicted: &Pose,
    cfg: &MatchConfig,
) -> i32 {
    let points = points.get(..points.len().min(MAX_POINTS)).unwrap_or(&[]);
    let g = map.geometry();
    let cell = i64::from(g.cell_mm().max(1));
    let (ox, oy) = g.origin_mm();
    let to_sub = |mm: i64| (mm * i64::from(SUB)).div_euclid(cell);
    let gx0 = to_sub(i64::from(predicted.x_mm) - i64::from(ox));
    let gy0 = to_sub(i64::from(predicted.y_mm) - i64::from(oy));
    if cfg.search_reads(points.len()) == 0 || gx0.abs() > MAX_POSE_SUB || gy0.abs() > MAX_POSE_SUB {
        return 0;
    }
    let frame = Frame {
        field: Field::new(map, Ramp::new(cfg.floor, cfg.occupied)),
        points,
        gx0: gx0 as i32,
        gy0: gy0 as i32,
        th0: u32::from(predicted.heading.0) << 8,
        lever: lever_of(points),
    };
    turn_search(&frame, cfg, i32::from(cfg.max_turn.0.min(32767)) << 8)
}

/// One regularised Gauss–Newton step in Q8 level cells (x, y, φ), each at most one level cell.
fn gn_step(ne: &Normal, s: &State, level: u8, lever_k: u32, cfg: &MatchConfig) -> Option<[i64; 3]> {
    let k = u32::from(level);
    let (lt, lr) = prior_weights(cfg, ne.used, level, lever_k);
    let lams = [lt, lt, lr];
    let off = [
        i64::from(s.dx >> k),
        i64::from(s.dy >> k),
        phi_q8(s.dth, lever_k),
    ];
    let mut h = ne.h;
    let mut b = ne.b;
    for (i, ((row, bi), (o, lam))) in h
        .iter_mut()
        .zip(b.iter_mut())
        .zip(off.iter().zip(lams))
        .enumerate()
    {
        if let Some(d) = row.get_mut(i) {
            *d = d.saturating_add(lam);
        }
        // The prior pulls the correction back towards zero: −λ · offset (offset in Q8).
        *bi = bi.saturating_sub((lam >> 8).saturating_mul(*o));
    }
    let step = solve3(&h, &b)?;
    Some(step.map(|v| v.clamp(-i64::from(SUB), i64::from(SUB))))
}

/// The score of the points at the state, moved by each probe (four directions ±, two turns).
fn probe_quality(frame: &Frame<'_>, s: &State, d: i32, free: i16) -> Quality {
    let (tx, ty, c, sn) = frame.transform(s);
    // Diagonal component of the probe: d/√2, rounded.
    let e = ((i64::from(d) * 46_341 + (1 << 15)) >> 16) as i32;
    let offs: [(i32, i32); 8] = [
        (d, 0),
        (-d, 0),
        (0, d),
        (0, -d),
        (e, e),
        (-e, -e),
        (-e, e),
        (e, -e),
    ];
    let mut moved = [0i64; 8];
    let (mut score, mut matched, mut contradicted) = (0i64, 0u32, 0u32);
    let f = &frame.field;
    for p in frame.points {
        let (px, py) = (i64::from(p.x), i64::from(p.y));
        let (rx, ry) = (
            ((px * c - py * sn) >> 30) as i32,
            ((px * sn + py * c) >> 30) as i32,
        );
        let (gx, gy) = (tx + rx, ty + ry);
        let m = f.nearest(gx, gy);
        score += i64::from(m);
        matched += u32::from(m >= ONE / 2);
        contradicted += u32::from(f.see_through(gx, gy, rx, ry, free));
        for (acc, (ox, oy)) in moved.iter_mut().zip(offs) {
            *acc += i64::from(f.nearest(gx + ox, gy + oy));
        }
    }
    // The turn that moves a point at the lever distance by `d`: d / 2^lever radians.
    let turn = ((i64::from(d) * Q8_UNITS_PER_RAD_Q16) >> (16 + frame.lever)).max(256);
    let mut turned = 0i64;
    for sign in [1i64, -1] {
        let ts = State {
            dth: s.dth.saturating_add((sign * turn) as i32),
            ..*s
        };
        let (tx, ty, c, sn) = frame.transform(&ts);
        for p in frame.points {
            let (px, py) = (i64::from(p.x), i64::from(p.y));
            let gx = tx + ((px * c - py * sn) >> 30) as i32;
            let gy = ty + ((px * sn + py * c) >> 30) as i32;
            turned += i64::from(f.nearest(gx, gy));
        }
    }
    let [xp, xm, yp, ym, dp, dm, ap, am] = moved;
    // Loss of score along each axis (mean of ±), then the quadratic form's entries.
    let lx = score - (xp + xm) / 2;
    let ly = score - (yp + ym) / 2;
    let ld = score - (dp + dm) / 2; // along 45°
    let la = score - (ap + am) / 2; // along 135°
    let (weak, strong, axis) = eigen2(lx, (ld - la) / 2, ly);
    let lt = score - turned / 2;
    let permille = |v: i64| {
        if score <= 0 {
            0
        } else {
            (v.max(0).saturating_mul(1000) / score).min(1000) as u16
        }
    };
    Quality {
        points: frame.points.len().min(usize::from(u16::MAX)) as u16,
        matched: matched.min(u32::from(u16::MAX)) as u16,
        score: score.clamp(0, i64::from(u32::MAX)) as u32,
        drop_weak: permille(weak),
        drop_strong: permille(strong),
        weak_axis: axis,
        drop_turn: permille(lt),
        overlap: 0,
        contradicted: (u64::from(contradicted) * 1000 / frame.points.len().max(1) as u64) as u16,
    }
}

/// The verdict from the quality measures (in the order the module docs give).
fn verdict(q: &Quality, at_edge: bool, cfg: &MatchConfig) -> Verdict {
    if q.overlap < cfg.min_overlap_permille || q.score == 0 {
        Verdict::NoOverlap
    } else if at_edge {
        Verdict::OutOfWindow
    } else if q.contradicted > cfg.max_contradicted_permille {
        Verdict::Contradicted
    } else if q.drop_turn < cfg.min_turn_drop_permille && q.drop_weak < cfg.min_drop_permille {
        Verdict::Unconstrained
    } else if q.drop_turn < cfg.min_turn_drop_permille {
        Verdict::AmbiguousRotation
    } else if q.drop_weak < cfg.min_drop_permille {
        Verdict::Ambiguous {
            weak_axis: q.weak_axis,
        }
    } else {
        Verdict::Trusted
    }
}
