//! What the listener counts and reports: [`ListenStats`] (`status.json`), the [`Gap`]s in the
//! scan numbers and the [`Notice`]s worth a line of their own.

use std::fmt;

use ogm_core::config::RunConfig;
use ogm_core::wire::{Counters, DeviceError, Done};
use serde::Serialize;

use crate::stream::OwnedHello;

/// Scans by what the robot's scan matcher decided (`ScanReport::correction`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CorrectionCounts {
    /// Correction off: mapped at the pose as sent.
    pub off: u64,
    /// Mapped at a corrected pose (trusted, or ambiguous in one direction or the rotation).
    pub corrected: u64,
    /// The matcher could not tell (a new area, too few points, an odometry jump…): mapped at
    /// the odometry prediction.
    pub cannot_tell: u64,
    /// Scans of a robot without odometry, tracking itself from matching alone.
    pub without_odometry: u64,
}

impl CorrectionCounts {
    /// Counts one scan's report.
    pub fn add(&mut self, c: &ogm_core::wire::CorrectionReport) {
        use ogm_core::wire::MatchVerdict;
        match c.verdict {
            MatchVerdict::Off => self.off += 1,
            v if v.corrected() => self.corrected += 1,
            _ => self.cannot_tell += 1,
        }
        self.without_odometry += u64::from(c.without_odometry);
    }
}

/// Everything the listener counts (written to `status.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct ListenStats {
    /// Bytes through the decoder (capture replay included).
    pub bytes: u64,
    /// Good frames.
    pub frames: u64,
    /// Frames dropped: bad COBS, CRC-32, schema version or postcard (a frame cut by a
    /// disconnect is one of these).
    pub bad_frames: u64,
    /// Of `bad_frames`, those whose CRC-32 did not match.
    pub crc_errors: u64,
    /// Runs of bytes longer than any frame without a `0x00` (skipped).
    pub oversized: u64,
    /// Bytes outside good frames (bad frames, oversized runs).
    pub garbage_bytes: u64,
    /// Robot boots seen (`Hello`); each starts a new map.
    pub hellos: u64,
    /// `Hello`s refused (a grid larger than [`MAX_CELLS`](super::MAX_CELLS) or empty).
    pub bad_hellos: u64,
    /// Scan reports received.
    pub scans_seen: u64,
    /// Sequence number of the last scan report.
    pub last_seq: Option<u32>,
    /// Scans whose report never arrived (sum of the gaps).
    pub scans_missed: u64,
    /// The gaps (the last [`MAX_GAPS_KEPT`](super::MAX_GAPS_KEPT)).
    pub gaps: Vec<Gap>,
    /// Scan numbers that went backwards without a new `Hello` (the host restarted its count).
    pub seq_restarts: u64,
    /// Tiles applied.
    pub tiles: u64,
    /// Tiles dropped: of the wrong size, or too far away (`tiles_refused`).
    pub bad_tiles: u64,
    /// Of `bad_tiles`, those that would have grown the building past
    /// [`MAX_BUILDING_CELLS`](crate::stream::MAX_BUILDING_CELLS) cells.
    pub tiles_refused: u64,
    /// The robot's last rolling-window report (wire v6; none with a fixed grid).
    pub window: Option<ogm_core::wire::WindowReport>,
    /// Stored tiles sent back to the robot (their `Restore` parts: 12 each at 16-cell tiles),
    /// as its window came back to them.
    pub tiles_sent_back: u64,
    /// Regions the robot came back to: tiles restored, merged, unsure (the map's count).
    pub revisits: Option<crate::stream::Revisits>,
    /// What the robot's pose correction did with the scans reported (wire v7).
    pub corrections: CorrectionCounts,
    /// Scan ranges of the wrong size (dropped).
    pub bad_ranges: u64,
    /// Scans whose ranges were placed at their report's pose (recorded, shown live).
    pub ranges_placed: u64,
    /// Points of the latest of them.
    pub scan_points: usize,
    /// `Error` messages from the robot.
    pub device_errors: u64,
    /// The last of them.
    pub last_device_error: Option<DeviceError>,
    /// The robot's own counters (its last `Counters`).
    pub robot: Option<Counters>,
    /// The robot's `Done`, once it came.
    pub done: Option<Done>,
    /// The robot's `Hello`.
    pub hello: Option<OwnedHello>,
    /// The settings the robot runs with (its `Configured`).
    pub config: Option<RunConfig>,
    /// Times the device was reopened after an error (unplug/replug), by this listener.
    pub reconnects: u64,
    /// Seconds without an open device (between a loss and the reopen), this listener.
    pub disconnected_secs: f64,
    /// Times a listener resumed this capture (restarts after a kill or an exit).
    pub restarts: u64,
    /// Host messages (lines) sent by this listener.
    pub sent: u64,
    /// Saves by this listener.
    pub saves: u64,
}

/// Scans `first..=last` were never reported to the listener.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Gap {
    /// First missing sequence number.
    pub first: u32,
    /// Last missing sequence number.
    pub last: u32,
}

impl Gap {
    /// Scans missing.
    pub fn len(&self) -> u64 {
        u64::from(self.last - self.first) + 1
    }

    /// Never true (a gap has at least one scan); for clippy's `len_without_is_empty`.
    pub fn is_empty(&self) -> bool {
        false
    }
}

/// Something worth a line of its own.
#[derive(Clone, Debug, PartialEq)]
pub enum Notice {
    /// The robot booted: a new map.
    Hello(OwnedHello),
    /// The robot took its settings.
    Configured(RunConfig),
    /// Scans were missed.
    Gap(Gap),
    /// The first good frame after a reconnect or a restart, after this many garbage bytes (the
    /// frame the cut interrupted included).
    Resynced(u64),
    /// The robot reported an error.
    DeviceError(DeviceError),
    /// The robot finished its run.
    Done(Done),
    /// Something odd (a refused `Hello`, a tile off the grid, no `Hello` yet, …).
    Warning(String),
}

impl fmt::Display for Notice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Notice::Hello(h) => write!(
                f,
                "robot: {} on {}, {}x{} grid, {}-cell tiles (a new map)",
                h.firmware, h.board, h.width, h.height, h.tile_edge
            ),
            Notice::Configured(c) => write!(
                f,
                "robot configured: {} mm cells, origin ({}, {}) mm",
                c.cell_mm, c.origin_x_mm, c.origin_y_mm
            ),
            Notice::Gap(g) if g.first == g.last => write!(f, "missed scan {}", g.first),
            Notice::Gap(g) => write!(
                f,
                "missed scans {}..={} ({} scans)",
                g.first,
                g.last,
                g.len()
            ),
            Notice::Resynced(n) => write!(f, "resynchronised ({n} garbage bytes skipped)"),
            Notice::DeviceError(e) => write!(
                f,
                "robot error: {:?} (scan {}, detail {})",
                e.code, e.seq, e.detail
            ),
            Notice::Done(d) => write!(
                f,
                "robot done: {} scans, grid FNV {:#010x}",
                d.scans, d.grid_fnv
            ),
            Notice::Warning(w) => write!(f, "warning: {w}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::wire::{CorrectionReport, MatchVerdict};
    use ogm_core::Angle;

    #[test]
    fn corrections_are_counted_by_what_the_matcher_decided() {
        let mut c = CorrectionCounts::default();
        let report = |verdict, without_odometry| CorrectionReport {
            verdict,
            without_odometry,
            ..CorrectionReport::default()
        };
        c.add(&report(MatchVerdict::Off, false));
        c.add(&report(MatchVerdict::Trusted, false));
        c.add(&report(
            MatchVerdict::Ambiguous {
                weak_axis: Angle(0),
            },
            true,
        ));
        c.add(&report(MatchVerdict::AmbiguousRotation, false));
        c.add(&report(MatchVerdict::NoOverlap, true));
        c.add(&report(MatchVerdict::OutOfWindow, false));
        assert_eq!(
            c,
            CorrectionCounts {
                off: 1,
                corrected: 3,
                cannot_tell: 2,
                without_odometry: 2,
            }
        );
    }
}
