//! A robot session as an MCAP file for Foxglove (`host-sim listen --mcap FILE`): the maps and
//! the robot's pose as they arrive, to replay in Foxglove Studio (or read with any MCAP library).
//!
//! Why Foxglove and MCAP rather than rerun: MCAP is the recording format ROS 2 and Foxglove share
//! (one self-describing file, readable with `mcap` libraries in Rust, Python, C++, Go), Foxglove
//! Studio opens it directly and draws `foxglove.Grid` maps and `foxglove.PoseInFrame` poses
//! without any plugin, and the `mcap` crate is small and pure Rust; rerun's viewer and its SDK
//! are much heavier for a tool that otherwise saves PGM/YAML.
//!
//! Topics (JSON messages, each channel with a JSON Schema of the fields used):
//!
//! | topic | schema | when |
//! |---|---|---|
//! | `/map/marginals` | `foxglove.Grid` | every save (`--save-every`, and at the end) |
//! | `/map/log_odds` | `foxglove.Grid` | same |
//! | `/robot/pose` | `foxglove.PoseInFrame` | every scan report |
//! | `/robot/scan` | `foxglove.PointCloud` | every scan's ranges (`DeviceMsg::Ranges`) |
//!
//! A grid has one `INT8` field `occupancy`, the ROS convention: −1 unknown (no evidence), else
//! p(occupied) in percent; `cell_size` and `pose` (the map's lower-left corner) come from the
//! robot's settings. The scan is the robot's 2° bins' closest hits as points (`x`, `y`, `z`:
//! `FLOAT32`) in the map frame, placed at the pose of the scan they belong to. Frame `map`. Log
//! and publish times are the host's clock when it arrived.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::Context;
use base64::Engine;
use serde_json::json;

/// `foxglove.Grid`'s numeric type code of an `int8` field.
const INT8: u32 = 2;
/// Foxglove's numeric type code of a `float32` field.
const FLOAT32: u32 = 7;

/// The JSON Schema of the `foxglove.Grid` fields written here.
const GRID_SCHEMA: &str = r#"{"type":"object","properties":{
"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},
"frame_id":{"type":"string"},
"pose":{"type":"object","properties":{
 "position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},
 "orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}},
"column_count":{"type":"integer"},
"cell_size":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"}}},
"row_stride":{"type":"integer"},
"cell_stride":{"type":"integer"},
"fields":{"type":"array","items":{"type":"object","properties":{"name":{"type":"string"},"offset":{"type":"integer"},"type":{"type":"integer"}}}},
"data":{"type":"string","contentEncoding":"base64"}}}"#;

/// The JSON Schema of the `foxglove.PoseInFrame` fields written here.
const POSE_SCHEMA: &str = r#"{"type":"object","properties":{
"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},
"frame_id":{"type":"string"},
"pose":{"type":"object","properties":{
 "position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},
 "orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}}}"#;

/// The JSON Schema of the `foxglove.PointCloud` fields written here.
const POINTS_SCHEMA: &str = r#"{"type":"object","properties":{
"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},
"frame_id":{"type":"string"},
"pose":{"type":"object","properties":{
 "position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},
 "orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}},
"point_stride":{"type":"integer"},
"fields":{"type":"array","items":{"type":"object","properties":{"name":{"type":"string"},"offset":{"type":"integer"},"type":{"type":"integer"}}}},
"data":{"type":"string","contentEncoding":"base64"}}}"#;

/// Topic of the sampler's marginals.
pub const MARGINALS_TOPIC: &str = "/map/marginals";
/// Topic of the log-odds map.
pub const LOG_ODDS_TOPIC: &str = "/map/log_odds";
/// Topic of the robot's pose at each scan.
pub const POSE_TOPIC: &str = "/robot/pose";
/// Topic of the latest scan's points.
pub const SCAN_TOPIC: &str = "/robot/scan";

/// One channel of a session: topic, schema name and JSON Schema (messages are JSON). The MCAP
/// recording and the live view (`crate::live`) offer the same three.
#[derive(Clone, Copy, Debug)]
pub struct ChannelSpec {
    /// Topic.
    pub topic: &'static str,
    /// Foxglove schema name.
    pub schema_name: &'static str,
    /// JSON Schema of the fields written.
    pub schema: &'static str,
}

/// The session's channels, in the order of [`Channel`].
pub const CHANNELS: [ChannelSpec; 4] = [
    ChannelSpec {
        topic: MARGINALS_TOPIC,
        schema_name: "foxglove.Grid",
        schema: GRID_SCHEMA,
    },
    ChannelSpec {
        topic: LOG_ODDS_TOPIC,
        schema_name: "foxglove.Grid",
        schema: GRID_SCHEMA,
    },
    ChannelSpec {
        topic: POSE_TOPIC,
        schema_name: "foxglove.PoseInFrame",
        schema: POSE_SCHEMA,
    },
    ChannelSpec {
        topic: SCAN_TOPIC,
        schema_name: "foxglove.PointCloud",
        schema: POINTS_SCHEMA,
    },
];

/// A channel of [`CHANNELS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// The sampler's marginals.
    Marginals = 0,
    /// The log-odds map.
    LogOdds = 1,
    /// The robot's pose.
    Pose = 2,
    /// The latest scan's points.
    Scan = 3,
}

/// The `foxglove.Grid` message of one map layer at host time `t_ns`.
pub fn grid_message(g: &GridFrame<'_>, t_ns: u64) -> serde_json::Value {
    let bytes: Vec<u8> = g
        .cells
        .iter()
        .map(|c| match c {
            None => -1i8 as u8,
            Some(p) => (p.clamp(0.0, 1.0) * 100.0).round() as u8,
        })
        .collect();
    json!({
        "timestamp": stamp(t_ns),
        "frame_id": "map",
        "pose": {
            "position": {"x": g.origin_m.0, "y": g.origin_m.1, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "column_count": g.width,
        "cell_size": {"x": g.cell_m, "y": g.cell_m},
        "row_stride": g.width,
        "cell_stride": 1,
        "fields": [{"name": "occupancy", "offset": 0, "type": INT8}],
        "data": base64::engine::general_purpose::STANDARD.encode(&bytes),
    })
}

/// The `foxglove.PoseInFrame` message of the robot's pose (x, y in m, heading in rad) at host
/// time `t_ns`.
pub fn pose_message(x_m: f64, y_m: f64, heading: f64, t_ns: u64) -> serde_json::Value {
    json!({
        "timestamp": stamp(t_ns),
        "frame_id": "map",
        "pose": {
            "position": {"x": x_m, "y": y_m, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": (heading / 2.0).sin(), "w": (heading / 2.0).cos()},
        },
    })
}

/// The `foxglove.PointCloud` message of a scan's points (x, y in m, map frame) at host time
/// `t_ns`.
pub fn points_message(points: &[(f64, f64)], t_ns: u64) -> serde_json::Value {
    let mut bytes = Vec::with_capacity(points.len() * 12);
    for &(x, y) in points {
        for v in [x as f32, y as f32, 0.0f32] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    json!({
        "timestamp": stamp(t_ns),
        "frame_id": "map",
        "pose": {
            "position": {"x": 0.0, "y": 0.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "point_stride": 12,
        "fields": [
            {"name": "x", "offset": 0, "type": FLOAT32},
            {"name": "y", "offset": 4, "type": FLOAT32},
            {"name": "z", "offset": 8, "type": FLOAT32},
        ],
        "data": base64::engine::general_purpose::STANDARD.encode(&bytes),
    })
}

/// The hits of a scan's ranges as points in the map frame, the robot at (`x_m`, `y_m`) facing
/// `heading` (rad); bins with no return are left out.
pub fn scan_points(
    bins: &[(ogm_core::Angle, ogm_core::types::scan::Range)],
    x_m: f64,
    y_m: f64,
    heading: f64,
) -> Vec<(f64, f64)> {
    bins.iter()
        .filter_map(|&(a, r)| match r {
            ogm_core::types::scan::Range::Hit(mm) => {
                let (d, th) = (f64::from(mm) / 1000.0, heading + a.to_radians());
                Some((x_m + d * th.cos(), y_m + d * th.sin()))
            }
            ogm_core::types::scan::Range::NoReturn => None,
        })
        .collect()
}

/// One map layer as the recording needs it.
pub struct GridFrame<'a> {
    /// Columns, rows.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Cell edge, m.
    pub cell_m: f64,
    /// World position of cell (0, 0)'s lower-left corner, m.
    pub origin_m: (f64, f64),
    /// Row-major, row 0 at the bottom: p(occupied), or `None` where nothing was observed.
    pub cells: &'a [Option<f64>],
}

/// An MCAP file being written.
pub struct Recording {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    marginals: u16,
    log_odds: u16,
    pose: u16,
    scan: u16,
    sequence: u32,
    /// Messages written.
    pub messages: u64,
}

impl Recording {
    /// Creates `path` (replacing it) with the schemas and channels above.
    pub fn create(path: &Path) -> anyhow::Result<Recording> {
        let file =
            File::create(path).with_context(|| format!("{}: cannot create", path.display()))?;
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .create(BufWriter::new(file))
            .with_context(|| format!("{}: cannot start an MCAP file", path.display()))?;
        let none = BTreeMap::new();
        let mut ids = [0u16; CHANNELS.len()];
        let mut schemas = BTreeMap::new();
        for (id, c) in ids.iter_mut().zip(CHANNELS) {
            let schema = match schemas.get(c.schema_name) {
                Some(&s) => s,
                None => {
                    let s = writer.add_schema(c.schema_name, "jsonschema", c.schema.as_bytes())?;
                    schemas.insert(c.schema_name, s);
                    s
                }
            };
            *id = writer.add_channel(schema, c.topic, "json", &none)?;
        }
        let [marginals, log_odds, pose, scan] = ids;
        Ok(Recording {
            writer,
            path: path.to_path_buf(),
            marginals,
            log_odds,
            pose,
            scan,
            sequence: 0,
            messages: 0,
        })
    }

    fn write(
        &mut self,
        channel_id: u16,
        t_ns: u64,
        value: &serde_json::Value,
    ) -> anyhow::Result<()> {
        let data = serde_json::to_vec(value)?;
        self.sequence = self.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: self.sequence,
                    log_time: t_ns,
                    publish_time: t_ns,
                },
                &data,
            )
            .with_context(|| format!("{}: cannot write", self.path.display()))?;
        self.messages += 1;
        Ok(())
    }

    /// The map of one layer (`marginals`: the sampler's, else the log-odds) at host time `t_ns`.
    pub fn grid(&mut self, marginals: bool, g: &GridFrame<'_>, t_ns: u64) -> anyhow::Result<()> {
        let channel = if marginals {
            self.marginals
        } else {
            self.log_odds
        };
        self.write(channel, t_ns, &grid_message(g, t_ns))
    }

    /// The robot's pose (x, y in m, heading in rad) at host time `t_ns`.
    pub fn pose(&mut self, x_m: f64, y_m: f64, heading: f64, t_ns: u64) -> anyhow::Result<()> {
        let channel = self.pose;
        self.write(channel, t_ns, &pose_message(x_m, y_m, heading, t_ns))
    }

    /// A scan's points (x, y in m, map frame) at host time `t_ns`.
    pub fn scan(&mut self, points: &[(f64, f64)], t_ns: u64) -> anyhow::Result<()> {
        let channel = self.scan;
        self.write(channel, t_ns, &points_message(points, t_ns))
    }

    /// Writes the summary and index and closes the file (nothing is lost before this: a file
    /// cut off without it still holds every message written, readable as a stream).
    pub fn finish(mut self) -> anyhow::Result<PathBuf> {
        self.writer
            .finish()
            .with_context(|| format!("{}: cannot finish", self.path.display()))?;
        Ok(self.path)
    }
}

fn stamp(t_ns: u64) -> serde_json::Value {
    json!({"sec": t_ns / 1_000_000_000, "nsec": t_ns % 1_000_000_000})
}

/// Nanoseconds since the Unix epoch, now.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}
