//! The compile-time sizes of every board's buffers: one [`BoardSizes`] per board, the only place
//! they are written. The board's binary allocates exactly these (`src/memory.rs`), the
//! application is built for [`APP`] (the selected board's; on the host, which builds no board,
//! the reference board's: QEMU mps2-an386) and reports them in `Hello`, from which the host tools
//! take them at run time. Justification of the figures: docs/firmware.md ("RAM layout").

use ogm_core::wire::MAX_TILE_BYTES;

/// One board's buffer sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardSizes {
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Edge of a streamed tile, cells (a tile of log-odds must fit one wire frame:
    /// 2 · edge² ≤ [`MAX_TILE_BYTES`], checked at compile time).
    pub tile_edge: u16,
    /// Beams per scan buffer.
    pub max_beams: usize,
    /// Ray store: rays (6 bytes each), in a build with the `rays` feature.
    pub rays: usize,
    /// Ray store: scans (20 bytes each), in a build with the `rays` feature.
    pub scans: usize,
    /// The sampler's per-tile ray list (`LocalRay`, 28 bytes each, plus its block bitsets), in
    /// a build with the `rays` feature.
    pub local_rays: usize,
}

impl BoardSizes {
    /// Cells of the grid.
    pub const fn cells(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// QEMU's mps2-an386 (Cortex-M4F; `memory.x` gives it 256 KiB of RAM): a 12.8 m square at 5 cm
/// (256 × 256 cells), 16 × 16 tiles (512 B of log-odds each), 456 beams per turn (the LD06's
/// 4 500 points/s at 10 Hz = 450, in whole 12-point packets), and the ray store of the `rays`
/// measurement build.
pub const MPS2_AN386: BoardSizes = BoardSizes {
    width: 256,
    height: 256,
    tile_edge: 16,
    max_beams: 456,
    rays: 3072,
    scans: 128,
    local_rays: 128,
};

/// The nRF52840-DK (Cortex-M4F, 256 KiB of RAM): the same RAM as the reference board, so the
/// same buffers (docs/firmware.md, "nRF52840-DK").
pub const NRF52840: BoardSizes = MPS2_AN386;

/// The sizes this build of the application is made for: the board feature's, else (the host)
/// the reference board's.
pub const APP: BoardSizes = if cfg!(feature = "nrf52840") {
    NRF52840
} else {
    MPS2_AN386
};

// A streamed tile of log-odds (2 bytes a cell) fits one wire frame, on every board.
const _: () = assert!(2 * (MPS2_AN386.tile_edge as usize).pow(2) <= MAX_TILE_BYTES);
const _: () = assert!(2 * (NRF52840.tile_edge as usize).pow(2) <= MAX_TILE_BYTES);
