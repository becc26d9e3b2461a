//! Pose correction on the robot: scan-to-map matching against the robot's own log-odds map, so
//! that wheel odometry is enough (issue 39). A layer above [`crate::map`]: imports
//! [`crate::types`], [`crate::error`], [`crate::config`] ([`crate::config::OdometryNoise`]) and
//! [`crate::map`] only (not the sampler, lidar, wire or
//! session layers), so a [`crate::Session`] can own it.
//!
//! ## Using it (what a `Session` does once per scan)
//! ```
//! use ogm_core::localize::{MapView, MatchConfig, Tracker};
//! use ogm_core::{Angle, Beam, GridGeometry, LogOdds, Pose, Range};
//!
//! // Owned by the session: settings, a point buffer (8 bytes a point), the correction.
//! let mut tracker: Tracker<512> = Tracker::new(MatchConfig::default());
//! let geometry = GridGeometry::new(64, 64, 50, -1600, -1600).unwrap();
//! let cells = vec![LogOdds::ZERO; geometry.len()];
//! let beams = [Beam { angle: Angle::ZERO, range: Range::Hit(1000) }];
//! // Per scan: the map *before* inserting it, the odometry pose, the scan's beams.
//! let map = MapView::new(&cells, geometry).unwrap();
//! let c = tracker.update(&map, &Pose::new(10, 0, Angle::ZERO), &beams);
//! // Insert with `c.pose`; report `c.pose`, `c.verdict()` and `c.matched` (quality, work).
//! assert_eq!(c.pose, c.predicted); // one beam on an empty map: cannot tell, odometry kept
//! ```
//! * [`Tracker::update`]`(map, odometry pose, beams) → `[`Correction`]: the corrected pose to
//!   insert with (if the match is [`Verdict::is_usable`], the prediction moved towards it as far
//!   as the filter of [`fuse`] says; else the prediction), the prediction, the [`MatchResult`]
//!   (verdict, [`Quality`], [`Work`]) and what became of the beams.
//! * The tracker holds map ← odometry ([`Tracker::correct`] maps any odometry pose, e.g. for a
//!   live view between scans); [`Tracker::set_matching`] turns matching off (the correction
//!   stays); [`Tracker::reset`] forgets it (new map).
//! * Work per call is bounded: at most [`MatchConfig::max_reads`]`(N)` cell reads
//!   ([`MatchConfig::budget_reads`] caps it); memory is the tracker itself, no allocation.
//! * [`odometry`] is a seeded wheel-odometry model for simulators and evaluations (not used by
//!   the robot).
//!
//! ## What it does
//! [`match_scan`] takes a read-only map ([`MapView`]: the `LogOdds` cells and their
//! [`crate::GridGeometry`]), a scan already turned into points ([`prepare_points`], robot frame,
//! caller memory) and the pose odometry predicts, and returns a [`MatchResult`]: the corrected
//! pose, a [`Quality`] and a [`Verdict`] that says whether the correction can be trusted. When the
//! matcher cannot tell (too few points, no overlap with the map, a correction outside the search
//! window) the caller keeps mapping on odometry; when the map leaves one direction open (a
//! corridor, a single wall) or the rotation, the weak prior on the prediction has kept that part
//! near where odometry put it, and the filter of [`fuse`] takes next to nothing of it.
//!
//! ## How: NDT from the occupancy grid, Gauss–Newton, coarse to fine
//! * **Weights.** A cell's log-odds `l` becomes a weight in `[0, 1]` (Q15) by a ramp: 0 at or
//!   below [`MatchConfig::floor`] (free and unknown cells say nothing about where a wall is), 1 at
//!   or above [`MatchConfig::occupied`].
//! * **The map near a point as a normal distribution** (NDT, Biber & Straßer 2003, computed per
//!   point from the grid rather than stored per cell): the weighted centroid and covariance of
//!   the cells within [`MatchConfig::radius`] cells of the point. The point's residual is its
//!   offset to the centroid, measured with the inverse covariance — across a wall that is the
//!   point-to-line distance, along it almost nothing — and a Cauchy weight
//!   ([`MatchConfig::cauchy_q8`]) damps points far from anything that looks like their wall.
//!   Unlike the interpolated map value of Hector SLAM (Kohlbrecher et al. 2011), whose slope
//!   vanishes on a wall's ridge or plateau, this residual is zero at the optimum with a
//!   non-vanishing Jacobian, so Gauss–Newton converges there (NOTES-39.md has the measurements).
//! * **Pyramid without memory.** A level-`k` cell is a `2^k × 2^k` block of grid cells whose
//!   weight is the block's maximum (max-pooling keeps one-cell-thin walls, as Cartographer's
//!   precomputation grids do), computed on the fly — a 256 × 256 map has no RAM to spare for a
//!   pooled copy — so coarse levels use every `2^(k + coarse_thin)`-th point only.
//! * **Heading search first.** Wheel odometry's error is mostly the heading, and a few degrees
//!   put far points out of every window's reach. Before Gauss–Newton, `2·`[`MatchConfig::turn_search`]
//!   ` + 1` headings one cell at the lever apart (within [`MatchConfig::max_turn`]) are scored
//!   on the grid max-pooled 2 × 2, translation kept; the best one is where Gauss–Newton starts.
//! * **Then a filter** ([`fuse`]): the match is one measurement with its own error
//!   ([`MatchConfig::match_sigma_mm`], [`MatchConfig::match_sigma_mdeg`]), odometry another
//!   ([`MatchConfig::odometry`]); a Kalman filter on the corrected pose weighs them,
//!   so a match's location-dependent bias is averaged over scans instead of walked into the map.
//! * **Gauss–Newton with the prediction as a prior.** From [`MatchConfig::levels`] down to the
//!   grid, up to [`MatchConfig::iterations`] steps per level solve `(H + Λ) δ = b − Λ ξ` with
//!   `H = Σ JᵀΩJ`, `b = Σ JᵀΩμ` in `i64`. `Λ` weighs the odometry prediction
//!   ([`MatchConfig::prior_trans_q8`], [`MatchConfig::prior_rot`]): wheel odometry measures a
//!   step's translation well and its heading badly, so the match corrects mostly the heading and
//!   what the heading error did; in a corridor the open direction stays where odometry put it.
//!   The 3 × 3 system is solved by Cramer's rule after scaling into 19 bits; the rotation is
//!   solved as `φ = θ·2^s` cells (`2^s` ≈ the points' mean distance) so that the three unknowns
//!   have comparable scale. A step moves at most one cell of its level; the pose stays inside the
//!   search window ([`MatchConfig::max_shift_mm`], [`MatchConfig::max_turn`]).
//! * **Quality (Olson 2009, "Real-time correlative scan matching", in miniature).** At the final
//!   pose the score `S = Σ weight` (nearest cell) is compared with the score of the same points
//!   moved by [`MatchConfig::probe_mm`] in four directions (±) and turned by the angle that moves
//!   a point at the mean distance as far. How much score each displacement loses fits a quadratic
//!   form whose smaller eigenvalue is the *weakest* translation constraint and whose eigenvector
//!   is the direction a corridor leaves open; the turn's loss is the rotation constraint. Small
//!   losses mean the map cannot tell: [`Verdict::Ambiguous`], [`Verdict::AmbiguousRotation`].
//!
//! ## Work bound
//! The unit of work is a cell read. A Gauss–Newton pass at level `k` over `n` points reads at most
//! `(2r + 1)² · 4^k · ⌈n / s⌉` cells for a window radius `r` and a point stride `s`
//! ([`MatchConfig::radius_at`], [`MatchConfig::stride_at`], [`MatchConfig::pass_reads`]); the quality probes read `14 n`
//! ([`MatchConfig::probe_reads`]), the heading search `4 · (2·turn_search + 1) · ⌈n / stride_at(1)⌉`
//! ([`MatchConfig::search_reads`]). [`MatchConfig::budget_reads`] caps the search and the
//! passes together: the search is skipped if it alone exceeds the budget, a pass that does not
//! fit in what is left is not started, and a coarse pass also leaves room for one pass on the
//! grid (a match the budget cuts short skips coarse iterations, not the final level). So a call
//! reads at most `budget_reads + 14 n` cells whatever the input; [`MatchConfig::max_reads`] gives
//! the bound for
//! `n` points and [`Work::reads`] what a call used. Per read the M4 spends a few instructions,
//! per point and pass a few tens (`NOTES-39.md` has the measured instructions per scan).
//!
//! ## Fixed point
//! Positions are in 1/256 cell ([`SUB`]) relative to the grid's origin, headings in 1/256 of an
//! [`crate::Angle`] unit (2²⁴ per turn), weights Q15, inverse covariances Q12 per cell², the
//! normal equations `i64` (Q28). Every
//! value derived from input is clamped or saturated (points beyond [`MAX_POINT_SUB`], poses far
//! outside the grid: no overlap), so no input panics or overflows. [`mod@reference`] (feature
//! `reference`) is the same algorithm in `f64`, which the tests compare against.

pub mod field;
pub mod fuse;
pub mod matcher;
pub mod odometry;
pub mod points;
mod solve;
pub mod tracker;

#[cfg(feature = "reference")]
pub mod reference;

pub use field::MapView;
pub use matcher::{match_scan, MatchResult, Quality, Verdict, Work};
pub use points::{prepare_points, PointStats, ScanPoint};
pub use tracker::{Correction, TrackState, Tracker};

use crate::config::OdometryNoise;
use crate::error::{Error, Result};
use crate::types::angle::Angle;
use crate::types::fixed::LogOdds;

/// Sub-cell resolution: positions are in `1/SUB` cell.
pub const SUB: i32 = 256;

/// Points farther than this from the robot (in sub-cells, i.e. 65 536 cells) are dropped: the
/// widest grid has 65 535 columns, so such a point can never be compared with a cell, and the
/// bound keeps every product in `i64`.
pub const MAX_POINT_SUB: i64 = 1 << 24;

/// The coarsest pyramid level: a level-3 cell is 8 × 8 grid cells and a sample reads 256 cells.
pub const MAX_LEVEL: u8 = 3;

/// At most this many points are matched per call (more are ignored): keeps every `i64` sum of
/// the Gauss–Newton system below 2⁶⁰.
pub const MAX_POINTS: usize = 8192;

/// The matcher's settings. All distances in mm, so one config serves any cell size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MatchConfig {
    /// Hits closer than this are not matched (robot body, sensor dead zone).
    pub min_range_mm: u32,
    /// Hits at or beyond this are not matched (far points are noisy and make the rotation
    /// dominate the system).
    pub max_range_mm: u32,
    /// Added to every hit's range before it becomes a point (after the range filters): where
    /// the map's occupied cells lie behind a reading. 0 for a map whose hits mark the reading's
    /// own cell; a face-band map (`crate::config::RunConfig::face_band`) puts its occupied
    /// mass about a band's σ behind the reading, and matching the reading itself would pull
    /// every point that far into the wall.
    pub hit_offset_mm: u16,
    /// A hit closer than this to the last point kept (in the order of the beams) is skipped:
    /// near the robot the beams crowd, and evenly spread points weigh every wall alike.
    pub min_spacing_mm: u32,
    /// Log-odds at or below which a cell weighs 0 (free and unknown cells).
    pub floor: LogOdds,
    /// Log-odds at or above which a cell weighs 1; must exceed `floor`.
    pub occupied: LogOdds,
    /// Coarsest pyramid level (0..=[`MAX_LEVEL`]); the match starts there.
    pub levels: u8,
    /// Radius of the window of cells a point's distribution is taken from at the grid's own
    /// level, cells (1..=[`field::MAX_RADIUS`]): the reach of the final match.
    pub radius: u8,
    /// The same at the coarse levels (≥ 1), in their cells. Smaller than `radius` because a
    /// coarse window reads `4^level` times as many grid cells.
    pub coarse_radius: u8,
    /// Coarse levels use every `2^(level + coarse_thin)`-th point (the grid's level uses all):
    /// a coarse pass only has to bring the pose into the next level's reach, and its windows
    /// read `4^level` grid cells each.
    pub coarse_thin: u8,
    /// Gauss–Newton steps per level at most (a level ends early once a step is below 1/16 cell).
    pub iterations: u8,
    /// Added to each window's covariance, cells² of its level, Q8 (plus a cell's own extent,
    /// 1/12): bounds the inverse covariance across a straight wall.
    pub reg_q8: u16,
    /// Cauchy scale c² (cells² of the level, Q8): a point at Mahalanobis distance d weighs
    /// `c² / (c² + d²)`.
    pub cauchy_q8: u16,
    /// Information of the prediction's translation, per point matched, per cell² (Q8).
    pub prior_trans_q8: u16,
    /// Information of the prediction's heading, per point matched, per rad².
    pub prior_rot: u16,
    /// The correction may move the pose this far from the prediction (per axis).
    pub max_shift_mm: u32,
    /// The correction may turn the pose this far from the prediction.
    pub max_turn: Angle,
    /// Headings tried each side of the prediction before Gauss–Newton (0 = none), one step
    /// apart (the turn that moves a point at the points' mean distance by one cell) and within
    /// `max_turn`: the best-scoring one (points on the grid max-pooled 2 × 2) is where
    /// Gauss–Newton starts. Wheel odometry's error is mostly
    /// the heading, and a heading error of a few degrees moves far points out of every window's
    /// reach, where Gauss–Newton only finds part of the way back.
    pub turn_search: u8,
    /// Displacement of the quality probes.
    pub probe_mm: u32,
    /// Fewer points than this: [`Verdict::TooFewPoints`].
    pub min_points: u16,
    /// In the last Gauss–Newton pass at least this share (‰) of the points must have occupied
    /// cells within the window ([`Quality::overlap`]), else [`Verdict::NoOverlap`].
    pub min_overlap_permille: u16,
    /// Log-odds at or below which a cell counts as observed free, for [`Quality::contradicted`].
    pub free: LogOdds,
    /// At most this share (‰) of the points may lie where the map has seen through, else
    /// [`Verdict::Contradicted`].
    pub max_contradicted_permille: u16,
    /// Moving the points by `probe_mm` along the weakest direction must lose at least this share
    /// (‰) of the score, else [`Verdict::Ambiguous`].
    pub min_drop_permille: u16,
    /// Turning the points by the probe angle must lose at least this share (‰) of the score,
    /// else [`Verdict::AmbiguousRotation`].
    pub min_turn_drop_permille: u16,
    /// Cell reads allowed per call for the heading search and the Gauss–Newton passes (see the
    /// module docs, "Work bound"); 0 = no limit.
    pub budget_reads: u32,
    /// σ of the match's position per axis ([`fuse`]: how far a usable match moves the
    /// prediction); 0 = no filter, the match is the pose (a robot without odometry).
    pub match_sigma_mm: u16,
    /// σ of the match's heading, millidegrees ([`fuse`]).
    pub match_sigma_mdeg: u16,
    /// The robot's odometry noise ([`fuse`]: the filter's process noise).
    pub odometry: OdometryNoise,
}

impl Default for MatchConfig {
    /// Settings measured on the shared CARMEN logs at 5 cm cells (docs/results.md, "Odometry
    /// and scan matching on real logs"); the filter's match σ, 10 mm and 0.13°, did best there
    /// (0.26° did worse at 100 scans: `match_eval --seeds 1,…,6`). A session derives its own
    /// from the sensor's σ (`RunConfig::match_config`).
    fn default() -> Self {
        MatchConfig {
            min_range_mm: 100,
            max_range_mm: 20_000,
            hit_offset_mm: 0,
            min_spacing_mm: 45,
            floor: LogOdds(0),
            occupied: LogOdds(2048),
            levels: 1,
            radius: 2,
            coarse_radius: 2,
            coarse_thin: 1,
            iterations: 6,
            reg_q8: 128,
            cauchy_q8: 1024,
            prior_trans_q8: 16,
            prior_rot: 25,
            max_shift_mm: 300,
            max_turn: Angle(1820), // 10°
            turn_search: 4,
            probe_mm: 100,
            min_points: 30,
            min_overlap_permille: 150,
            free: LogOdds(-2048),
            max_contradicted_permille: 700,
            min_drop_permille: 150,
            min_turn_drop_permille: 150,
            budget_reads: 50_000,
            match_sigma_mm: 10,
            match_sigma_mdeg: 130,
            odometry: OdometryNoise::CHEAP_ROBOT,
        }
    }
}

impl MatchConfig {
    /// These settings for a robot without odometry (every scan's "odometry" the same pose, e.g.
    /// a board powered without a host): the prediction is then where the last scan was, so its
    /// priors are a quarter of the defaults' and the match is taken as it is, not filtered
    /// ([`MatchConfig::match_sigma_mm`] 0) — the match, not the prediction, decides how far the
    /// robot moved (Hector SLAM's setting). The search window stays: a robot that moves more
    /// than `max_shift_mm` or turns more than `max_turn` between two scans is lost.
    #[must_use]
    pub const fn without_odometry(self) -> Self {
        MatchConfig {
            prior_trans_q8: self.prior_trans_q8 / 4,
            prior_rot: self.prior_rot / 4,
            match_sigma_mm: 0,
            ..self
        }
    }

    /// Checks the settings: `floor < occupied`, `levels ≤ MAX_LEVEL`, both radii in
    /// `1..=MAX_RADIUS`, a non-empty range.
    pub fn validate(&self) -> Result<()> {
        if self.floor.0 >= self.occupied.0
            || self.levels > MAX_LEVEL
            || !(1..=field::MAX_RADIUS).contains(&self.radius)
            || !(1..=field::MAX_RADIUS).contains(&self.coarse_radius)
            || self.min_range_mm >= self.max_range_mm
        {
            return Err(Error::InvalidModel);
        }
        Ok(())
    }

    /// The window radius at `level`: `radius` at 0, `coarse_radius` above (clamped to
    /// `1..=MAX_RADIUS`).
    pub fn radius_at(&self, level: u8) -> u8 {
        let r = if level == 0 {
            self.radius
        } else {
            self.coarse_radius
        };
        r.clamp(1, field::MAX_RADIUS)
    }

    /// The point stride at `level`: 1 at 0, `2^(level + coarse_thin)` above (at most 2^8).
    pub fn stride_at(&self, level: u8) -> usize {
        if level == 0 {
            1
        } else {
            1 << (u32::from(level.min(MAX_LEVEL)) + u32::from(self.coarse_thin.min(5)))
        }
    }

    /// Cell reads of one Gauss–Newton pass at `level` over `n` points.
    pub fn pass_reads(&self, level: u8, n: usize) -> u64 {
        let level = u32::from(level.min(MAX_LEVEL));
        let stride = self.stride_at(level as u8);
        let side = 1 + 2 * u64::from(self.radius_at(level as u8));
        ((side * side) << (2 * level)) * n.div_ceil(stride) as u64
    }

    /// Cell reads of the heading search over `n` points: `2·turn_search + 1` headings, every
    /// `stride_at(1)`-th point, four cells each; 0 when it is off or does not fit the budget
    /// (it is then skipped).
    pub fn search_reads(&self, n: usize) -> u64 {
        if self.turn_search == 0 {
            return 0;
        }
        let n = n.min(MAX_POINTS);
        let reads =
            (2 * u64::from(self.turn_search) + 1) * 4 * n.div_ceil(self.stride_at(1)) as u64;
        if self.budget_reads != 0 && reads > u64::from(self.budget_reads) {
            return 0;
        }
        reads
    }

    /// Cell reads of the quality probes over `n` points (the score at the pose, four
    /// directions ±, two turns, and three cells along each beam for [`Quality::contradicted`]).
    pub fn probe_reads(n: usize) -> u64 {
        14 * n as u64
    }

    /// The most cells a call over `n` points reads: every level's iterations in full, or the
    /// budget if that is smaller, plus the probes.
    pub fn max_reads(&self, n: usize) -> u64 {
        let n = n.min(MAX_POINTS);
        let passes: u64 = (0..=self.levels.min(MAX_LEVEL))
            .map(|k| u64::from(self.iterations) * self.pass_reads(k, n))
            .sum();
        let mut work = passes + self.search_reads(n);
        if self.budget_reads != 0 {
            work = work.min(u64::from(self.budget_reads));
        }
        work + MatchConfig::probe_reads(n)
    }
}
