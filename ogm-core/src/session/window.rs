//! The rolling window: a session's grid is a `width × height` window onto an unbounded building,
//! moved by whole tiles so that the robot stays inside a margin of its edges.
//!
//! * **When** ([`Session::shift_for`]): a scan's pose lies closer than
//!   [`RunConfig::window_margin_cells`](crate::config::RunConfig::window_margin_cells) cells to
//!   an edge. The window then moves, on that axis, by the whole tiles that bring the pose
//!   nearest the centre: afterwards the pose is within half a tile of the centre, so another
//!   shift needs a move of at least `size/2 − edge/2 − margin ≥ edge/2` cells (the hysteresis
//!   band; [`Session::window_fits`] checks `margin + edge ≤ size/2`). A robot on a boundary
//!   cannot make the window thrash.
//! * **How** ([`Session::apply_shift`]): every per-cell array (log-odds, sample bits, estimates)
//!   is moved in place by one `memmove` per row ([`crate::map::shift`]), so every hot loop keeps
//!   its linear indexing; the sampler's tile schedule moves by whole tiles; the visit in progress,
//!   the caches and the ray store (only [`crate::config::DataTerm::Rays`] keeps rays; its rays
//!   are of the old placement) are cleared. Cells entering the window are unknown (log-odds 0,
//!   the sample and estimate an unknown cell starts with) unless a stored tile is restored.
//! * **Before** a tile leaves, the caller streams it ([`Shift::leaving`]: each tile's cells in
//!   the current window and its tile coordinates in the building) through the
//!   [`crate::wire::TileSource`] the session is, then applies the shift.
//!
//! The window's log-odds equal those of an unbounded map of the same scans as long as no ray
//! leaves the window: when the margin is at least the mapper's reach
//! ([`Session::window_reach_cells`]: maximum range plus the face band, in cells, plus one)
//! and every scan's pose passes [`Session::shift_for`] before it is inserted. Rays that leave
//! the window anyway (a margin below the reach, a refused shift) are clipped exactly and
//! counted ([`WindowReport::scans_clipped`], [`WindowReport::beams_clipped`]).

use super::{Session, SessionError, Storage};
use crate::map::mapper;
use crate::wire::{TileRect, WindowReport};
use crate::Pose;

/// A move of the window, computed by [`Session::shift_for`] and applied by
/// [`Session::apply_shift`]: cell `(x, y)` of the new window is cell `(x + dx, y + dy)` of the
/// old one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Shift {
    /// Columns moved (a multiple of `edge`).
    pub dx: i32,
    /// Rows moved (a multiple of `edge`).
    pub dy: i32,
    /// The tile edge, cells.
    pub edge: u16,
    /// The window's origin before the shift, building cells.
    pub from: (i32, i32),
    width: u16,
    height: u16,
}

/// A tile about to leave the window ([`Shift::leaving`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeavingTile {
    /// Its cells in the current window.
    pub rect: TileRect,
    /// Its column in the building's tiling (tile (0, 0) holds building cell (0, 0)).
    pub tx: i32,
    /// Its row in the building's tiling.
    pub ty: i32,
}

impl Shift {
    /// The window's origin after the shift, building cells (saturating).
    pub fn to(&self) -> (i32, i32) {
        (
            self.from.0.saturating_add(self.dx),
            self.from.1.saturating_add(self.dy),
        )
    }

    /// The tiles of the current window that the shift moves out of it, row-major, with their
    /// building tile coordinates: stream them before [`Session::apply_shift`].
    pub fn leaving(&self) -> impl Iterator<Item = LeavingTile> + '_ {
        let (w, h, e) = (
            usize::from(self.width),
            usize::from(self.height),
            usize::from(self.edge.max(1)),
        );
        let (tiles_x, tiles_y) = (w / e, h / e);
        let e32 = i32::from(self.edge.max(1));
        let (dtx, dty) = (i64::from(self.dx / e32), i64::from(self.dy / e32));
        let (otx, oty) = (self.from.0.div_euclid(e32), self.from.1.div_euclid(e32));
        let stays = move |t: i64, d: i64, n: usize| (0..n as i64).contains(&(t - d));
        (0..tiles_x * tiles_y).filter_map(move |t| {
            let (tx, ty) = (t % tiles_x.max(1), t / tiles_x.max(1));
            if stays(tx as i64, dtx, tiles_x) && stays(ty as i64, dty, tiles_y) {
                return None;
            }
            let rect = TileRect::new(w, h, e, u16::try_from(tx).ok()?, u16::try_from(ty).ok()?)?;
            Some(LeavingTile {
                rect,
                tx: otx.saturating_add(i32::try_from(tx).ok()?),
                ty: oty.saturating_add(i32::try_from(ty).ok()?),
            })
        })
    }

    /// How many tiles [`Shift::leaving`] yields.
    pub fn leaving_count(&self) -> usize {
        let e = i64::from(self.edge.max(1));
        let (tx, ty) = (i64::from(self.width) / e, i64::from(self.height) / e);
        let keep = |n: i64, d: i64| (n - (d / e).abs()).max(0);
        (tx * ty - keep(tx, i64::from(self.dx)) * keep(ty, i64::from(self.dy))) as usize
    }
}

/// The window's place and counters, kept by the session.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct WindowState {
    pub(super) report: WindowReport,
}

/// The shift on one axis for a pose at cell `c` of a window of `n` cells: 0 inside the margin,
/// else the whole tiles that bring `c` nearest the centre.
fn axis_shift(c: i32, n: u16, margin: u16, edge: u16) -> i64 {
    let (c, n, m, e) = (
        i64::from(c),
        i64::from(n),
        i64::from(margin),
        i64::from(edge.max(1)),
    );
    if c >= m && c <= n - 1 - m {
        return 0;
    }
    let off = c - n / 2;
    (off + e / 2).div_euclid(e) * e
}

impl<S: Storage> Session<S> {
    /// Whether the rolling window works with tiles of `edge` cells: the grid is a whole number
    /// of tiles on each axis and `margin + edge ≤ size / 2` (the hysteresis band). Always true
    /// with a fixed grid (margin 0).
    pub fn window_fits(&self, edge: u16) -> bool {
        let margin = u32::from(self.config.window_margin_cells);
        if margin == 0 {
            return true;
        }
        let g = self.geometry();
        let (w, h, e) = (u32::from(g.width()), u32::from(g.height()), u32::from(edge));
        e > 0 && w % e == 0 && h % e == 0 && margin + e <= w.min(h) / 2
    }

    /// How far the scans' rays reach from the pose's cell ([`mapper::reach_cells`]): with a
    /// margin at least this, no ray leaves the window.
    pub fn window_reach_cells(&self) -> u32 {
        mapper::reach_cells(&self.geometry(), self.mapper.config())
    }

    /// The window's place and counters.
    pub fn window(&self) -> WindowReport {
        self.window.report
    }

    /// The shift a scan at `pose` needs before it is inserted, in tiles of `edge` cells, or
    /// `None` (a fixed grid, a pose inside the margin, a window that does not fit `edge`
    /// ([`Session::window_fits`]), or a shift that would move the origin out of the `i32` mm
    /// range: that one is refused, the scan clipped and counted).
    pub fn shift_for(&self, pose: &Pose, edge: u16) -> Option<Shift> {
        let margin = self.config.window_margin_cells;
        if margin == 0 || !self.window_fits(edge) {
            return None;
        }
        let g = self.geometry();
        let c = g.cell_of_pose(pose);
        let dx = axis_shift(c.x, g.width(), margin, edge);
        let dy = axis_shift(c.y, g.height(), margin, edge);
        if dx == 0 && dy == 0 {
            return None;
        }
        let (dx, dy) = (i32::try_from(dx).ok()?, i32::try_from(dy).ok()?);
        g.shifted(dx, dy)?;
        let r = &self.window.report;
        let from = (r.origin_x, r.origin_y);
        from.0.checked_add(dx)?;
        from.1.checked_add(dy)?;
        Some(Shift {
            dx,
            dy,
            edge,
            from,
            width: g.width(),
            height: g.height(),
        })
    }

    /// [`Session::shift_for`] that counts a refused shift (a pose outside the margin whose
    /// shift cannot be made) in [`WindowReport::shifts_refused`].
    pub fn check_shift(&mut self, pose: &Pose, edge: u16) -> Option<Shift> {
        let shift = self.shift_for(pose, edge);
        let margin = self.config.window_margin_cells;
        if shift.is_none() && margin > 0 && self.window_fits(edge) {
            let g = self.geometry();
            let c = g.cell_of_pose(pose);
            if axis_shift(c.x, g.width(), margin, edge) != 0
                || axis_shift(c.y, g.height(), margin, edge) != 0
            {
                let r = &mut self.window.report;
                r.shifts_refused = r.shifts_refused.saturating_add(1);
            }
        }
        shift
    }

    /// Moves the window by `shift` (see the module): the log-odds, the sampler's sample,
    /// estimates and schedule move in place; entering cells are unknown; the ray store is
    /// cleared. Stream [`Shift::leaving`] first: their cells are gone afterwards.
    /// [`SessionError::Window`] if `shift` is not this window's (its origin has moved since)
    /// or cannot be made; nothing changes then.
    pub fn apply_shift(&mut self, shift: &Shift) -> Result<(), SessionError> {
        let r = self.window.report;
        let g = self.geometry();
        let ok = shift.from == (r.origin_x, r.origin_y)
            && (shift.width, shift.height) == (g.width(), g.height());
        let new = g.shifted(shift.dx, shift.dy);
        let (Some(new), true) = (new, ok) else {
            return Err(SessionError::Window(crate::Error::InvalidGeometry));
        };
        let (Some(ox), Some(oy)) = (
            r.origin_x.checked_add(shift.dx),
            r.origin_y.checked_add(shift.dy),
        ) else {
            return Err(SessionError::Window(crate::Error::InvalidGeometry));
        };
        // Each part checks the same origin arithmetic as `new`, so none refuses now.
        let moved = self.mapper.shift(shift.dx, shift.dy) && self.gibbs.shift(shift.dx, shift.dy);
        self.store.clear_on(new);
        if !moved {
            return Err(SessionError::Window(crate::Error::InvalidGeometry));
        }
        self.window.report = WindowReport {
            origin_x: ox,
            origin_y: oy,
            ..self.window_after(shift)
        };
        Ok(())
    }

    /// Counts a lidar turn held after a shift ([`WindowReport::turns_held`]) and, if the host
    /// did not answer it, in [`WindowReport::holds_unanswered`].
    pub fn count_held_turn(&mut self, answered: bool) {
        let r = &mut self.window.report;
        r.turns_held = r.turns_held.saturating_add(1);
        if !answered {
            r.holds_unanswered = r.holds_unanswered.saturating_add(1);
        }
    }

    /// What [`Session::window`] will say once `shift` is applied (a device announces it
    /// before it streams the leaving tiles).
    pub fn window_after(&self, shift: &Shift) -> WindowReport {
        let r = self.window.report;
        let (origin_x, origin_y) = shift.to();
        WindowReport {
            origin_x,
            origin_y,
            shifts: r.shifts.saturating_add(1),
            tiles_out: r
                .tiles_out
                .saturating_add(u32::try_from(shift.leaving_count()).unwrap_or(u32::MAX)),
            ..r
        }
    }

    /// Restores a stored tile as the window comes back over it: building tile (`tx`, `ty`) of
    /// `edge` cells, its raw log-odds `log_odds` (`i16`, the tile's cells row-major from its
    /// lower-left, as the wire's `LogOdds` layer) and optionally its estimates (`u8` in 1/255,
    /// the `Counts` layer). Accepted only while the tile lies inside the window and every cell
    /// of it is still unknown (log-odds 0: nothing mapped there since it entered), so a
    /// restore never overwrites this visit's evidence; the log-odds are then exactly those the
    /// tile left with. Anything else is refused, nothing is written, and
    /// [`WindowReport::restore_refused`] counts it ([`SessionError::Window`]).
    pub fn restore_tile(
        &mut self,
        tx: i32,
        ty: i32,
        edge: u16,
        log_odds: &[i16],
        estimates: Option<&[u8]>,
    ) -> Result<(), SessionError> {
        let rect = self.restore_rect(tx, ty, edge, log_odds.len(), estimates.map(<[u8]>::len));
        let Some(rect) = rect else {
            let r = &mut self.window.report;
            r.restore_refused = r.restore_refused.saturating_add(1);
            return Err(SessionError::Window(crate::Error::InvalidGeometry));
        };
        for (k, i) in rect.cells().enumerate() {
            let l = crate::LogOdds(log_odds.get(k).copied().unwrap_or(0));
            if let Some(c) = self.mapper.grid_mut().cells_mut().get_mut(i) {
                *c = l;
            }
            let e = estimates.and_then(|e| e.get(k).copied());
            self.gibbs.restore_cell(i, l, e);
        }
        let r = &mut self.window.report;
        r.tiles_restored = r.tiles_restored.saturating_add(1);
        Ok(())
    }

    /// The window's cells of building tile (`tx`, `ty`) if a restore of `cells` log-odds (and
    /// `estimates` bytes) may write them.
    pub(super) fn restore_rect(
        &self,
        tx: i32,
        ty: i32,
        edge: u16,
        cells: usize,
        estimates: Option<usize>,
    ) -> Option<TileRect> {
        if !self.window_fits(edge) || edge == 0 {
            return None;
        }
        let e = i32::from(edge);
        let r = &self.window.report;
        let lx = tx.checked_sub(r.origin_x.div_euclid(e))?;
        let ly = ty.checked_sub(r.origin_y.div_euclid(e))?;
        let g = self.geometry();
        let rect = TileRect::new(
            usize::from(g.width()),
            usize::from(g.height()),
            usize::from(edge),
            u16::try_from(lx).ok()?,
            u16::try_from(ly).ok()?,
        )?;
        let whole = rect.len() == cells && estimates.is_none_or(|n| n == cells);
        let cells = self.mapper.grid().cells();
        let unknown = rect.cells().all(|i| cells.get(i).is_some_and(|c| c.0 == 0));
        (whole && unknown).then_some(rect)
    }

    /// Counts the beams of a scan at `pose` whose rays leave the window (called by
    /// [`Session::insert`] with a rolling window; O(1) unless the pose lies within the reach of
    /// an edge). Returns the count.
    pub(super) fn count_clipped(&mut self, pose: &Pose, beams: &[crate::Beam]) -> u32 {
        let g = self.geometry();
        let reach = i64::from(self.window_reach_cells());
        let c = g.cell_of_pose(pose);
        let inside = |v: i32, n: u16| {
            let v = i64::from(v);
            v >= reach && v <= i64::from(n) - 1 - reach
        };
        if inside(c.x, g.width()) && inside(c.y, g.height()) {
            return 0;
        }
        let n = mapper::beams_leaving(&g, self.mapper.config(), pose, beams);
        if n > 0 {
            let r = &mut self.window.report;
            r.scans_clipped = r.scans_clipped.saturating_add(1);
            r.beams_clipped = r.beams_clipped.saturating_add(n);
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// After a shift the pose is within half a tile of the centre, and a pose inside the
        /// margin never shifts.
        #[test]
        fn axis_shift_recentres_by_whole_tiles(
            c in -100_000i32..100_000, n in prop::sample::select(vec![64u16, 128, 256, 512]),
            margin in 1u16..40, edge in prop::sample::select(vec![8u16, 16, 32]),
        ) {
            prop_assume!(u32::from(margin) + u32::from(edge) <= u32::from(n) / 2);
            let d = axis_shift(c, n, margin, edge);
            let (ci, ni, mi) = (i64::from(c), i64::from(n), i64::from(margin));
            if ci >= mi && ci <= ni - 1 - mi {
                prop_assert_eq!(d, 0);
            } else {
                prop_assert_eq!(d % i64::from(edge), 0);
                let after = ci - d;
                prop_assert!((after - ni / 2).abs() <= i64::from(edge) / 2);
                // Hysteresis: the new position is inside the band with room to spare.
                prop_assert!(after - mi >= i64::from(edge) / 2);
                prop_assert!(ni - 1 - mi - after >= i64::from(edge) / 2 - 1);
            }
        }

        #[test]
        fn extreme_cells_do_not_overflow(c: i32, margin in 1u16..100) {
            let d = axis_shift(c, 256, margin, 16);
            prop_assert_eq!(d % 16, 0);
        }
    }
}
