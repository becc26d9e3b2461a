//! The whole building from the stream: [`BuildingMap`], the robot's tiles keyed by their
//! building tile coordinates (wire v6, docs/wire.md "Rolling window"), the newest tile of every
//! layer winning, its bounds growing as tiles arrive; rendered as a [`StreamedMap`] whose cell
//! (0, 0) is building cell ([`BuildingRender::x0`], [`BuildingRender::y0`]).
//!
//! With a fixed grid (window off) every tile lies in the `Hello`'s grid and the render is
//! exactly the [`StreamedMap`] the tiles applied in order give. Every tile is untrusted: its
//! coordinates may be anything, so the bounds are capped ([`MAX_BUILDING_CELLS`],
//! [`MAX_BUILDING_TILES`]) and a tile beyond them is refused and counted, never allocated.
//!
//! A region the robot comes back to (a tile that enters the window again, `Window` reports,
//! module `visit`): its stored tiles are what a host sends back ([`BuildingMap::note_window`],
//! [`BuildingMap::restore_msgs`]); if the robot restored them, its next tiles contain the stored
//! evidence and replace it, else the robot restarted the region from unknown and its tiles are
//! merged with the stored ones (log-odds added).

use std::collections::BTreeMap;

use ogm_core::wire::{Layer, TileRect, WindowReport};

use super::visit::{merge, Older, Revisits};
use super::{DeviceEvent, OwnedHello, OwnedTile, StreamedMap};

/// Largest building a stream may grow to, in cells (4096 × 4096: 205 m square at 5 cm).
pub const MAX_BUILDING_CELLS: u64 = 1 << 24;
/// Most distinct tiles a building may hold outside the robot's grid (4096 × 4096 cells of
/// 16-cell tiles).
pub const MAX_BUILDING_TILES: usize = 1 << 16;

/// Why a tile was not stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuildingError {
    /// Its data does not have its tile's size for its layer.
    Size {
        /// Tile column.
        tx: i32,
        /// Tile row.
        ty: i32,
        /// Bytes received.
        got: usize,
        /// Bytes expected.
        expected: usize,
    },
    /// It lies so far away that the building would exceed [`MAX_BUILDING_CELLS`] or
    /// [`MAX_BUILDING_TILES`].
    TooLarge {
        /// Tile column.
        tx: i32,
        /// Tile row.
        ty: i32,
    },
}

impl std::fmt::Display for BuildingError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            BuildingError::Size {
                tx,
                ty,
                got,
                expected,
            } => write!(f, "tile ({tx}, {ty}): {got} bytes, expected {expected}"),
            BuildingError::TooLarge { tx, ty } => write!(
                f,
                "tile ({tx}, {ty}): the building would exceed {MAX_BUILDING_CELLS} cells or \
                 {MAX_BUILDING_TILES} tiles; refused"
            ),
        }
    }
}

impl std::error::Error for BuildingError {}

/// One building tile: its size in cells and the newest data of each layer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct Stored {
    pub(super) w: usize,
    pub(super) h: usize,
    /// `LogOdds`, `Counts`, `Sample`: the robot's newest (of this visit, after a revisit).
    pub(super) layers: [Option<Vec<u8>>; 3],
    /// Earlier visits' evidence, when the tile entered the window again (module `visit`).
    pub(super) older: Option<Older>,
}

/// Inclusive tile bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Bounds {
    tx0: i64,
    ty0: i64,
    tx1: i64,
    ty1: i64,
}

/// The building as the stream's tiles give it: tiles keyed by building tile coordinates, the
/// newest of each layer winning, the bounds growing (capped) as tiles arrive.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildingMap {
    width: usize,
    height: usize,
    edge: usize,
    pub(super) tiles: BTreeMap<(i32, i32), Stored>,
    /// Tile bounds: the `Hello`'s grid and every stored tile.
    bounds: Bounds,
    /// Distinct tiles stored outside the `Hello`'s grid.
    outside: usize,
    applied: u64,
    bad_size: u64,
    refused: u64,
    window: Option<WindowReport>,
    /// Revisited regions: the tiles that entered at the last `Window`, and the counts.
    pub(super) revisits: Revisits,
}

fn layer_index(layer: Layer) -> usize {
    match layer {
        Layer::LogOdds => 0,
        Layer::Counts => 1,
        Layer::Sample => 2,
    }
}

impl BuildingMap {
    /// The building a map stream stitches to: `hello`'s grid, then every `Window` of `events`
    /// noted and every tile applied, in order (a tile that does not fit is counted and skipped:
    /// [`BuildingMap::tiles_bad_size`], [`BuildingMap::tiles_refused`]).
    pub fn stitch(hello: &OwnedHello, events: &[DeviceEvent]) -> Self {
        let mut b = BuildingMap::new(
            usize::from(hello.width),
            usize::from(hello.height),
            usize::from(hello.tile_edge),
        );
        for e in events {
            match e {
                DeviceEvent::Window(w) => b.note_window(*w),
                DeviceEvent::Tile(t) => {
                    let _ = b.apply(t);
                }
                _ => {}
            }
        }
        b
    }

    /// An empty building around the robot's `width × height` grid of `edge`-cell tiles (its
    /// `Hello`), whose tile (0, 0) is building tile (0, 0).
    pub fn new(width: usize, height: usize, edge: usize) -> Self {
        let edge = edge.max(1);
        let tiles_x = width.div_ceil(edge) as i64;
        let tiles_y = height.div_ceil(edge) as i64;
        BuildingMap {
            width,
            height,
            edge,
            tiles: BTreeMap::new(),
            bounds: Bounds {
                tx0: 0,
                ty0: 0,
                tx1: tiles_x - 1,
                ty1: tiles_y - 1,
            },
            outside: 0,
            applied: 0,
            bad_size: 0,
            refused: 0,
            window: None,
            revisits: Revisits::default(),
        }
    }

    /// The tile edge (cells).
    pub fn edge(&self) -> usize {
        self.edge
    }

    /// Tiles stored (every layer counts).
    pub fn tiles_applied(&self) -> u64 {
        self.applied
    }

    /// Tiles refused for their size.
    pub fn tiles_bad_size(&self) -> u64 {
        self.bad_size
    }

    /// Tiles refused because the building would grow past the caps.
    pub fn tiles_refused(&self) -> u64 {
        self.refused
    }

    /// Distinct building tiles holding something.
    pub fn building_tiles(&self) -> usize {
        self.tiles.len()
    }

    /// The robot's last `Window` report (none with a fixed grid).
    pub fn window(&self) -> Option<&WindowReport> {
        self.window.as_ref()
    }

    /// The window's size and tile edge (the `Hello`'s grid).
    pub(super) fn grid(&self) -> (usize, usize, usize) {
        (self.width, self.height, self.edge)
    }

    /// The window before `w` (the first window lies at building cell (0, 0)).
    pub(super) fn set_window(&mut self, w: WindowReport) -> WindowReport {
        self.window.replace(w).unwrap_or_default()
    }

    /// Whether tile (`tx`, `ty`) is one of the `Hello`'s grid.
    fn in_grid(&self, tx: i32, ty: i32) -> bool {
        let inside = |t: i32, cells: usize| t >= 0 && (t as usize) < cells.div_ceil(self.edge);
        inside(tx, self.width) && inside(ty, self.height)
    }

    /// The size of tile (`tx`, `ty`): the `Hello`'s grid's tile there (smaller at its right and
    /// top edges), else a full `edge × edge` tile.
    fn tile_size(&self, tx: i32, ty: i32) -> (usize, usize) {
        if let (Ok(x), Ok(y)) = (u16::try_from(tx), u16::try_from(ty)) {
            if let Some(r) = TileRect::new(self.width, self.height, self.edge, x, y) {
                return (r.w, r.h);
            }
        }
        (self.edge, self.edge)
    }

    /// Cell bounds `(x0, y0, width, height)` of tile bounds `b` (the `Hello`'s grid included).
    fn cells_of(&self, b: Bounds) -> (i64, i64, u64, u64) {
        let e = self.edge as i64;
        let x0 = (b.tx0 * e).min(0);
        let y0 = (b.ty0 * e).min(0);
        // The grid's right and top tiles may be partial: its own size unless tiles lie beyond.
        let beyond = |t1: i64, cells: usize| {
            if t1 >= cells.div_ceil(self.edge) as i64 {
                (t1 + 1) * e
            } else {
                cells as i64
            }
        };
        let x1 = beyond(b.tx1, self.width);
        let y1 = beyond(b.ty1, self.height);
        (x0, y0, (x1 - x0) as u64, (y1 - y0) as u64)
    }

    /// Stores a tile (replacing that layer's older data of the same building tile); grows the
    /// bounds. A tile of the wrong size, or one that would grow the building past the caps,
    /// changes nothing and is counted.
    pub fn apply(&mut self, t: &OwnedTile) -> Result<(), BuildingError> {
        let (w, h) = self.tile_size(t.tx, t.ty);
        let cells = w.saturating_mul(h);
        let expected = match t.layer {
            Layer::LogOdds => cells.saturating_mul(2),
            Layer::Counts => cells,
            Layer::Sample => cells.div_ceil(8),
        };
        if t.data.len() != expected {
            self.bad_size += 1;
            return Err(BuildingError::Size {
                tx: t.tx,
                ty: t.ty,
                got: t.data.len(),
                expected,
            });
        }
        let key = (t.tx, t.ty);
        if !self.tiles.contains_key(&key) {
            let (tx, ty) = (i64::from(t.tx), i64::from(t.ty));
            let b = Bounds {
                tx0: self.bounds.tx0.min(tx),
                ty0: self.bounds.ty0.min(ty),
                tx1: self.bounds.tx1.max(tx),
                ty1: self.bounds.ty1.max(ty),
            };
            // The `Hello`'s grid (whatever its size: a fixed grid's tiles as before) is always
            // there; beyond it the caps hold.
            if !self.in_grid(t.tx, t.ty) {
                let (_, _, cw, ch) = self.cells_of(b);
                let too_large = cw.checked_mul(ch).is_none_or(|n| n > MAX_BUILDING_CELLS);
                if too_large || self.outside >= MAX_BUILDING_TILES {
                    self.refused += 1;
                    return Err(BuildingError::TooLarge { tx: t.tx, ty: t.ty });
                }
                self.outside += 1;
                self.bounds = b;
            }
        }
        let stored = self.tiles.entry(key).or_insert_with(|| Stored {
            w,
            h,
            layers: [None, None, None],
            older: None,
        });
        stored.layers[layer_index(t.layer)] = Some(t.data.clone());
        self.applied += 1;
        Ok(())
    }

    /// The building as one map: every stored tile's newest layers, unknown (log-odds 0) where
    /// no tile arrived; the `Hello`'s grid is always inside it.
    pub fn render(&self) -> BuildingRender {
        let (x0, y0, w, h) = self.cells_of(self.bounds);
        // Both within MAX_BUILDING_CELLS (checked when the bounds grew) or the Hello's grid.
        let (w, h) = (w as usize, h as usize);
        let mut map = StreamedMap::new(w, h, self.edge);
        map.tiles = self.applied;
        let mut have_counts = vec![false; w * h];
        let e = self.edge as i64;
        for (&(tx, ty), stored) in &self.tiles {
            let merged;
            let s = match &stored.older {
                None => stored,
                Some(_) => {
                    merged = merge(stored);
                    &merged
                }
            };
            let cx = (i64::from(tx) * e - x0) as usize;
            let cy = (i64::from(ty) * e - y0) as usize;
            let index = |k: usize| (cy + k / s.w) * w + cx + k % s.w;
            if let Some(d) = &s.layers[0] {
                for (k, c) in d.chunks_exact(2).enumerate() {
                    if let (Some(cell), &[lo, hi]) = (map.log_odds.get_mut(index(k)), c) {
                        *cell = i16::from_le_bytes([lo, hi]);
                    }
                }
            }
            if let Some(d) = &s.layers[1] {
                for (k, &c) in d.iter().enumerate() {
                    let i = index(k);
                    if let (Some(cell), Some(have)) =
                        (map.counts.get_mut(i), have_counts.get_mut(i))
                    {
                        *cell = c;
                        *have = true;
                    }
                }
            }
            if let Some(d) = &s.layers[2] {
                for k in 0..s.w * s.h {
                    let bit = d.get(k / 8).is_some_and(|b| b >> (k % 8) & 1 != 0);
                    if let Some(cell) = map.sample.get_mut(index(k)) {
                        *cell = bit;
                    }
                }
            }
        }
        BuildingRender {
            map,
            have_counts,
            x0,
            y0,
        }
    }
}

/// A [`BuildingMap`] rendered.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildingRender {
    /// The cells (`map.tiles`: tiles stored).
    pub map: StreamedMap,
    /// Cells whose marginal (`Counts`) tile has arrived.
    pub have_counts: Vec<bool>,
    /// Building column of the map's column 0 (0 unless tiles arrived left of the `Hello`'s grid).
    pub x0: i64,
    /// Building row of the map's row 0.
    pub y0: i64,
}

impl BuildingRender {
    /// The world position (m) of the map's cell (0, 0), given the cell size (m) and the
    /// position of building cell (0, 0) (the settings' origin, m).
    pub fn origin_m(&self, cell_m: f64, origin_m: (f64, f64)) -> (f64, f64) {
        let shift = |o: f64, c: i64| if c == 0 { o } else { o + c as f64 * cell_m };
        (shift(origin_m.0, self.x0), shift(origin_m.1, self.y0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile(layer: Layer, tx: i32, ty: i32, data: Vec<u8>) -> OwnedTile {
        OwnedTile {
            layer,
            tx,
            ty,
            data,
        }
    }

    /// A 4 × 4 log-odds tile whose every cell is `v`.
    fn lo(tx: i32, ty: i32, v: i16) -> OwnedTile {
        tile(Layer::LogOdds, tx, ty, v.to_le_bytes().repeat(16))
    }

    fn cell(r: &BuildingRender, bx: i64, by: i64) -> i16 {
        let w = r.map.width as i64;
        r.map.log_odds[((by - r.y0) * w + bx - r.x0) as usize]
    }

    #[test]
    fn newest_tile_wins_in_any_order_and_negative_tiles_grow_the_map() {
        // An 8 × 8 grid of 4-cell tiles (2 × 2 tiles).
        let mut b = BuildingMap::new(8, 8, 4);
        b.apply(&lo(3, 1, 30)).unwrap();
        b.apply(&lo(-2, -1, 7)).unwrap();
        b.apply(&lo(0, 0, 1)).unwrap();
        b.apply(&lo(3, 1, 31)).unwrap(); // newer: replaces
        b.apply(&tile(Layer::Counts, 3, 1, vec![9; 16])).unwrap();
        b.apply(&lo(-2, -1, -5)).unwrap();
        let r = b.render();
        // Tiles -2 ..= 3 by -1 ..= 1: 24 × 12 cells from building cell (-8, -4).
        assert_eq!((r.map.width, r.map.height, r.x0, r.y0), (24, 12, -8, -4));
        assert_eq!(r.map.tiles, 6);
        assert_eq!(cell(&r, 12, 4), 31);
        assert_eq!(cell(&r, 15, 7), 31);
        assert_eq!(cell(&r, -8, -4), -5);
        assert_eq!(cell(&r, -5, -1), -5);
        assert_eq!(cell(&r, 0, 0), 1);
        // Nothing arrived here: unknown.
        assert_eq!(cell(&r, -1, 3), 0);
        assert_eq!(cell(&r, 5, 5), 0);
        let i = ((4 - r.y0) * 24 + 12 - r.x0) as usize;
        assert!(r.have_counts[i] && r.map.counts[i] == 9);
        assert_eq!(r.have_counts.iter().filter(|&&h| h).count(), 16);
        assert_eq!(r.origin_m(0.05, (1.0, 2.0)), (1.0 - 0.4, 2.0 - 0.2));
        // Order does not matter for distinct tiles; for one tile the last one wins.
        let mut c = BuildingMap::new(8, 8, 4);
        for t in [lo(-2, -1, -5), lo(0, 0, 1), lo(3, 1, 31)] {
            c.apply(&t).unwrap();
        }
        c.apply(&tile(Layer::Counts, 3, 1, vec![9; 16])).unwrap();
        let rc = c.render();
        assert_eq!(rc.map.log_odds, r.map.log_odds);
        assert_eq!(rc.have_counts, r.have_counts);
    }

    #[test]
    fn the_fixed_grid_keeps_its_partial_edge_tiles() {
        // 10 × 6 cells of 4-cell tiles: the right column is 2 wide, the top row 2 high.
        let mut b = BuildingMap::new(10, 6, 4);
        let mut m = StreamedMap::new(10, 6, 4);
        let t = tile(Layer::LogOdds, 2, 1, vec![1, 0, 2, 0, 3, 0, 4, 0]);
        b.apply(&t).unwrap();
        m.apply(&t).unwrap();
        let bad = tile(Layer::LogOdds, 2, 1, vec![1; 32]);
        assert!(matches!(b.apply(&bad), Err(BuildingError::Size { .. })));
        assert!(m.apply(&bad).is_err());
        let s = tile(Layer::Sample, 1, 1, vec![0b1010_0101]);
        b.apply(&s).unwrap();
        m.apply(&s).unwrap();
        let r = b.render();
        assert_eq!((r.x0, r.y0), (0, 0));
        assert_eq!(r.map, m);
        assert_eq!(b.tiles_bad_size(), 1);
    }

    #[test]
    fn hostile_coordinates_are_refused_and_counted() {
        let mut b = BuildingMap::new(8, 8, 4);
        b.apply(&lo(1, 1, 3)).unwrap();
        for (tx, ty) in [
            (i32::MIN, 0),
            (i32::MAX, i32::MAX),
            (0, i32::MIN),
            (i32::MIN, i32::MAX),
            (5000, 5000),
        ] {
            assert_eq!(
                b.apply(&lo(tx, ty, 1)),
                Err(BuildingError::TooLarge { tx, ty })
            );
        }
        assert_eq!(b.tiles_refused(), 5);
        // Far, but within the cap: accepted.
        b.apply(&lo(-1000, 900, 2)).unwrap();
        let r = b.render();
        assert!((r.map.width * r.map.height) as u64 <= MAX_BUILDING_CELLS);
        assert_eq!(cell(&r, -4000, 3600), 2);
        assert_eq!(cell(&r, 4, 4), 3);
        // The cap holds for a stream of tiles creeping outwards, too.
        let mut refused = 0;
        for k in 0..3000 {
            refused += usize::from(b.apply(&lo(-1000 - k, 900 + k, 1)).is_err());
        }
        assert!(refused > 0);
        let r = b.render();
        assert!((r.map.width * r.map.height) as u64 <= MAX_BUILDING_CELLS);
        assert_eq!(b.tiles_refused(), 5 + refused as u64);
    }

    #[test]
    fn many_small_tiles_beyond_the_grid_are_capped() {
        // 1-cell tiles: the cells cap alone would allow 2^24 of them.
        let mut b = BuildingMap::new(4, 4, 1);
        let one = |tx, ty| tile(Layer::Counts, tx, ty, vec![1]);
        let mut refused = 0;
        for k in 0..MAX_BUILDING_TILES as i32 + 100 {
            refused += usize::from(b.apply(&one(k % 300, -1 - k / 300)).is_err());
        }
        assert_eq!((refused, b.building_tiles()), (100, MAX_BUILDING_TILES));
        // The robot's own grid still takes its tiles.
        b.apply(&one(3, 3)).unwrap();
        assert_eq!(b.tiles_refused(), 100);
    }
}
