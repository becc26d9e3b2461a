//! The link protocol: the messages between the robot and the host, and their framing.
//! Schema and rationale: `docs/wire.md`.
//!
//! ## Framing
//! Every message is one frame:
//!
//! ```text
//! COBS( VERSION ‖ postcard(message) ‖ CRC-32(VERSION ‖ postcard(message)), little endian ) ‖ 0x00
//! ```
//!
//! * postcard 1.x (varint integers, enum variants as varint indices); `VERSION` is one raw byte
//!   first so a decoder can refuse a newer schema before decoding anything;
//! * CRC-32 = CRC-32/ISO-HDLC (zlib, Ethernet), over the version byte and the payload;
//! * COBS removes every `0x00`, so `0x00` only ever ends a frame; a receiver that starts
//!   mid-stream or sees garbage skips to the next `0x00`.
//!
//! Device → host: frames back to back ([`DeviceMsg`]). Host → device: the same frames
//! ([`HostMsg`]) *with an extra `0x00` in front*, interleaved with raw LD06 packets on the same
//! UART; the leading zero is what tells the robot's demultiplexer ([`crate::lidar::link`]) that a frame
//! and not a lidar packet (`0x54 …`) begins.
//!
//! ## Compatibility
//! Only append enum variants and never change existing fields; anything else bumps
//! [`VERSION`]. A frame with another version is counted and dropped, never misread.

use serde::{Deserialize, Serialize};

use crate::config::RunConfig;
use crate::types::geometry::Pose;
use crate::{Angle, LogOdds};

/// Schema version, the first byte of every frame.
pub const VERSION: u8 = 5;

/// CRC-32/ISO-HDLC (the zlib/Ethernet CRC-32), table driven (1 KiB of flash).
pub static CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Longest host → device frame on the wire, both `0x00` delimiters included (a [`RunConfig`]
/// with every field at its maximum is 113 bytes; tested).
pub const MAX_HOST_FRAME: usize = 128;

/// Fewest bytes of a [`HostMsg::Pose`] frame on the wire (a lower bound; tested): a read of
/// `n` link bytes completes at most `n / MIN_POSE_FRAME + 1` poses.
pub const MIN_POSE_FRAME: usize = 8;

/// Longest tile payload: 16 × 16 cells of `i16`.
pub const MAX_TILE_BYTES: usize = 512;

/// Longest device → host frame on the wire (a full log-odds tile; tested), plus the few bytes
/// [`encode`] needs as working room.
pub const MAX_DEVICE_FRAME: usize = MAX_TILE_BYTES + 32;

/// Host → device.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HostMsg {
    /// Settings; must come first, exactly once.
    Config(RunConfig),
    /// The LD06 points that follow, up to the matching [`HostMsg::ScanEnd`], are one scan taken
    /// at `pose` (known-pose mapping).
    ScanStart {
        /// Scan number (the host counts from 0).
        seq: u32,
        /// Where the scan was taken.
        pose: Pose,
    },
    /// End of scan `seq`; the host sent `points` LD06 points (fewer arrived = some were lost).
    ScanEnd {
        /// Scan number.
        seq: u32,
        /// Points sent.
        points: u32,
    },
    /// No more scans: stream the final map and stop.
    Finish,
    /// Sample for `period_us` of board time with no scan coming (the robot stands still), then
    /// report ([`DeviceMsg::Idle`]). `seq` numbers the idle periods so that a repeated frame is
    /// not a second period.
    Idle {
        /// Idle period number.
        seq: u32,
        /// Board time to sample for, µs.
        period_us: u32,
    },
    /// Where the robot was at `t_us` (µs of the lidar's clock: the LD06 timestamps, unwrapped
    /// by the device from the first packet it read; each [`ScanReport::t_us`] gives a host that
    /// clock). Poses come in time order, at their own rate; lidar packets are placed by
    /// interpolating between the two around their time ([`crate::lidar::turn`]).
    Pose {
        /// Time, µs of the lidar clock.
        t_us: u64,
        /// The robot's pose (not the lidar's: [`RunConfig::mount`] is applied on the device).
        pose: Pose,
    },
}

/// Which map a [`Tile`] carries.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Layer {
    /// The online log-odds map: `i16` little endian per cell ([`LogOdds`] raw, ln 4 = 1024).
    LogOdds,
    /// The sampler's marginal counts: `u8` per cell; p(occupied) = count / [`SamplerReport::samples`].
    Counts,
    /// The sampler's current map sample: one bit per cell, LSB first.
    Sample,
}

/// A square block of the map, row-major from its lower-left cell (row 0 = lowest y).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Tile<'a> {
    /// Which map.
    pub layer: Layer,
    /// Tile column (cells `tx·edge ..`).
    pub tx: u16,
    /// Tile row.
    pub ty: u16,
    /// The cells (see [`Layer`]); tiles at the map's edge may be smaller than `edge²`.
    pub data: &'a [u8],
}

/// Angular bins of a streamed scan ([`ScanRanges`]): 2° each, counter-clockwise from the
/// robot's heading, bin `i` covering `[i·2°, (i+1)·2°)`.
pub const SCAN_BINS: usize = 180;
/// Bytes of [`ScanRanges::data`]: one little-endian `u16` per bin.
pub const SCAN_RANGES_LEN: usize = 2 * SCAN_BINS;
/// [`ScanRanges`] bin value: no beam fell in the bin.
pub const RANGE_NONE: u16 = 0;
/// [`ScanRanges`] bin value: the bin's beams returned nothing within range.
pub const RANGE_NO_RETURN: u16 = u16::MAX;

/// A scan's ranges as the robot streams them for a live view (sent right after the scan's
/// [`ScanReport`], same `seq`, in the robot's frame at the report's pose): the closest hit of
/// each of [`SCAN_BINS`] angular bins, millimetres, [`RANGE_NONE`] or [`RANGE_NO_RETURN`]
/// otherwise. A 450-beam LD06 turn is 360 bytes instead of ~1.8 KB; the map itself never
/// depends on it. [`encode_ranges`] and [`ScanRanges::bins`] are its one codec.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanRanges<'a> {
    /// The scan's number ([`ScanReport::seq`]).
    pub seq: u32,
    /// [`SCAN_RANGES_LEN`] bytes.
    pub data: &'a [u8],
}

/// The bin of a beam direction.
fn range_bin(angle: Angle) -> usize {
    // < SCAN_BINS: angle < 2^16.
    ((u32::from(angle.0) * SCAN_BINS as u32) >> 16) as usize
}

/// Bins `beams` into `out` ([`ScanRanges::data`]): per bin the closest hit (clamped to
/// 1 ..= 65 534 mm), else [`RANGE_NO_RETURN`] if a beam returned nothing, else [`RANGE_NONE`].
pub fn encode_ranges(beams: &[crate::types::scan::Beam], out: &mut [u8; SCAN_RANGES_LEN]) {
    out.fill(0);
    for b in beams {
        let v = match b.range {
            crate::types::scan::Range::Hit(mm) => {
                mm.clamp(1, u32::from(RANGE_NO_RETURN - 1)) as u16
            }
            crate::types::scan::Range::NoReturn => RANGE_NO_RETURN,
        };
        let i = 2 * range_bin(b.angle);
        if let Some([lo, hi]) = out.get_mut(i..i + 2) {
            let old = u16::from_le_bytes([*lo, *hi]);
            if old == RANGE_NONE || v < old {
                [*lo, *hi] = v.to_le_bytes();
            }
        }
    }
}

impl ScanRanges<'_> {
    /// The bins that hold a reading: each bin's centre direction (robot frame) and its
    /// reading; [`WireError::Ranges`] if `data` is not [`SCAN_RANGES_LEN`] bytes.
    pub fn bins(
        &self,
    ) -> Result<impl Iterator<Item = (Angle, crate::types::scan::Range)> + '_, WireError> {
        if self.data.len() != SCAN_RANGES_LEN {
            return Err(WireError::Ranges);
        }
        Ok(self.data.chunks_exact(2).enumerate().filter_map(|(i, b)| {
            let v = match *b {
                [lo, hi] => u16::from_le_bytes([lo, hi]),
                _ => RANGE_NONE,
            };
            // The bin's centre: (i + ½) · 2^16 / SCAN_BINS.
            let angle = Angle((((2 * i + 1) << 16) / (2 * SCAN_BINS)) as u16);
            match v {
                RANGE_NONE => None,
                RANGE_NO_RETURN => Some((angle, crate::types::scan::Range::NoReturn)),
                mm => Some((angle, crate::types::scan::Range::Hit(u32::from(mm)))),
            }
        }))
    }
}

/// The cells of one streamed tile: tile (`tx`, `ty`) of a `width × height` map cut into
/// `edge`-cell squares from its lower-left corner; tiles at the map's right and top edges are
/// smaller. [`encode_tile`] and [`decode_tile`] are the one codec of [`Tile::data`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileRect {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// Columns.
    pub w: usize,
    /// Rows.
    pub h: usize,
    /// The map's width (row stride).
    pub stride: usize,
    /// The tile edge it was cut with.
    pub edge: usize,
}

impl TileRect {
    /// Tile (`tx`, `ty`); `None` if it lies outside the map or `edge` is 0.
    pub fn new(width: usize, height: usize, edge: usize, tx: u16, ty: u16) -> Option<Self> {
        let x0 = usize::from(tx).checked_mul(edge)?;
        let y0 = usize::from(ty).checked_mul(edge)?;
        if edge == 0 || x0 >= width || y0 >= height {
            return None;
        }
        Some(TileRect {
            x0,
            y0,
            w: edge.min(width - x0),
            h: edge.min(height - y0),
            stride: width,
            edge,
        })
    }

    /// Tile number `t`, row-major over the map's tiles; `None` past the last.
    pub fn nth(width: usize, height: usize, edge: usize, t: usize) -> Option<Self> {
        let across = width.checked_div(edge)? + usize::from(width % edge != 0);
        let (tx, ty) = (t.checked_rem(across)?, t / across);
        Self::new(
            width,
            height,
            edge,
            u16::try_from(tx).ok()?,
            u16::try_from(ty).ok()?,
        )
    }

    /// The tile's column and row.
    pub fn coords(&self) -> (u16, u16) {
        let e = self.edge.max(1);
        ((self.x0 / e) as u16, (self.y0 / e) as u16)
    }

    /// Cells in the tile.
    pub fn len(&self) -> usize {
        self.w * self.h
    }

    /// Whether the tile has no cells (never, for a tile [`TileRect::new`] made).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of `layer`'s data for this tile.
    pub fn data_len(&self, layer: Layer) -> usize {
        match layer {
            Layer::LogOdds => 2 * self.len(),
            Layer::Counts => self.len(),
            Layer::Sample => self.len().div_ceil(8),
        }
    }

    /// The map indices of its cells, in the tile's order (row-major from the lower-left).
    pub fn cells(&self) -> impl Iterator<Item = usize> + '_ {
        (self.y0..self.y0 + self.h)
            .flat_map(move |y| (self.x0..self.x0 + self.w).map(move |x| y * self.stride + x))
    }
}

/// A map a tile can be cut from (the firmware's [`crate::session::Session`]).
pub trait TileSource {
    /// Raw log-odds of cell `index` ([`LogOdds::raw`]).
    fn log_odds(&self, index: usize) -> i16;
    /// Marginal count of cell `index`, saturated to a byte.
    fn count(&self, index: usize) -> u8;
    /// Whether cell `index` is occupied in the current sample.
    fn occupied(&self, index: usize) -> bool;
}

/// A map a tile can be written into (a host's rebuilt map).
pub trait TileSink {
    /// Sets the raw log-odds of cell `index`.
    fn set_log_odds(&mut self, index: usize, raw: i16);
    /// Sets the marginal count of cell `index`.
    fn set_count(&mut self, index: usize, count: u8);
    /// Sets the sample bit of cell `index`.
    fn set_occupied(&mut self, index: usize, occupied: bool);
}

/// Encodes `layer` of the cells of `rect` from `src` into `buf` ([`Layer`] says how); returns
/// the data, or [`WireError::BufferFull`] if `buf` is shorter than [`TileRect::data_len`].
pub fn encode_tile<'b>(
    src: &impl TileSource,
    layer: Layer,
    rect: &TileRect,
    buf: &'b mut [u8],
) -> Result<&'b [u8], WireError> {
    let out = buf
        .get_mut(..rect.data_len(layer))
        .ok_or(WireError::BufferFull)?;
    match layer {
        Layer::LogOdds => {
            for (d, i) in out.chunks_exact_mut(2).zip(rect.cells()) {
                d.copy_from_slice(&src.log_odds(i).to_le_bytes());
            }
        }
        Layer::Counts => {
            for (d, i) in out.iter_mut().zip(rect.cells()) {
                *d = src.count(i);
            }
        }
        Layer::Sample => {
            out.fill(0);
            for (k, i) in rect.cells().enumerate() {
                if src.occupied(i) {
                    if let Some(d) = out.get_mut(k / 8) {
                        *d |= 1 << (k % 8);
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Writes a received tile's cells into `sink`; [`WireError::Tile`] if the tile lies outside a
/// `width × height` map cut into `edge`-cell tiles or its data has the wrong length (nothing is
/// written then).
pub fn decode_tile(
    tile: &Tile<'_>,
    width: usize,
    height: usize,
    edge: usize,
    sink: &mut impl TileSink,
) -> Result<TileRect, WireError> {
    let rect = TileRect::new(width, height, edge, tile.tx, tile.ty).ok_or(WireError::Tile)?;
    if tile.data.len() != rect.data_len(tile.layer) {
        return Err(WireError::Tile);
    }
    match tile.layer {
        Layer::LogOdds => {
            for (d, i) in tile.data.chunks_exact(2).zip(rect.cells()) {
                if let [lo, hi] = *d {
                    sink.set_log_odds(i, i16::from_le_bytes([lo, hi]));
                }
            }
        }
        Layer::Counts => {
            for (&d, i) in tile.data.iter().zip(rect.cells()) {
                sink.set_count(i, d);
            }
        }
        Layer::Sample => {
            for (k, i) in rect.cells().enumerate() {
                let bit = tile.data.get(k / 8).is_some_and(|d| d >> (k % 8) & 1 != 0);
                sink.set_occupied(i, bit);
            }
        }
    }
    Ok(rect)
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
    /// Pose used.
    pub pose: Pose,
    /// Beams in the scan.
    pub beams: u32,
    /// Beams that did not fit the scan buffer.
    pub beams_overflowed: u32,
    /// Mapper: beams used.
    pub beams_used: u32,
    /// Mapper: beams dropped (closer than the minimum range).
    pub beams_dropped: u32,
    /// Mapper: cells given the occupied update.
    pub cells_hit: u32,
    /// Mapper: cells given the free update.
    pub cells_freed: u32,
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
        Lidar = 6 => "lidar",
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
    Idle(IdleReport),
    /// The latest scan's ranges, for a live view (after its [`DeviceMsg::Scan`]).
    #[serde(borrow)]
    Ranges(ScanRanges<'a>),
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

/// Framing errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum WireError {
    /// The output buffer is too small.
    BufferFull,
    /// Not valid COBS (a zero inside, or a length byte pointing past the end).
    Cobs,
    /// Too short to hold a version byte and a CRC.
    TooShort,
    /// CRC mismatch.
    Crc,
    /// Another schema version (the byte found).
    Version(u8),
    /// postcard could not decode the payload, or bytes were left over.
    Decode,
    /// A tile outside the map, or with data of the wrong length for its layer.
    Tile,
    /// [`ScanRanges::data`] of the wrong length.
    Ranges,
}

impl core::error::Error for WireError {}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::BufferFull => f.write_str("frame buffer too small"),
            WireError::Cobs => f.write_str("bad COBS encoding"),
            WireError::TooShort => f.write_str("frame too short"),
            WireError::Crc => f.write_str("CRC-32 mismatch"),
            WireError::Version(v) => write!(f, "schema version {v}, expected {VERSION}"),
            WireError::Decode => f.write_str("postcard decoding failed"),
            WireError::Tile => f.write_str("tile outside the map or of the wrong size"),
            WireError::Ranges => f.write_str("scan ranges of the wrong size"),
        }
    }
}

/// Encodes `msg` as one frame (COBS, terminating `0x00` included) into `buf`; returns the bytes.
///
/// One buffer, three passes, no per-byte generic code (small in flash): postcard writes the
/// payload behind a gap at the front of `buf`, the CRC-32 is appended, and COBS then encodes
/// forwards into the front of the same buffer (the gap, ⌈len/254⌉ + 1 bytes, is what COBS adds,
/// so the writer never overtakes the reader).
pub fn encode<'b, T: Serialize + ?Sized>(
    msg: &T,
    buf: &'b mut [u8],
) -> Result<&'b mut [u8], WireError> {
    let gap = buf.len() / 254 + 2;
    let body = buf.get_mut(gap..).ok_or(WireError::BufferFull)?;
    let (version, rest) = body.split_first_mut().ok_or(WireError::BufferFull)?;
    *version = VERSION;
    let n = 1 + postcard::serialize_with_flavor(msg, Payload { buf: rest, len: 0 })
        .map_err(|_| WireError::BufferFull)?;
    let crc = CRC32.checksum(body.get(..n).ok_or(WireError::BufferFull)?);
    body.get_mut(n..n + 4)
        .ok_or(WireError::BufferFull)?
        .copy_from_slice(&crc.to_le_bytes());
    let len = cobs_encode_in_place(buf, gap, n + 4);
    let end = buf.get_mut(len).ok_or(WireError::BufferFull)?;
    *end = 0;
    buf.get_mut(..=len).ok_or(WireError::BufferFull)
}

/// postcard's output for [`encode`]: the payload's bytes written into a slice by two out-of-line
/// functions, so that each field of each message costs a call instead of postcard's inlined
/// slice bounds check and copy (which the firmware's one `encode` of every message multiplies).
struct Payload<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl postcard::ser_flavors::Flavor for Payload<'_> {
    /// The payload's length.
    type Output = usize;

    #[inline(never)]
    fn try_push(&mut self, byte: u8) -> postcard::Result<()> {
        let slot = self
            .buf
            .get_mut(self.len)
            .ok_or(postcard::Error::SerializeBufferFull)?;
        *slot = byte;
        self.len += 1;
        Ok(())
    }

    #[inline(never)]
    fn try_extend(&mut self, bytes: &[u8]) -> postcard::Result<()> {
        let end = self.len.saturating_add(bytes.len());
        let out = self
            .buf
            .get_mut(self.len..end)
            .ok_or(postcard::Error::SerializeBufferFull)?;
        // Not `copy_from_slice`: its length check's panic would pull `core::fmt` into the
        // firmware; the lengths are equal here (`end − len = bytes.len()`, never saturated since
        // the range is inside `buf`).
        for (o, b) in out.iter_mut().zip(bytes) {
            *o = *b;
        }
        self.len = end;
        Ok(())
    }

    fn finalize(self) -> postcard::Result<usize> {
        Ok(self.len)
    }
}

/// COBS-encodes `buf[src..src + len]` into `buf[0..]` (no terminator); returns the encoded
/// length. Needs `src ≥ 1 + len / 254` (then every write lands on an already-read byte).
fn cobs_encode_in_place(buf: &mut [u8], src: usize, len: usize) -> usize {
    let (mut code_at, mut w, mut code) = (0usize, 1usize, 1u8);
    for i in src..src + len {
        let b = buf.get(i).copied().unwrap_or(0);
        if b != 0 {
            if let Some(slot) = buf.get_mut(w) {
                *slot = b;
            }
            w += 1;
            code += 1;
        }
        if b == 0 || code == 0xFF {
            if let Some(slot) = buf.get_mut(code_at) {
                *slot = code;
            }
            (code_at, w, code) = (w, w + 1, 1);
        }
    }
    if let Some(slot) = buf.get_mut(code_at) {
        *slot = code;
    }
    w
}

/// Decodes COBS in place (`buf` without the terminating `0x00`); returns the decoded length.
pub fn cobs_decode_in_place(buf: &mut [u8]) -> Result<usize, WireError> {
    let (mut read, mut write) = (0usize, 0usize);
    let len = buf.len();
    while read < len {
        let code = buf.get(read).copied().unwrap_or(0);
        if code == 0 {
            return Err(WireError::Cobs);
        }
        read += 1;
        for _ in 1..code {
            let b = buf.get(read).copied().ok_or(WireError::Cobs)?;
            if b == 0 {
                return Err(WireError::Cobs);
            }
            if let Some(slot) = buf.get_mut(write) {
                *slot = b;
            }
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < len {
            if let Some(slot) = buf.get_mut(write) {
                *slot = 0;
            }
            write += 1;
        }
    }
    Ok(write)
}

/// Decodes one frame: `frame` is the COBS bytes *without* the terminating `0x00` (decoded in
/// place); checks the CRC and the version and decodes a `T` that may borrow from `frame`.
pub fn decode<'a, T: Deserialize<'a>>(frame: &'a mut [u8]) -> Result<T, WireError> {
    let n = cobs_decode_in_place(frame)?;
    let frame: &'a [u8] = frame;
    let raw = frame.get(..n).ok_or(WireError::TooShort)?;
    if raw.len() < 5 {
        return Err(WireError::TooShort);
    }
    let (body, crc) = raw.split_at(raw.len() - 4);
    let want = u32::from_le_bytes(crc.try_into().map_err(|_| WireError::TooShort)?);
    if CRC32.checksum(body) != want {
        return Err(WireError::Crc);
    }
    let (&version, payload) = body.split_first().ok_or(WireError::TooShort)?;
    if version != VERSION {
        return Err(WireError::Version(version));
    }
    match postcard::take_from_bytes(payload) {
        Ok((msg, [])) => Ok(msg),
        _ => Err(WireError::Decode),
    }
}

/// FNV-1a (32-bit) over `bytes`, continuing from `h` (start with [`FNV_START`]).
pub fn fnv1a(h: u32, bytes: &[u8]) -> u32 {
    bytes
        .iter()
        .fold(h, |h, &b| (h ^ u32::from(b)).wrapping_mul(0x0100_0193))
}

/// FNV-1a's offset basis.
pub const FNV_START: u32 = 0x811c_9dc5;

/// [`fnv1a`] over a log-odds map (`i16` LE, in order), as in [`Done::grid_fnv`].
pub fn grid_fnv(cells: &[LogOdds]) -> u32 {
    cells
        .iter()
        .fold(FNV_START, |h, c| fnv1a(h, &c.raw().to_le_bytes()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Budget, DataTerm, Estimator, LidarModel, PoseInput};

    fn max_config() -> RunConfig {
        RunConfig {
            origin_x_mm: i32::MIN,
            origin_y_mm: i32::MIN,
            cell_mm: u32::MAX,
            max_range_mm: u32::MAX,
            min_range_mm: u32::MAX,
            seed: u64::MAX,
            sigma_milli_cells: u32::MAX,
            outlier_ppm: u32::MAX,
            p_rand_patch_ppm: u32::MAX,
            burn_in_sweeps: u32::MAX,
            max_candidates: u8::MAX,
            sampler_tile_shift: u8::MAX,
            visit_sweeps: u8::MAX,
            budget: Budget::Time {
                period_us: u32::MAX,
                max_updates: u32::MAX,
            },
            tiles_per_scan: u16::MAX,
            count_tiles_per_scan: u16::MAX,
            face_band: true,
            data: DataTerm::Hybrid,
            evidence_gain_q8: u16::MAX,
            evidence_free_q8: u16::MAX,
            free_update_q8: u16::MAX,
            data_candidate: true,
            estimator: Estimator::Average {
                shift: u8::MAX,
                max_shift: u8::MAX,
                reset_on_change: true,
                rao_blackwell: true,
            },
            hot_share: u8::MAX,
            mount: Pose {
                x_mm: i32::MIN,
                y_mm: i32::MIN,
                heading: Angle(u16::MAX),
            },
            poses: PoseInput::Fixed,
            lidar: LidarModel::Rplidar {
                sample_us: u16::MAX,
            },
        }
    }

    #[test]
    fn min_pose_frame_is_a_lower_bound() {
        let mut buf = [0u8; MAX_HOST_FRAME];
        let smallest = HostMsg::Pose {
            t_us: 0,
            pose: Pose::default(),
        };
        let n = encode(&smallest, &mut buf).map(|b| b.len()).unwrap();
        assert!(n >= MIN_POSE_FRAME, "{n}");
    }

    #[test]
    fn round_trip_and_sizes() {
        let mut buf = [0u8; 256];
        let msgs = [
            HostMsg::Config(max_config()),
            HostMsg::ScanStart {
                seq: u32::MAX,
                pose: Pose {
                    x_mm: i32::MIN,
                    y_mm: i32::MAX,
                    heading: Angle(u16::MAX),
                },
            },
            HostMsg::ScanEnd {
                seq: u32::MAX,
                points: u32::MAX,
            },
            HostMsg::Finish,
            HostMsg::Pose {
                t_us: u64::MAX,
                pose: Pose {
                    x_mm: i32::MIN,
                    y_mm: i32::MIN,
                    heading: Angle(u16::MAX),
                },
            },
        ];
        for m in msgs {
            let n = encode(&m, &mut buf).unwrap().len();
            // + the leading 0x00 the host adds
            assert!(n < MAX_HOST_FRAME, "{m:?}: {n} bytes");
            assert_eq!(buf[n - 1], 0);
            assert!(!buf[..n - 1].contains(&0));
            let back: HostMsg = decode(&mut buf[..n - 1]).unwrap();
            assert_eq!(back, m);
        }
        let data = [0xA5u8; MAX_TILE_BYTES];
        let t = DeviceMsg::Tile(Tile {
            layer: Layer::LogOdds,
            tx: u16::MAX,
            ty: u16::MAX,
            data: &data,
        });
        let mut big = [0u8; MAX_DEVICE_FRAME];
        let n = encode(&t, &mut big).unwrap().len();
        let back: DeviceMsg = decode(&mut big[..n - 1]).unwrap();
        assert_eq!(back, t);
    }

    #[test]
    fn rejects_corruption_and_other_versions() {
        let mut buf = [0u8; 64];
        let m = HostMsg::ScanEnd {
            seq: 7,
            points: 360,
        };
        let n = encode(&m, &mut buf).unwrap().len();
        for i in 0..n - 1 {
            for bit in 0..8 {
                let mut f = buf;
                f[i] ^= 1 << bit;
                let r: Result<HostMsg, _> = decode(&mut f[..n - 1]);
                assert!(r.is_err(), "flip {i}.{bit} undetected");
            }
        }
        // A frame with another version (valid CRC) is refused by version.
        let other = VERSION.wrapping_add(1);
        let mut raw = std::vec![other];
        raw.extend_from_slice(postcard::to_slice(&m, &mut [0u8; 64]).unwrap());
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut enc = cobs_encode(&raw);
        let r: Result<HostMsg, _> = decode(&mut enc);
        assert_eq!(r, Err(WireError::Version(other)));
        // Trailing bytes after the message are refused.
        let mut raw = std::vec![VERSION];
        raw.extend_from_slice(postcard::to_slice(&m, &mut [0u8; 64]).unwrap());
        raw.push(0x11);
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut enc = cobs_encode(&raw);
        assert_eq!(decode::<HostMsg>(&mut enc), Err(WireError::Decode));
        assert_eq!(decode::<HostMsg>(&mut []), Err(WireError::TooShort));
    }

    /// Plain reference COBS encoder (without terminator).
    fn cobs_encode(data: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8];
        let mut code_at = 0;
        let mut code = 1u8;
        for &b in data {
            if b == 0 {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            } else {
                out.push(b);
                code += 1;
                if code == 0xFF {
                    out[code_at] = code;
                    code_at = out.len();
                    out.push(0);
                    code = 1;
                }
            }
        }
        out[code_at] = code;
        out
    }

    /// The frame of a postcard `payload` built step by step with the reference COBS encoder:
    /// COBS(VERSION ‖ payload ‖ CRC-32) ‖ 0x00.
    fn reference_frame(payload: &[u8]) -> Vec<u8> {
        let mut raw = vec![VERSION];
        raw.extend_from_slice(payload);
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut frame = cobs_encode(&raw);
        frame.push(0);
        frame
    }

    /// `encode`'s own postcard output (`Payload`) equals postcard's slice flavour's, and every
    /// buffer too short for the frame is `BufferFull`, never a panic or a cut frame.
    #[test]
    fn encode_writes_postcard_bytes_and_refuses_short_buffers() {
        let msgs = [
            HostMsg::Config(max_config()),
            HostMsg::ScanEnd {
                seq: u32::MAX,
                points: 0,
            },
            HostMsg::Finish,
        ];
        for m in msgs {
            let mut buf = [0u8; 256];
            let frame = encode(&m, &mut buf).unwrap().to_vec();
            let want = reference_frame(postcard::to_slice(&m, &mut [0u8; 256]).unwrap());
            assert_eq!(frame, want, "{m:?}");
            for len in 0..frame.len() + frame.len() / 254 + 2 {
                let mut short = vec![0u8; len];
                match encode(&m, &mut short) {
                    Ok(f) => assert_eq!(f, &frame[..], "{m:?} in {len} bytes"),
                    Err(e) => assert_eq!(e, WireError::BufferFull, "{m:?} in {len} bytes"),
                }
            }
        }
    }

    #[test]
    fn encode_matches_the_reference_cobs_at_block_boundaries() {
        for len in [
            0usize, 1, 200, 243, 244, 245, 246, 250, 253, 254, 255, 497, 498, 499, 500,
        ] {
            let data: Vec<u8> = (0..len).map(|i| (i % 7) as u8 * 40).collect();
            let msg = DeviceMsg::Tile(Tile {
                layer: Layer::Counts,
                tx: 1,
                ty: 2,
                data: &data,
            });
            let mut buf = [0u8; MAX_DEVICE_FRAME];
            let frame = encode(&msg, &mut buf).unwrap().to_vec();
            let want = reference_frame(postcard::to_slice(&msg, &mut [0u8; 600]).unwrap());
            assert_eq!(frame, want, "len {len}");
            let mut f = frame.clone();
            let back: DeviceMsg = decode(&mut f[..frame.len() - 1]).unwrap();
            assert_eq!(back, msg);
        }
    }

    #[test]
    fn cobs_matches_reference_on_edge_lengths() {
        for len in [0usize, 1, 253, 254, 255, 256, 508, 509, 600] {
            for zeros in [false, true] {
                let data: Vec<u8> = (0..len)
                    .map(|i| {
                        if zeros && i % 97 == 3 {
                            0
                        } else {
                            (i % 251 + 1) as u8
                        }
                    })
                    .collect();
                let mut enc = cobs_encode(&data);
                assert!(!enc.contains(&0));
                let n = cobs_decode_in_place(&mut enc).unwrap();
                assert_eq!(&enc[..n], &data[..], "len {len} zeros {zeros}");
            }
        }
        assert_eq!(cobs_decode_in_place(&mut [3, 1]), Err(WireError::Cobs));
        assert_eq!(cobs_decode_in_place(&mut [2, 0]), Err(WireError::Cobs));
    }

    /// The reference of [`encode_ranges`]: per bin (by the angle in degrees, f64), the
    /// closest hit, else no return, else nothing.
    fn ranges_reference(
        beams: &[crate::types::scan::Beam],
    ) -> Vec<Option<crate::types::scan::Range>> {
        use crate::types::scan::Range;
        let mut bins = vec![None; SCAN_BINS];
        for b in beams {
            let deg = f64::from(b.angle.0) * 360.0 / 65_536.0;
            let i = (deg / 2.0).floor() as usize;
            let r = match b.range {
                Range::Hit(mm) => Range::Hit(mm.clamp(1, 65_534)),
                r => r,
            };
            bins[i] = match (bins[i], r) {
                (None, r) | (Some(Range::NoReturn), r) => Some(r),
                (Some(Range::Hit(a)), Range::Hit(b)) => Some(Range::Hit(a.min(b))),
                (old, Range::NoReturn) => old,
            };
        }
        bins
    }

    proptest::proptest! {
        #[test]
        fn scan_ranges_bin_the_closest_hit_and_survive_the_link(
            raw in proptest::collection::vec((0u16.., proptest::option::of(0u32..100_000)), 0..600)
        ) {
            use crate::types::scan::{Beam, Range};
            let beams: Vec<Beam> = raw
                .iter()
                .map(|&(a, r)| Beam { angle: Angle(a), range: r.map_or(Range::NoReturn, Range::Hit) })
                .collect();
            let mut data = [0u8; SCAN_RANGES_LEN];
            encode_ranges(&beams, &mut data);
            let mut buf = [0u8; 512];
            let mut frame = encode(&DeviceMsg::Ranges(ScanRanges { seq: 9, data: &data }), &mut buf)
                .unwrap()
                .to_vec();
            let n = frame.len() - 1;
            let got = match decode::<DeviceMsg>(&mut frame[..n]).unwrap() {
                DeviceMsg::Ranges(r) => {
                    proptest::prop_assert_eq!(r.seq, 9);
                    r.bins().unwrap().collect::<Vec<_>>()
                }
                m => panic!("{m:?}"),
            };
            let want: Vec<(Angle, Range)> = ranges_reference(&beams)
                .into_iter()
                .enumerate()
                .filter_map(|(i, r)| r.map(|r| (i, r)))
                .map(|(i, r)| (Angle::from_degrees(2.0 * i as f64 + 1.0), r))
                .collect();
            proptest::prop_assert_eq!(got.len(), want.len());
            for ((ga, gr), (wa, wr)) in got.iter().zip(&want) {
                proptest::prop_assert_eq!(gr, wr);
                proptest::prop_assert!(ga.signed_diff(*wa).abs() <= 1, "{:?} {:?}", ga, wa);
            }
        }
    }

    #[test]
    fn scan_ranges_of_the_wrong_length_are_refused() {
        let data = [1u8; SCAN_RANGES_LEN - 2];
        assert!(ScanRanges {
            seq: 0,
            data: &data
        }
        .bins()
        .is_err());
        let data = [0u8; SCAN_RANGES_LEN];
        assert_eq!(
            ScanRanges {
                seq: 0,
                data: &data
            }
            .bins()
            .unwrap()
            .count(),
            0
        );
    }
}
