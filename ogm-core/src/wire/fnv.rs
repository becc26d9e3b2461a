//! FNV-1a, the checksum of the maps in [`Done`](super::Done).

use crate::types::fixed::LogOdds;

/// FNV-1a (32-bit) over `bytes`, continuing from `h` (start with [`FNV_START`]).
pub fn fnv1a(h: u32, bytes: &[u8]) -> u32 {
    bytes
        .iter()
        .fold(h, |h, &b| (h ^ u32::from(b)).wrapping_mul(0x0100_0193))
}

/// FNV-1a's offset basis.
pub const FNV_START: u32 = 0x811c_9dc5;

/// [`fnv1a`] over a log-odds map (`i16` LE, in order), as in [`Done::grid_fnv`].
///
/// [`Done::grid_fnv`]: super::Done::grid_fnv
pub fn grid_fnv(cells: &[LogOdds]) -> u32 {
    cells
        .iter()
        .fold(FNV_START, |h, c| fnv1a(h, &c.raw().to_le_bytes()))
}
