//! A reader for CARMEN laser logs (plain text or gzip): `FLASER` and `ROBOTLASER1` lines.
//!
//! * `FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname
//!   logger_timestamp` — exactly `n + 11` fields. The scan is taken at the first pose
//!   (`x y theta`; in the corrected logs of `../shared/data/logs` it equals the odometry pose).
//!   The beam geometry is not in the line and follows from `n` (`../shared/data/README.md`):
//!   a 180° field of view starting at `theta − 90°`; an **odd** `n` includes both ends
//!   (181 → 1° steps, 361 → 0.5°), an **even** `n` does not (180 → 1°, 360 → 0.5°, the last
//!   beam at +89° / +89.5°). Other counts follow the same rule (step 180°/(n−1) for odd `n`,
//!   180°/n for even `n`). Note that CARMEN's own `carmen_laser_guess_fov` centres even counts
//!   instead (first beam at −89.5° for 180 beams); we follow the data README.
//! * `ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy
//!   remission_mode n r1..rn m e1..em laser_x laser_y laser_theta robot_x robot_y robot_theta tv
//!   rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname
//!   logger_timestamp` — exactly `n + m + 24` fields. The beams are at `start_angle +
//!   i·angular_resolution` from the **laser** pose, which is the pose used; `maximum_range` is
//!   that line's sensor range.
//!
//! **Maximum-range readings.** A reading at or beyond the sensor's maximum range becomes
//! [`Range::NoReturn`] (the beam frees space only). For `ROBOTLASER1` the range is in the line.
//! `FLASER` lines do not say it, and the logs use different sentinels (SICK 81.91 m but also
//! 81.87 / 81.83 m, 51.05–51.1 m in `fhw`, 32.759–32.767 m in `orebro`), so unless
//! [`ReadOptions::max_range_m`] is given the reader detects it: if the largest reading `M` of the
//! log's `FLASER` beams recurs (at least [`SENTINEL_MIN_COUNT`] readings within
//! [`SENTINEL_BAND`] of it), the maximum range is `(1 − SENTINEL_BAND)·M`; otherwise it is
//! [`DEFAULT_MAX_RANGE_M`] (the SICK LMS's 81.9 m).
//!
//! **Malformed lines** (wrong field count, a number that does not parse or is NaN/∞, a
//! truncated line, a scan with no beams, a negative reading count) are skipped and reported with
//! their 1-based line number in [`LogInfo::warnings`]; nothing here panics on bad input.
//! Readings that are negative or zero are not lines' faults but dropped beams
//! ([`LogInfo::invalid_readings`]). Blank lines, `#` comments and other message types (`ODOM`,
//! `PARAM`, `NEFF`, ...) are counted and ignored.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use anyhow::Context;
use ogm_core::{Angle, Beam, Pose, Range};
use serde::{Deserialize, Serialize};

use crate::sim::explore::ScanRecord;

/// Used when a log's `FLASER` readings show no max-range sentinel: the SICK LMS's 81.9 m.
pub const DEFAULT_MAX_RANGE_M: f64 = 81.9;

/// Relative width of the band below the largest reading that counts as the sentinel cluster.
pub const SENTINEL_BAND: f64 = 0.005;

/// Readings within [`SENTINEL_BAND`] of the largest needed to call it a max-range sentinel.
pub const SENTINEL_MIN_COUNT: usize = 10;

/// At most this many warnings are kept (all are counted in [`LogInfo::malformed_lines`]).
pub const MAX_WARNINGS: usize = 1000;

/// Reader settings.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReadOptions {
    /// Maximum range (m) for `FLASER` readings; `None` = detect it (see the module docs).
    pub max_range_m: Option<f64>,
}

/// A malformed line.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LineWarning {
    /// 1-based line number.
    pub line: usize,
    /// What is wrong with it.
    pub message: String,
}

impl std::fmt::Display for LineWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.message)
    }
}

/// How the `FLASER` maximum range was chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaxRangeSource {
    /// Given by the caller.
    Option,
    /// Detected from a recurring largest reading.
    Detected,
    /// No sentinel found: [`DEFAULT_MAX_RANGE_M`].
    Default,
}

/// What the reader found in a log.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LogInfo {
    /// Lines read (including blank ones).
    pub lines: usize,
    /// `FLASER` scans accepted.
    pub flaser: usize,
    /// `ROBOTLASER1` scans accepted.
    pub robotlaser1: usize,
    /// Lines of other message types, by type (ignored).
    pub other: BTreeMap<String, usize>,
    /// `#` comment lines.
    pub comments: usize,
    /// Blank lines.
    pub blank: usize,
    /// Malformed lines skipped.
    pub malformed_lines: usize,
    /// The first [`MAX_WARNINGS`] malformed lines, with line numbers.
    pub warnings: Vec<LineWarning>,
    /// Accepted scans by beam count.
    pub beam_counts: BTreeMap<usize, usize>,
    /// Maximum range (m) used for `FLASER` readings.
    pub flaser_max_range_m: f64,
    /// How it was chosen (`None` if the log has no `FLASER` scan).
    pub flaser_max_range_source: Option<MaxRangeSource>,
    /// Largest `maximum_range` (m) of the `ROBOTLASER1` lines (0 if none).
    pub robotlaser_max_range_m: f64,
    /// Beams with a hit.
    pub hits: usize,
    /// Beams at or beyond the maximum range ([`Range::NoReturn`]).
    pub no_returns: usize,
    /// Readings ≤ 0 (dropped).
    pub invalid_readings: usize,
    /// Largest hit range (m).
    pub max_hit_m: f64,
}

impl LogInfo {
    /// The sensor's maximum range (m) over all accepted scans.
    pub fn max_range_m(&self) -> f64 {
        let f = if self.flaser > 0 {
            self.flaser_max_range_m
        } else {
            0.0
        };
        f.max(self.robotlaser_max_range_m)
    }
}

/// A parsed log: scans in file order and what the reader found.
#[derive(Clone, Debug, PartialEq)]
pub struct CarmenLog {
    /// Scans (pose in mm / binary angle, beams relative to the heading).
    pub scans: Vec<ScanRecord>,
    /// Counters, warnings and sensor range.
    pub info: LogInfo,
}

/// A scan before its readings are classified.
struct RawScan {
    pose: (f64, f64, f64),
    start_rad: f64,
    step_rad: f64,
    ranges: Vec<f64>,
    /// `Some` for `ROBOTLASER1` (from the line), `None` for `FLASER` (from the log).
    max_range_m: Option<f64>,
}

/// Start angle and increment (degrees, relative to the heading) of an `n`-beam `FLASER` scan.
pub fn flaser_angles_deg(n: usize) -> (f64, f64) {
    let step = if n % 2 == 1 {
        180.0 / (n.saturating_sub(1).max(1)) as f64
    } else {
        180.0 / n.max(1) as f64
    };
    (-90.0, step)
}

/// Opens `path` (gzip if it starts with the gzip magic bytes, else plain text) and parses it.
pub fn read_log(path: &Path, opts: &ReadOptions) -> anyhow::Result<CarmenLog> {
    let mut file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut magic = [0u8; 2];
    let n = read_up_to(&mut file, &mut magic)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let reader: Box<dyn BufRead> = if n == 2 && magic == [0x1f, 0x8b] {
        Box::new(BufReader::new(flate2::read::MultiGzDecoder::new(file)))
    } else {
        Box::new(BufReader::new(file))
    };
    parse_log(reader, opts).with_context(|| format!("{}: cannot read", path.display()))
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// Parses a log from any reader. Errors only on I/O failure (including invalid UTF-8 or a
/// corrupt gzip stream); bad lines are warnings.
pub fn parse_log(reader: impl BufRead, opts: &ReadOptions) -> anyhow::Result<CarmenLog> {
    let mut info = LogInfo::default();
    let mut raw = Vec::new();
    for (i, line) in reader.split(b'\n').enumerate() {
        let bytes = line.with_context(|| format!("line {}", i + 1))?;
        info.lines += 1;
        let lineno = i + 1;
        let text = match std::str::from_utf8(&bytes) {
            Ok(t) => t,
            Err(_) => {
                warn(&mut info, lineno, "not UTF-8 text".into());
                continue;
            }
        };
        let mut fields = text.split_ascii_whitespace();
        let Some(tag) = fields.next() else {
            info.blank += 1;
            continue;
        };
        if tag.starts_with('#') {
            info.comments += 1;
            continue;
        }
        let rest: Vec<&str> = fields.collect();
        let parsed = match tag {
            "FLASER" => parse_flaser(&rest),
            "ROBOTLASER1" => parse_robotlaser1(&rest),
            other => {
                *info.other.entry(other.to_string()).or_default() += 1;
                continue;
            }
        };
        match parsed {
            Ok(scan) => {
                if scan.max_range_m.is_some() {
                    info.robotlaser1 += 1;
                } else {
                    info.flaser += 1;
                }
                raw.push(scan);
            }
            Err(msg) => warn(&mut info, lineno, format!("{tag}: {msg}")),
        }
    }
    // The FLASER maximum range.
    if info.flaser > 0 {
        let (range, source) = match opts.max_range_m {
            Some(r) => (r, MaxRangeSource::Option),
            None => detect_max_range(&raw),
        };
        info.flaser_max_range_m = range;
        info.flaser_max_range_source = Some(source);
    }
    let mut scans = Vec::with_capacity(raw.len());
    for r in raw {
        let max_range = r.max_range_m.unwrap_or(info.flaser_max_range_m);
        if let Some(m) = r.max_range_m {
            info.robotlaser_max_range_m = info.robotlaser_max_range_m.max(m);
        }
        let mut beams = Vec::with_capacity(r.ranges.len());
        for (i, &z) in r.ranges.iter().enumerate() {
            let angle = Angle::from_radians(r.start_rad + i as f64 * r.step_rad);
            let range = if z <= 0.0 {
                info.invalid_readings += 1;
                continue;
            } else if z >= max_range {
                info.no_returns += 1;
                Range::NoReturn
            } else {
                info.hits += 1;
                info.max_hit_m = info.max_hit_m.max(z);
                Range::Hit(metres_to_mm(z))
            };
            beams.push(Beam { angle, range });
        }
        *info.beam_counts.entry(r.ranges.len()).or_default() += 1;
        let (x, y, th) = r.pose;
        scans.push(ScanRecord {
            pose: Pose {
                x_mm: metres_to_mm_i32(x),
                y_mm: metres_to_mm_i32(y),
                heading: Angle::from_radians(th),
            },
            beams,
        });
    }
    Ok(CarmenLog { scans, info })
}

fn warn(info: &mut LogInfo, line: usize, message: String) {
    info.malformed_lines += 1;
    if info.warnings.len() < MAX_WARNINGS {
        info.warnings.push(LineWarning { line, message });
    }
}

/// Millimetres of a positive finite distance (saturating at `u32::MAX`).
fn metres_to_mm(m: f64) -> u32 {
    (m * 1000.0).round().clamp(0.0, f64::from(u32::MAX)) as u32
}

fn metres_to_mm_i32(m: f64) -> i32 {
    (m * 1000.0)
        .round()
        .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}

/// The sentinel rule of the module docs, over the `FLASER` readings.
fn detect_max_range(raw: &[RawScan]) -> (f64, MaxRangeSource) {
    let readings = || {
        raw.iter()
            .filter(|r| r.max_range_m.is_none())
            .flat_map(|r| r.ranges.iter().copied())
    };
    let top = readings().fold(0.0f64, f64::max);
    if top > 0.0 {
        let cut = top * (1.0 - SENTINEL_BAND);
        if readings().filter(|&z| z >= cut).count() >= SENTINEL_MIN_COUNT {
            return (cut, MaxRangeSource::Detected);
        }
    }
    (DEFAULT_MAX_RANGE_M, MaxRangeSource::Default)
}

fn number(s: &str, what: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("{what} is {v}, not a finite number")),
        Err(_) => Err(format!("{what} `{}` is not a number", clip(s))),
    }
}

fn count(s: &str, what: &str) -> Result<usize, String> {
    s.parse::<usize>()
        .map_err(|_| format!("{what} `{}` is not a non-negative integer", clip(s)))
}

/// A field quoted in a message, shortened.
fn clip(s: &str) -> String {
    if s.chars().count() > 24 {
        format!("{}…", s.chars().take(24).collect::<String>())
    } else {
        s.to_string()
    }
}

fn ranges(fields: &[&str]) -> Result<Vec<f64>, String> {
    fields
        .iter()
        .enumerate()
        .map(|(i, s)| number(s, &format!("reading {}", i + 1)))
        .collect()
}

fn parse_flaser(f: &[&str]) -> Result<RawScan, String> {
    let n = count(f.first().ok_or("no reading count")?, "reading count")?;
    if n == 0 {
        return Err("no readings (reading count 0)".into());
    }
    let expected = n
        .checked_add(10)
        .ok_or("reading count too large".to_string())?;
    if f.len() != expected {
        return Err(format!(
            "{} fields after FLASER, expected {expected} for {n} readings (n, readings, x y theta \
             odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp)",
            f.len()
        ));
    }
    let z = ranges(&f[1..=n])?;
    let p = &f[n + 1..];
    let x = number(p[0], "x")?;
    let y = number(p[1], "y")?;
    let th = number(p[2], "theta")?;
    for (k, what) in [(3, "odom_x"), (4, "odom_y"), (5, "odom_theta")] {
        number(p[k], what)?;
    }
    let (start, step) = flaser_angles_deg(n);
    Ok(RawScan {
        pose: (x, y, th),
        start_rad: start.to_radians(),
        step_rad: step.to_radians(),
        ranges: z,
        max_range_m: None,
    })
}

fn parse_robotlaser1(f: &[&str]) -> Result<RawScan, String> {
    // laser_type start fov res max_range accuracy remission_mode n
    if f.len() < 8 {
        return Err(format!("truncated: {} fields after ROBOTLASER1", f.len()));
    }
    let start = number(f[1], "start_angle")?;
    number(f[2], "field_of_view")?;
    let res = number(f[3], "angular_resolution")?;
    let max_range = number(f[4], "maximum_range")?;
    if max_range <= 0.0 {
        return Err(format!("maximum_range {max_range} is not positive"));
    }
    let n = count(f[7], "reading count")?;
    if n == 0 {
        return Err("no readings (reading count 0)".into());
    }
    let m_at = n.checked_add(8).ok_or("reading count too large")?;
    let m = count(
        f.get(m_at)
            .ok_or_else(|| format!("truncated: {} fields for {n} readings", f.len()))?,
        "remission count",
    )?;
    let expected = m_at
        .checked_add(1)
        .and_then(|v| v.checked_add(m))
        .and_then(|v| v.checked_add(14))
        .ok_or("remission count too large")?;
    if f.len() != expected {
        return Err(format!(
            "{} fields after ROBOTLASER1, expected {expected} for {n} readings and {m} remissions",
            f.len()
        ));
    }
    let z = ranges(&f[8..m_at])?;
    let p = &f[m_at + 1 + m..];
    let x = number(p[0], "laser_pose_x")?;
    let y = number(p[1], "laser_pose_y")?;
    let th = number(p[2], "laser_pose_theta")?;
    for (k, what) in [
        (3, "robot_pose_x"),
        (4, "robot_pose_y"),
        (5, "robot_pose_theta"),
    ] {
        number(p[k], what)?;
    }
    Ok(RawScan {
        pose: (x, y, th),
        start_rad: start,
        step_rad: res,
        ranges: z,
        max_range_m: Some(max_range),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flaser_geometry_follows_the_readme() {
        assert_eq!(flaser_angles_deg(180), (-90.0, 1.0));
        assert_eq!(flaser_angles_deg(181), (-90.0, 1.0));
        assert_eq!(flaser_angles_deg(360), (-90.0, 0.5));
        assert_eq!(flaser_angles_deg(361), (-90.0, 0.5));
        assert_eq!(flaser_angles_deg(1), (-90.0, 180.0));
    }

    #[test]
    fn sentinel_detection() {
        let scan = |r: Vec<f64>| RawScan {
            pose: (0.0, 0.0, 0.0),
            start_rad: 0.0,
            step_rad: 0.0,
            ranges: r,
            max_range_m: None,
        };
        let mut v = vec![1.0; 100];
        v.extend([32.767; 10]);
        let (r, s) = detect_max_range(&[scan(v)]);
        assert_eq!(s, MaxRangeSource::Detected);
        assert!((r - 32.767 * 0.995).abs() < 1e-9);
        let (r, s) = detect_max_range(&[scan(vec![1.0, 2.0, 30.0])]);
        assert_eq!((r, s), (DEFAULT_MAX_RANGE_M, MaxRangeSource::Default));
    }
}
