//! [`Session::insert`](crate::session::Session::insert)'s work: the scan into the log-odds map,
//! newly observed cells seeded into the sampler's sample, its rays into the store when the
//! data term reads rays ([`insert_and_seed`]); and what it tells the caller ([`Inserted`]).

use crate::localize::Correction;
use crate::map::mapper::{self, Mapper, MapperConfig, ScanStats};
use crate::sampler::gibbs::{Count, Gibbs, LocalRay, PatchPrior};
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::Beam;
use crate::LogOdds;

/// What [`Session::insert`](crate::session::Session::insert) did with a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Inserted<'b> {
    /// What the mapper did.
    pub stats: ScanStats,
    /// The index range of the rays the store took (empty when the data term reads no rays).
    pub rays: core::ops::Range<usize>,
    /// Beams whose rays left a rolling window (clipped to it; 0 with a fixed grid, whose
    /// clipping is not counted).
    pub beams_clipped: u32,
    /// The pose the scan was inserted at and how it was found (the odometry pose it came
    /// with, the scan matcher's result).
    pub correction: Correction,
    geometry: GridGeometry,
    mapper: MapperConfig,
    pose: Pose,
    beams: &'b [Beam],
}

impl Inserted<'_> {
    /// The box of cells the scan may have changed, inclusive (`lo`, `hi`), in grid cells (it
    /// may reach past the grid): the pose's cell and every used beam's end cell — the mapper's
    /// rays change nothing outside it ([`crate::map::mapper::scan_box`]).
    ///
    /// Computed when asked, not by the insert: it costs about 7 % of an insert's instructions
    /// (docs/performance.md), which the firmware spends after its sampler budget, not in it.
    pub fn changed_box(&self) -> (CellCoord, CellCoord) {
        mapper::scan_box(&self.geometry, &self.mapper, &self.pose, self.beams)
    }
}

/// [`Inserted`] of a scan at `pose` with `beams`, whose insert returned `stats` and `rays`.
pub(crate) fn inserted<'b, S, M>(
    mapper: &Mapper<S, M>,
    pose: &Pose,
    beams: &'b [Beam],
    (stats, rays): (ScanStats, core::ops::Range<usize>),
) -> Inserted<'b>
where
    S: AsRef<[LogOdds]> + AsMut<[LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
{
    Inserted {
        stats,
        rays,
        beams_clipped: 0,
        correction: Correction::none(pose),
        geometry: *mapper.grid().geometry(),
        mapper: *mapper.config(),
        pose: *pose,
        beams,
    }
}

/// Integrates a scan into the online map *and* an online sampler: inserts it into `mapper`, seeds
/// every cell this scan observes for the first time (log-odds was exactly 0) in the sampler's
/// current sample from its new log-odds (occupied iff above the sampler's `init_threshold`),
/// tells the sampler which cells changed ([`crate::sampler::gibbs::Gibbs::note_changed`]: change-driven
/// tile visits, estimates restarted), and — when the sampler's data term uses rays — stores the
/// scan's rays and marks first-occupied caches stale: of every ray if a cell was seeded, else of
/// the new rays only (they are recomputed lazily, inside the sampler's bounded steps, when a tile
/// visit gathers them). Returns the mapper's statistics and the new rays' range (empty when no
/// rays are stored).
///
/// Without seeding, newly observed space would start as whatever the sample said about the
/// unknown (the border prior rarely flips a consistent all-free region, so walls seen later would
/// be slow to appear).
#[allow(clippy::type_complexity)]
pub(crate) fn insert_and_seed<S, M, SS, RR, P, B, C, L, K, N>(
    mapper: &mut Mapper<S, M>,
    store: &mut RayStore<SS, RR>,
    gibbs: &mut Gibbs<P, B, C, L, K, N>,
    pose: &Pose,
    beams: &[Beam],
) -> crate::Result<(ScanStats, core::ops::Range<usize>)>
where
    S: AsRef<[LogOdds]> + AsMut<[LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
    SS: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
    RR: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    let mut seeder = Seeder {
        threshold: gibbs.config().init_threshold,
        notify: gibbs.config().hot_share > 0 || gibbs.config().estimator.resets(),
        gibbs: &mut *gibbs,
        seeded: false,
    };
    let stats = mapper.insert_scan_into(pose, beams, &mut seeder)?;
    let seeded = seeder.seeded;
    if !gibbs.config().data.uses_rays() {
        return Ok((stats, 0..0));
    }
    let new = store.add_scan(pose, beams);
    let stale = if seeded { 0..usize::MAX } else { new.clone() };
    gibbs.invalidate_rays(store, stale);
    Ok((stats, new))
}

/// [`insert_and_seed`]'s listener: marks the tiles of the scan's cells from its mark words,
/// seeds first-observed cells and restarts the estimates of the notable ones.
struct Seeder<'a, P, B, C, L, K, N> {
    gibbs: &'a mut Gibbs<P, B, C, L, K, N>,
    threshold: LogOdds,
    /// Whether the sampler hears of changes at all (change-driven visits or estimate restarts).
    notify: bool,
    seeded: bool,
}

impl<P, B, C, L, K, N> crate::map::mapper::UpdateListener for Seeder<'_, P, B, C, L, K, N>
where
    P: PatchPrior,
    N: Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[LocalRay]> + AsMut<[LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    const REPORTS: crate::map::mapper::Reports = crate::map::mapper::Reports::Notable;

    // Out of line: only notable cells get here, and inlined into the sweep its state would
    // crowd the sweep's own out of the Cortex-M4's registers.
    #[inline(never)]
    fn changed(&mut self, index: usize, before: LogOdds, after: LogOdds) {
        if before.0 == 0 {
            self.gibbs.seed(index, after > self.threshold);
            self.seeded = true;
        }
        if self.notify {
            self.gibbs.note_estimate(index, before, after);
        }
    }

    #[inline(always)]
    fn fresh_word(&mut self, word: usize, bits: u32, after: LogOdds) {
        self.gibbs.seed_word(word, bits, after > self.threshold);
        self.seeded = true;
        if self.notify {
            self.gibbs.note_estimate_word(word, bits, LogOdds(0), after);
        }
    }

    #[inline(always)]
    fn marked_words(&mut self, first: usize, words: &[u32]) {
        if self.notify {
            self.gibbs.note_marked_words(first, words);
        }
    }
}

#[cfg(all(test, feature = "alloc", feature = "rays"))]
mod tests {
    use crate::config::{DataTerm, RunConfig};
    use crate::sampler::ray_store::STALE;
    use crate::session::{Owned, Session, Sizes};
    use crate::{Angle, Beam, Pose, Range};

    const CELL: u32 = 100;

    // Moved here from tests/gibbs.rs (which called `insert_and_seed` directly): the same
    // checks through the session, with its border prior instead of that file's test prior and
    // the same sampler settings (`RunConfig::PAPER`'s are `SamplerConfig::default()`).
    #[test]
    fn online_seeding_follows_first_observations_and_keeps_caches_exact() {
        let max = 20 * CELL;
        // The paper's rays sampler, its forward model (σ = 3 cells, 1 % outliers, 20 cells),
        // the textbook mapper of `MapperConfig::new(max)`.
        let config = RunConfig {
            cell_mm: CELL,
            ..RunConfig::PAPER.with_max_range_mm(max)
        };
        assert_eq!(config.data, DataTerm::Rays);
        let sizes = Sizes {
            width: 24,
            height: 24,
            rays: 8192,
            scans: 256,
            local: 4096,
        };
        let mut s = Session::new(config, Owned::<u32>::buffers(&sizes)).unwrap();
        let cells = 24 * 24;
        // Unknown starts occupied (init threshold −1): everything is occupied before any scan.
        assert!((0..cells).all(|i| s.gibbs().occupied(i)));
        let pose = Pose {
            x_mm: 1250,
            y_mm: 1250,
            heading: Angle::ZERO,
        };
        let beams: Vec<Beam> = (0..64)
            .map(|i| Beam {
                angle: Angle((i * 1024) as u16),
                range: Range::Hit(700),
            })
            .collect();
        s.step(500);
        let inserted = s.insert(&pose, &beams).unwrap();
        assert_eq!(inserted.rays, 0..64);
        let stats = inserted.stats;
        assert!(stats.cells_hit > 20 && stats.cells_freed > 50);
        for (i, l) in s.log_odds().iter().enumerate() {
            if l.0 != 0 {
                assert_eq!(s.gibbs().occupied(i), l.0 > 0, "cell {i} log-odds {}", l.0);
            }
        }
        // Seeding marked every cache stale (recomputed lazily); after sampling, every cache that
        // was recomputed equals a from-scratch recomputation.
        assert!(s.store().rays().iter().all(|r| r.first_occupied == STALE));
        s.step(3000);
        let before: Vec<u16> = s.store().rays().iter().map(|r| r.first_occupied).collect();
        assert!(before.iter().any(|&f| f != STALE));
        s.gibbs.refresh_rays(&mut s.store, 0..usize::MAX);
        let after: Vec<u16> = s.store().rays().iter().map(|r| r.first_occupied).collect();
        for (b, a) in before.iter().zip(&after) {
            assert!(*b == STALE || b == a, "{b} vs {a}");
        }
        // A second scan from the same pose observes nothing new: only its own rays are
        // refreshed, and already-observed cells keep the sampler's state.
        s.step(2000);
        let sample: Vec<bool> = (0..cells).map(|i| s.gibbs().occupied(i)).collect();
        s.insert(&pose, &beams).unwrap();
        assert_eq!(
            sample,
            (0..cells)
                .map(|i| s.gibbs().occupied(i))
                .collect::<Vec<_>>()
        );
    }
}
