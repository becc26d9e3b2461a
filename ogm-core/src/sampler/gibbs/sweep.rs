//! [`DataTerm::Evidence`]'s sweep: the robot's hot path.
//!
//! With per-cell evidence there are no rays to gather, so a tile visit does not need random
//! patch centres to amortise anything; it scans the tile's centres in raster order instead
//! (a systematic-scan Gibbs sampler: every update is still an exact draw from Eq. 1, only the
//! order is fixed, which leaves the posterior invariant). Consecutive patches then share all but
//! one column of their 5 × 5 window and 3 × 3 evidence, so the sweep reads a run of up to 27
//! centres of a row at once — five sample rows as words, and each centre's evidence masks — and
//! each update shifts its window out of the rows and loads its masks: a few memory reads, and no
//! random numbers for the placement. Unseen borders (a few per cent) take the general path.

use super::{Count, Gibbs, LocalRay, PatchPrior};
use crate::config::DataTerm;
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use crate::types::fixed::LogOdds;
use crate::types::geometry::CellCoord;

/// Where the sweep is, and what it knows about the windows of a run of centres in its row.
///
/// A run ("segment") of up to [`MAX_SPAN`] consecutive centres is read once: five sample rows
/// as words and the 3 × 3 evidence masks of each centre, so that each update only shifts its
/// 5 × 5 window out of the rows and loads its masks. A change of the patch writes its bits back
/// into the rows.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Raster {
    /// Current patch centre.
    x: i32,
    y: i32,
    /// Whether the rows describe the segment that holds (x, y).
    valid: bool,
    /// Whether the rows describe the segment one row above (x, y), the update count having
    /// just moved past its end to the next row of the tile.
    next_row: bool,
    /// First centre of the segment.
    x_start: i32,
    /// Centres in the segment.
    span: i32,
    /// Sample rows y − 2 + r; bit k is column `x_start − 2 + k`.
    rows: [u32; 5],
    /// The evidence masks of centre `x_start + s`, `known | occupied << 16` (log-odds ≠ 0, > 0;
    /// [`crate::sampler::patch`]'s config layout): built once per segment, so that an update loads them
    /// instead of shifting six rows (and the run keeps six words fewer in registers).
    masks: [u32; 32],
}

/// Most centres per segment: a sample row then spans `MAX_SPAN + 4` ≤ 31 bits.
const MAX_SPAN: i32 = 27;

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
        (self.raster.valid, self.raster.next_row) = (false, false);
        let mut left = budget;
        while left > 0 {
            if self.visit_left == 0 {
                self.start_visit(store);
                let (x0, y0, x1, y1) = self.tile;
                // Whole raster passes: a pass updates every centre once, i.e. covers every
                // cell nine times (nine sweeps' worth of updates).
                let cells = ((x1 - x0 + 1) * (y1 - y0 + 1)) as u32;
                self.visit_left = cells * u32::from(self.config.visit_sweeps.max(1)).div_ceil(9);
                self.raster.x = x0;
                self.raster.y = y0;
                (self.raster.valid, self.raster.next_row) = (false, false);
            }
            if !self.raster.valid {
                self.raster_load(map);
            }
            // The rest of the segment, of the visit and of the budget, whichever ends first
            // (≥ 1 each: the segment holds the current centre).
            let in_segment = (self.raster.x_start + self.raster.span - self.raster.x).max(1) as u32;
            let n = left.min(self.visit_left).min(in_segment);
            self.raster_run(store, map, n);
            self.visit_left -= n;
            left -= n;
            self.stats.updates += u64::from(n);
            self.accumulate_n(n);
            self.raster_advance(n);
        }
        budget
    }

    /// Reads the segment that starts at the current centre: up to [`MAX_SPAN`] centres, to the
    /// tile's last column. Right after the same columns one row up (the next row of a tile no
    /// wider than a segment) it keeps the four sample rows and two evidence rows it shares with
    /// them and reads one of each: the rows a segment's updates changed are kept current, and
    /// the evidence does not change within a [`Gibbs::step`].
    fn raster_load(&mut self, map: &[LogOdds]) {
        let (x, y) = (self.raster.x, self.raster.y);
        let span = (self.tile.2 - x + 1).clamp(1, MAX_SPAN);
        if core::mem::take(&mut self.raster.next_row)
            && (self.raster.x_start, self.raster.span) == (x, span)
        {
            let [_, r1, r2, r3, r4] = self.raster.rows;
            self.raster.rows = [r1, r2, r3, r4, self.sample_row(x, y + 2, span)];
            self.evidence_up(map, x, y + 1, span);
            self.raster.valid = true;
            return;
        }
        let mut rows = [0u32; 5];
        for (r, row) in rows.iter_mut().enumerate() {
            *row = self.sample_row(x, y - 2 + r as i32, span);
        }
        self.raster.rows = rows;
        (self.raster.x_start, self.raster.span) = (x, span);
        // Three rows up from whatever the masks held: only the three rows remain.
        for y in y - 1..=y + 1 {
            self.evidence_up(map, x, y, span);
        }
        self.raster.valid = true;
    }

    /// The sample bits of row `y`, columns `x − 2 .. x + span + 2` (bit 0 first).
    #[inline]
    fn sample_row(&self, x: i32, y: i32, span: i32) -> u32 {
        let width = usize::from(self.geometry.width());
        // Patch centres keep a 2-cell margin: the window is in the map.
        if y >= 0 && x >= 2 {
            self.bits(y as usize * width + (x - 2) as usize, (span + 4) as u32)
        } else {
            0
        }
    }

    /// Moves the segment's masks up a row: the evidence (log-odds ≠ 0, > 0) of row `y`, columns
    /// `x − 1 ..= x + span`, becomes their top row, each centre's three bits from a window that
    /// slides along the row (one pass over its cells). Not inlined: once per segment.
    #[inline(never)]
    fn evidence_up(&mut self, map: &[LogOdds], x: i32, y: i32, span: i32) {
        let width = usize::from(self.geometry.width());
        // In the map (the 2-cell margin), so a slice that is not (only a broken tiling) reads as
        // no evidence.
        let start = y as usize * width + (x - 1) as usize;
        let cells = map.get(start..start + span as usize + 2).unwrap_or(&[]);
        // The window's bits: known in 0..3, occupied in 16..19 (the masks' layout).
        let push = |w: u32, j: usize| {
            let l = cells.get(j).map_or(0, |l| l.0);
            (w >> 1 & 0x0003_0003) | u32::from(l != 0) << 2 | u32::from(l > 0) << 18
        };
        let mut w = push(push(0, 0), 1);
        for (s, m) in self.raster.masks.iter_mut().enumerate().take(span as usize) {
            w = push(w, s + 2);
            *m = (*m >> 3 & 0x003F_003F) | w << 6;
        }
    }

    /// Writes the segment's rows y − 1 ..= y + 1 (`rows`, what [`Gibbs::sample_row`] read and the
    /// run's changed patches wrote into) back into the sample. Not inlined: once per run that
    /// changed a patch.
    #[inline(never)]
    fn raster_store(&mut self, rows: [u32; 3]) {
        let width = usize::from(self.geometry.width());
        let (x, n) = (self.raster.x_start - 2, (self.raster.span + 4) as u32);
        for (y, row) in (self.raster.y - 1..).zip(rows) {
            if y >= 0 && x >= 0 {
                self.set_bits(y as usize * width + x as usize, n, row);
            }
        }
    }

    /// A raster run's random patch at `centre`: the gap to the next one (drawn first, as
    /// `update::random_patch_step` does), then the patch; returns both. Not inlined: about one
    /// update in a thousand.
    #[inline(never)]
    fn raster_random<S, R>(
        &mut self,
        store: &mut RayStore<S, R>,
        centre: CellCoord,
        current: u16,
    ) -> (u16, u32)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let gap = super::update::next_gap(self.rand_period, &mut self.rng);
        (self.random_patch(store, centre, current), gap)
    }

    /// Moves `n` centres on in the tile's raster order, within the current segment or just past
    /// its end (then the next update reads a new one, on the next row past the tile's last
    /// column).
    #[inline]
    fn raster_advance(&mut self, n: u32) {
        let (x0, y0, x1, y1) = self.tile;
        let (x, y) = (self.raster.x + n as i32, self.raster.y);
        if x > x1 {
            self.raster.x = x0;
            self.raster.y = if y >= y1 { y0 } else { y + 1 };
            self.raster.valid = false;
            // The next row's segment may share four of these rows (checked by raster_load).
            self.raster.next_row = y < y1;
            return;
        }
        self.raster.x = x;
        if x - self.raster.x_start >= self.raster.span {
            self.raster.valid = false;
        }
    }

    /// `n` updates at consecutive centres of the loaded segment, from the current one (which the
    /// caller advances past afterwards). Each update shifts its window out of the segment's
    /// rows, loads its masks, and writes a changed patch back into the rows (and, after the run,
    /// [`Gibbs::raster_store`], into the sample). Not inlined: one copy of the hot loop (inlined
    /// into `step` it was duplicated, +3.6 KiB of flash).
    #[inline(never)]
    fn raster_run<S, R>(&mut self, store: &mut RayStore<S, R>, map: &[LogOdds], n: u32)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let (x_start, y) = (self.raster.x_start, self.raster.y);
        let (x_first, x_end) = (self.raster.x, self.raster.x + n as i32);
        // `random_patch_step`'s countdown as the centre of the next random patch (one compare
        // per update); `drawn` keeps the last gap drawn and where, for the countdown after the
        // run.
        let period = self.rand_period;
        let to_centre = |x: i32, gap: u32| x.saturating_add(i32::try_from(gap).unwrap_or(i32::MAX));
        let mut rand_x = if period == 0 {
            i32::MAX
        } else {
            to_centre(x_first, self.rand_gap.saturating_sub(1))
        };
        let mut drawn: Option<(i32, u32)> = None;
        // Updates that took the general path or were random, and multi-candidate evidence
        // updates: the rest of the run were single-candidate evidence updates (counted once,
        // after the run, instead of a 64-bit increment each).
        let (mut other, mut multi) = (0u32, 0u32);
        // Whether an evidence update changed its patch: the sample's rows are then written
        // back from `rows` once, after the run (nothing reads the sample during it).
        let mut dirty = false;
        for x in x_first..x_end {
            let centre = CellCoord { x, y };
            // The centre's offset in the segment (0 ≤ s < span ≤ 27).
            let sh = (x - x_start) as u32 & 31;
            // The rows stay in `self.raster` (one load-multiple per update) rather than in
            // locals, which the calls below would spill and reload.
            let [r0, r1, r2, r3, r4] = self.raster.rows.map(|r| r >> sh);
            // The patch and its border ([`crate::sampler::patch`]'s layouts) straight from the rows.
            let current = ((r1 >> 1 & 7) | (r2 >> 1 & 7) << 3 | (r3 >> 1 & 7) << 6) as u16;
            let border = ((r0 & 0x1F)
                | (r4 & 0x1F) << 5
                | (r1 & 1) << 10
                | (r2 & 1) << 11
                | (r3 & 1) << 12
                | (r1 >> 4 & 1) << 13
                | (r2 >> 4 & 1) << 14
                | (r3 >> 4 & 1) << 15) as u16;
            let m = self.raster.masks.get(sh as usize).copied().unwrap_or(0);
            let (known, occupied) = (m & 0x1FF, m >> 16);
            // The incremental window and masks equal a fresh read (checked in every debug build).
            debug_assert_eq!((current, border), self.config_and_border(centre));
            debug_assert_eq!(
                {
                    let e = super::evidence::patch_evidence(
                        map,
                        usize::from(self.geometry.width()),
                        centre,
                        3,
                    );
                    (u32::from(e.known), u32::from(e.occupied))
                },
                (known, occupied)
            );
            let new = if x == rand_x {
                let (new, gap) = self.raster_random(store, centre, current);
                (rand_x, drawn) = (to_centre(x, gap), Some((x, gap)));
                other += 1;
                new
            } else if let Some((configs, log_priors)) = self.prior.table(border) {
                let masks = (known as u16, occupied as u16);
                let (new, single) =
                    self.evidence_update(map, centre, current, masks, configs, log_priors);
                if !single {
                    multi += 1;
                }
                if new != current {
                    self.stats.changed += 1;
                    dirty = true;
                    if cfg!(debug_assertions) {
                        // Debug builds keep the sample current for the fresh-read checks above.
                        self.apply(store, centre, new, None);
                    }
                }
                new
            } else {
                // An unseen border: the prior's back-off, through the general path.
                other += 1;
                self.update_at(store, map, centre, current, border)
            };
            if new != current {
                // The patch's cells in the segment's rows: columns sh + 1 ..= sh + 3.
                for (r, row) in self.raster.rows.iter_mut().skip(1).take(3).enumerate() {
                    let bits = u32::from(new) >> (3 * r) & 7;
                    *row = (*row & !(7 << (sh + 1))) | bits << (sh + 1);
                }
            }
        }
        if dirty {
            let [_, r1, r2, r3, _] = self.raster.rows;
            self.raster_store([r1, r2, r3]);
        }
        if period != 0 {
            // No random patch came after the last one drawn (or, with none drawn, in the run).
            self.rand_gap = match drawn {
                Some((x, gap)) => gap.saturating_sub((x_end - 1 - x) as u32),
                None => self.rand_gap.saturating_sub(n),
            };
        }
        self.stats.single_candidate += u64::from(n.saturating_sub(other).saturating_sub(multi));
    }
}
