//! A scan's rays from the pose's cell: the cell a beam's ray ends in (in 32-bit arithmetic where
//! it can be), which of its steps lie in the grid and in a reading's face band, and the box of
//! cells a scan can change.

use super::band::{Band, BandRay};
use super::MapperConfig;
use crate::map::ray::{GridRay, IndexWalk, Ray, Steps};
use crate::types::angle::Angle;
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::{Beam, Range};

/// A scan's rays from the pose's cell: where a beam's ray ends and which of its steps lie in
/// the grid. One home for the classification and the fast pass, so the two agree.
pub(super) struct Rays<'a> {
    g: &'a GridGeometry,
    pose: &'a Pose,
    to_cell: PointToCell,
    pub(super) origin: CellCoord,
    origin_inside: bool,
    /// The pose relative to the grid's origin, in mm, when both coordinates lie within ±2^30
    /// and the cell size fits an `i32` (every real map): then a beam end's cell is found in
    /// 32 bits ([`Rays::end`]).
    pose_in_grid_mm: Option<(i32, i32)>,
}

/// Readings shorter than this (mm) take [`Rays::end`]'s 32-bit path.
const SHORT_RANGE_MM: u32 = 1 << 30;

impl<'a> Rays<'a> {
    pub(super) fn new(g: &'a GridGeometry, pose: &'a Pose) -> Self {
        let to_cell = PointToCell::new(g);
        let origin = to_cell.cell(i64::from(pose.x_mm), i64::from(pose.y_mm));
        let within = |v: i64| (v.unsigned_abs() < 1 << 30).then_some(v as i32);
        let pose_in_grid_mm = match (
            to_cell.cell_mm > 0,
            within(i64::from(pose.x_mm) - to_cell.origin.0),
            within(i64::from(pose.y_mm) - to_cell.origin.1),
        ) {
            (true, Some(x), Some(y)) => Some((x, y)),
            _ => None,
        };
        Rays {
            g,
            pose,
            to_cell,
            origin,
            origin_inside: g.contains(origin),
            pose_in_grid_mm,
        }
    }

    /// The cell `range` mm from the pose along `angle`. Out of line: called once per beam, and
    /// its sine lookups and divisions would otherwise be copied into every pass.
    #[inline(never)]
    pub(super) fn end(&self, range: u32, angle: Angle) -> CellCoord {
        let (dx, dy) = self.pose.beam_offset(angle, range);
        if let Some((px, py)) = self.pose_in_grid_mm.filter(|_| range < SHORT_RANGE_MM) {
            // |p| < 2^30 and |d| ≤ range < 2^30: the point relative to the grid's origin fits
            // an i32, and it is `PointToCell::cell`'s, so the same cell.
            if let Some(c) = self
                .to_cell
                .cell_from_origin(px + dx as i32, py + dy as i32)
            {
                return c;
            }
        }
        let (x, y) = (
            i64::from(self.pose.x_mm) + dx,
            i64::from(self.pose.y_mm) + dy,
        );
        self.to_cell.cell(x, y)
    }

    /// The ray to `end` and its steps in the grid, if any.
    #[inline]
    pub(super) fn in_grid(&self, end: CellCoord) -> Option<(Ray, Steps)> {
        let ray = Ray::new(self.origin, end);
        // Both ends inside: the whole ray is (what `clip` would find, without its arithmetic).
        let steps = if self.origin_inside && self.g.contains(end) {
            Steps {
                first: 0,
                last: ray.steps(),
            }
        } else {
            ray.clip(self.g.width(), self.g.height())?
        };
        Some((ray, steps))
    }

    /// The ray to `end` when it and the pose's cell are both in the grid (the usual case), set
    /// up in 32 bits; `None` otherwise ([`Rays::in_grid`] then clips it).
    #[inline]
    pub(super) fn grid_ray(&self, end: CellCoord) -> Option<GridRay> {
        (self.origin_inside && self.g.contains(end))
            .then(|| GridRay::new(self.origin, end, self.g.width()))
    }

    /// The walk over the face band of a reading at `range` mm whose ray (traced to `range` plus
    /// the band's reach) ends at `end`, backwards from `end`, with the offset past the reading of
    /// its first cell (`end`'s) and of each step, in eighths of σ, Q16 (for [`face_slot`]): the
    /// usual case, where the pose's cell and `end` are both in the grid, so the band ends at the
    /// ray's last cell. `None` otherwise ([`Rays::band`] then walks it forwards) or if the band
    /// has no cell.
    ///
    /// The same cells and offsets as [`Rays::band`]'s walk, in reverse, without its clipping and
    /// the division that finds where its walk starts ([`GridRay::walk_back`]): step `k` lies
    /// `(n − k)·dt` before the end, which is `8·reach/σ` past the reading (`reach_t`).
    ///
    /// [`face_slot`]: super::band::face_slot
    #[inline]
    pub(super) fn band_back(
        &self,
        b: Band,
        range: u32,
        end: Option<CellCoord>,
    ) -> Option<(IndexWalk, (i32, i32))> {
        let end = end?;
        let ray = self.grid_ray(end)?;
        let end_index = self.g.index(end)?;
        let n = u64::from(ray.steps());
        let traced = range.saturating_add(b.reach_mm);
        // N < 2^16: the count fits a u32.
        let cells = (n.checked_sub(b.first_step(range, traced, n))? + 1) as u32;
        let walk = ray.walk_back(end_index, cells);
        // reach_t ≤ 12·2^16, dt ≤ 2^22 and the far edge's shift ≤ 2^20 (`Band::of`,
        // `Band::step_t`, `Band::far_shift`): all fit an i32.
        let dt = b.step_t(traced, n);
        Some((walk, ((b.reach_t + b.far_shift(dt)) as i32, -(dt as i32))))
    }

    /// The face band of a reading at `range` mm along `angle`, if any of it is in the grid;
    /// `end`, if known, is the end cell of its ray (traced to `range` plus the band's reach).
    #[inline(never)]
    pub(super) fn band(
        &self,
        b: Band,
        range: u32,
        angle: Angle,
        end: Option<CellCoord>,
    ) -> Option<BandRay> {
        let traced = range.saturating_add(b.reach_mm);
        let end = end.unwrap_or_else(|| self.end(traced, angle));
        let (ray, mut steps) = self.in_grid(end)?;
        let n = ray.steps();
        steps.first = steps.first.max(b.first_step(range, traced, n));
        if steps.first > steps.last {
            return None;
        }
        // In eighths of σ (Q16): the ray's end lies 8·reach/σ past the reading and each step
        // 8·traced/(σ·n) after the one before, so step k lies (n − k) steps before the end.
        // From the first step on, (n − first)·dt ≤ 2·reach·2^19/σ ≤ 24·2^16, or one step before
        // a narrow band's end of dt ≤ 4·reach_t (`Band::first_step`): |t0| ≤ 36·2^16.
        // A far edge moves every offset on by its shift (≤ 16·2^16): the last ≤ 28·2^16.
        let dt = b.step_t(traced, n);
        let back = n
            .saturating_sub(steps.first)
            .saturating_mul(dt)
            .min(1 << 41);
        Some(BandRay {
            ray,
            end,
            steps,
            t0: b.reach_t - back as i64 + b.far_shift(dt),
            dt: dt as i64,
        })
    }
}

/// The box of cells a scan can change under the beam model, as inclusive `(min, max)` corners:
/// the pose's cell and the end cell of every beam the mapper uses (traced to the maximum range
/// for no-returns), inside the grid or not. The firmware streams the tiles it covers.
pub fn scan_box(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
) -> (CellCoord, CellCoord) {
    // The mapper's own end cells (32-bit cell conversion: no 64-bit division per beam).
    let rays = Rays::new(g, pose);
    let c = rays.origin;
    let (mut lo, mut hi) = (c, c);
    let band = Band::of(cfg);
    for b in beams {
        let Some((range, hit)) = beam_extent(cfg, b) else {
            continue;
        };
        let e = rays.end(Band::traced(band, range, hit), b.angle);
        lo = CellCoord {
            x: lo.x.min(e.x),
            y: lo.y.min(e.y),
        };
        hi = CellCoord {
            x: hi.x.max(e.x),
            y: hi.y.max(e.y),
        };
    }
    (lo, hi)
}

/// How far from the pose's cell, in cells, a scan's rays can change anything: the longest traced
/// ray (a hit just below the maximum range plus its face band) rounded up, plus one cell for the
/// pose's position inside its cell. A pose whose cell lies at least this far inside every edge
/// of the grid has no ray that leaves it.
pub fn reach_cells(g: &GridGeometry, cfg: &MapperConfig) -> u32 {
    let traced = Band::traced(Band::of(cfg), cfg.max_range_mm, true);
    traced.div_ceil(g.cell_mm().max(1)).saturating_add(1)
}

/// The beams of a scan whose traced ray ends outside the grid (the mapper clips them to it):
/// the beams [`scan_box`] counts, with the same end cells.
pub fn beams_leaving(g: &GridGeometry, cfg: &MapperConfig, pose: &Pose, beams: &[Beam]) -> u32 {
    let rays = Rays::new(g, pose);
    let band = Band::of(cfg);
    let mut n = 0u32;
    for b in beams {
        let Some((range, hit)) = beam_extent(cfg, b) else {
            continue;
        };
        if !g.contains(rays.end(Band::traced(band, range, hit), b.angle)) {
            n = n.saturating_add(1);
        }
    }
    n
}

/// The range a beam is traced to, and whether it ends in a hit.
pub(super) fn beam_extent(cfg: &MapperConfig, beam: &Beam) -> Option<(u32, bool)> {
    match beam.range {
        Range::Hit(mm) if mm < cfg.min_range_mm => None,
        Range::Hit(mm) if mm < cfg.max_range_mm => Some((mm, true)),
        Range::Hit(_) | Range::NoReturn => Some((cfg.max_range_mm, false)),
    }
}

/// [`GridGeometry::cell_of_point`] with 32-bit division when the operands fit (a Cortex-M4
/// divides `i32` in hardware but `i64` in a library routine); identical results.
#[derive(Clone, Copy)]
struct PointToCell {
    geometry: GridGeometry,
    origin: (i64, i64),
    cell_mm: i32,
    /// On a 64-bit host, division by the cell size as a multiply ([`FloorDiv`]); a 32-bit
    /// core divides in one instruction and keeps this struct as small as before.
    #[cfg(target_pointer_width = "64")]
    by_cell: Option<FloorDiv>,
}

impl PointToCell {
    fn new(geometry: &GridGeometry) -> Self {
        let (ox, oy) = geometry.origin_mm();
        // 0 (never: a geometry's cell size is ≥ 1) or > i32::MAX selects the slow path.
        let cell_mm = i32::try_from(geometry.cell_mm()).unwrap_or(0);
        PointToCell {
            geometry: *geometry,
            origin: (i64::from(ox), i64::from(oy)),
            cell_mm,
            #[cfg(target_pointer_width = "64")]
            by_cell: FloorDiv::new(cell_mm),
        }
    }

    #[inline]
    fn cell(&self, x_mm: i64, y_mm: i64) -> CellCoord {
        let dx = i32::try_from(x_mm.saturating_sub(self.origin.0));
        let dy = i32::try_from(y_mm.saturating_sub(self.origin.1));
        if let (Ok(dx), Ok(dy)) = (dx, dy) {
            if let Some(c) = self.cell_from_origin(dx, dy) {
                return c;
            }
        }
        self.geometry.cell_of_point(x_mm, y_mm)
    }

    /// The cell of the point `(dx, dy)` mm from the grid's origin, unless the cell size does
    /// not fit an `i32` (then only [`PointToCell::cell`]'s fallback can say).
    #[inline]
    fn cell_from_origin(&self, dx: i32, dy: i32) -> Option<CellCoord> {
        #[cfg(target_pointer_width = "64")]
        if let Some(d) = self.by_cell {
            return Some(CellCoord {
                x: d.floor(dx),
                y: d.floor(dy),
            });
        }
        Some(CellCoord {
            x: dx.checked_div_euclid(self.cell_mm)?,
            y: dy.checked_div_euclid(self.cell_mm)?,
        })
    }
}

/// `⌊n / d⌋` for any `i32` `n` and a fixed `d ≥ 1` as a multiply and a shift: a host's 32-bit
/// division takes several times longer, twice per beam ([`PointToCell::cell_from_origin`]); a
/// Cortex-M4's takes one instruction, so only hosts use this.
///
/// With `ℓ = ⌈log2 d⌉`, `k = 31 + ℓ` and `m = ⌈2^k / d⌉ ≤ 2^32`, `⌊u·m / 2^k⌋ = ⌊u / d⌋` for every
/// `u < 2^31` (`m·d − 2^k < d ≤ 2^ℓ`, so the error `u·(m·d − 2^k)/(d·2^k)` is below `1/d`), and
/// `u·m < 2^63`. A negative `n` is divided as `!n = −n − 1 ≥ 0`: `⌊n/d⌋ = !⌊!n / d⌋`.
#[cfg(any(test, target_pointer_width = "64"))]
#[derive(Clone, Copy, Debug)]
struct FloorDiv {
    m: u64,
    k: u32,
}

#[cfg(any(test, target_pointer_width = "64"))]
impl FloorDiv {
    /// The division by `d`, if `d ≥ 1`.
    fn new(d: i32) -> Option<FloorDiv> {
        let d = u32::try_from(d).ok().filter(|&d| d >= 1)?;
        // ⌈log2 d⌉ ≤ 31.
        let l = 32 - (d - 1).leading_zeros();
        let k = 31 + l;
        Some(FloorDiv {
            m: (1u64 << k).div_ceil(u64::from(d)),
            k,
        })
    }

    #[inline(always)]
    fn floor(self, n: i32) -> i32 {
        // 0 for n ≥ 0, −1 (all ones) for n < 0; u = n or !n, < 2^31.
        let s = n >> 31;
        let u = u64::from((n ^ s) as u32);
        // u < 2^31 and m ≤ 2^32: no overflow; the quotient is < 2^31.
        ((u * self.m) >> self.k) as i32 ^ s
    }
}

#[cfg(test)]
mod tests {
    use super::super::strategies::{geometry, mm};
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// The 32-bit point → cell conversion equals `GridGeometry::cell_of_point`.
        #[test]
        fn point_to_cell_matches_geometry(g in geometry(),
                                          x in prop_oneof![-100_000i64..100_000, any::<i64>()],
                                          y in prop_oneof![-100_000i64..100_000, any::<i64>()]) {
            prop_assert_eq!(PointToCell::new(&g).cell(x, y), g.cell_of_point(x, y));
        }

        /// A beam's end cell (32-bit path or not) is the cell of `Pose::beam_end`'s point.
        #[test]
        fn beam_end_cell_matches_geometry(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                          angle in any::<u16>(),
                                          range in prop_oneof![0u32..20_000, (1u32 << 30) - 2..(1 << 30) + 2, any::<u32>()]) {
            let pose = Pose { x_mm: x, y_mm: y, heading: Angle(heading) };
            let (px, py) = pose.beam_end(Angle(angle), range);
            prop_assert_eq!(Rays::new(&g, &pose).end(range, Angle(angle)), g.cell_of_point(px, py));
        }

        /// [`FloorDiv`] equals `div_euclid` for any `i32` and any divisor ≥ 1.
        #[test]
        fn floor_div_matches_any(n in any::<i32>(), d in prop_oneof![1i32..200, 1i32..=i32::MAX]) {
            prop_assert_eq!(FloorDiv::new(d).unwrap().floor(n), n.div_euclid(d));
        }
    }

    /// The multiply-and-shift division equals `div_euclid` (floor, for a positive divisor) at
    /// the extremes of `n` and of `d`, and on a spread of values between.
    #[test]
    fn floor_div_matches_div_euclid() {
        let ds = [
            1,
            2,
            3,
            5,
            7,
            10,
            50,
            64,
            100,
            127,
            1000,
            65_537,
            1 << 30,
            i32::MAX - 1,
            i32::MAX,
        ];
        let mut ns = vec![i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX];
        let mut x = 0x9E37_79B9u32;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            ns.push(x as i32);
            ns.push((x as i32) >> (x % 31));
        }
        for d in ds {
            let f = FloorDiv::new(d).unwrap();
            for &n in &ns {
                for n in [n, n.wrapping_add(d), n.wrapping_sub(d), n.wrapping_sub(1)] {
                    assert_eq!(f.floor(n), n.div_euclid(d), "{n} / {d}");
                }
            }
        }
        assert!(FloorDiv::new(0).is_none() && FloorDiv::new(-5).is_none());
    }

    /// The scan box: the pose's cell and the used beams' end cells (no-returns and ranges past
    /// the maximum at the maximum range; beams below the minimum range ignored).
    #[test]
    fn scan_box_covers_the_pose_and_the_used_beam_ends() {
        // 100 mm cells, cell (0, 0) at the origin; pose in cell (5, 5).
        let g = GridGeometry::new(20, 20, 100, 0, 0).unwrap();
        let mut cfg = MapperConfig::new(1_000);
        cfg.min_range_mm = 100;
        let pose = Pose {
            x_mm: 550,
            y_mm: 550,
            heading: Angle(0),
        };
        let beam = |deg: f64, range| Beam {
            angle: Angle::from_degrees(deg),
            range,
        };
        let beams = [
            beam(0.0, Range::Hit(300)),      // +x to cell 8
            beam(90.0, Range::NoReturn),     // +y to the maximum range: cell 15
            beam(180.0, Range::Hit(50_000)), // -x, clamped to 1 000 mm: cell -5
            beam(270.0, Range::Hit(50)),     // below the minimum range: ignored
        ];
        let (lo, hi) = scan_box(&g, &cfg, &pose, &beams);
        assert_eq!((lo.x, lo.y, hi.x, hi.y), (-5, 5, 8, 15));
        assert_eq!(
            scan_box(&g, &cfg, &pose, &[]),
            (CellCoord { x: 5, y: 5 }, CellCoord { x: 5, y: 5 })
        );
    }
}
