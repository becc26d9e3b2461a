//! `host-sim bench-insert`: online insertion throughput of `ogm_core::Mapper` on real CARMEN
//! logs, in the unit of the MRPT/OctoMap peer (`../shared/peers/insert_bench.cpp`), so the two
//! can be run one after the other on the same logs and compared as a ratio (docs/performance.md).
//!
//! * **Scans.** Every `FLASER`/`ROBOTLASER1` scan of each log ([`crate::sim::carmen`]), with the
//!   maximum range fixed at `--max-range` (default [`PEER_USABLE_RANGE_M`], the peer's 49.9 m):
//!   a reading `0 < r < max` is a hit, as the peer's valid beams; `r ≥ max` is a no-return,
//!   which the mapper traces to the maximum range as free space (`--no-returns drop` leaves
//!   them out instead; the peer's MRPT grid frees an invalid beam only when both neighbours are
//!   invalid too).
//! * **Grid.** [`crate::eval::eval_log::log_geometry`]: the bounding box of the poses and hit end
//!   points plus [`crate::eval::eval_log::MARGIN_M`], in cells of `--cell-size`; the Hähnel mapper
//!   with that maximum range.
//! * **Units.** *Cells walked* is the peer's: the sum over hits of `range / cell size` (a
//!   no-return is not counted, as the peer does not count invalid beams), times `--repeat`.
//!   *Cells updated* is the mapper's own: `cells_hit + cells_freed` summed over scans (each cell
//!   changes at most once per scan). Both are divided by the wall-clock time of the insertion
//!   loop alone (the log is read and the grid allocated before the clock starts).
//! * **Repeat.** `--repeat N` inserts the whole log N times into the same map (as the peer's
//!   third argument): more work per measurement, less noise.
//!
//! The map's SHA-256 is printed too: it must not change when the mapper is optimised.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Context};
use ogm_core::map::mapper::marks_len;
use ogm_core::{Beam, LogOdds, LogOddsGrid, Mapper, MapperConfig, Range};
use serde::Serialize;
use sha2::{Digest, Sha256};

use crate::eval::eval_log::{log_geometry, log_name, MARGIN_M};
use crate::sim::carmen::{read_log, ReadOptions};
use crate::sim::explore::ScanRecord;

/// The peer's usable range (m): readings `0 < r < 49.9` are its valid beams.
pub const PEER_USABLE_RANGE_M: f64 = 49.9;

/// What to do with no-return beams (readings at or beyond the maximum range).
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NoReturns {
    /// Insert them: the mapper frees cells up to the maximum range (what the product does).
    #[default]
    Free,
    /// Leave them out of the scans.
    Drop,
}

/// `host-sim bench-insert` arguments.
#[derive(clap::Args, Clone, Debug)]
pub struct BenchInsertArgs {
    /// CARMEN logs (plain text or gzip), each benchmarked on its own.
    #[arg(long, num_args = 1.., required = true)]
    pub log: Vec<PathBuf>,
    /// Cell size in metres (a whole number of millimetres).
    #[arg(long, default_value_t = 0.05)]
    pub cell_size: f64,
    /// Insert each log this many times into the same map.
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// Maximum range in metres: readings at or beyond it are no-returns (the peer's 49.9).
    #[arg(long, default_value_t = PEER_USABLE_RANGE_M)]
    pub max_range: f64,
    /// No-return beams: `free` (insert them, the mapper frees up to the maximum range) or
    /// `drop`.
    #[arg(long, value_enum, default_value_t = NoReturns::Free)]
    pub no_returns: NoReturns,
    /// Print one JSON object per log instead of the text lines.
    #[arg(long)]
    pub json: bool,
}

/// One log's figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct InsertFigures {
    /// Log name (file name without `.log` / `.gz`).
    pub log: String,
    /// Scans per pass.
    pub scans: usize,
    /// Hit beams per pass (the peer's valid beams).
    pub beams: u64,
    /// No-return beams per pass (inserted or dropped, see `no_returns`).
    pub no_return_beams: u64,
    /// How no-returns were handled.
    pub no_returns: NoReturns,
    /// Cell size (m).
    pub cell_size_m: f64,
    /// Grid width × height (cells).
    pub grid: (u16, u16),
    /// Passes over the log.
    pub repeat: u32,
    /// Cells walked, the peer's unit: Σ range / cell size over hits, × repeat.
    pub cells_walked: f64,
    /// Cells updated: Σ (cells_hit + cells_freed) over all scans of all passes.
    pub cells_updated: u64,
    /// Seconds in the insertion loop.
    pub seconds: f64,
    /// Million cells walked per second.
    pub mcells_walked_per_s: f64,
    /// Million cells updated per second.
    pub mcells_updated_per_s: f64,
    /// SHA-256 of the final map (raw `i16` log-odds, little endian, row-major).
    pub map_sha256: String,
}

/// Runs the benchmark over every log and prints a line (or JSON object) per log.
pub fn cli(args: &BenchInsertArgs) -> anyhow::Result<()> {
    ensure!(
        !args.log.is_empty(),
        "bench-insert: give at least one --log"
    );
    for path in &args.log {
        let f = bench_log(path, args)?;
        if args.json {
            println!("{}", serde_json::to_string(&f)?);
        } else {
            println!(
                "{}: scans={} beams={} cells_walked={:.0} res={:.3} repeat={} grid={}x{} \
                 no_returns={} ({:?})",
                f.log,
                f.scans,
                f.beams,
                f.cells_walked,
                f.cell_size_m,
                f.repeat,
                f.grid.0,
                f.grid.1,
                f.no_return_beams,
                f.no_returns,
            );
            println!(
                "ogm_core_mapper seconds={:.4} Mcells_walked_per_s={:.1} \
                 Mcells_updated_per_s={:.1} cells_updated={} map_sha256={}",
                f.seconds,
                f.mcells_walked_per_s,
                f.mcells_updated_per_s,
                f.cells_updated,
                f.map_sha256,
            );
        }
    }
    Ok(())
}

/// Reads one log and benchmarks insertion into a fresh map.
pub fn bench_log(path: &Path, args: &BenchInsertArgs) -> anyhow::Result<InsertFigures> {
    ensure!(
        args.cell_size.is_finite() && args.cell_size > 0.0,
        "--cell-size {} m: must be a positive number of metres",
        args.cell_size
    );
    ensure!(
        args.max_range.is_finite() && args.max_range >= 0.001 && args.max_range <= 4.0e6,
        "--max-range {} m: must be between 1 mm and 4000 km",
        args.max_range
    );
    ensure!(args.repeat >= 1, "--repeat must be at least 1");
    let log = read_log(
        path,
        &ReadOptions {
            max_range_m: Some(args.max_range),
        },
    )?;
    if log.info.malformed_lines > 0 {
        eprintln!(
            "warning: {}: {} malformed lines skipped",
            path.display(),
            log.info.malformed_lines
        );
    }
    ensure!(
        !log.scans.is_empty(),
        "{}: no FLASER or ROBOTLASER1 scan",
        path.display()
    );
    // ROBOTLASER1 lines carry their own maximum range; this benchmark uses one for all scans.
    let max_mm = (args.max_range * 1000.0).round() as u32;
    let scans = prepare(log.scans, args.no_returns);
    bench_scans(
        &log_name(path),
        &scans,
        args.cell_size,
        max_mm,
        args.repeat,
        args.no_returns,
    )
    .with_context(|| path.display().to_string())
}

/// The scans as inserted: no-returns kept or dropped.
fn prepare(mut scans: Vec<ScanRecord>, no_returns: NoReturns) -> Vec<ScanRecord> {
    if no_returns == NoReturns::Drop {
        for s in &mut scans {
            s.beams.retain(|b| matches!(b.range, Range::Hit(_)));
        }
    }
    scans
}

/// Benchmarks `scans` (already prepared) into a fresh map of the log's geometry.
pub fn bench_scans(
    name: &str,
    scans: &[ScanRecord],
    cell_m: f64,
    max_range_mm: u32,
    repeat: u32,
    no_returns: NoReturns,
) -> anyhow::Result<InsertFigures> {
    ensure!(!scans.is_empty(), "no scans to insert");
    ensure!(repeat >= 1, "--repeat must be at least 1");
    ensure!(max_range_mm >= 1, "maximum range must be at least 1 mm");
    let geometry = log_geometry(scans, cell_m, max_range_mm, MARGIN_M)?;
    let cell_mm = f64::from(geometry.cell_mm());
    let (mut beams, mut no_return_beams, mut walked_mm) = (0u64, 0u64, 0.0f64);
    for b in scans.iter().flat_map(|s| &s.beams) {
        match b.range {
            Range::Hit(mm) if mm < max_range_mm => {
                beams += 1;
                walked_mm += f64::from(mm);
            }
            // The reader turned readings at or beyond the maximum range into no-returns; a hit
            // rounded up to it (within half a millimetre) is one too for the mapper.
            Range::Hit(_) | Range::NoReturn => no_return_beams += 1,
        }
    }
    let cells_walked = walked_mm / cell_mm * f64::from(repeat);
    let grid = LogOddsGrid::new(geometry, vec![LogOdds::ZERO; geometry.len()])?;
    let mut mapper = Mapper::new(
        grid,
        vec![0u32; marks_len(geometry.len())],
        MapperConfig::new(max_range_mm),
    )?;
    let t0 = Instant::now();
    let cells_updated = insert_all(&mut mapper, scans, repeat)?;
    let seconds = t0.elapsed().as_secs_f64().max(1e-9);
    let mut sha = Sha256::new();
    for c in mapper.grid().cells() {
        sha.update(c.0.to_le_bytes());
    }
    Ok(InsertFigures {
        log: name.to_string(),
        scans: scans.len(),
        beams,
        no_return_beams,
        no_returns,
        cell_size_m: cell_mm / 1000.0,
        grid: (geometry.width(), geometry.height()),
        repeat,
        cells_walked,
        cells_updated,
        seconds,
        mcells_walked_per_s: cells_walked / seconds / 1e6,
        mcells_updated_per_s: cells_updated as f64 / seconds / 1e6,
        map_sha256: sha.finalize().iter().map(|b| format!("{b:02x}")).collect(),
    })
}

/// The timed loop: `repeat` passes over `scans`; returns the cells updated. Not inlined, so that
/// `valgrind --tool=callgrind --toggle-collect='*bench_insert*insert_all*'` counts exactly the
/// insertion's instructions.
#[inline(never)]
pub fn insert_all(
    mapper: &mut Mapper<Vec<LogOdds>, Vec<u32>>,
    scans: &[ScanRecord],
    repeat: u32,
) -> anyhow::Result<u64> {
    let mut cells_updated = 0u64;
    for _ in 0..repeat {
        for s in scans {
            let beams: &[Beam] = std::hint::black_box(&s.beams);
            let st = mapper.insert_scan(&s.pose, beams)?;
            cells_updated += u64::from(st.cells_hit) + u64::from(st.cells_freed);
        }
    }
    Ok(cells_updated)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::{Angle, Pose};
    use std::io::Write;

    fn args(log: PathBuf) -> BenchInsertArgs {
        BenchInsertArgs {
            log: vec![log],
            cell_size: 0.05,
            repeat: 2,
            max_range: PEER_USABLE_RANGE_M,
            no_returns: NoReturns::Free,
            json: false,
        }
    }

    /// A tiny FLASER log: 3 scans of 5 beams, one beam beyond the peer's range.
    fn tiny_log() -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        for k in 0..3 {
            writeln!(
                f,
                "FLASER 5 1.0 2.0 60.0 1.5 0.5 {x} 0.0 0.0 {x} 0.0 0.0 1.0 host 1.0",
                x = f64::from(k) * 0.1
            )
            .unwrap();
        }
        f
    }

    #[test]
    fn counts_the_peers_unit() {
        let log = tiny_log();
        let f = bench_log(log.path(), &args(log.path().to_path_buf())).unwrap();
        assert_eq!(
            (f.scans, f.beams, f.no_return_beams, f.repeat),
            (3, 12, 3, 2)
        );
        // (1.0 + 2.0 + 1.5 + 0.5) m per scan = 100 cells of 5 cm; 3 scans, 2 passes.
        assert!((f.cells_walked - 600.0).abs() < 1e-6, "{}", f.cells_walked);
        assert!(f.cells_updated > 0);
        assert_eq!(f.map_sha256.len(), 64);
        let mut drop = args(log.path().to_path_buf());
        drop.no_returns = NoReturns::Drop;
        let g = bench_log(log.path(), &drop).unwrap();
        assert_eq!((g.beams, g.no_return_beams), (12, 0));
        assert!(g.cells_updated < f.cells_updated);
    }

    #[test]
    fn bad_input_is_an_error() {
        let missing = PathBuf::from("/nonexistent/ogm/bench-insert.log");
        assert!(bench_log(&missing, &args(missing.clone())).is_err());
        let empty = tempfile::NamedTempFile::new().unwrap();
        let e = bench_log(empty.path(), &args(empty.path().to_path_buf())).unwrap_err();
        assert!(format!("{e:#}").contains("no FLASER"), "{e:#}");
        let log = tiny_log();
        for cell in [0.0, -1.0, f64::NAN, 0.0001, 1e12] {
            let mut a = args(log.path().to_path_buf());
            a.cell_size = cell;
            assert!(bench_log(log.path(), &a).is_err(), "cell size {cell}");
        }
        let mut a = args(log.path().to_path_buf());
        a.repeat = 0;
        assert!(bench_log(log.path(), &a).is_err());
        a.repeat = 1;
        a.max_range = f64::INFINITY;
        assert!(bench_log(log.path(), &a).is_err());
        let scan = ScanRecord {
            pose: Pose {
                x_mm: 0,
                y_mm: 0,
                heading: Angle::ZERO,
            },
            beams: vec![],
        };
        assert!(bench_scans("x", &[], 0.05, 1000, 1, NoReturns::Free).is_err());
        assert!(bench_scans("x", &[scan], 0.05, 1000, 1, NoReturns::Free).is_ok());
    }
}
