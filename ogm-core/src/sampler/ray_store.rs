//! The measurement store: the rays the Gibbs sampler evaluates, in bounded, caller-provided
//! memory.
//!
//! Rays are grouped by scan and sorted by angle within it: a [`StoredScan`] keeps the pose
//! once, and each of its rays
//! ([`StoredRay`], 6 bytes) keeps only the beam angle, the measured range (or "no return") and a
//! cache of the ray's first occupied step in the sampler's current map. Every ray is traced from
//! the cell of its scan's pose to the point at maximum range (the "far end"), so the sampler can
//! ask "where is the first occupied cell?" beyond the measured range too; the measured range is
//! stored as a (fractional) step index along that Bresenham line.
//!
//! **When full**, the store thins uniformly instead of forgetting places: if the ray array is full
//! every stored scan drops every second ray and new scans are decimated by the same (doubled)
//! factor; if the scan array is full every second scan is dropped. Both keep spatial coverage,
//! which the sampler needs more than density (the papers' sparse-data experiments show the
//! sampler does well with thinned data). Everything dropped is counted in [`RayStore::stats`].

use crate::error::{Error, Result};
use crate::map::ray::Ray;
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::{Beam, Range};
use crate::wire::StoreReport;
use crate::Angle;

/// Marker for "no return" in [`StoredRay::z_q4`] and "no occupied cell" in
/// [`StoredRay::first_occupied`].
pub const NONE: u16 = u16::MAX;

/// [`StoredRay::first_occupied`] not known (a new ray, or the sample changed under it): the
/// sampler recomputes it when it next gathers the ray. Steps never reach this value
/// (rays are at most [`MAX_STEPS`] long).
pub const STALE: u16 = u16::MAX - 1;

/// Longest ray (in steps) the sampler handles; the ray store rejects longer sensor ranges.
pub const MAX_STEPS: u32 = 1 << 15;

/// A scan in the store.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoredScan {
    /// Where it was taken.
    pub pose: Pose,
    /// Index of its first ray in the ray array.
    pub first: u32,
    /// Number of rays.
    pub len: u32,
}

/// A ray in the store (6 bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoredRay {
    /// Beam direction relative to the scan's heading.
    pub angle: Angle,
    /// Measured range as a step index along the ray, in 1/16 steps; [`NONE`] = no return.
    pub z_q4: u16,
    /// Cache: first occupied step in the sampler's current map, [`NONE`] if none, [`STALE`] if
    /// not known yet.
    pub first_occupied: u16,
}

/// A ray's geometry, derived from its scan's pose and its angle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RayGeometry {
    /// The Bresenham ray from the pose's cell to the far end.
    pub ray: Ray,
    /// Length of one step in cells, Q12 (4096 = 1, up to √2).
    pub step_q12: u32,
}

/// The bounded ray store over caller storage.
#[derive(Clone, Debug)]
pub struct RayStore<S, R> {
    geometry: GridGeometry,
    max_range_mm: u32,
    min_range_mm: u32,
    scans: S,
    rays: R,
    n_scans: usize,
    n_rays: usize,
    decimation: u32,
    /// The counters of what the store did; [`RayStore::stats`] fills in the rest (decimation
    /// and fill), which stays zero here.
    stats: StoreReport,
}

/// Length (Q8 cells) of the vector (dx, dy); exact below 2^16 cells per component, within a
/// relative 2^-16 above (any `i64` components).
fn length_q8(dx: i64, dy: i64) -> u64 {
    let (ax, ay) = (dx.unsigned_abs(), dy.unsigned_abs());
    if ax >= 1 << 16 || ay >= 1 << 16 {
        // Far longer than any stored ray (rays are < MAX_STEPS cells; only hostile coordinates
        // get here): scale to 31 bits so the squares fit, root, scale back. Relative error
        // < 2^-16, no overflow, and no u128 code in flash.
        let k = (64 - ax.max(ay).leading_zeros()).saturating_sub(31);
        let (bx, by) = (ax >> k, ay >> k);
        return ((bx * bx + by * by).isqrt() << 8).saturating_mul(1 << k);
    }
    // < 2^49: no overflow.
    let sq = (ax * ax + ay * ay) << 16;
    // The 32-bit square root when it fits (rays under 256 cells): no 64-bit arithmetic on a
    // 32-bit core, the same root.
    match u32::try_from(sq) {
        Ok(v) => u64::from(v.isqrt()),
        Err(_) => sq.isqrt(),
    }
}

/// Length of one Bresenham step of the ray `start → end`, in cells, Q12 (4096 = 1, ≤ √2).
pub fn step_q12(start: CellCoord, end: CellCoord) -> u32 {
    let (dx, dy) = (
        i64::from(end.x) - i64::from(start.x),
        i64::from(end.y) - i64::from(start.y),
    );
    let n = dx.unsigned_abs().max(dy.unsigned_abs());
    let len = length_q8(dx, dy) << 4; // < 2^46
                                      // A u32 division (one `udiv` on a Cortex-M4) whenever the operands fit (rays shorter than
                                      // 2^20 cells); the same quotient as the u64 one.
    match (u32::try_from(len), u32::try_from(n)) {
        (Ok(a), Ok(b)) => a.checked_div(b),
        _ => len.checked_div(n).map(|v| v as u32),
    }
    .unwrap_or(4096)
}

impl<S, R> RayStore<S, R>
where
    S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
    R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
{
    /// An empty store for rays on `geometry` from a sensor with the given range limits (the
    /// mapper's). Needs room for at least one scan and one ray, and a maximum range below
    /// [`MAX_STEPS`] cells.
    pub fn new(
        geometry: GridGeometry,
        max_range_mm: u32,
        min_range_mm: u32,
        scans: S,
        rays: R,
    ) -> Result<Self> {
        if scans.as_ref().is_empty()
            || rays.as_ref().is_empty()
            || rays.as_ref().len() > u32::MAX as usize
        {
            return Err(Error::BufferSize {
                expected: 1,
                actual: 0,
            });
        }
        // The sampler's short-ray arithmetic needs rays of at most MAX_STEPS steps.
        let reach = max_range_mm.div_ceil(geometry.cell_mm());
        if max_range_mm == 0 || min_range_mm >= max_range_mm || reach >= MAX_STEPS - 2 {
            return Err(Error::InvalidModel);
        }
        Ok(RayStore {
            geometry,
            max_range_mm,
            min_range_mm,
            scans,
            rays,
            n_scans: 0,
            n_rays: 0,
            decimation: 1,
            stats: StoreReport::default(),
        })
    }

    /// Forgets every stored scan and ray and places the store on `geometry` (a rolling window
    /// moved: [`crate::session::Session::apply_shift`]); its statistics go on counting.
    pub fn clear_on(&mut self, geometry: GridGeometry) {
        self.geometry = geometry;
        self.n_scans = 0;
        self.n_rays = 0;
        self.decimation = 1;
    }

    /// The grid the rays live on.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Maximum sensor range in mm (rays are traced this far).
    pub fn max_range_mm(&self) -> u32 {
        self.max_range_mm
    }

    /// What the store did (beams accepted, decimated, thinned, invalid) and holds now, as the
    /// wire reports it.
    pub fn stats(&self) -> StoreReport {
        StoreReport {
            decimation: self.decimation,
            scans: self.scans().len() as u32,
            rays: self.rays().len() as u32,
            ..self.stats
        }
    }

    /// Current decimation (1 = every beam is stored).
    pub fn decimation(&self) -> u32 {
        self.decimation
    }

    /// Stored scans.
    pub fn scans(&self) -> &[StoredScan] {
        self.scans.as_ref().get(..self.n_scans).unwrap_or(&[])
    }

    /// Stored rays (all scans, in order).
    pub fn rays(&self) -> &[StoredRay] {
        self.rays.as_ref().get(..self.n_rays).unwrap_or(&[])
    }

    /// Stored rays, mutable (the sampler updates the first-occupied caches).
    pub fn rays_mut(&mut self) -> &mut [StoredRay] {
        let n = self.n_rays;
        self.rays.as_mut().get_mut(..n).unwrap_or(&mut [])
    }

    /// Capacity in rays.
    pub fn ray_capacity(&self) -> usize {
        self.rays.as_ref().len()
    }

    /// Geometry of a ray of `scan`.
    pub fn ray_geometry(&self, pose: &Pose, angle: Angle) -> RayGeometry {
        let start = self.geometry.cell_of_pose(pose);
        let end = self.far_end(pose, angle);
        RayGeometry {
            ray: Ray::new(start, end),
            step_q12: step_q12(start, end),
        }
    }

    /// The far-end cell (at maximum range) of a beam.
    #[inline]
    pub fn far_end(&self, pose: &Pose, angle: Angle) -> CellCoord {
        let (x, y) = pose.beam_end(angle, self.max_range_mm);
        self.geometry.cell_of_point(x, y)
    }

    /// The cell of `pose` (the start of its rays).
    pub fn start_cell(&self, pose: &Pose) -> CellCoord {
        self.geometry.cell_of_pose(pose)
    }

    /// The measured range of a beam as a step index (1/16 steps) along its far-end ray.
    fn z_q4(&self, geom: &RayGeometry, range_mm: u32) -> u16 {
        let n = geom.ray.steps();
        if n == 0 {
            return 0;
        }
        // steps = range_cells / step_len = mm / cell_mm · 4096 / step_q12. num < 2^48 and
        // den < 2^45 fit a u64; ranges under 65.5 m with ordinary cells fit a u32, one `udiv`
        // on a Cortex-M4 instead of a library call (same quotient either way).
        let num = u64::from(range_mm) << 16;
        let den = u64::from(self.geometry.cell_mm()) * u64::from(geom.step_q12.max(1));
        let z = match (u32::try_from(num), u32::try_from(den)) {
            (Ok(a), Ok(b)) => a.checked_div(b).map(u64::from),
            _ => num.checked_div(den),
        }
        .unwrap_or(u64::MAX);
        z.min(n.saturating_mul(16)).min(u64::from(NONE - 1)) as u16
    }

    /// Adds a scan's beams (every `decimation`-th), thinning first if the store is full.
    /// Returns the index range of the new rays in [`RayStore::rays`] — their `first_occupied`
    /// caches are [`STALE`] until the sampler fills them in.
    pub fn add_scan(&mut self, pose: &Pose, beams: &[Beam]) -> core::ops::Range<usize> {
        loop {
            if self.n_scans >= self.scans.as_ref().len() {
                if self.n_scans > 1 {
                    self.thin_scans();
                } else {
                    // A one-scan store keeps only the newest scan.
                    self.stats.rays_thinned =
                        self.stats.rays_thinned.saturating_add(self.n_rays as u32);
                    (self.n_scans, self.n_rays) = (0, 0);
                }
                continue;
            }
            let wanted = beams.len().div_ceil(self.decimation as usize);
            if self.n_rays + wanted > self.rays.as_ref().len() {
                // Terminates: each pass halves the stored rays and the rays wanted.
                self.thin_rays();
                continue;
            }
            break;
        }
        let first = self.n_rays;
        for (i, beam) in beams.iter().enumerate() {
            if i as u32 % self.decimation != 0 {
                self.stats.rays_decimated = self.stats.rays_decimated.saturating_add(1);
                continue;
            }
            let z_q4 = match beam.range {
                Range::Hit(mm) if mm < self.min_range_mm => {
                    self.stats.rays_invalid = self.stats.rays_invalid.saturating_add(1);
                    continue;
                }
                Range::Hit(mm) if mm < self.max_range_mm => {
                    let g = self.ray_geometry(pose, beam.angle);
                    self.z_q4(&g, mm)
                }
                _ => NONE,
            };
            let n = self.n_rays;
            let Some(slot) = self.rays.as_mut().get_mut(n) else {
                break;
            };
            *slot = StoredRay {
                angle: beam.angle,
                z_q4,
                first_occupied: STALE,
            };
            self.n_rays += 1;
            self.stats.rays_added = self.stats.rays_added.saturating_add(1);
        }
        // Keep each scan's rays sorted by angle (the sampler finds the rays crossing a region by
        // binary search). Insertion sort: no allocation, linear on the sorted scans lidars emit.
        if let Some(new) = self.rays.as_mut().get_mut(first..self.n_rays) {
            for i in 1..new.len() {
                let mut j = i;
                while j > 0 {
                    let (Some(a), Some(b)) = (new.get(j - 1), new.get(j)) else {
                        break;
                    };
                    if a.angle.0 <= b.angle.0 {
                        break;
                    }
                    new.swap(j - 1, j);
                    j -= 1;
                }
            }
        }
        let len = (self.n_rays - first) as u32;
        if let Some(slot) = self.scans.as_mut().get_mut(self.n_scans) {
            *slot = StoredScan {
                pose: *pose,
                first: first as u32,
                len,
            };
            self.n_scans += 1;
            self.stats.scans_added = self.stats.scans_added.saturating_add(1);
        }
        first..self.n_rays
    }

    /// Drops every second ray of every scan and doubles the decimation.
    fn thin_rays(&mut self) {
        let mut w = 0usize;
        let n_scans = self.n_scans;
        for s in 0..n_scans {
            let Some(scan) = self.scans.as_ref().get(s).copied() else {
                break;
            };
            let start = w;
            for k in 0..scan.len as usize {
                let r = scan.first as usize + k;
                if k % 2 == 0 {
                    if let Some(ray) = self.rays.as_ref().get(r).copied() {
                        if let Some(slot) = self.rays.as_mut().get_mut(w) {
                            *slot = ray;
                        }
                        w += 1;
                    }
                } else {
                    self.stats.rays_thinned = self.stats.rays_thinned.saturating_add(1);
                }
            }
            if let Some(sc) = self.scans.as_mut().get_mut(s) {
                sc.first = start as u32;
                sc.len = (w - start) as u32;
            }
        }
        self.n_rays = w;
        self.decimation = self.decimation.saturating_mul(2);
        self.stats.thinnings = self.stats.thinnings.saturating_add(1);
        warn!(
            "ray store full: thinned to every {}th beam",
            self.decimation
        );
    }

    /// Drops every second scan (the odd ones) and compacts the rays.
    fn thin_scans(&mut self) {
        let (mut ws, mut wr) = (0usize, 0usize);
        for s in 0..self.n_scans {
            let Some(scan) = self.scans.as_ref().get(s).copied() else {
                break;
            };
            if s % 2 == 1 {
                self.stats.rays_thinned = self.stats.rays_thinned.saturating_add(scan.len);
                continue;
            }
            let start = wr;
            for k in 0..scan.len as usize {
                if let Some(ray) = self.rays.as_ref().get(scan.first as usize + k).copied() {
                    if let Some(slot) = self.rays.as_mut().get_mut(wr) {
                        *slot = ray;
                    }
                    wr += 1;
                }
            }
            if let Some(sc) = self.scans.as_mut().get_mut(ws) {
                *sc = StoredScan {
                    pose: scan.pose,
                    first: start as u32,
                    len: (wr - start) as u32,
                };
            }
            ws += 1;
        }
        self.n_scans = ws;
        self.n_rays = wr;
        self.stats.thinnings = self.stats.thinnings.saturating_add(1);
        warn!("scan store full: kept every second scan ({} left)", ws);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The 32-bit fast paths of `step_q12` and `z_q4` give exactly the wide-integer result.
        #[test]
        fn narrow_arithmetic_equals_the_wide_reference(
            x0 in proptest::prop_oneof![-3000i32..3000, proptest::num::i32::ANY],
            y0 in proptest::prop_oneof![-3000i32..3000, proptest::num::i32::ANY],
            x1 in proptest::prop_oneof![-3000i32..3000, proptest::num::i32::ANY],
            y1 in proptest::prop_oneof![-3000i32..3000, proptest::num::i32::ANY],
            range_mm in proptest::prop_oneof![0u32..200_000, proptest::num::u32::ANY],
            cell_mm in proptest::prop_oneof![1u32..2000, 1u32..=u32::MAX],
        ) {
            let (start, end) = (CellCoord { x: x0, y: y0 }, CellCoord { x: x1, y: y1 });
            let (dx, dy) = (i128::from(x1) - i128::from(x0), i128::from(y1) - i128::from(y0));
            let n = dx.unsigned_abs().max(dy.unsigned_abs());
            let len = ((dx * dx + dy * dy) as u128 * 65_536).isqrt() << 4;
            let want = len.checked_div(n).map_or(4096, |v| v as u32);
            let got = step_q12(start, end);
            if dx.unsigned_abs() < 1 << 16 && dy.unsigned_abs() < 1 << 16 {
                proptest::prop_assert_eq!(got, want);
            } else {
                // Hostile lengths (no stored ray is this long): scaled, within one Q12 unit.
                proptest::prop_assert!(got.abs_diff(want) <= 1, "{} vs {}", got, want);
            }

            let Ok(g) = GridGeometry::new(100, 100, cell_mm, 0, 0) else {
                return Ok(());
            };
            let Ok(s) = RayStore::new(
                g,
                cell_mm.saturating_mul(50),
                0,
                [StoredScan::default(); 1],
                [StoredRay::default(); 1],
            ) else {
                return Ok(());
            };
            let geom = RayGeometry { ray: Ray::new(start, end), step_q12: want };
            let steps = u128::from(geom.ray.steps());
            let z = if steps == 0 {
                0
            } else {
                (u128::from(range_mm) * 65_536 / (u128::from(cell_mm) * u128::from(want.max(1))))
                    .min(steps * 16)
                    .min(u128::from(NONE - 1)) as u16
            };
            proptest::prop_assert_eq!(s.z_q4(&geom, range_mm), z);
        }
    }

    fn store(scans: usize, rays: usize) -> RayStore<Vec<StoredScan>, Vec<StoredRay>> {
        let g = GridGeometry::new(100, 100, 100, 0, 0).unwrap();
        RayStore::new(
            g,
            5_000,
            100,
            vec![StoredScan::default(); scans],
            vec![StoredRay::default(); rays],
        )
        .unwrap()
    }

    fn scan(n: u16, range: Range) -> Vec<Beam> {
        (0..n)
            .map(|i| Beam {
                angle: Angle(i.wrapping_mul(997)),
                range,
            })
            .collect()
    }

    fn pose(x: i32) -> Pose {
        Pose {
            x_mm: x,
            y_mm: 5_000,
            heading: Angle::ZERO,
        }
    }

    #[test]
    fn stores_sorted_rays_and_measured_ranges() {
        let mut s = store(4, 64);
        let r = s.add_scan(&pose(5_000), &scan(10, Range::Hit(1_000)));
        assert_eq!(r, 0..10);
        assert!(s.rays().windows(2).all(|w| w[0].angle.0 <= w[1].angle.0));
        // 1 m = 10 cells; along any direction that is 10 cells / step length steps (1/16 units).
        for ray in s.rays() {
            let g = s.ray_geometry(&pose(5_000), ray.angle);
            let steps = f64::from(ray.z_q4) / 16.0;
            let cells = steps * f64::from(g.step_q12) / 4096.0;
            assert!((cells - 10.0).abs() < 0.6, "{cells} cells");
        }
        s.add_scan(&pose(5_000), &scan(3, Range::NoReturn));
        s.add_scan(&pose(5_000), &scan(2, Range::Hit(50))); // inside the 100 mm minimum range
        assert_eq!(s.rays().iter().filter(|r| r.z_q4 == NONE).count(), 3);
        assert_eq!(s.stats().rays_invalid, 2);
        assert_eq!((s.scans().len(), s.rays().len()), (3, 13));
    }

    #[test]
    fn full_ray_store_thins_uniformly_and_decimates_new_scans() {
        let mut s = store(16, 40);
        for k in 0..4 {
            s.add_scan(&pose(1_000 + k * 1_000), &scan(10, Range::Hit(2_000)));
        }
        assert_eq!((s.rays().len(), s.decimation()), (40, 1));
        // The fifth scan does not fit: every stored scan keeps every second ray.
        let new = s.add_scan(&pose(6_000), &scan(10, Range::Hit(2_000)));
        assert_eq!(s.decimation(), 2);
        assert_eq!(new.len(), 5);
        assert_eq!(s.scans().len(), 5);
        assert!(s.scans().iter().all(|sc| sc.len == 5), "{:?}", s.scans());
        assert_eq!(s.stats().rays_thinned, 20);
        assert_eq!(s.stats().rays_decimated, 5);
        assert_eq!(s.stats().thinnings, 1);
        assert_eq!(
            (s.stats().decimation, s.stats().scans, s.stats().rays),
            (2, 5, 25)
        );
        // Scans stay contiguous and in order.
        let mut next = 0;
        for sc in s.scans() {
            assert_eq!(sc.first, next);
            next += sc.len;
        }
    }

    #[test]
    fn full_scan_store_keeps_every_second_scan() {
        let mut s = store(4, 1_000);
        for k in 0..4 {
            s.add_scan(&pose(1_000 + k * 100), &scan(3, Range::Hit(2_000)));
        }
        s.add_scan(&pose(9_000), &scan(3, Range::Hit(2_000)));
        let xs: Vec<i32> = s.scans().iter().map(|sc| sc.pose.x_mm).collect();
        assert_eq!(xs, vec![1_000, 1_200, 9_000]);
        assert_eq!(s.rays().len(), 9);
        assert_eq!(s.stats().rays_thinned, 6);
    }

    #[test]
    fn oversized_scans_and_tiny_stores_never_overflow() {
        let mut s = store(1, 3);
        for _ in 0..5 {
            let r = s.add_scan(&pose(5_000), &scan(100, Range::Hit(1_500)));
            assert!(r.end <= 3 && s.rays().len() <= 3 && s.scans().len() == 1);
        }
        assert!(RayStore::new(
            GridGeometry::new(1, 1, 1, 0, 0).unwrap(),
            0,
            0,
            vec![StoredScan::default()],
            vec![StoredRay::default()]
        )
        .is_err());
        assert!(RayStore::new(
            GridGeometry::new(1, 1, 1, 0, 0).unwrap(),
            10,
            0,
            Vec::<StoredScan>::new(),
            vec![StoredRay::default()]
        )
        .is_err());
        assert!(RayStore::new(
            GridGeometry::new(1, 1, 1, 0, 0).unwrap(),
            40_000,
            0,
            vec![StoredScan::default()],
            vec![StoredRay::default()]
        )
        .is_err());
    }
}
