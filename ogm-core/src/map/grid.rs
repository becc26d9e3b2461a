//! The occupancy grid: fixed-point log-odds cells in caller-provided storage.
//!
//! Storage is any `AsRef<[LogOdds]> + AsMut<[LogOdds]>`: a `static` array on the firmware (size
//! fixed at compile time), a `Vec` on the host. The grid never allocates.

use crate::error::{Error, Result};
use crate::types::fixed::{Clamp, LogOdds};
use crate::types::geometry::{CellCoord, GridGeometry};

/// A grid of log-odds cells, row-major (`index = y · width + x`).
#[derive(Clone, Debug)]
pub struct LogOddsGrid<S> {
    geometry: GridGeometry,
    cells: S,
}

impl<S: AsRef<[LogOdds]>> LogOddsGrid<S> {
    /// Wraps `storage`, whose length must equal `geometry.len()`. Cells keep their contents.
    pub fn new(geometry: GridGeometry, storage: S) -> Result<Self> {
        let actual = storage.as_ref().len();
        if actual != geometry.len() {
            return Err(Error::BufferSize {
                expected: geometry.len(),
                actual,
            });
        }
        Ok(LogOddsGrid {
            geometry,
            cells: storage,
        })
    }

    /// The grid's geometry.
    #[inline]
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// All cells, row-major.
    #[inline]
    pub fn cells(&self) -> &[LogOdds] {
        self.cells.as_ref()
    }

    /// The cell at `c`, or `None` outside the grid.
    pub fn get(&self, c: CellCoord) -> Option<LogOdds> {
        self.geometry
            .index(c)
            .and_then(|i| self.cells.as_ref().get(i).copied())
    }

    /// Gives the storage back.
    pub fn into_storage(self) -> S {
        self.cells
    }
}

impl<S: AsRef<[LogOdds]> + AsMut<[LogOdds]>> LogOddsGrid<S> {
    /// All cells, mutable.
    #[inline]
    pub fn cells_mut(&mut self) -> &mut [LogOdds] {
        self.cells.as_mut()
    }

    /// Sets every cell to `value`.
    pub fn fill(&mut self, value: LogOdds) {
        self.cells.as_mut().fill(value);
    }

    /// Moves the grid by `(dx, dy)` whole cells ([`GridGeometry::shifted`]): cell `(x, y)` takes
    /// the value of cell `(x + dx, y + dy)`, cells entering the grid are unknown (0). Returns
    /// `false`, changing nothing, if the new origin leaves the `i32` mm range.
    pub fn shift(&mut self, dx: i32, dy: i32) -> bool {
        let Some(g) = self.geometry.shifted(dx, dy) else {
            return false;
        };
        let (w, h) = (usize::from(g.width()), usize::from(g.height()));
        crate::map::shift::shift_cells(self.cells.as_mut(), w, h, dx, dy, LogOdds::ZERO);
        self.geometry = g;
        true
    }

    /// Adds `delta` to the cell at `index`, clamped; `false` if the index is out of range.
    #[inline]
    pub fn apply(&mut self, index: usize, delta: LogOdds, clamp: &Clamp) -> bool {
        match self.cells.as_mut().get_mut(index) {
            Some(cell) => {
                *cell = clamp.apply(*cell, delta);
                true
            }
            None => false,
        }
    }
}
