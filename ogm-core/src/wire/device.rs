//! Device → host: [`DeviceMsg`] and the reports, counters and error codes it carries.

use serde::{Deserialize, Serialize};

use super::correction::CorrectionReport;
use super::ranges::ScanRanges;
use super::tile::Tile;
use crate::config::RunConfig;
use crate::types::geometry::Pose;
use crate::types::scan::ScanStats;

/// Device → host.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeviceMsg<'a> {
    /// At boot.
    #[serde(borrow)]
    Hello(Hello<'a>),
    /// `Config` accepted (echo).
    Configured(RunConfig),
    /// One scan done.
    Scan(ScanReport),
    /// Map data.
    #[serde(borrow)]
    Tile(Tile<'a>),
    /// Sampler and ray store statistics (after every scan and at the end).
    Sampler(SamplerReport),
    /// Counters (after every scan and at the end).
    Counters(Counters),
    /// Something went wrong (the run goes on).
    Error(DeviceError),
    /// Final message.
    Done(Done),
    /// An idle period ([`HostMsg::Idle`]) is over.
    ///
    /// [`HostMsg::Idle`]: super::HostMsg::Idle
    Idle(IdleReport),
    /// The latest scan's ranges, for a live view (after its [`DeviceMsg::Scan`]).
    #[serde(borrow)]
    Ranges(ScanRanges<'a>),
    /// The rolling window moved (before the tiles that left it) or the run ends (version 6).
    Window(WindowReport),
}

/// Sent once at boot: what this firmware is and its compile-time sizes.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hello<'a> {
    /// Firmware name and version.
    pub firmware: &'a str,
    /// Board name.
    pub board: &'a str,
    /// Timer ticks per second (the unit of the `*_ticks` fields).
    pub tick_hz: u32,
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Edge of the streamed tiles, cells.
    pub tile_edge: u16,
    /// Beams per scan buffer.
    pub max_beams: u32,
    /// Ray store capacity, rays.
    pub ray_capacity: u32,
    /// Ray store capacity, scans.
    pub scan_capacity: u32,
    /// Sampler's per-tile ray list capacity.
    pub local_capacity: u32,
    /// Largest marginal count (255 for `u8` counters).
    pub count_max: u32,
}

/// What the robot did with one scan. Followed by the tiles it streamed for it.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanReport {
    /// Scan number.
    pub seq: u32,
    /// The pose the scan was mapped at: [`ScanReport::odometry`] corrected by the scan matcher
    /// (version 7; before, and with correction off, the pose as it came).
    pub pose: Pose,
    /// Beams in the scan.
    pub beams: u32,
    /// Beams that did not fit the scan buffer.
    pub beams_overflowed: u32,
    /// What the mapper did (on the wire: its four counts in place, as before).
    pub mapper: ScanStats,
    /// Rays the ray store kept from this scan.
    pub rays_stored: u32,
    /// Sampler patch updates run after this scan (the host replays exactly this many).
    pub sampler_updates: u32,
    /// Timer ticks of the log-odds update.
    pub insert_ticks: u32,
    /// Timer ticks of adding the scan to the ray store and filling its rays' caches.
    pub store_ticks: u32,
    /// Timer ticks of the sampler updates.
    pub sampler_ticks: u32,
    /// When the scan began, µs of the lidar clock (turns read on the robot's UART; 0 for
    /// scans a host tunnelled).
    pub t_us: u64,
    /// The pose the scan came with (version 7): odometry, from the link's pose messages or a
    /// tunnelled scan, or the fixed pose of a robot without odometry.
    pub odometry: Pose,
    /// How [`ScanReport::pose`] was found: the matcher's verdict and quality (version 7).
    pub correction: CorrectionReport,
    /// Timer ticks of the scan matcher (version 7; part of neither `insert_ticks` nor
    /// `sampler_ticks`).
    pub match_ticks: u32,
}

/// The ray store's state.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoreReport {
    /// Scans accepted.
    pub scans_added: u32,
    /// Rays accepted.
    pub rays_added: u32,
    /// Beams not stored because of decimation.
    pub rays_decimated: u32,
    /// Rays removed later by thinning.
    pub rays_thinned: u32,
    /// Beams dropped as invalid.
    pub rays_invalid: u32,
    /// Times the store halved its rays or scans.
    pub thinnings: u32,
    /// Current decimation (1 = every beam).
    pub decimation: u32,
    /// Scans held now.
    pub scans: u32,
    /// Rays held now.
    pub rays: u32,
}

/// Sampler statistics.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SamplerReport {
    /// Patch updates done.
    pub updates: u64,
    /// Of which random configurations.
    pub random_patches: u64,
    /// Updates with a single candidate.
    pub single_candidate: u64,
    /// Updates that changed the patch.
    pub changed: u64,
    /// Ray × patch likelihood evaluations.
    pub rays_evaluated: u64,
    /// Tile visits started.
    pub tile_visits: u64,
    /// Rays that did not fit the per-tile list.
    pub local_overflow: u64,
    /// Completed sweeps.
    pub sweeps: u32,
    /// Samples in the marginal counts.
    pub samples: u32,
    /// The ray store.
    pub store: StoreReport,
}

/// What the receive side saw (see [`crate::lidar::link`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkCounters {
    /// Bytes received.
    pub rx_bytes: u32,
    /// Bytes skipped (neither a packet nor a frame).
    pub garbage_bytes: u32,
    /// Good LD06 packets.
    pub ld06_packets: u32,
    /// LD06 packets with a CRC mismatch.
    pub ld06_crc_errors: u32,
    /// `0x54` not followed by `0x2C`.
    pub ld06_bad_headers: u32,
    /// LD06 packets cut short.
    pub ld06_truncated: u32,
    /// Good host frames.
    pub frames: u32,
    /// Frames that failed COBS, CRC or postcard decoding.
    pub frame_errors: u32,
    /// Frames with another schema version.
    pub frames_bad_version: u32,
    /// Frames longer than [`MAX_HOST_FRAME`].
    ///
    /// [`MAX_HOST_FRAME`]: super::MAX_HOST_FRAME
    pub frames_too_long: u32,
    /// LD06 points received outside a scan (no `ScanStart`).
    pub points_outside_scan: u32,
    /// Points announced by `ScanEnd` that did not arrive.
    pub points_lost: u32,
    /// `ScanEnd` without a matching `ScanStart`, or a scan never ended.
    pub scan_seq_errors: u32,
}

/// Counters of the whole device.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Receive side.
    pub link: LinkCounters,
    /// Scans processed.
    pub scans: u32,
    /// Beams dropped for lack of scan buffer space.
    pub beams_overflowed: u32,
    /// UART receive errors (overruns).
    pub uart_errors: u32,
    /// Error messages sent.
    pub errors: u32,
    /// The lidar on the robot's own UART.
    pub lidar: LidarCounters,
}

/// What the device counted of the lidar on its own UART and of the poses that place it
/// ([`crate::lidar::turn`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LidarCounters {
    /// Packets that passed the parser.
    pub packets: u32,
    /// Packets the parser rejected (header, CRC, truncated).
    pub bad_packets: u32,
    /// Packets read before the settings arrived (not mapped).
    pub packets_before_config: u32,
    /// Turns mapped.
    pub turns: u32,
    /// Packets dropped: older than every pose kept.
    pub packets_without_pose: u32,
    /// Packets dropped: too many waiting for a pose.
    pub packets_overflowed: u32,
    /// Poses accepted.
    pub poses: u32,
    /// Poses rejected: not newer than the last.
    pub poses_out_of_order: u32,
}

/// Error kinds.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// A scan or `Finish` before `Config`.
    NoConfig,
    /// A second `Config`.
    ConfigTwice,
    /// `Config` rejected (`detail`: a [`ConfigFault`]).
    BadConfig,
    /// The mapper rejected a scan.
    Map,
    /// Scan framing broken (`detail`: the `ScanEnd` sequence number that did not match).
    ScanSequence,
    /// Points lost in a scan (`detail`: how many).
    PointsLost,
    /// A scan had more beams than the buffer (`detail`: how many were dropped).
    ScanOverflow,
    /// The UART reported an error (overrun).
    Uart,
    /// A bad LD06 packet or host frame (`detail`: a [`LinkFault`]).
    Link,
    /// A pose not newer than the last one, dropped (`detail`: its time, ms, saturated).
    PoseOrder,
    /// A [`super::HostMsg::Restore`] part or tile refused (`detail`: a [`RestoreFault`]).
    Restore,
}

/// Defines a `u32`-numbered detail enum of [`DeviceError::detail`] with its `Display`.
macro_rules! detail_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $v:ident = $n:literal => $text:literal,)* }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[non_exhaustive]
        pub enum $name {
            $($(#[$vm])* $v = $n,)*
        }

        impl $name {
            /// Its number in [`DeviceError::detail`].
            pub const fn detail(self) -> u32 {
                self as u32
            }

            /// The variant numbered `detail`, if any.
            pub const fn from_detail(detail: u32) -> Option<Self> {
                match detail {
                    $($n => Some($name::$v),)*
                    _ => None,
                }
            }
        }

        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(match self {
                    $($name::$v => $text,)*
                })
            }
        }
    };
}

detail_enum! {
    /// Which part rejected the settings: the `detail` of [`ErrorCode::BadConfig`].
    ConfigFault {
        /// The grid placement (cell size 0, or a grid too large).
        Geometry = 0 => "grid geometry",
        /// The mapper's sensor model or buffers.
        Mapper = 1 => "mapper",
        /// The forward model (σ, outlier weight, range).
        ForwardModel = 2 => "forward model",
        /// The ray store (ranges, buffers).
        Store = 3 => "ray store",
        /// The sampler (settings or buffers).
        Sampler = 4 => "sampler",
        /// The device has no room left for a mapping state.
        NoRoom = 5 => "no room for the mapping state",
        /// The lidar settings ([`LidarModel::is_valid`]).
        ///
        /// [`LidarModel::is_valid`]: crate::config::LidarModel::is_valid
        Lidar = 6 => "lidar",
        /// The rolling window's margin does not fit the grid and its tiles
        /// (`Session::window_fits`).
        Window = 7 => "rolling window",
    }
}

detail_enum! {
    /// What was wrong on the link: the `detail` of [`ErrorCode::Link`].
    LinkFault {
        /// An LD06 packet with a bad CRC.
        Ld06Crc = 0 => "LD06 packet CRC",
        /// An LD06 packet cut short by the next header.
        Ld06Truncated = 1 => "LD06 packet truncated",
        /// An LD06 packet with a bad length byte.
        Ld06Header = 2 => "LD06 packet header",
        /// A host frame that failed COBS, CRC, version or decoding.
        Frame = 3 => "host frame",
        /// A host frame longer than any valid one.
        FrameTooLong = 4 => "host frame too long",
        /// LD06 points outside a `ScanStart` … `ScanEnd` pair.
        PointsOutsideScan = 5 => "LD06 points outside a scan",
    }
}

/// An error report.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceError {
    /// What.
    pub code: ErrorCode,
    /// The scan it concerns (the last one started).
    pub seq: u32,
    /// Code-specific detail.
    pub detail: u32,
}

/// The last message of a run.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Done {
    /// Scans processed.
    pub scans: u32,
    /// FNV-1a (32-bit) over every log-odds cell, `i16` LE, row-major.
    pub grid_fnv: u32,
    /// FNV-1a over every marginal count byte, row-major.
    pub counts_fnv: u32,
    /// Stack high-water mark of the mapping loop (after the settings were applied), bytes.
    pub stack_used: u32,
    /// Stack size, bytes.
    pub stack_size: u32,
    /// Stack high-water mark up to and including applying the settings (building the
    /// sampler, a one-off peak), bytes.
    pub stack_config: u32,
}

/// What an idle period did.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IdleReport {
    /// The period's number.
    pub seq: u32,
    /// Sampler updates done.
    pub sampler_updates: u32,
    /// Board timer ticks they took.
    pub sampler_ticks: u32,
}

/// The rolling window (wire version 6): where it lies in the building and what moving it did.
/// The building frame's cell (0, 0) is the one at the settings' origin
/// ([`RunConfig::origin_x_mm`], [`RunConfig::origin_y_mm`]); window cell `(x, y)` is building
/// cell `(origin_x + x, origin_y + y)`.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WindowReport {
    /// The window's lower-left cell, building frame (a multiple of the tile edge).
    pub origin_x: i32,
    /// The same, y.
    pub origin_y: i32,
    /// Shifts so far.
    pub shifts: u32,
    /// Tiles that left the window (each streamed before the shift, unless all unknown).
    pub tiles_out: u32,
    /// Shifts refused: the window's origin would leave the `i32` mm range.
    pub shifts_refused: u32,
    /// Scans with a beam whose ray left the window (clipped).
    pub scans_clipped: u32,
    /// Beams whose ray left the window (clipped).
    pub beams_clipped: u32,
    /// Stored tiles the host sent back that were applied.
    pub tiles_restored: u32,
    /// Stored tiles refused (outside the window, wrong size, already mapped).
    pub restore_refused: u32,
    /// Lidar turns held after a shift until the host answered (version 8,
    /// [`RunConfig::window_hold`](crate::config::RunConfig::window_hold)).
    pub turns_held: u32,
    /// Of those, turns mapped without the host's `Resume`: it did not come in time, or another
    /// message came first.
    pub holds_unanswered: u32,
}

detail_enum! {
    /// Why a stored tile sent back was refused: the `detail` of [`ErrorCode::Restore`] (each
    /// also counted in [`WindowReport::restore_refused`]).
    RestoreFault {
        /// A layer other than `LogOdds` or `Counts`.
        Layer = 0 => "restore: layer not LogOdds or Counts",
        /// `row` does not start a part inside the tile.
        Row = 1 => "restore: row not at a part's start inside the tile",
        /// The part's data is not exactly its rows' bytes.
        Length = 2 => "restore: part of the wrong length",
        /// The device's tiles cannot travel in restore parts (a row over 64 bytes).
        Edge = 3 => "restore: tile edge too large for a part",
        /// The tile does not lie (whole) inside the current window.
        Outside = 4 => "restore: tile not inside the window",
        /// A cell of the tile was mapped since it entered the window.
        Mapped = 5 => "restore: tile already mapped on this visit",
        /// An incomplete tile was dropped because parts of another tile began.
        Dropped = 6 => "restore: incomplete tile dropped for another",
        /// No rolling window (a fixed grid) or no settings yet.
        NoWindow = 7 => "restore: no rolling window",
    }
}
