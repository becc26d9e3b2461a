//! Every large buffer of the firmware: zero-initialised `static`s in `.bss` (no heap, never built
//! on the stack), handed out once. Sizes are the board's (`Board::SIZES`, written once per board
//! in `ogm_firmware::sizes`). The layout and its justification are in
//! docs/firmware.md ("RAM layout").

use crate::board::{SharedMarks, StaticArray, StaticBuf, StaticSlot};
use ogm_core::lidar::pose_track::Mount;
use ogm_core::lidar::turn::Turns;
use ogm_core::map::mapper::marks_len;
use ogm_core::sampler::gibbs::{block_words, LocalRay};
use ogm_core::sampler::ray_store::{StoredRay, StoredScan};
use ogm_core::session::{Buffers, Session, Storage, TileRestore};
use ogm_core::wire::{MAX_DEVICE_FRAME, MAX_TILE_BYTES};
use ogm_core::{LogOdds, ScanBuf};
use ogm_firmware::sizes::BoardSizes;
use ogm_firmware::Memory;

/// This board's sizes.
const SZ: BoardSizes = <crate::board::Selected as crate::board::Board>::SIZES;

// The application is built for the same sizes (it reports them in `Hello`).
const _: () = assert!(
    SZ.width == ogm_firmware::sizes::APP.width
        && SZ.height == ogm_firmware::sizes::APP.height
        && SZ.tile_edge == ogm_firmware::sizes::APP.tile_edge
        && SZ.max_beams == ogm_firmware::sizes::APP.max_beams
);

/// Cells of the map.
pub const CELLS: usize = SZ.cells();
/// Words of the mapper's per-scan mark bitset.
pub const MARK_WORDS: usize = marks_len(CELLS);
/// Words of the sampler's map sample (one bit per cell).
pub const SAMPLE_WORDS: usize = CELLS.div_ceil(32);
/// Ray store and tile-visit sizes: the ray data terms' (feature `rays`), else one of each — the
/// per-cell evidence term stores no rays, and the 24 KiB go to the stack.
pub const RAYS: usize = if cfg!(feature = "rays") { SZ.rays } else { 1 };
/// See [`RAYS`].
pub const SCANS: usize = if cfg!(feature = "rays") { SZ.scans } else { 1 };
/// See [`RAYS`].
pub const LOCAL_RAYS: usize = if cfg!(feature = "rays") {
    SZ.local_rays
} else {
    1
};

/// The log-odds map: 256 × 256 × 2 B = 128 KiB.
static GRID: StaticBuf<[LogOdds; CELLS]> = StaticBuf::new([LogOdds::ZERO; CELLS]);
/// The mapper's "touched in this scan" bits: 8 KiB; between scans, the scan matcher's points
/// (`SharedMarks`).
static MARKS: StaticBuf<[u32; MARK_WORDS]> = StaticBuf::new([0; MARK_WORDS]);
/// The sampler's current map sample: 8 KiB.
static SAMPLE: StaticBuf<[u32; SAMPLE_WORDS]> = StaticBuf::new([0; SAMPLE_WORDS]);
/// The sampler's marginal counts, `u8`: 64 KiB.
static COUNTS: StaticBuf<[u8; CELLS]> = StaticBuf::new([0; CELLS]);
/// The ray store's rays: 6 B each.
static RAY_BUF: StaticArray<StoredRay, { RAYS }> = StaticArray::new();
/// The ray store's scans: 20 B each.
static SCAN_BUF: StaticArray<StoredScan, { SCANS }> = StaticArray::new();
/// The sampler's per-tile ray list: 24 B each.
static LOCAL_BUF: StaticArray<LocalRay, { LOCAL_RAYS }> = StaticArray::new();
/// Which local rays touch which block of a tile visit (8 × 8 blocks): one bit per (block, ray).
pub const BLOCK_WORDS: usize =
    block_words(LOCAL_RAYS, ogm_core::sampler::gibbs::DEFAULT_BLOCK_GRID);
static BLOCKS: StaticBuf<[u32; BLOCK_WORDS]> = StaticBuf::new([0; BLOCK_WORDS]);
/// The scan being received: 12 B per beam.
static SCAN: StaticBuf<ScanBuf<{ SZ.max_beams }>> = StaticBuf::new(ScanBuf::new());
/// The lidar turn being assembled: 12 B per beam.
static TURN: StaticBuf<ScanBuf<{ SZ.max_beams }>> = StaticBuf::new(ScanBuf::new());
/// Lidar packets waiting for their pose, and the poses (~4 KiB).
static TURNS: StaticBuf<Turns> = StaticBuf::new(Turns::new(Mount::ZERO, false));
/// One encoded outgoing frame.
static TX: StaticBuf<[u8; MAX_DEVICE_FRAME]> = StaticBuf::new([0; MAX_DEVICE_FRAME]);
/// One tile's cells, before encoding.
static TILE: StaticBuf<[u8; MAX_TILE_BYTES]> = StaticBuf::new([0; MAX_TILE_BYTES]);
/// A stored tile the host is sending back, being assembled.
static RESTORE: StaticBuf<TileRestore> = StaticBuf::new(TileRestore::new());

/// The mapping engine itself (~2.5 KiB, mostly the sampler's forward-model tables): a `static`
/// too, so it lives in no stack frame.
static SESSION: StaticSlot<Option<Session<Static>>> = StaticSlot::new();

/// This firmware's storage: every buffer a `&'static mut` array of the sizes above.
pub struct Static;

impl Storage for Static {
    type Count = u8;
    type Grid = &'static mut [LogOdds; CELLS];
    type Marks = SharedMarks<MARK_WORDS>;
    type Scans = &'static mut [StoredScan; SCANS];
    type Rays = &'static mut [StoredRay; RAYS];
    type Sample = &'static mut [u32; SAMPLE_WORDS];
    type Counts = &'static mut [u8; CELLS];
    type Local = &'static mut [LocalRay; LOCAL_RAYS];
    type Blocks = &'static mut [u32; BLOCK_WORDS];
}

/// All of it, the first time; `None` afterwards.
pub fn take() -> Option<Memory<'static, Static>> {
    Some(Memory {
        buffers: Buffers {
            width: SZ.width,
            height: SZ.height,
            grid: GRID.take()?,
            marks: SharedMarks(MARKS.take()?),
            sample: SAMPLE.take()?,
            counts: COUNTS.take()?,
            rays: RAY_BUF.take_filled(StoredRay::default)?,
            scans: SCAN_BUF.take_filled(StoredScan::default)?,
            local: LOCAL_BUF.take_filled(LocalRay::default)?,
            blocks: BLOCKS.take()?,
        },
        session: SESSION.put_with(|| None)?,
        scan: SCAN.take()?,
        turn: TURN.take()?,
        turns: TURNS.take()?,
        tx: TX.take()?,
        tile: TILE.take()?,
        restore: RESTORE.take()?,
    })
}
