//! [`DataTerm::Evidence`]'s sweep: the robot's hot path.
//!
//! With per-cell evidence there are no rays to gather, so a tile visit does not need random
//! patch centres to amortise anything; it scans the tile's centres in raster order instead
//! (a systematic-scan Gibbs sampler: every update is still an exact draw from Eq. 1, only the
//! order is fixed, which leaves the posterior invariant). Consecutive patches then share all but
//! one column of their 5 × 5 window and 3 × 3 evidence, so the sweep keeps both in registers
//! and reads one new column per update: 5 sample bits and 3 log-odds instead of 25 and 9, and no
//! random numbers for the placement. Unseen borders (a few per cent) take the general path.

use super::{Count, DataTerm, Gibbs, LocalRay, PatchPrior};
use crate::fixed::LogOdds;
use crate::geometry::CellCoord;
use crate::ray_store::{RayStore, StoredRay, StoredScan};

/// Where the sweep is, and what it knows about the window there.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Raster {
    /// Current patch centre.
    x: i32,
    y: i32,
    /// Whether `rows`, `known` and `occupied` describe the window at (x, y).
    valid: bool,
    /// The 5 × 5 sample window, row r (y − 2 + r) in bits 0..5 (bit k: x − 2 + k).
    rows: [u32; 5],
    /// The 3 × 3 patch's evidence masks ([`crate::patch`] bit order): log-odds ≠ 0, > 0.
    known: u32,
    occupied: u32,
}

/// Columns 0 and 1 of a 3 × 3 mask (bit 3r + c).
const KEEP_COLS_01: u32 = 0b011_011_011;

impl<P, B, C, L, K, N> Gibbs<P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    /// [`Gibbs::step`] for [`DataTerm::Evidence`] with a 3 × 3 prior.
    pub(super) fn step_raster<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        map: &[LogOdds],
        budget: u32,
    ) -> u32
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        debug_assert_eq!(self.config.data, DataTerm::Evidence);
        // The map and the sample may have changed since the last call (a scan, seeding).
        self.raster.valid = false;
        for _ in 0..budget {
            if self.visit_left == 0 {
                self.start_visit(store);
                let (x0, y0, x1, y1) = self.tile;
                // Whole raster passes: a pass updates every centre once, i.e. covers every
                // cell nine times (nine sweeps' worth of updates).
                let cells = ((x1 - x0 + 1) * (y1 - y0 + 1)) as u32;
                self.visit_left = cells * u32::from(self.config.visit_sweeps.max(1)).div_ceil(9);
                self.raster.x = x0;
                self.raster.y = y0;
                self.raster.valid = false;
            }
            self.visit_left -= 1;
            self.raster_update(store, map);
            self.accumulate();
            self.raster_advance(map);
        }
        budget
    }

    /// Evidence bits (≠ 0, > 0) of cell (x, y) (none outside the map).
    #[inline]
    fn evidence_at(map: &[LogOdds], width: i32, x: i32, y: i32) -> (u32, u32) {
        if x < 0 || y < 0 || x >= width {
            return (0, 0);
        }
        let v = map
            .get(y as usize * width as usize + x as usize)
            .map_or(0, |l| i32::from(l.0));
        // Sign bits, branch-free: v | −v < 0 iff v ≠ 0; −v < 0 iff v > 0.
        (
            ((v | v.wrapping_neg()) as u32) >> 31,
            (v.wrapping_neg() as u32) >> 31,
        )
    }

    /// Reads the whole window and masks at the current position.
    fn raster_load(&mut self, map: &[LogOdds]) {
        let (x, y) = (self.raster.x, self.raster.y);
        let width = usize::from(self.geometry.width());
        let mut rows = [0u32; 5];
        for (r, row) in rows.iter_mut().enumerate() {
            let yy = y - 2 + r as i32;
            // Patch centres keep a 2-cell margin: the window is in the map.
            if yy >= 0 && x >= 2 {
                *row = self.bits(yy as usize * width + (x - 2) as usize, 5);
            }
        }
        self.raster.rows = rows;
        let (mut known, mut occupied) = (0u32, 0u32);
        for r in 0..3 {
            for c in 0..3 {
                let (k, o) = Self::evidence_at(map, width as i32, x - 1 + c, y - 1 + r);
                known |= k << (3 * r + c);
                occupied |= o << (3 * r + c);
            }
        }
        (self.raster.known, self.raster.occupied) = (known, occupied);
        self.raster.valid = true;
    }

    /// Moves to the next centre of the tile in raster order, shifting the window by a column
    /// within a row.
    #[inline]
    fn raster_advance(&mut self, map: &[LogOdds]) {
        let (x0, y0, x1, y1) = self.tile;
        let (x, y) = (self.raster.x + 1, self.raster.y);
        if x > x1 {
            self.raster.x = x0;
            self.raster.y = if y >= y1 { y0 } else { y + 1 };
            self.raster.valid = false;
            return;
        }
        self.raster.x = x;
        if !self.raster.valid {
            return;
        }
        // Window: column x + 2 comes in (patch centres keep a 2-cell margin, so the column is in
        // the map; a bit outside the sample reads 0).
        let w = usize::from(self.geometry.width());
        let words = self.buf.sample.as_ref();
        let mut idx = (y - 2).max(0) as usize * w + (x + 2) as usize;
        let mut rows = self.raster.rows;
        for row in rows.iter_mut() {
            let bit = words.get(idx / 32).map_or(0, |v| (v >> (idx % 32)) & 1);
            *row = (*row >> 1) | (bit << 4);
            idx += w;
        }
        self.raster.rows = rows;
        // Evidence: column x + 1 comes in.
        let width = i32::from(self.geometry.width());
        // >> 1 moves columns 1, 2 to 0, 1; the mask drops what crossed into column 2 from the
        // row above.
        let (mut known, mut occupied) = (
            (self.raster.known >> 1) & KEEP_COLS_01,
            (self.raster.occupied >> 1) & KEEP_COLS_01,
        );
        for r in 0..3 {
            let (k, o) = Self::evidence_at(map, width, x + 1, y - 1 + r);
            known |= k << (3 * r + 2);
            occupied |= o << (3 * r + 2);
        }
        (self.raster.known, self.raster.occupied) = (known, occupied);
    }

    /// One update at the raster position.
    fn raster_update<S, R>(&mut self, store: &mut RayStore<S, R>, map: &[LogOdds])
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        if !self.raster.valid {
            self.raster_load(map);
        }
        self.stats.updates += 1;
        let centre = CellCoord {
            x: self.raster.x,
            y: self.raster.y,
        };
        let [r0, r1, r2, r3, r4] = self.raster.rows;
        let window = r0 | r1 << 5 | r2 << 10 | r3 << 15 | r4 << 20;
        let (current, border) = (
            crate::patch::patch_of(window),
            crate::patch::border_of(window),
        );
        // The incremental window and masks equal a fresh read (checked in every debug build).
        debug_assert_eq!((current, border), self.config_and_border(centre));
        debug_assert_eq!(
            {
                let e = super::patch_evidence(map, usize::from(self.geometry.width()), centre, 3);
                (u32::from(e.known), u32::from(e.occupied))
            },
            (self.raster.known, self.raster.occupied)
        );
        let new = if self.random_patch_due() {
            self.random_patch(store, centre, current)
        } else if let Some((configs, log_priors)) = self.prior.table(border) {
            let masks = (self.raster.known as u16, self.raster.occupied as u16);
            let new = self.evidence_update(map, centre, current, masks, configs, log_priors);
            if new != current {
                self.stats.changed += 1;
                self.apply(store, centre, new, None);
            }
            new
        } else {
            // An unseen border: the prior's back-off, through the general path.
            self.update_at(store, map, centre, current, border)
        };
        if new != current {
            // The patch's cells in the window.
            for (r, row) in self.raster.rows.iter_mut().skip(1).take(3).enumerate() {
                let bits = u32::from(new) >> (3 * r) & 7;
                *row = (*row & !0b01110) | bits << 1;
            }
        }
    }
}
