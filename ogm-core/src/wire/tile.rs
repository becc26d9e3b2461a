//! The map stream's tiles: the [`Tile`] message, the cells it holds ([`TileRect`]) and its one
//! codec ([`encode_tile`], [`decode_tile`]).

use serde::{Deserialize, Serialize};

use super::error::WireError;

/// Longest tile payload: 16 × 16 cells of `i16`.
pub const MAX_TILE_BYTES: usize = 512;

/// A square block of the map, row-major from its lower-left cell (row 0 = lowest y).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Tile<'a> {
    /// Which map.
    pub layer: Layer,
    /// Tile column in the building's tiling (cells `tx·edge ..` of the building frame, whose
    /// cell (0, 0) is the one at the settings' origin; wire version 6). With a fixed grid the
    /// window never moves and this is the grid's own tile column.
    pub tx: i32,
    /// Tile row in the building's tiling.
    pub ty: i32,
    /// The cells (see [`Layer`]); tiles at the map's edge may be smaller than `edge²`.
    pub data: &'a [u8],
}

/// Which map a [`Tile`] carries.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Layer {
    /// The online log-odds map: `i16` little endian per cell ([`LogOdds`] raw, ln 4 = 1024).
    ///
    /// [`LogOdds`]: crate::types::fixed::LogOdds
    LogOdds,
    /// The sampler's marginal counts: `u8` per cell; p(occupied) = count / [`SamplerReport::samples`].
    ///
    /// [`SamplerReport::samples`]: super::SamplerReport::samples
    Counts,
    /// The sampler's current map sample: one bit per cell, LSB first.
    Sample,
}

/// The cells of one streamed tile: tile (`tx`, `ty`) of a `width × height` map cut into
/// `edge`-cell squares from its lower-left corner; tiles at the map's right and top edges are
/// smaller. [`encode_tile`] and [`decode_tile`] are the one codec of [`Tile::data`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileRect {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// Columns.
    pub w: usize,
    /// Rows.
    pub h: usize,
    /// The map's width (row stride).
    pub stride: usize,
    /// The tile edge it was cut with.
    pub edge: usize,
}

impl TileRect {
    /// Tile (`tx`, `ty`); `None` if it lies outside the map or `edge` is 0.
    pub fn new(width: usize, height: usize, edge: usize, tx: u16, ty: u16) -> Option<Self> {
        let x0 = usize::from(tx).checked_mul(edge)?;
        let y0 = usize::from(ty).checked_mul(edge)?;
        if edge == 0 || x0 >= width || y0 >= height {
            return None;
        }
        Some(TileRect {
            x0,
            y0,
            w: edge.min(width - x0),
            h: edge.min(height - y0),
            stride: width,
            edge,
        })
    }

    /// Tile number `t`, row-major over the map's tiles; `None` past the last.
    pub fn nth(width: usize, height: usize, edge: usize, t: usize) -> Option<Self> {
        let across = width.checked_div(edge)? + usize::from(width % edge != 0);
        let (tx, ty) = (t.checked_rem(across)?, t / across);
        Self::new(
            width,
            height,
            edge,
            u16::try_from(tx).ok()?,
            u16::try_from(ty).ok()?,
        )
    }

    /// The tile's column and row.
    pub fn coords(&self) -> (u16, u16) {
        let e = self.edge.max(1);
        ((self.x0 / e) as u16, (self.y0 / e) as u16)
    }

    /// Cells in the tile.
    pub fn len(&self) -> usize {
        self.w * self.h
    }

    /// Whether the tile has no cells (never, for a tile [`TileRect::new`] made).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of `layer`'s data for this tile.
    pub fn data_len(&self, layer: Layer) -> usize {
        match layer {
            Layer::LogOdds => 2 * self.len(),
            Layer::Counts => self.len(),
            Layer::Sample => self.len().div_ceil(8),
        }
    }

    /// The map indices of its cells, in the tile's order (row-major from the lower-left).
    pub fn cells(&self) -> impl Iterator<Item = usize> + '_ {
        (self.y0..self.y0 + self.h)
            .flat_map(move |y| (self.x0..self.x0 + self.w).map(move |x| y * self.stride + x))
    }
}

/// A map a tile can be cut from (the firmware's [`crate::session::Session`]).
pub trait TileSource {
    /// Raw log-odds of cell `index` ([`LogOdds::raw`]).
    ///
    /// [`LogOdds::raw`]: crate::types::fixed::LogOdds::raw
    fn log_odds(&self, index: usize) -> i16;
    /// Marginal count of cell `index`, saturated to a byte.
    fn count(&self, index: usize) -> u8;
    /// Whether cell `index` is occupied in the current sample.
    fn occupied(&self, index: usize) -> bool;
}

/// A map a tile can be written into (a host's rebuilt map).
pub trait TileSink {
    /// Sets the raw log-odds of cell `index`.
    fn set_log_odds(&mut self, index: usize, raw: i16);
    /// Sets the marginal count of cell `index`.
    fn set_count(&mut self, index: usize, count: u8);
    /// Sets the sample bit of cell `index`.
    fn set_occupied(&mut self, index: usize, occupied: bool);
}

/// Encodes `layer` of the cells of `rect` from `src` into `buf` ([`Layer`] says how); returns
/// the data, or [`WireError::BufferFull`] if `buf` is shorter than [`TileRect::data_len`].
pub fn encode_tile<'b>(
    src: &impl TileSource,
    layer: Layer,
    rect: &TileRect,
    buf: &'b mut [u8],
) -> Result<&'b [u8], WireError> {
    let out = buf
        .get_mut(..rect.data_len(layer))
        .ok_or(WireError::BufferFull)?;
    match layer {
        Layer::LogOdds => {
            for (d, i) in out.chunks_exact_mut(2).zip(rect.cells()) {
                d.copy_from_slice(&src.log_odds(i).to_le_bytes());
            }
        }
        Layer::Counts => {
            for (d, i) in out.iter_mut().zip(rect.cells()) {
                *d = src.count(i);
            }
        }
        Layer::Sample => {
            out.fill(0);
            for (k, i) in rect.cells().enumerate() {
                if src.occupied(i) {
                    if let Some(d) = out.get_mut(k / 8) {
                        *d |= 1 << (k % 8);
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Writes a received tile's cells into `sink`, a `width × height` map cut into `edge`-cell tiles
/// whose tile (0, 0) is the building's; [`WireError::Tile`] if the tile lies outside it or its
/// data has the wrong length (nothing is written then).
pub fn decode_tile(
    tile: &Tile<'_>,
    width: usize,
    height: usize,
    edge: usize,
    sink: &mut impl TileSink,
) -> Result<TileRect, WireError> {
    let (tx, ty) = (
        u16::try_from(tile.tx).map_err(|_| WireError::Tile)?,
        u16::try_from(tile.ty).map_err(|_| WireError::Tile)?,
    );
    let rect = TileRect::new(width, height, edge, tx, ty).ok_or(WireError::Tile)?;
    if tile.data.len() != rect.data_len(tile.layer) {
        return Err(WireError::Tile);
    }
    match tile.layer {
        Layer::LogOdds => {
            for (d, i) in tile.data.chunks_exact(2).zip(rect.cells()) {
                if let [lo, hi] = *d {
                    sink.set_log_odds(i, i16::from_le_bytes([lo, hi]));
                }
            }
        }
        Layer::Counts => {
            for (&d, i) in tile.data.iter().zip(rect.cells()) {
                sink.set_count(i, d);
            }
        }
        Layer::Sample => {
            for (k, i) in rect.cells().enumerate() {
                let bit = tile.data.get(k / 8).is_some_and(|d| d >> (k % 8) & 1 != 0);
                sink.set_occupied(i, bit);
            }
        }
    }
    Ok(rect)
}
