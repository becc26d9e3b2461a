//! The mapping loop's one step, shared by the firmware and the host simulator.
//!
//! `read scan → look up pose → (sort, for the cone model) → insert`. The firmware calls it with
//! its UART-backed sensor; `host-sim` with its synthetic lidar. Same function, same results.
//! [`insert_and_seed`] is the step that keeps an online sampler in sync with the growing map.

use crate::lidar::source::{PoseSource, RangeSensor};
use crate::map::mapper::{Mapper, ScanStats};
use crate::map::sensor_model::InverseModelKind;
use crate::types::geometry::Pose;
use crate::types::scan::ScanBuf;

/// Why a pipeline step failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PipelineError<SE, PE> {
    /// The range sensor failed.
    Sensor(SE),
    /// The pose source failed.
    Pose(PE),
    /// The mapper rejected the scan.
    Map(crate::Error),
}

impl<SE: core::fmt::Display, PE: core::fmt::Display> core::fmt::Display for PipelineError<SE, PE> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PipelineError::Sensor(e) => write!(f, "range sensor: {e}"),
            PipelineError::Pose(e) => write!(f, "pose source: {e}"),
            PipelineError::Map(e) => write!(f, "mapper: {e}"),
        }
    }
}

impl<SE, PE> From<crate::Error> for PipelineError<SE, PE> {
    fn from(e: crate::Error) -> Self {
        PipelineError::Map(e)
    }
}

/// The outcome of one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport {
    /// Pose the scan was inserted at.
    pub pose: Pose,
    /// Beams read from the sensor (including any dropped for lack of buffer space).
    pub beams_read: u32,
    /// Beams the scan buffer had no room for.
    pub beams_overflowed: u32,
    /// What the mapper did.
    pub stats: ScanStats,
}

/// Reads one scan and its pose and integrates it.
pub fn map_next_scan<R, P, S, M, const N: usize>(
    sensor: &mut R,
    poses: &mut P,
    scan: &mut ScanBuf<N>,
    mapper: &mut Mapper<S, M>,
) -> Result<StepReport, PipelineError<R::Error, P::Error>>
where
    R: RangeSensor,
    P: PoseSource,
    S: AsRef<[crate::LogOdds]> + AsMut<[crate::LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
{
    sensor.read_scan(scan).map_err(PipelineError::Sensor)?;
    let pose = poses.current_pose().map_err(PipelineError::Pose)?;
    if matches!(mapper.config().model.kind(), InverseModelKind::Cone { .. }) {
        scan.sort_by_angle();
    }
    let stats = mapper
        .insert_scan(&pose, scan.beams())
        .map_err(PipelineError::Map)?;
    Ok(StepReport {
        pose,
        beams_read: (scan.beams().len() as u32).saturating_add(scan.overflow()),
        beams_overflowed: scan.overflow(),
        stats,
    })
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
pub fn insert_and_seed<S, M, SS, RR, P, B, C, L, K, N>(
    mapper: &mut Mapper<S, M>,
    store: &mut crate::sampler::ray_store::RayStore<SS, RR>,
    gibbs: &mut crate::sampler::gibbs::Gibbs<P, B, C, L, K, N>,
    pose: &Pose,
    beams: &[crate::Beam],
) -> crate::Result<(ScanStats, core::ops::Range<usize>)>
where
    S: AsRef<[crate::LogOdds]> + AsMut<[crate::LogOdds]>,
    M: AsRef<[u32]> + AsMut<[u32]>,
    SS: AsRef<[crate::sampler::ray_store::StoredScan]>
        + AsMut<[crate::sampler::ray_store::StoredScan]>,
    RR: AsRef<[crate::sampler::ray_store::StoredRay]>
        + AsMut<[crate::sampler::ray_store::StoredRay]>,
    P: crate::sampler::gibbs::PatchPrior,
    N: crate::sampler::gibbs::Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[crate::sampler::gibbs::LocalRay]> + AsMut<[crate::sampler::gibbs::LocalRay]>,
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
    gibbs: &'a mut crate::sampler::gibbs::Gibbs<P, B, C, L, K, N>,
    threshold: crate::LogOdds,
    /// Whether the sampler hears of changes at all (change-driven visits or estimate restarts).
    notify: bool,
    seeded: bool,
}

impl<P, B, C, L, K, N> crate::map::mapper::UpdateListener for Seeder<'_, P, B, C, L, K, N>
where
    P: crate::sampler::gibbs::PatchPrior,
    N: crate::sampler::gibbs::Count,
    B: AsRef<[u32]> + AsMut<[u32]>,
    C: AsRef<[N]> + AsMut<[N]>,
    L: AsRef<[crate::sampler::gibbs::LocalRay]> + AsMut<[crate::sampler::gibbs::LocalRay]>,
    K: AsRef<[u32]> + AsMut<[u32]>,
{
    const REPORTS: crate::map::mapper::Reports = crate::map::mapper::Reports::Notable;

    // Out of line: only notable cells get here, and inlined into the sweep its state would
    // crowd the sweep's own out of the Cortex-M4's registers.
    #[inline(never)]
    fn changed(&mut self, index: usize, before: crate::LogOdds, after: crate::LogOdds) {
        if before.0 == 0 {
            self.gibbs.seed(index, after > self.threshold);
            self.seeded = true;
        }
        if self.notify {
            self.gibbs.note_estimate(index, before, after);
        }
    }

    #[inline(always)]
    fn fresh_word(&mut self, word: usize, bits: u32, after: crate::LogOdds) {
        self.gibbs.seed_word(word, bits, after > self.threshold);
        self.seeded = true;
        if self.notify {
            self.gibbs
                .note_estimate_word(word, bits, crate::LogOdds(0), after);
        }
    }

    #[inline(always)]
    fn marked_words(&mut self, first: usize, words: &[u32]) {
        if self.notify {
            self.gibbs.note_marked_words(first, words);
        }
    }
}
