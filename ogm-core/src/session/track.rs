//! Pose correction in the session: the scan matcher ([`crate::localize`]) run against the
//! session's own log-odds map before each scan is inserted ([`Session::correct`]), its points
//! kept in the mapper's marks, and what the scan report says about it ([`correction_report`]).
//!
//! The points need 4 KiB for an LD06 turn, which the nRF52840 does not have to spare. The
//! mapper's marks (one bit per cell: 8 KiB on a 256 × 256 grid) are zero between scans and only
//! used inside an insert, so the matcher borrows them ([`MarkWords::points`]) and zeroes what it
//! wrote before the insert: no RAM of its own. On the host the points are a `Vec` of their own.

use super::{Session, Storage};
use crate::config::PoseInput;
use crate::localize::{Correction, MapView, ScanPoint, Verdict};
use crate::types::geometry::Pose;
use crate::types::scan::Beam;
use crate::wire::{CorrectionReport, MatchVerdict};

/// The most points the session's matcher uses per scan (8 bytes each): an LD06 turn (~450
/// beams) fits; more are thinned evenly ([`crate::localize::prepare_points`]). A constant, so
/// that the firmware and the host replay match the same points.
pub const TRACK_POINTS: usize = 512;

/// The mapper's marks, and the scan matcher's point buffer, which may be the same memory.
pub trait MarkWords: AsRef<[u32]> + AsMut<[u32]> {
    /// The points buffer: either the marks' own words seen as points (a board's `static`,
    /// two words a point), or separate memory. The session writes at most [`TRACK_POINTS`]
    /// points between inserts and sets them to zero again before the mapper runs, so the
    /// words the mapper sees are zero as it left them. Fewer than [`TRACK_POINTS`] (a small
    /// grid's marks) only means fewer points matched.
    fn points(&mut self) -> &mut [ScanPoint];
}

/// Host marks ([`super::Owned`]): the words, and [`TRACK_POINTS`] points of their own.
#[cfg(feature = "alloc")]
#[derive(Clone, Debug, Default)]
pub struct OwnedMarks {
    /// The mapper's words.
    pub words: alloc::vec::Vec<u32>,
    /// The matcher's points.
    pub points: alloc::vec::Vec<ScanPoint>,
}

#[cfg(feature = "alloc")]
impl OwnedMarks {
    /// `words` zeroed words and [`TRACK_POINTS`] points.
    pub fn new(words: usize) -> Self {
        OwnedMarks {
            words: alloc::vec![0; words],
            points: alloc::vec![ScanPoint::default(); TRACK_POINTS],
        }
    }
}

#[cfg(feature = "alloc")]
impl AsRef<[u32]> for OwnedMarks {
    fn as_ref(&self) -> &[u32] {
        &self.words
    }
}

#[cfg(feature = "alloc")]
impl AsMut<[u32]> for OwnedMarks {
    fn as_mut(&mut self) -> &mut [u32] {
        &mut self.words
    }
}

#[cfg(feature = "alloc")]
impl MarkWords for OwnedMarks {
    fn points(&mut self) -> &mut [ScanPoint] {
        &mut self.points
    }
}

impl<S: Storage> Session<S> {
    /// The pose to map a scan taken at `odometry` with: with
    /// [`crate::config::PoseCorrection::Match`], the
    /// last corrected pose moved by the odometry step since, matched against the map as it is
    /// now (before the scan); the match's pose if it can be trusted, else that prediction
    /// ([`crate::localize::TrackState::update`]). With correction off, `odometry` as
    /// it is. Work: at most [`crate::localize::MatchConfig::max_reads`]`(`[`TRACK_POINTS`]`)`
    /// cell reads; never panics.
    ///
    /// [`Session::insert`] calls it; call it yourself first only with a rolling window, whose
    /// shift must follow the corrected pose ([`Session::shift_for`]`(&correction.pose)`): the
    /// insert with the same `odometry` then uses this correction instead of matching again.
    pub fn correct(&mut self, odometry: &Pose, beams: &[Beam]) -> Correction {
        let c = match self.config.match_config() {
            None => Correction::none(odometry),
            Some(cfg) => {
                let geometry = self.geometry();
                let (grid, marks) = self.mapper.grid_and_marks();
                let all = marks.points();
                let cap = all.len().min(TRACK_POINTS);
                let points = all.get_mut(..cap).unwrap_or(&mut []);
                let c = match MapView::new(grid.cells(), geometry) {
                    Ok(map) => self.track.update(&cfg, true, &map, odometry, beams, points),
                    Err(_) => Correction::none(odometry),
                };
                // What `prepare_points` wrote (all candidates up to the buffer, before its
                // thinning pass) back to zero: the mapper's marks, when they are the same words.
                let written = c.points.candidates.min(cap);
                if let Some(used) = points.get_mut(..written) {
                    used.fill(ScanPoint::default());
                }
                c
            }
        };
        self.pending = Some(c);
        c
    }

    /// The correction map ← odometry: the last scan's odometry pose and the pose it was mapped
    /// at (`None` before the first scan or with correction off).
    pub fn last_correction(&self) -> Option<(Pose, Pose)> {
        self.track.last()
    }

    /// What the scan report says about `c` ([`CorrectionReport`]).
    pub fn correction_report(&self, c: &Correction) -> CorrectionReport {
        correction_report(c, self.config.poses == PoseInput::Fixed)
    }
}

/// The wire's report of a correction (the default, [`MatchVerdict::Off`], when nothing was
/// matched); `without_odometry` when the robot has none.
pub fn correction_report(c: &Correction, without_odometry: bool) -> CorrectionReport {
    let Some(m) = c.matched else {
        return CorrectionReport::default();
    };
    let verdict = match m.verdict {
        Verdict::Trusted => MatchVerdict::Trusted,
        Verdict::Ambiguous { weak_axis } => MatchVerdict::Ambiguous { weak_axis },
        Verdict::AmbiguousRotation => MatchVerdict::AmbiguousRotation,
        Verdict::Unconstrained => MatchVerdict::Unconstrained,
        Verdict::TooFewPoints => MatchVerdict::TooFewPoints,
        Verdict::NoOverlap => MatchVerdict::NoOverlap,
        Verdict::OutOfWindow => MatchVerdict::OutOfWindow,
        Verdict::Contradicted => MatchVerdict::Contradicted,
    };
    CorrectionReport {
        verdict,
        without_odometry,
        points: m.quality.points,
        overlap: m.quality.overlap,
        drop_weak: m.quality.drop_weak,
        drop_turn: m.quality.drop_turn,
        reads: m.work.reads,
    }
}
