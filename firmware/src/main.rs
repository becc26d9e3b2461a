//! ogm-firmware: occupancy grid mapping on a Cortex-M4F.
//!
//! For now (groundwork): boot, build an ogm-core [`Mapper`] over a `static` 256 × 256 grid of
//! 5 cm cells (12.8 m × 12.8 m), insert a synthetic lidar scan of a square room from a few
//! poses, time each insert, log the results with defmt, write a one-line report with the grid's
//! checksum to the host link (UART1), and exit. The LD06 driver, the postcard map stream and
//! the sampler replace the synthetic part later.
//!
//! The synthetic scene and the checksum are fully specified here (integer arithmetic only, via
//! ogm-core's own trigonometry), so a host test can rebuild the same grid with ogm-core and
//! compare checksums bit for bit:
//! * room: walls on x = ±4000 mm and y = ±4000 mm; grid origin (−6400, −6400) mm;
//! * scan: 360 beams, beam i at `Angle::from_centidegrees(100 · i)` relative to the heading,
//!   range = distance to the first wall along `heading + angle` (ogm-core's Q30 sin/cos,
//!   `((±4000 − p) << 30) / dir` truncated), `Hit` if < 12 000 mm else `NoReturn`;
//! * inserts: the [`POSES`] in order, `MapperConfig::new(12_000)` (Hähnel model, default clamp);
//! * checksum: FNV-1a (32-bit) over every cell's raw `i16` as little-endian bytes, row-major.
#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[allow(unsafe_code)] // all hardware access (and all `unsafe`) lives in here
mod board;

use core::fmt::Write as _;
use core::sync::atomic::{AtomicBool, Ordering};

use board::{Board, StaticBuf, Timer};
use defmt::{error, info};
use embedded_io::Write as _;
use ogm_core::mapper::marks_len;
use ogm_core::{
    Angle, Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose, Range, ScanBuf,
};

/// Grid width and height in cells.
const GRID_CELLS_PER_SIDE: u16 = 256;
/// Cell edge in mm.
const CELL_MM: u32 = 50;
const CELLS: usize = GRID_CELLS_PER_SIDE as usize * GRID_CELLS_PER_SIDE as usize;
const MARK_WORDS: usize = marks_len(CELLS);
/// World position of the grid's lower-left corner (the grid is centred on the origin).
const GRID_ORIGIN_MM: i32 = -(GRID_CELLS_PER_SIDE as i32 * CELL_MM as i32) / 2;

/// The map (128 KiB) and the mapper's per-scan marks (8 KiB): zero-initialised statics in
/// `.bss`, handed out once.
static GRID: StaticBuf<[LogOdds; CELLS]> = StaticBuf::new([LogOdds::ZERO; CELLS]);
static MARKS: StaticBuf<[u32; MARK_WORDS]> = StaticBuf::new([0; MARK_WORDS]);

/// Beams per scan (LD06: ~450 per turn at 10 Hz; 360 keeps the synthetic scan at 1°).
const BEAMS: usize = 360;
/// LD06 maximum range.
const MAX_RANGE_MM: u32 = 12_000;
/// Half the side of the synthetic square room.
const ROOM_HALF_MM: i64 = 4_000;

/// Poses the synthetic scan is inserted from, in order (the first twice).
const POSES: [Pose; 4] = [
    pose(0, 0, 0),
    pose(1_500, -1_000, 30),
    pose(-2_000, 1_800, 200),
    pose(0, 0, 0),
];

const fn pose(x_mm: i32, y_mm: i32, heading_deg: u32) -> Pose {
    Pose {
        x_mm,
        y_mm,
        // = Angle::from_centidegrees(heading_deg * 100), which is not `const`.
        heading: Angle(((heading_deg as u64 * 65_536 + 180) / 360) as u16),
    }
}

/// `cortex_m::asm::delay` argument used to check the tick ↔ instruction relation at boot.
const CALIBRATION_CYCLES: u32 = 1_000_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(mut board) = Board::take() else {
        defmt::panic!("Board::take called twice");
    };
    info!(
        "boot: ogm-firmware {=str} on {=str}",
        env!("CARGO_PKG_VERSION"),
        board::BOARD_NAME
    );

    // `asm::delay(n)` runs exactly 2·(n + 1) instructions (a `subs; bne` loop, n + 1 times).
    // Under QEMU with `-icount shift=0` every instruction is 1 ns, i.e. 1/40 tick, so the
    // measured time must come out at 1000 ps per instruction (±1 tick); without icount the ticks
    // are host wall-clock time and the ratio is meaningless.
    let t0 = board.timer.now();
    cortex_m::asm::delay(CALIBRATION_CYCLES);
    let cal_ns = Timer::ticks_to_ns(board.timer.now().wrapping_sub(t0));
    let cal_insns = 2 * (u64::from(CALIBRATION_CYCLES) + 1);
    info!(
        "timer: {=u64} instructions took {=u64} ns = {=u64} ps per instruction (1000 under -icount shift=0)",
        cal_insns,
        cal_ns,
        (cal_ns * 1000 + cal_insns / 2) / cal_insns
    );

    let code = match map_synthetic_room(&mut board) {
        Ok(()) => 0,
        Err(e) => {
            error!("mapping failed: {}", e);
            1
        }
    };
    let stack = board::stack_usage();
    info!(
        "stack: {=u32} of {=u32} bytes used (high-water mark)",
        stack.used, stack.size
    );
    info!("exit {=i32}", code);
    board::exit(code)
}

/// Builds the mapper, inserts the synthetic scans, reports the checksum.
fn map_synthetic_room(board: &mut Board) -> Result<(), ogm_core::Error> {
    let geometry = GridGeometry::new(
        GRID_CELLS_PER_SIDE,
        GRID_CELLS_PER_SIDE,
        CELL_MM,
        GRID_ORIGIN_MM,
        GRID_ORIGIN_MM,
    )?;
    let (Some(cells), Some(marks)) = (GRID.take(), MARKS.take()) else {
        defmt::panic!("map storage taken twice");
    };
    let grid = LogOddsGrid::new(geometry, cells)?;
    let mut mapper = Mapper::new(grid, marks, MapperConfig::new(MAX_RANGE_MM))?;
    info!(
        "mapper: {=u16}x{=u16} cells of {=u32} mm, {=usize} KiB grid + {=usize} KiB marks",
        GRID_CELLS_PER_SIDE,
        GRID_CELLS_PER_SIDE,
        CELL_MM,
        core::mem::size_of::<[LogOdds; CELLS]>() / 1024,
        core::mem::size_of::<[u32; MARK_WORDS]>() / 1024
    );

    let mut scan: ScanBuf<BEAMS> = ScanBuf::new();
    let (mut total_ticks, mut total_cells) = (0u64, 0u64);
    for (k, pose) in POSES.iter().enumerate() {
        room_scan(pose, &mut scan);
        let t0 = board.timer.now();
        let stats = mapper.insert_scan(pose, scan.beams())?;
        let ticks = board.timer.now().wrapping_sub(t0);
        let cells = u64::from(stats.cells_hit + stats.cells_freed);
        total_ticks += u64::from(ticks);
        total_cells += cells;
        info!(
            "scan {=usize}: pose {} -> {}; {=u32} ticks = {=u64} ns",
            k,
            pose,
            stats,
            ticks,
            Timer::ticks_to_ns(ticks)
        );
    }
    let n = POSES.len() as u64;
    let ns = Timer::ticks_to_ns(1) * total_ticks;
    info!(
        "insert: {=u64} ns per scan on average, {=u64} ns per updated cell ({=u64} cells/scan)",
        ns / n,
        ns / total_cells.max(1),
        total_cells / n
    );

    let summary = GridSummary::of(mapper.grid().cells());
    info!("grid: {}", summary);

    // The host link gets one text line (a stand-in for the postcard map stream).
    let mut line: heapless::String<128> = heapless::String::new();
    // Cannot fail: the line is < 128 bytes.
    let _ = writeln!(
        line,
        "OGM checksum={:08x} scans={} cells={} occupied={} free={} unknown={}",
        summary.checksum,
        POSES.len(),
        CELLS,
        summary.occupied,
        summary.free,
        summary.unknown
    );
    match board
        .link
        .write_all(line.as_bytes())
        .and_then(|()| board.link.flush())
    {
        Ok(()) => info!("uart1: {=str}", line.as_str().trim_end()),
        Err(e) => error!("uart1 write failed: {}", e),
    }
    Ok(())
}

/// Fills `scan` with the synthetic square-room scan seen from `pose` (see the crate docs).
fn room_scan(pose: &Pose, scan: &mut ScanBuf<BEAMS>) {
    scan.clear();
    for i in 0..BEAMS as u32 {
        let angle = Angle::from_centidegrees(i * 36_000 / BEAMS as u32);
        let dir = pose.heading.wrapping_add(angle);
        let tx = wall_distance(pose.x_mm, dir.cos_q30());
        let ty = wall_distance(pose.y_mm, dir.sin_q30());
        let r = tx.min(ty);
        let range = if r < i64::from(MAX_RANGE_MM) {
            Range::Hit(r as u32)
        } else {
            Range::NoReturn
        };
        scan.push(Beam { angle, range });
    }
}

/// Distance (mm) from coordinate `p` to the wall at ±`ROOM_HALF_MM` along a direction whose
/// component on this axis is `d` (Q30); `i64::MAX` if parallel.
fn wall_distance(p: i32, d: i32) -> i64 {
    let (p, d) = (i64::from(p), i64::from(d));
    match d {
        0 => i64::MAX,
        d if d > 0 => ((ROOM_HALF_MM - p) << 30) / d,
        d => ((-ROOM_HALF_MM - p) << 30) / d,
    }
}

/// Cell counts and the FNV-1a checksum of a grid.
#[derive(defmt::Format)]
struct GridSummary {
    checksum: u32,
    occupied: u32,
    free: u32,
    unknown: u32,
}

impl GridSummary {
    fn of(cells: &[LogOdds]) -> Self {
        let mut s = GridSummary {
            checksum: 0x811c_9dc5,
            occupied: 0,
            free: 0,
            unknown: 0,
        };
        for c in cells {
            for b in c.raw().to_le_bytes() {
                s.checksum = (s.checksum ^ u32::from(b)).wrapping_mul(0x0100_0193);
            }
            match c.raw() {
                0 => s.unknown += 1,
                r if r > 0 => s.occupied += 1,
                _ => s.free += 1,
            }
        }
        s
    }
}

/// Logs the panic with defmt and exits with status 101 (like a Rust test that panicked), so a
/// QEMU run fails fast instead of hanging until its timeout.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    static PANICKING: AtomicBool = AtomicBool::new(false);
    if !PANICKING.swap(true, Ordering::Relaxed) {
        error!("panic: {}", defmt::Display2Format(info));
    }
    board::exit(101)
}
