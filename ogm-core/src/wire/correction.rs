//! What a scan report says about the pose the scan was mapped at (wire version 7): the
//! odometry pose it came with, and the scan matcher's verdict and quality
//! ([`crate::localize`]), compactly.

use serde::{Deserialize, Serialize};

use crate::types::angle::Angle;

/// The scan matcher's verdict as the wire carries it (the localize layer's `Verdict`, which the
/// wire layer does not import, plus [`MatchVerdict::Off`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MatchVerdict {
    /// Correction is off: the scan was mapped at its pose as it came.
    #[default]
    Off,
    /// The map constrained every direction and the rotation: the corrected pose was used.
    Trusted,
    /// One direction of translation was open (a corridor, a single wall), along `weak_axis`
    /// (world frame, an axis): that part of the pose is odometry's, the rest corrected.
    Ambiguous {
        /// The direction the map left open.
        weak_axis: Angle,
    },
    /// The rotation was open: odometry's heading, the translation corrected.
    AmbiguousRotation,
    /// The matcher could not tell (a direction and the rotation open): odometry used.
    Unconstrained,
    /// Too few points (a lidar that sees nothing): odometry used.
    TooFewPoints,
    /// Too few points on the map (a new area): odometry used.
    NoOverlap,
    /// The correction reached the edge of the search window (odometry jumped): odometry used.
    OutOfWindow,
    /// The map has seen through too many of the points (odometry jumped, the world changed):
    /// odometry used.
    Contradicted,
}

impl MatchVerdict {
    /// Whether the scan was mapped at a corrected pose (trusted or ambiguous), not at the
    /// odometry prediction.
    pub fn corrected(&self) -> bool {
        matches!(
            self,
            MatchVerdict::Trusted
                | MatchVerdict::Ambiguous { .. }
                | MatchVerdict::AmbiguousRotation
        )
    }

    /// Whether the matcher could not tell (the scan was mapped on odometry).
    pub fn cannot_tell(&self) -> bool {
        !matches!(self, MatchVerdict::Off) && !self.corrected()
    }
}

/// How the scan's pose was found: the scan matcher's verdict and the quality it rests on.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CorrectionReport {
    /// The verdict ([`MatchVerdict::Off`] when correction is off).
    pub verdict: MatchVerdict,
    /// The robot has no odometry ([`crate::config::PoseInput::Fixed`]) and tracks itself from
    /// matching alone.
    pub without_odometry: bool,
    /// Points matched (after the range and spacing filters and the buffer's thinning).
    pub points: u16,
    /// Share (‰) of the points that had occupied cells within reach: how much of the scan
    /// the map explains.
    pub overlap: u16,
    /// Share (‰) of the score lost by moving the points along the weakest direction (small:
    /// that direction is open).
    pub drop_weak: u16,
    /// Share (‰) of the score lost by turning the points (small: the rotation is open).
    pub drop_turn: u16,
    /// Map cells the matcher read (its work).
    pub reads: u32,
}
