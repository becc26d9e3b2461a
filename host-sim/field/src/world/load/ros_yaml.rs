//! The ROS map_server YAML: reading and validating it ([`read_ros_yaml`], [`parse_ros_yaml`]).

use std::io::Read;
use std::path::{Path, PathBuf};

use serde_yaml::Value;

use super::file::open;
use super::semantics::{ImageParams, MapMode, DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use crate::world::error::{clip, one_line};
use crate::world::MapError;

/// A parsed ROS map_server YAML.
#[derive(Clone, Debug, PartialEq)]
pub struct RosMapMeta {
    /// The image, resolved against the YAML's directory if relative.
    pub image: PathBuf,
    /// Resolution, origin (x, y), negate, thresholds and mode.
    pub params: ImageParams,
    /// The origin's yaw (rad). [`World`](crate::world::World) has no rotation, so the loader ignores it (like most
    /// map_server consumers do for the grid itself).
    pub origin_yaw: f64,
}

/// Reads and validates a ROS map_server YAML.
///
/// Required keys: `image` (relative paths resolve against the YAML's directory), `resolution`
/// (finite, > 0) and `origin` (`[x, y, yaw]`, finite). Optional: `negate` (0/1 or a boolean,
/// default 0), `occupied_thresh` / `free_thresh` (in [0, 1] with free < occupied, defaults
/// 0.65 / 0.196), `mode` (`trinary`, `scale` or `raw`, default trinary). Other keys are
/// ignored. Whether the image exists is not checked here.
pub fn read_ros_yaml(path: &Path) -> Result<RosMapMeta, MapError> {
    let (file, len) = open(path)?;
    let yaml_err = |detail: String| MapError::Yaml {
        path: path.to_path_buf(),
        detail,
    };
    if len > MAX_YAML_BYTES {
        return Err(yaml_err(format!(
            "{len} bytes, larger than any map description ({MAX_YAML_BYTES} bytes allowed)"
        )));
    }
    let mut bytes = Vec::new();
    file.take(MAX_YAML_BYTES)
        .read_to_end(&mut bytes)
        .map_err(|e| MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        })?;
    parse_ros_yaml(path, &bytes)
}

/// The byte-level half of [`read_ros_yaml`]: validates a map YAML's contents (`path` names it in
/// errors and anchors a relative `image`). Used by the `map_loader` fuzz target.
pub fn parse_ros_yaml(path: &Path, bytes: &[u8]) -> Result<RosMapMeta, MapError> {
    let yaml_err = |detail: String| MapError::Yaml {
        path: path.to_path_buf(),
        detail,
    };
    if bytes.is_empty() {
        return Err(MapError::Empty {
            path: path.to_path_buf(),
        });
    }
    if bytes.len() as u64 > MAX_YAML_BYTES {
        return Err(yaml_err(format!(
            "{} bytes, larger than any map description ({MAX_YAML_BYTES} bytes allowed)",
            bytes.len()
        )));
    }
    let text = std::str::from_utf8(bytes).map_err(|_| yaml_err("not UTF-8 text".into()))?;
    let doc: Value = serde_yaml::from_str(text).map_err(|e| yaml_err(one_line(e)))?;
    let map = match &doc {
        Value::Mapping(m) => m,
        other => {
            return Err(yaml_err(format!(
                "expected a mapping with `image`, `resolution`, `origin`, found {}",
                kind(other)
            )))
        }
    };
    let bad = |key: &'static str, detail: String| MapError::BadValue {
        path: path.to_path_buf(),
        key,
        detail,
    };
    let required = |key: &'static str| {
        map.get(key).ok_or(MapError::MissingKey {
            path: path.to_path_buf(),
            key,
        })
    };
    let number = |key: &'static str, v: &Value| -> Result<f64, MapError> {
        match v.as_f64() {
            Some(x) if x.is_finite() => Ok(x),
            Some(x) => Err(bad(key, format!("expected a finite number, got {x}"))),
            None => Err(bad(key, format!("expected a number, found {}", kind(v)))),
        }
    };

    let image = match required("image")? {
        Value::String(s) if !s.trim().is_empty() => PathBuf::from(s.trim()),
        Value::String(_) => return Err(bad("image", "empty file name".into())),
        v => {
            return Err(bad(
                "image",
                format!("expected a file name, found {}", kind(v)),
            ))
        }
    };
    let image = if image.is_absolute() {
        image
    } else {
        match path.parent() {
            Some(dir) if !dir.as_os_str().is_empty() => dir.join(image),
            _ => image,
        }
    };

    let resolution_m = number("resolution", required("resolution")?)?;
    if resolution_m <= 0.0 {
        return Err(bad(
            "resolution",
            format!("must be > 0 (metres per cell), got {resolution_m}"),
        ));
    }

    let origin = match required("origin")? {
        Value::Sequence(s) if s.len() == 3 => [
            number("origin", &s[0])?,
            number("origin", &s[1])?,
            number("origin", &s[2])?,
        ],
        Value::Sequence(s) => {
            return Err(bad(
                "origin",
                format!("expected [x, y, yaw], got {} values", s.len()),
            ))
        }
        v => {
            return Err(bad(
                "origin",
                format!("expected [x, y, yaw], found {}", kind(v)),
            ))
        }
    };

    let negate = match map.get("negate") {
        None => false,
        Some(Value::Bool(b)) => *b,
        Some(v) => match v.as_i64() {
            Some(0) => false,
            Some(1) => true,
            _ => return Err(bad("negate", "expected 0 or 1".into())),
        },
    };

    let thresh = |key: &'static str, default: f64| -> Result<f64, MapError> {
        let Some(v) = map.get(key) else {
            return Ok(default);
        };
        let t = number(key, v)?;
        if (0.0..=1.0).contains(&t) {
            Ok(t)
        } else {
            Err(bad(key, format!("must be in [0, 1], got {t}")))
        }
    };
    let occupied_thresh = thresh("occupied_thresh", DEFAULT_OCCUPIED_THRESH)?;
    let free_thresh = thresh("free_thresh", DEFAULT_FREE_THRESH)?;
    if free_thresh >= occupied_thresh {
        return Err(bad(
            "free_thresh",
            format!("must be below occupied_thresh ({free_thresh} >= {occupied_thresh})"),
        ));
    }

    let mode = match map.get("mode") {
        None => MapMode::Trinary,
        Some(Value::String(s)) => match s.trim().to_ascii_lowercase().as_str() {
            "trinary" => MapMode::Trinary,
            "scale" => MapMode::Scale,
            "raw" => MapMode::Raw,
            other => {
                return Err(bad(
                    "mode",
                    format!("expected trinary, scale or raw, got `{}`", clip(other)),
                ))
            }
        },
        Some(v) => return Err(bad("mode", format!("expected a string, found {}", kind(v)))),
    };

    Ok(RosMapMeta {
        image,
        params: ImageParams {
            resolution_m,
            origin_m: (origin[0], origin[1]),
            negate,
            occupied_thresh,
            free_thresh,
            mode,
        },
        origin_yaw: origin[2],
    })
}

/// Largest map YAML read (bytes); anything bigger is not a map description.
const MAX_YAML_BYTES: u64 = 1 << 20;

fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "nothing",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Sequence(_) => "a list",
        Value::Mapping(_) => "a mapping",
        Value::Tagged(_) => "a tagged value",
    }
}
