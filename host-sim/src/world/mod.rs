//! Ground-truth worlds: the shared type, procedural generation, loading and export.
//!
//! Convention (shared with `ogm-core`): cells are row-major with **row 0 at the bottom**
//! (world y increases with the row index), `origin_m` is the world position of the lower-left
//! corner of cell (0, 0). Image files store the top row first; the loaders and writers flip.

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

impl World {
    /// The cell at (x, y), `None` outside.
    pub fn get(&self, x: i64, y: i64) -> Option<Truth> {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return None;
        }
        self.cells.get(y as usize * self.width + x as usize).copied()
    }

    /// Whether a lidar beam stops at (x, y): everything but known free space does (unknown
    /// regions are solid to the simulator, and outside the map is a closed world).
    pub fn blocks_beam(&self, x: i64, y: i64) -> bool {
        !matches!(self.get(x, y), Some(Truth::Free))
    }
}
