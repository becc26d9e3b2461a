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

// One file per concern; everything is re-exported here, so users write `wire::HostMsg`.
mod correction;
mod device;
mod error;
mod fnv;
mod frame;
mod host;
mod ranges;
mod restore;
mod tile;

pub use correction::{CorrectionReport, MatchVerdict};
pub use device::{
    ConfigFault, Counters, DeviceError, DeviceMsg, Done, ErrorCode, Hello, IdleReport,
    LidarCounters, LinkCounters, LinkFault, RestoreFault, SamplerReport, ScanReport, StoreReport,
    WindowReport,
};
pub use error::WireError;
pub use fnv::{fnv1a, grid_fnv, FNV_START};
pub use frame::{
    cobs_decode_in_place, decode, encode, CRC32, MAX_DEVICE_FRAME, MAX_HOST_FRAME, MIN_POSE_FRAME,
};
pub use host::HostMsg;
pub use ranges::{
    encode_ranges, ScanRanges, RANGE_NONE, RANGE_NO_RETURN, SCAN_BINS, SCAN_RANGES_LEN,
};
pub use restore::{
    check_restore_part, restore_cell_bytes, restore_msgs, restore_parts, restore_rows_per_part,
    RestoreData, RESTORE_PART_BYTES,
};
pub use tile::{
    decode_tile, encode_tile, Layer, Tile, TileRect, TileSink, TileSource, MAX_TILE_BYTES,
};

/// Schema version, the first byte of every frame.
pub const VERSION: u8 = 9;
