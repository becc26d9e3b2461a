//! The matcher's state for one robot: what a [`crate::Session`] owns to correct odometry with
//! the map, once per scan (see the [module docs](crate::localize), "Using it").
//!
//! The tracker keeps the correction map ← odometry the way ROS keeps `map → odom`: it remembers
//! the last scan's odometry pose and corrected pose; the next scan is predicted by applying the
//! odometry step since then to the corrected pose, matched, and the corrected pose remembered.
//! Poses are integers (mm, [`Angle`]); the algebra is exact up to one mm and one angle unit.

use crate::localize::fuse::Uncertainty;
use crate::localize::{match_scan, prepare_points, MapView, MatchConfig, MatchResult};
use crate::localize::{PointStats, ScanPoint, Verdict};
use crate::types::angle::Angle;
use crate::types::geometry::Pose;
use crate::types::scan::Beam;

/// Scan-to-map pose tracking over a buffer of `N` points (8 bytes each; 512 covers an LD06 turn):
/// the settings, the points and a [`TrackState`].
#[derive(Clone, Debug)]
pub struct Tracker<const N: usize> {
    config: MatchConfig,
    matching: bool,
    points: [ScanPoint; N],
    state: TrackState,
}

/// What [`Tracker::update`] decided for one scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Correction {
    /// The pose to insert the scan with (and to report): if the match is usable
    /// ([`Verdict::is_usable`]) the prediction moved towards it as far as the filter of
    /// [`crate::localize::fuse`] says, else the prediction.
    pub pose: Pose,
    /// The odometry pose the scan came with.
    pub odometry: Pose,
    /// The prediction: the last corrected pose moved by the odometry step.
    pub predicted: Pose,
    /// The match (`None` when matching is off).
    pub matched: Option<MatchResult>,
    /// What became of the beams.
    pub points: PointStats,
}

impl Correction {
    /// The verdict, or `None` when matching is off.
    pub fn verdict(&self) -> Option<Verdict> {
        self.matched.map(|m| m.verdict)
    }

    /// No correction: the scan at its odometry pose (nothing matched).
    pub fn none(odometry: &Pose) -> Self {
        Correction {
            pose: *odometry,
            odometry: *odometry,
            predicted: *odometry,
            matched: None,
            points: PointStats::default(),
        }
    }
}

/// The correction map ← odometry without settings or points (48 bytes): what a
/// [`crate::Session`] keeps, its point buffer lent per scan ([`TrackState::update`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackState {
    /// The last scan's odometry pose and the pose it was mapped with.
    last: Option<(Pose, Pose)>,
    /// How uncertain the last corrected pose is ([`crate::localize::fuse`]).
    uncertainty: Uncertainty,
}

impl TrackState {
    /// No scan seen yet: the next scan's pose is its odometry pose.
    pub const fn new() -> Self {
        TrackState {
            last: None,
            uncertainty: Uncertainty::ZERO,
        }
    }

    /// Forgets the correction (a new map).
    pub fn reset(&mut self) {
        *self = TrackState::new();
    }

    /// The last scan's odometry pose and corrected pose, if any.
    pub fn last(&self) -> Option<(Pose, Pose)> {
        self.last
    }

    /// How uncertain the last corrected pose is.
    pub fn uncertainty(&self) -> &Uncertainty {
        &self.uncertainty
    }

    /// The corrected pose of an odometry pose under the current correction: the last corrected
    /// pose moved by the odometry step since.
    pub fn correct(&self, odometry: &Pose) -> Pose {
        match self.last {
            Some((odo, pose)) => compose(&pose, &between(&odo, odometry)),
            None => *odometry,
        }
    }

    /// One scan ([`Tracker::update`]) with the settings `config`, matching on or off, and
    /// `points` as the scan's point buffer (its first [`PointStats::kept`] entries are
    /// overwritten).
    pub fn update(
        &mut self,
        config: &MatchConfig,
        matching: bool,
        map: &MapView<'_>,
        odometry: &Pose,
        beams: &[Beam],
        points: &mut [ScanPoint],
    ) -> Correction {
        let predicted = self.correct(odometry);
        let mut out = Correction {
            pose: predicted,
            odometry: *odometry,
            predicted,
            matched: None,
            points: PointStats::default(),
        };
        // The first scan of a map defines its frame: its pose is exactly known (ZERO).
        if let Some((odo, _)) = self.last {
            self.uncertainty.predict(&between(&odo, odometry), config);
        }
        if matching {
            let cell = map.geometry().cell_mm();
            out.points = prepare_points(beams, cell, config, points);
            let pts = points.get(..out.points.kept).unwrap_or(&[]);
            let r = match_scan(map, pts, &predicted, config);
            out.pose = self.uncertainty.fuse(&r, config);
            out.matched = Some(r);
        }
        self.last = Some((*odometry, out.pose));
        out
    }
}

impl<const N: usize> Tracker<N> {
    /// A tracker with these settings, matching on, no scan seen yet.
    pub const fn new(config: MatchConfig) -> Self {
        Tracker {
            config,
            matching: true,
            points: [ScanPoint { x: 0, y: 0 }; N],
            state: TrackState::new(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &MatchConfig {
        &self.config
    }

    /// New settings (takes effect at the next scan; the correction is kept).
    pub fn set_config(&mut self, config: MatchConfig) {
        self.config = config;
    }

    /// Matching on or off. Off, the tracker still applies the correction it has, so turning
    /// matching off does not make the pose jump back to raw odometry.
    pub fn set_matching(&mut self, on: bool) {
        self.matching = on;
    }

    /// Whether matching is on.
    pub fn matching(&self) -> bool {
        self.matching
    }

    /// Forgets the correction (a new map): the next scan's pose is its odometry pose.
    pub fn reset(&mut self) {
        self.state.reset();
    }

    /// The last scan's odometry pose and corrected pose, if any.
    pub fn last(&self) -> Option<(Pose, Pose)> {
        self.state.last()
    }

    /// The corrected pose of an odometry pose under the current correction (for poses between
    /// scans, e.g. a live view): the last corrected pose moved by the odometry step since.
    pub fn correct(&self, odometry: &Pose) -> Pose {
        self.state.correct(odometry)
    }

    /// One scan: predicts its pose from `odometry`, matches `beams` (robot frame, as inserted)
    /// against `map` (the map *before* this scan is inserted), and returns the pose to insert
    /// it with. Reads at most `config().max_reads(N)` cells; never panics.
    ///
    /// A robot without odometry passes the same pose (e.g. [`Pose::default`]) every scan: the
    /// prediction is then the last corrected pose (use weak priors and a wide window then:
    /// [`MatchConfig::without_odometry`]).
    pub fn update(&mut self, map: &MapView<'_>, odometry: &Pose, beams: &[Beam]) -> Correction {
        self.state.update(
            &self.config,
            self.matching,
            map,
            odometry,
            beams,
            &mut self.points,
        )
    }
}

/// `(cos, sin)` of a heading as `i128` Q30.
fn rot(a: Angle) -> (i128, i128) {
    let (c, s) = a.cos_sin_q30();
    (i128::from(c), i128::from(s))
}

/// Rounds a Q30 value to an `i32`, saturating.
fn q30_to_i32(v: i128) -> i32 {
    ((v + (1 << 29)) >> 30).clamp(i128::from(i32::MIN), i128::from(i32::MAX)) as i32
}

/// `a⁻¹ ⊕ b`: the motion from `a` to `b` in `a`'s frame (mm; the heading difference).
pub fn between(a: &Pose, b: &Pose) -> Pose {
    let (c, s) = rot(a.heading);
    let dx = i128::from(b.x_mm) - i128::from(a.x_mm);
    let dy = i128::from(b.y_mm) - i128::from(a.y_mm);
    Pose {
        x_mm: q30_to_i32(c * dx + s * dy),
        y_mm: q30_to_i32(c * dy - s * dx),
        heading: b.heading.wrapping_sub(a.heading),
    }
}

/// `a ⊕ d`: the motion `d` (in `a`'s frame) applied to `a`; positions saturate.
pub fn compose(a: &Pose, d: &Pose) -> Pose {
    let (c, s) = rot(a.heading);
    let (dx, dy) = (i128::from(d.x_mm), i128::from(d.y_mm));
    let x = (i128::from(a.x_mm) << 30) + c * dx - s * dy;
    let y = (i128::from(a.y_mm) << 30) + s * dx + c * dy;
    Pose {
        x_mm: q30_to_i32(x),
        y_mm: q30_to_i32(y),
        heading: a.heading.wrapping_add(d.heading),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_undoes_between() {
        let a = Pose::new(1200, -350, Angle::from_degrees(37.0));
        let b = Pose::new(-800, 2210, Angle::from_degrees(-101.0));
        let d = between(&a, &b);
        let back = compose(&a, &d);
        assert!((back.x_mm - b.x_mm).abs() <= 1 && (back.y_mm - b.y_mm).abs() <= 1);
        assert_eq!(back.heading, b.heading);
        // A quarter turn: forward 1 m from (0, 0) facing +y ends at (0, 1000).
        let q = compose(
            &Pose::new(0, 0, Angle::QUARTER),
            &Pose::new(1000, 0, Angle::ZERO),
        );
        assert!(q.x_mm.abs() <= 1 && (q.y_mm - 1000).abs() <= 1, "{q:?}");
    }

    #[test]
    fn extreme_poses_saturate() {
        let a = Pose::new(i32::MIN, i32::MAX, Angle(12345));
        let b = Pose::new(i32::MAX, i32::MIN, Angle(54321));
        let d = between(&a, &b);
        let _ = compose(&b, &d);
        let _ = compose(&a, &Pose::new(i32::MAX, i32::MAX, Angle::HALF));
    }
}
