//! What can be wrong with a frame, a tile or a scan's ranges.

use super::VERSION;

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
    ///
    /// [`ScanRanges::data`]: super::ScanRanges::data
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
