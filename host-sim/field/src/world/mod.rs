//! Occupancy maps as every tool reads and writes them: the trinary [`World`] (free, occupied,
//! unknown cells with a cell size and an origin), loading it from PNG / PGM / ROS map_server
//! YAML, and writing it as map_server PGM + YAML and PNG.
//!
//! Convention (shared with `ogm-core`): cells are row-major with **row 0 at the bottom**
//! (world y increases with the row index), `origin_m` is the world position of the lower-left
//! corner of cell (0, 0). Image files store the top row first; the loaders and writers flip.
//!
//! * [`load`] — PNG / PGM / ROS map_server YAML ([`load_world`], [`MapError`]);
//! * [`export`] — ROS map_server PGM + YAML and PNG ([`write_ros_map`], [`write_png`]).
//!
//! The simulator's ground-truth worlds are of this type too (`host_sim::sim::generate` builds
//! them); it lives here because the field tools write it and must not depend on the simulator.

mod error;
pub mod export;
pub mod load;

pub use error::MapError;
pub use export::{
    probabilities_to_world, write_pgm, write_png, write_ros_map, write_ros_probabilities,
};
pub use load::{load_image, load_world, read_ros_yaml, ImageParams, MapMode, RosMapMeta};

/// Largest accepted map side in cells (loaders reject bigger images, generators clamp).
pub const MAX_SIDE: usize = 20_000;

/// What a ground-truth cell is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Truth {
    /// Free space.
    Free,
    /// Wall, obstacle.
    Occupied,
    /// Not known (outside the building in some maps); excluded from metrics.
    Unknown,
}

/// A ground-truth occupancy map.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Cell edge in metres.
    pub resolution_m: f64,
    /// World position (m) of the lower-left corner of cell (0, 0).
    pub origin_m: (f64, f64),
    /// Row-major cells, row 0 at the bottom.
    pub cells: Vec<Truth>,
}

/// Cell counts of a [`World`] by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TruthCounts {
    /// Free cells.
    pub free: usize,
    /// Occupied cells.
    pub occupied: usize,
    /// Unknown cells.
    pub unknown: usize,
}

impl TruthCounts {
    /// All cells.
    pub fn total(&self) -> usize {
        self.free + self.occupied + self.unknown
    }

    fn fraction(&self, n: usize) -> f64 {
        match self.total() {
            0 => 0.0,
            t => n as f64 / t as f64,
        }
    }

    /// Free cells / all cells (0 for an empty map).
    pub fn free_fraction(&self) -> f64 {
        self.fraction(self.free)
    }

    /// Occupied cells / all cells (0 for an empty map).
    pub fn occupied_fraction(&self) -> f64 {
        self.fraction(self.occupied)
    }

    /// Unknown cells / all cells (0 for an empty map).
    pub fn unknown_fraction(&self) -> f64 {
        self.fraction(self.unknown)
    }
}

/// 4-connected components of the free space of a [`World`] (see [`World::free_components`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FreeComponents {
    /// Per cell (row-major, like [`World::cells`]): the component index, or
    /// [`FreeComponents::NONE`] for cells that are not free.
    pub labels: Vec<u32>,
    /// Cell count of each component, indexed by label.
    pub sizes: Vec<usize>,
}

impl FreeComponents {
    /// Label of cells that are not free.
    pub const NONE: u32 = u32::MAX;

    /// Number of components.
    pub fn count(&self) -> usize {
        self.sizes.len()
    }

    /// Label of the largest component (`None` if there is no free cell).
    pub fn largest(&self) -> Option<u32> {
        let mut best: Option<(usize, usize)> = None;
        for (i, &s) in self.sizes.iter().enumerate() {
            if best.is_none_or(|(_, b)| s > b) {
                best = Some((i, s));
            }
        }
        best.and_then(|(i, _)| u32::try_from(i).ok())
    }
}

impl World {
    /// A `width` × `height` world with every cell set to `fill`.
    pub fn new(
        width: usize,
        height: usize,
        resolution_m: f64,
        origin_m: (f64, f64),
        fill: Truth,
    ) -> World {
        World {
            width,
            height,
            resolution_m,
            origin_m,
            cells: vec![fill; width.saturating_mul(height)],
        }
    }

    /// The cell at (x, y), `None` outside.
    pub fn get(&self, x: i64, y: i64) -> Option<Truth> {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return None;
        }
        self.cells
            .get(y as usize * self.width + x as usize)
            .copied()
    }

    /// Sets the cell at (x, y); returns `false` (and does nothing) outside the map.
    pub fn set(&mut self, x: i64, y: i64, truth: Truth) -> bool {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return false;
        }
        match self.cells.get_mut(y as usize * self.width + x as usize) {
            Some(c) => {
                *c = truth;
                true
            }
            None => false,
        }
    }

    /// Whether a lidar beam stops at (x, y): everything but known free space does (unknown
    /// regions are solid to the simulator, and outside the map is a closed world).
    pub fn blocks_beam(&self, x: i64, y: i64) -> bool {
        !matches!(self.get(x, y), Some(Truth::Free))
    }

    /// Map extent in metres (width, height).
    pub fn size_m(&self) -> (f64, f64) {
        (
            self.width as f64 * self.resolution_m,
            self.height as f64 * self.resolution_m,
        )
    }

    /// The cell containing world point (x, y) in metres, `None` outside the map.
    pub fn cell_at(&self, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
        let cx = ((x_m - self.origin_m.0) / self.resolution_m).floor();
        let cy = ((y_m - self.origin_m.1) / self.resolution_m).floor();
        if !(cx >= 0.0 && cy >= 0.0 && cx < self.width as f64 && cy < self.height as f64) {
            return None;
        }
        Some((cx as usize, cy as usize))
    }

    /// World position (m) of the centre of cell (x, y).
    pub fn cell_center_m(&self, x: usize, y: usize) -> (f64, f64) {
        (
            self.origin_m.0 + (x as f64 + 0.5) * self.resolution_m,
            self.origin_m.1 + (y as f64 + 0.5) * self.resolution_m,
        )
    }

    /// Cell counts by kind.
    pub fn counts(&self) -> TruthCounts {
        let mut c = TruthCounts::default();
        for t in &self.cells {
            match t {
                Truth::Free => c.free += 1,
                Truth::Occupied => c.occupied += 1,
                Truth::Unknown => c.unknown += 1,
            }
        }
        c
    }

    /// Occupied cells / all cells (0 for an empty map). See [`World::counts`] for the others.
    pub fn occupied_fraction(&self) -> f64 {
        self.counts().occupied_fraction()
    }

    /// The sub-map of `w` × `h` cells whose lower-left cell is (x, y) (row 0 at the bottom),
    /// clipped to the map; the origin moves so that world coordinates are unchanged. A
    /// rectangle entirely outside gives a world with zero width or height.
    pub fn crop(&self, x: usize, y: usize, w: usize, h: usize) -> World {
        let x0 = x.min(self.width);
        let y0 = y.min(self.height);
        let x1 = x0.saturating_add(w).min(self.width);
        let y1 = y0.saturating_add(h).min(self.height);
        let (nw, nh) = (x1 - x0, y1 - y0);
        let mut cells = Vec::with_capacity(nw * nh);
        for row in y0..y1 {
            let start = row * self.width;
            if let Some(s) = self.cells.get(start + x0..start + x1) {
                cells.extend_from_slice(s);
            }
        }
        cells.resize(nw * nh, Truth::Unknown);
        World {
            width: nw,
            height: nh,
            resolution_m: self.resolution_m,
            origin_m: (
                self.origin_m.0 + x0 as f64 * self.resolution_m,
                self.origin_m.1 + y0 as f64 * self.resolution_m,
            ),
            cells,
        }
    }

    /// The same world at another cell size; the origin is kept and the extent is rounded up to
    /// whole cells.
    ///
    /// Downsampling is by area: a target cell is Occupied if any source cell it overlaps is
    /// Occupied, else Free if any is Free, else Unknown — so 1-cell walls survive (walls can
    /// only get thicker, never leak). Upsampling takes the source cell under each target cell's
    /// centre. Returns an unchanged copy if `resolution_m` (or the world's own resolution) is
    /// not finite and positive, or if the result would exceed [`MAX_SIDE`] cells a side.
    pub fn resample(&self, resolution_m: f64) -> World {
        let f = resolution_m / self.resolution_m;
        if !(resolution_m.is_finite() && resolution_m > 0.0 && f.is_finite() && f > 0.0) {
            return self.clone();
        }
        if f == 1.0 {
            return World {
                resolution_m,
                ..self.clone()
            };
        }
        const EPS: f64 = 1e-9;
        let dim = |n: usize| -> Option<usize> {
            let t = (n as f64 / f - EPS)
                .ceil()
                .max(if n > 0 { 1.0 } else { 0.0 });
            (t <= MAX_SIDE as f64).then_some(t as usize)
        };
        let (Some(nw), Some(nh)) = (dim(self.width), dim(self.height)) else {
            return self.clone();
        };
        // Source index range [lo, hi) covered by target index i along an axis of n cells.
        let span = |i: usize, n: usize| -> (usize, usize) {
            if f > 1.0 {
                let lo = ((i as f64 * f) * (1.0 + EPS)).floor() as usize;
                let hi = (((i + 1) as f64 * f) * (1.0 - EPS)).ceil() as usize;
                let lo = lo.min(n.saturating_sub(1));
                (lo, hi.clamp(lo + 1, n.max(lo + 1)))
            } else {
                let c = (((i as f64) + 0.5) * f).floor() as usize;
                let c = c.min(n.saturating_sub(1));
                (c, c + 1)
            }
        };
        let xs: Vec<(usize, usize)> = (0..nw).map(|i| span(i, self.width)).collect();
        let mut cells = Vec::with_capacity(nw * nh);
        for j in 0..nh {
            let (y0, y1) = span(j, self.height);
            for &(x0, x1) in &xs {
                let mut any_free = false;
                let mut any_occ = false;
                'block: for y in y0..y1 {
                    let row = y * self.width;
                    for t in self.cells.get(row + x0..row + x1).unwrap_or(&[]) {
                        match t {
                            Truth::Occupied => {
                                any_occ = true;
                                break 'block;
                            }
                            Truth::Free => any_free = true,
                            Truth::Unknown => {}
                        }
                    }
                }
                cells.push(if any_occ {
                    Truth::Occupied
                } else if any_free {
                    Truth::Free
                } else {
                    Truth::Unknown
                });
            }
        }
        World {
            width: nw,
            height: nh,
            resolution_m,
            origin_m: self.origin_m,
            cells,
        }
    }

    /// The 4-connected components of the free space.
    pub fn free_components(&self) -> FreeComponents {
        let n = self.cells.len().min(self.width.saturating_mul(self.height));
        let mut labels = vec![FreeComponents::NONE; n];
        let mut sizes = Vec::new();
        let mut stack = Vec::new();
        for start in 0..n {
            if self.cells.get(start) != Some(&Truth::Free) || labels[start] != FreeComponents::NONE
            {
                continue;
            }
            let label = sizes.len() as u32;
            let mut size = 0usize;
            labels[start] = label;
            stack.push(start);
            while let Some(i) = stack.pop() {
                size += 1;
                let (x, y) = (i % self.width, i / self.width);
                let mut visit = |j: usize| {
                    if self.cells.get(j) == Some(&Truth::Free) && labels[j] == FreeComponents::NONE
                    {
                        labels[j] = label;
                        stack.push(j);
                    }
                };
                if x > 0 {
                    visit(i - 1);
                }
                if x + 1 < self.width {
                    visit(i + 1);
                }
                if y > 0 {
                    visit(i - self.width);
                }
                if y + 1 < self.height {
                    visit(i + self.width);
                }
            }
            sizes.push(size);
        }
        FreeComponents { labels, sizes }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn w(rows_top_first: &[&str]) -> World {
        let height = rows_top_first.len();
        let width = rows_top_first.first().map_or(0, |r| r.len());
        let mut cells = Vec::new();
        for r in rows_top_first.iter().rev() {
            for c in r.chars() {
                cells.push(match c {
                    '#' => Truth::Occupied,
                    '.' => Truth::Free,
                    _ => Truth::Unknown,
                });
            }
        }
        World {
            width,
            height,
            resolution_m: 0.1,
            origin_m: (1.0, -2.0),
            cells,
        }
    }

    #[test]
    fn crop_keeps_world_coordinates() {
        let m = w(&["#..?", ".#..", "..#."]);
        let c = m.crop(1, 1, 2, 5);
        assert_eq!((c.width, c.height), (2, 2));
        assert_eq!(c.get(0, 0), Some(Truth::Occupied));
        assert_eq!(c.get(1, 1), Some(Truth::Free));
        assert!((c.origin_m.0 - 1.1).abs() < 1e-12 && (c.origin_m.1 + 1.9).abs() < 1e-12);
        let e = m.crop(10, 10, 3, 3);
        assert_eq!((e.width, e.height, e.cells.len()), (0, 0, 0));
        assert_eq!(e.counts().occupied_fraction(), 0.0);
    }

    #[test]
    fn resample_down_keeps_thin_walls() {
        let mut m = World::new(9, 6, 0.05, (0.0, 0.0), Truth::Free);
        for y in 0..6 {
            m.set(4, y, Truth::Occupied);
        }
        m.set(0, 5, Truth::Unknown);
        let d = m.resample(0.1);
        assert_eq!((d.width, d.height), (5, 3));
        for y in 0..3 {
            assert_eq!(d.get(2, y), Some(Truth::Occupied));
            assert_eq!(d.get(1, y), Some(Truth::Free));
        }
        // the unknown cell is outvoted by its free neighbours
        assert_eq!(d.get(0, 2), Some(Truth::Free));
        let u = World::new(2, 2, 0.1, (0.0, 0.0), Truth::Unknown);
        assert_eq!(u.resample(0.2).cells, vec![Truth::Unknown]);
        // non-integer factor: a wall at any source column still shows up
        let d3 = m.resample(0.125);
        assert_eq!(d3.width, 4);
        assert!((0..d3.height as i64).all(|y| d3.get(1, y) == Some(Truth::Occupied)));
    }

    #[test]
    fn resample_up_is_nearest_and_invalid_is_identity() {
        let m = w(&["#.", ".?"]);
        let u = m.resample(0.05);
        assert_eq!((u.width, u.height), (4, 4));
        assert_eq!(u.get(0, 3), Some(Truth::Occupied));
        assert_eq!(u.get(1, 2), Some(Truth::Occupied));
        assert_eq!(u.get(3, 0), Some(Truth::Unknown));
        assert_eq!(u.get(2, 3), Some(Truth::Free));
        assert_eq!(u.resample(0.1), m);
        assert_eq!(m.resample(f64::NAN), m);
        assert_eq!(m.resample(-1.0), m);
        assert_eq!(m.resample(1e-9), m);
        assert_eq!(m.resample(0.1), m);
    }

    #[test]
    fn components_and_counts() {
        let m = w(&["..#..", "..#..", "#####", "....?"]);
        let c = m.free_components();
        assert_eq!(c.count(), 3);
        assert_eq!(c.largest().map(|l| c.sizes[l as usize]), Some(4));
        let k = m.counts();
        assert_eq!((k.free, k.occupied, k.unknown), (12, 7, 1));
        assert!((m.occupied_fraction() - 0.35).abs() < 1e-12);
        assert_eq!(m.cell_at(1.05, -1.95), Some((0, 0)));
        assert_eq!(m.cell_at(0.99, -1.95), None);
        let (cx, cy) = m.cell_center_m(4, 3);
        assert!((cx - 1.45).abs() < 1e-12 && (cy + 1.65).abs() < 1e-12);
    }
}
