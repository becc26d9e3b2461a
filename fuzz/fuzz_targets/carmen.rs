//! The CARMEN log reader (`host_sim::sim::carmen::parse_log`): arbitrary text (and bytes) as a log,
//! with or without a given maximum range (the first byte picks it, NaN and ∞ included).
//! Invariants: nothing panics; only an I/O-level problem is an error; every accepted scan is
//! counted once; hits and no-returns add up to the beams kept; warnings are capped.
#![no_main]

use host_sim::sim::carmen::{parse_log, ReadOptions, MAX_WARNINGS};
use libfuzzer_sys::fuzz_target;
use ogm_core::Range;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, text)) = data.split_first() else {
        return;
    };
    let max_range_m = match sel % 8 {
        0 | 1 | 2 | 3 => None,
        4 => Some(f64::NAN),
        5 => Some(f64::INFINITY),
        6 => Some(-1.0),
        _ => Some(f64::from(sel) / 4.0),
    };
    let Ok(log) = parse_log(text, &ReadOptions { max_range_m }) else {
        return;
    };
    let info = &log.info;
    assert_eq!(log.scans.len(), info.flaser + info.robotlaser1);
    assert!(info.warnings.len() <= MAX_WARNINGS);
    assert!(info.warnings.len() <= info.malformed_lines);
    let (mut hits, mut misses) = (0usize, 0usize);
    for s in &log.scans {
        for b in &s.beams {
            match b.range {
                Range::Hit(_) => hits += 1,
                Range::NoReturn => misses += 1,
            }
        }
    }
    assert_eq!((hits, misses), (info.hits, info.no_returns));
});
