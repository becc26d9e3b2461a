//! Stored tiles sent back by the host ([`crate::wire::HostMsg::Restore`]): parts checked and
//! assembled in a fixed buffer ([`TileRestore`]), the tile restored through
//! [`Session::restore_tile`] once every part of both layers has arrived.
//!
//! The rule: a tile is restored only while it lies whole inside the window and every cell of
//! it is still unknown (log-odds 0), i.e. the robot has not mapped there since the tile
//! entered; the host sends a region's tiles as soon as a `Window` announces it entered, before
//! the robot can reach it. Everything else is refused, nothing is written, and the refusal is
//! counted in [`WindowReport::restore_refused`](crate::wire::WindowReport::restore_refused).
//! Work per part: one check of the tile's place (O(1)) and a copy of at most
//! [`RESTORE_PART_BYTES`]; per tile, one pass over its cells.

use super::{Session, Storage};
use crate::wire::{
    check_restore_part, restore_parts, Layer, RestoreFault, TileRect, RESTORE_PART_BYTES,
};

/// The most cells of a restored tile (16 × 16: the largest tile whose log-odds fit
/// [`crate::wire::MAX_TILE_BYTES`]).
pub const MAX_RESTORE_CELLS: usize = crate::wire::MAX_TILE_BYTES / 2;

/// Why a restore part or tile was refused (each counted in `WindowReport::restore_refused`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum RestoreError {
    /// No rolling window: a fixed grid has nothing to restore.
    NoWindow,
    /// The part itself is malformed: layer, row, length, or a tile edge parts cannot carry
    /// ([`check_restore_part`]).
    Part(RestoreFault),
    /// The tile does not lie whole inside the current window.
    Outside,
    /// A cell of the tile was mapped since it entered the window.
    Mapped,
}

impl RestoreError {
    /// Its number on the wire (`DeviceError::detail` of `ErrorCode::Restore`).
    pub fn fault(&self) -> RestoreFault {
        match self {
            RestoreError::NoWindow => RestoreFault::NoWindow,
            RestoreError::Part(f) => *f,
            RestoreError::Outside => RestoreFault::Outside,
            RestoreError::Mapped => RestoreFault::Mapped,
        }
    }
}

impl core::fmt::Display for RestoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Display::fmt(&self.fault(), f)
    }
}

impl core::error::Error for RestoreError {}

/// What an accepted part did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RestoreStep {
    /// The tile it completed and restored, if any (building tile coordinates).
    pub restored: Option<(i32, i32)>,
    /// Whether the part had arrived before (a repeated frame: its bytes are written again).
    pub repeat: bool,
    /// An incomplete tile dropped because this part began another (counted as a refusal).
    pub dropped: Option<(i32, i32)>,
}

/// One tile being assembled from its parts: 768 bytes of cells and two part masks. A part of
/// another tile starts over (the incomplete one is dropped and counted); parts may come in
/// any order and repeat, also right after the tile was restored (ignored then).
#[derive(Clone, Debug)]
pub struct TileRestore {
    tile: Option<(i32, i32)>,
    log_odds: [i16; MAX_RESTORE_CELLS],
    counts: [u8; MAX_RESTORE_CELLS],
    /// Parts received, per layer (`LogOdds`, `Counts`), one bit each.
    have: [u32; 2],
    /// The tile restored last, until a part of another tile arrives: a repeat of its parts
    /// (a host that sends each frame twice) is ignored rather than starting it over.
    done: Option<(i32, i32)>,
}

impl Default for TileRestore {
    fn default() -> Self {
        Self::new()
    }
}

impl TileRestore {
    /// Nothing assembled.
    pub const fn new() -> Self {
        TileRestore {
            tile: None,
            log_odds: [0; MAX_RESTORE_CELLS],
            counts: [0; MAX_RESTORE_CELLS],
            have: [0; 2],
            done: None,
        }
    }

    /// The tile being assembled, if any part of it has arrived.
    pub fn pending(&self) -> Option<(i32, i32)> {
        self.tile
    }

    fn clear(&mut self) {
        self.tile = None;
        self.have = [0; 2];
    }
}

/// Every part of `layer` for `edge`-cell tiles, as a mask.
fn full_mask(layer: Layer, edge: u16) -> u32 {
    match restore_parts(layer, edge) {
        Some(32) => u32::MAX,
        Some(n) => (1u32 << n) - 1,
        None => 0,
    }
}

impl<S: Storage> Session<S> {
    /// One part of a stored tile from the host ([`crate::wire::HostMsg::Restore`]) for tiles
    /// of `edge` cells, assembled in `asm`; restores the tile ([`Session::restore_tile`]) once
    /// every part of both layers has arrived. Every refusal is counted in
    /// [`WindowReport::restore_refused`](crate::wire::WindowReport::restore_refused) (a
    /// dropped incomplete tile too); a refused part leaves the tile being assembled as it was.
    #[allow(clippy::too_many_arguments)]
    pub fn restore_part(
        &mut self,
        asm: &mut TileRestore,
        edge: u16,
        tx: i32,
        ty: i32,
        layer: Layer,
        row: u8,
        data: &[u8],
    ) -> Result<RestoreStep, RestoreError> {
        let r = self.restore_part_inner(asm, edge, tx, ty, layer, row, data);
        // `restore_tile` counted a mapped tile itself.
        if r.is_err_and(|e| e != RestoreError::Mapped) {
            self.count_restore_refused();
        }
        r
    }

    fn count_restore_refused(&mut self) {
        let r = &mut self.window.report;
        r.restore_refused = r.restore_refused.saturating_add(1);
    }

    #[allow(clippy::too_many_arguments)]
    fn restore_part_inner(
        &mut self,
        asm: &mut TileRestore,
        edge: u16,
        tx: i32,
        ty: i32,
        layer: Layer,
        row: u8,
        data: &[u8],
    ) -> Result<RestoreStep, RestoreError> {
        if self.config.window_margin_cells == 0 || !self.window_fits(edge) {
            return Err(RestoreError::NoWindow);
        }
        let part = check_restore_part(layer, row, data.len(), edge).map_err(RestoreError::Part)?;
        let cells = usize::from(edge) * usize::from(edge);
        if cells > MAX_RESTORE_CELLS {
            return Err(RestoreError::Part(RestoreFault::Edge));
        }
        if !self.tile_in_window(tx, ty, edge) {
            return Err(RestoreError::Outside);
        }
        let mut step = RestoreStep {
            restored: None,
            repeat: false,
            dropped: None,
        };
        // A repeat of the tile just restored is ignored while the tile still holds it; a tile
        // all unknown again left the window and came back since, and these parts restore it
        // anew.
        let cells_known = || self.restore_rect(tx, ty, edge, cells, None).is_none();
        if asm.done == Some((tx, ty)) && cells_known() {
            step.repeat = true;
            return Ok(step);
        }
        asm.done = None;
        if asm.tile != Some((tx, ty)) {
            if let Some(old) = asm.tile {
                step.dropped = Some(old);
                self.count_restore_refused();
            }
            asm.clear();
            asm.tile = Some((tx, ty));
        }
        // The part's first cell: part · rows · edge = row · edge < edge² ≤ MAX_RESTORE_CELLS.
        let first = usize::from(row) * usize::from(edge);
        let (k, bit) = match layer {
            Layer::LogOdds => {
                let dst = asm
                    .log_odds
                    .get_mut(first..)
                    .ok_or(RestoreError::Part(RestoreFault::Row))?;
                for (d, c) in dst.iter_mut().zip(data.chunks_exact(2)) {
                    *d = i16::from_le_bytes([
                        c.first().copied().unwrap_or(0),
                        c.get(1).copied().unwrap_or(0),
                    ]);
                }
                (0, part)
            }
            _ => {
                let dst = asm
                    .counts
                    .get_mut(first..)
                    .ok_or(RestoreError::Part(RestoreFault::Row))?;
                for (d, c) in dst.iter_mut().zip(data) {
                    *d = *c;
                }
                (1, part)
            }
        };
        let mask = 1u32.checked_shl(bit).unwrap_or(0);
        if let Some(h) = asm.have.get_mut(k) {
            step.repeat = *h & mask != 0;
            *h |= mask;
        }
        let done = asm.have
            == [
                full_mask(Layer::LogOdds, edge),
                full_mask(Layer::Counts, edge),
            ];
        if done {
            asm.clear();
            let (l, c) = (
                asm.log_odds.get(..cells).unwrap_or(&[]),
                asm.counts.get(..cells).unwrap_or(&[]),
            );
            // In the window (checked above): the only refusal left is a mapped cell.
            // `restore_tile` counts it.
            return match self.restore_tile(tx, ty, edge, l, Some(c)) {
                Ok(()) => {
                    asm.done = Some((tx, ty));
                    step.restored = Some((tx, ty));
                    Ok(step)
                }
                Err(_) => Err(RestoreError::Mapped),
            };
        }
        Ok(step)
    }

    /// Whether building tile (`tx`, `ty`) of `edge` cells lies whole inside the window.
    pub fn tile_in_window(&self, tx: i32, ty: i32, edge: u16) -> bool {
        let e = i32::from(edge);
        if e == 0 {
            return false;
        }
        let r = &self.window.report;
        let (Some(lx), Some(ly)) = (
            tx.checked_sub(r.origin_x.div_euclid(e)),
            ty.checked_sub(r.origin_y.div_euclid(e)),
        ) else {
            return false;
        };
        let (Ok(lx), Ok(ly)) = (u16::try_from(lx), u16::try_from(ly)) else {
            return false;
        };
        let g = self.geometry();
        TileRect::new(
            usize::from(g.width()),
            usize::from(g.height()),
            usize::from(edge),
            lx,
            ly,
        )
        .is_some_and(|rect| rect.len() == usize::from(edge) * usize::from(edge))
    }
}

const _: () = assert!(RESTORE_PART_BYTES <= MAX_RESTORE_CELLS);
