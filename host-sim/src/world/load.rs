//! Loading ground truth from PNG, PGM and ROS map_server YAML.
//!
//! Every image is read with map_server semantics: a pixel of brightness `v` (0..255) has
//! occupancy `p = (255 − v) / 255` (`v / 255` with `negate`), and is Occupied if
//! `p > occupied_thresh`, Free if `p < free_thresh`, Unknown otherwise. Colour pixels use their
//! luminance; fully transparent pixels are Unknown. Image rows are flipped (the top image row
//! is the highest y). Plain images get [`ImageParams::default`] with the caller's resolution.
//!
//! Nothing here panics on bad input: every problem is a [`MapError`] with a one-line message
//! that names the file.

use std::fs::File;
use std::io::{BufReader, Cursor, Read};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use image::{DynamicImage, ImageFormat, ImageReader, Limits};
use serde_yaml::Value;

use super::{Truth, World, MAX_SIDE};

/// Cell size used for plain images when the caller gives none (m).
pub const DEFAULT_RESOLUTION_M: f64 = 0.05;
/// map_server's usual `occupied_thresh`.
pub const DEFAULT_OCCUPIED_THRESH: f64 = 0.65;
/// map_server's usual `free_thresh`.
pub const DEFAULT_FREE_THRESH: f64 = 0.196;
/// Largest map YAML read (bytes); anything bigger is not a map description.
const MAX_YAML_BYTES: u64 = 1 << 20;

/// Why a map could not be loaded (or written). Messages are one line and name the file.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The file does not exist.
    #[error("{path}: file not found")]
    NotFound {
        /// The missing file.
        path: PathBuf,
    },
    /// The file exists but could not be read (permissions, a directory, I/O error).
    #[error("{path}: cannot read: {detail}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        detail: String,
    },
    /// The file has no content.
    #[error("{path}: file is empty")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// Unknown extension, or content that is not what the extension says.
    #[error("{path}: wrong or unsupported format: {detail}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What was expected and found.
        detail: String,
    },
    /// The image could not be decoded (truncated, corrupt, bad header).
    #[error("{path}: truncated or corrupt image: {detail}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// The decoder's complaint.
        detail: String,
    },
    /// The image is larger than [`MAX_SIDE`] pixels a side or needs too much memory.
    #[error("{path}: image too large: {detail}")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Size and limit.
        detail: String,
    },
    /// The YAML could not be parsed or is not a mapping.
    #[error("{path}: invalid map YAML: {detail}")]
    Yaml {
        /// The YAML file.
        path: PathBuf,
        /// The parser's complaint.
        detail: String,
    },
    /// A required key is missing from the map YAML.
    #[error("{path}: map YAML has no `{key}` key")]
    MissingKey {
        /// The YAML file.
        path: PathBuf,
        /// The key.
        key: &'static str,
    },
    /// A value is of the wrong type or out of range (in a YAML, or a caller's parameter).
    #[error("{path}: bad `{key}`: {detail}")]
    BadValue {
        /// The file the value belongs to.
        path: PathBuf,
        /// The key or parameter.
        key: &'static str,
        /// What is wrong with it.
        detail: String,
    },
    /// The image named in a map YAML does not exist.
    #[error("{path}: image `{}` not found", clip(&.image.display().to_string()))]
    ImageMissing {
        /// The YAML file.
        path: PathBuf,
        /// The resolved image path.
        image: PathBuf,
    },
    /// Writing failed (export).
    #[error("{path}: cannot write: {detail}")]
    Write {
        /// The file being written.
        path: PathBuf,
        /// The OS or encoder error.
        detail: String,
    },
}

/// Flattens a message to one line.
pub(crate) fn one_line(s: impl std::fmt::Display) -> String {
    s.to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// A value from a file quoted in a message: one line, at most 60 characters.
pub(crate) fn clip(s: &str) -> String {
    let s = one_line(s);
    match s.char_indices().nth(60) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s,
    }
}

/// How map_server interprets pixel values (`mode` in the YAML).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MapMode {
    /// Three levels from the thresholds (the default).
    #[default]
    Trinary,
    /// Continuous in map_server; for ground truth it is read exactly like [`MapMode::Trinary`].
    Scale,
    /// The pixel value (after `negate`) is the occupancy in percent; values above 100 are
    /// unknown. For ground truth, `value / 100` is thresholded like the other modes.
    Raw,
}

/// How pixel values become [`Truth`] and where the map sits (map_server parameters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageParams {
    /// Cell edge (m).
    pub resolution_m: f64,
    /// World position (m) of the lower-left corner of the image.
    pub origin_m: (f64, f64),
    /// Invert the brightness ↔ occupancy relation.
    pub negate: bool,
    /// Occupied if the occupancy is above this.
    pub occupied_thresh: f64,
    /// Free if the occupancy is below this.
    pub free_thresh: f64,
    /// Pixel interpretation.
    pub mode: MapMode,
}

impl Default for ImageParams {
    /// 0.05 m, origin (0, 0), thresholds 0.65 / 0.196, not negated, trinary.
    fn default() -> Self {
        ImageParams {
            resolution_m: DEFAULT_RESOLUTION_M,
            origin_m: (0.0, 0.0),
            negate: false,
            occupied_thresh: DEFAULT_OCCUPIED_THRESH,
            free_thresh: DEFAULT_FREE_THRESH,
            mode: MapMode::Trinary,
        }
    }
}

impl ImageParams {
    /// Truth of a pixel of brightness `v` in [0, 1] (1 = white).
    fn classify(&self, v: f64) -> Truth {
        let v = v.clamp(0.0, 1.0);
        let v = if self.negate { 1.0 - v } else { v };
        let p = match self.mode {
            MapMode::Trinary | MapMode::Scale => 1.0 - v,
            MapMode::Raw => {
                let raw = (v * 255.0).round();
                if raw > 100.0 {
                    return Truth::Unknown;
                }
                raw / 100.0
            }
        };
        if p > self.occupied_thresh {
            Truth::Occupied
        } else if p < self.free_thresh {
            Truth::Free
        } else {
            Truth::Unknown
        }
    }

    fn lut(&self, levels: usize) -> Vec<Truth> {
        let max = (levels - 1) as f64;
        (0..levels).map(|i| self.classify(i as f64 / max)).collect()
    }
}

/// A parsed ROS map_server YAML.
#[derive(Clone, Debug, PartialEq)]
pub struct RosMapMeta {
    /// The image, resolved against the YAML's directory if relative.
    pub image: PathBuf,
    /// Resolution, origin (x, y), negate, thresholds and mode.
    pub params: ImageParams,
    /// The origin's yaw (rad). [`World`] has no rotation, so the loader ignores it (like most
    /// map_server consumers do for the grid itself).
    pub origin_yaw: f64,
}

impl World {
    /// Ground truth from a decoded image with map_server semantics (see the module docs); the
    /// top image row becomes the highest row. `params` are used as given (the loaders validate
    /// them first).
    pub fn from_image(image: &DynamicImage, params: &ImageParams) -> World {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let mut cells = vec![Truth::Unknown; w * h];
        // `f(x, y_top)` classifies one pixel; rows are written bottom-up.
        let mut fill = |f: &dyn Fn(usize, usize) -> Truth| {
            for (r, row) in cells.chunks_exact_mut(w.max(1)).enumerate() {
                let y_top = h - 1 - r;
                for (x, c) in row.iter_mut().enumerate() {
                    *c = f(x, y_top);
                }
            }
        };
        let lum = |r: f64, g: f64, b: f64| 0.299 * r + 0.587 * g + 0.114 * b;
        match image {
            DynamicImage::ImageLuma8(img) => {
                let lut = params.lut(256);
                let raw = img.as_raw();
                fill(&|x, y| lut[usize::from(raw[y * w + x])]);
            }
            DynamicImage::ImageLuma16(img) => {
                let lut = params.lut(65536);
                let raw = img.as_raw();
                fill(&|x, y| lut[usize::from(raw[y * w + x])]);
            }
            DynamicImage::ImageLumaA8(img) => {
                let lut = params.lut(256);
                let raw = img.as_raw();
                fill(&|x, y| {
                    let i = 2 * (y * w + x);
                    match raw[i + 1] {
                        0 => Truth::Unknown,
                        _ => lut[usize::from(raw[i])],
                    }
                });
            }
            DynamicImage::ImageLumaA16(img) => {
                let lut = params.lut(65536);
                let raw = img.as_raw();
                fill(&|x, y| {
                    let i = 2 * (y * w + x);
                    match raw[i + 1] {
                        0 => Truth::Unknown,
                        _ => lut[usize::from(raw[i])],
                    }
                });
            }
            DynamicImage::ImageRgb8(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[3 * (y * w + x)..][..3];
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 255.0)
                });
            }
            DynamicImage::ImageRgba8(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[4 * (y * w + x)..][..4];
                    if p[3] == 0 {
                        return Truth::Unknown;
                    }
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 255.0)
                });
            }
            DynamicImage::ImageRgb16(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[3 * (y * w + x)..][..3];
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 65535.0)
                });
            }
            DynamicImage::ImageRgba16(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[4 * (y * w + x)..][..4];
                    if p[3] == 0 {
                        return Truth::Unknown;
                    }
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 65535.0)
                });
            }
            other => {
                let img = other.to_rgba32f();
                fill(&|x, y| {
                    let p = img.get_pixel(x as u32, y as u32).0;
                    if p[3] <= 0.0 {
                        return Truth::Unknown;
                    }
                    params.classify(lum(p[0].into(), p[1].into(), p[2].into()))
                });
            }
        }
        World {
            width: w,
            height: h,
            resolution_m: params.resolution_m,
            origin_m: params.origin_m,
            cells,
        }
    }
}

/// Loads ground truth from `path`, by extension: `.yaml`/`.yml` (ROS map_server), `.png`,
/// `.pgm` (case-insensitive).
///
/// `resolution_override`, if given, replaces the cell size of any map, YAML ones included
/// (their origin is kept as written); without it plain images get
/// [`DEFAULT_RESOLUTION_M`] and YAML maps their own `resolution`. Plain images use origin
/// (0, 0) and the default thresholds.
pub fn load_world(path: &Path, resolution_override: Option<f64>) -> Result<World, MapError> {
    if let Some(r) = resolution_override {
        check_resolution(path, r, "the requested resolution")?;
    }
    check_exists(path)?;
    let ext = extension(path);
    match ext.as_str() {
        "yaml" | "yml" => {
            let meta = read_ros_yaml(path)?;
            if !meta.image.exists() {
                return Err(MapError::ImageMissing {
                    path: path.to_path_buf(),
                    image: meta.image,
                });
            }
            let mut params = meta.params;
            if let Some(r) = resolution_override {
                params.resolution_m = r;
            }
            load_image(&meta.image, &params)
        }
        "png" | "pgm" => {
            let params = ImageParams {
                resolution_m: resolution_override.unwrap_or(DEFAULT_RESOLUTION_M),
                ..ImageParams::default()
            };
            load_image(path, &params)
        }
        _ => Err(MapError::Format {
            path: path.to_path_buf(),
            detail: format!(
                "unknown extension {}; expected .png, .pgm, .yaml or .yml",
                if ext.is_empty() {
                    "(none)".to_string()
                } else {
                    format!("`.{ext}`")
                }
            ),
        }),
    }
}

/// Loads a `.png` or `.pgm` image as ground truth with the given parameters.
pub fn load_image(path: &Path, params: &ImageParams) -> Result<World, MapError> {
    let img = decode_image(path)?;
    Ok(World::from_image(&img, params))
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

fn check_exists(path: &Path) -> Result<(), MapError> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => Err(MapError::Io {
            path: path.to_path_buf(),
            detail: "is a directory".into(),
        }),
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(MapError::NotFound {
            path: path.to_path_buf(),
        }),
        Err(e) => Err(MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        }),
    }
}

fn open(path: &Path) -> Result<(File, u64), MapError> {
    check_exists(path)?;
    let io = |e: std::io::Error| match e.kind() {
        std::io::ErrorKind::NotFound => MapError::NotFound {
            path: path.to_path_buf(),
        },
        _ => MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        },
    };
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len == 0 {
        return Err(MapError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((file, len))
}

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// What the first bytes say a file is.
fn sniff(head: &[u8]) -> &'static str {
    if head.starts_with(PNG_SIGNATURE) {
        return "PNG";
    }
    if head.len() < PNG_SIGNATURE.len() && PNG_SIGNATURE.starts_with(head) {
        return "truncated PNG";
    }
    match head {
        [b'P', b'2' | b'5', ..] => "PGM",
        [b'P', b'1' | b'4', ..] => "PBM (bitmap)",
        [b'P', b'3' | b'6', ..] => "PPM (colour)",
        [b'P', b'7', ..] => "PAM",
        [0xFF, 0xD8, 0xFF, ..] => "JPEG",
        [b'G', b'I', b'F', b'8', ..] => "GIF",
        [b'B', b'M', ..] => "BMP",
        [b'R', b'I', b'F', b'F', ..] => "RIFF/WebP",
        [b'I', b'I', 42, 0, ..] | [b'M', b'M', 0, 42, ..] => "TIFF",
        _ if head.iter().all(|b| b.is_ascii()) => "text",
        _ => "unrecognised data",
    }
}

/// The image formats a map can be stored in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// PNG (any bit depth and colour type the `image` crate reads).
    Png,
    /// PGM, plain (P2) or binary (P5).
    Pgm,
}

/// Decodes a `.png` (PNG) or `.pgm` (P2/P5) file, checking content against extension, size
/// against [`MAX_SIDE`], and turning every decoder failure (even a panic) into a [`MapError`].
pub(crate) fn decode_image(path: &Path) -> Result<DynamicImage, MapError> {
    let ext = extension(path);
    let kind = match ext.as_str() {
        "png" => ImageKind::Png,
        "pgm" => ImageKind::Pgm,
        _ => {
            return Err(MapError::Format {
                path: path.to_path_buf(),
                detail: format!("image extension `.{ext}` not supported; use .png or .pgm"),
            })
        }
    };
    let (file, len) = open(path)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    BufReader::new(file)
        .read_to_end(&mut bytes)
        .map_err(|e| MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        })?;
    decode_image_bytes(path, &bytes, kind, MAX_SIDE)
}

/// The byte-level half of the image loader (what [`load_image`] runs on a file's contents, and
/// what the `map_loader` fuzz target drives): checks the content against `kind`, the size
/// against `max_side` pixels a side (at most [`MAX_SIDE`]), and turns every decoder failure
/// (even a panic) into a [`MapError`] naming `path`.
pub fn decode_image_bytes(
    path: &Path,
    bytes: &[u8],
    kind: ImageKind,
    max_side: usize,
) -> Result<DynamicImage, MapError> {
    let max_side = max_side.min(MAX_SIDE);
    let (format, expected) = match kind {
        ImageKind::Png => (ImageFormat::Png, "PNG"),
        ImageKind::Pgm => (ImageFormat::Pnm, "PGM"),
    };
    let len = bytes.len();
    if len == 0 {
        return Err(MapError::Empty {
            path: path.to_path_buf(),
        });
    }
    let head = &bytes[..len.min(8)];
    match sniff(head) {
        found if found == expected => {}
        "truncated PNG" if expected == "PNG" => {
            return Err(MapError::Corrupt {
                path: path.to_path_buf(),
                detail: format!("only {len} bytes"),
            })
        }
        found => {
            return Err(MapError::Format {
                path: path.to_path_buf(),
                detail: format!(
                    "expected {expected}{}, found {found}",
                    if expected == "PGM" { " (P2/P5)" } else { "" }
                ),
            })
        }
    }
    let mut reader = Cursor::new(bytes);
    let corrupt = |e: image::ImageError| match e {
        image::ImageError::Limits(l) => MapError::TooLarge {
            path: path.to_path_buf(),
            detail: one_line(l),
        },
        image::ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            MapError::Corrupt {
                path: path.to_path_buf(),
                detail: "unexpected end of file".into(),
            }
        }
        e => MapError::Corrupt {
            path: path.to_path_buf(),
            detail: one_line(e),
        },
    };
    let panicked = |_| MapError::Corrupt {
        path: path.to_path_buf(),
        detail: "the image decoder failed unexpectedly".into(),
    };
    let (w, h) = catch_unwind(AssertUnwindSafe(|| {
        ImageReader::with_format(&mut reader, format).into_dimensions()
    }))
    .map_err(panicked)?
    .map_err(corrupt)?;
    if w as usize > max_side || h as usize > max_side {
        return Err(MapError::TooLarge {
            path: path.to_path_buf(),
            detail: format!("{w}x{h} px, the limit is {max_side} px a side"),
        });
    }
    if w == 0 || h == 0 {
        return Err(MapError::Corrupt {
            path: path.to_path_buf(),
            detail: format!("image is {w}x{h} px"),
        });
    }
    reader.set_position(0);
    let img = catch_unwind(AssertUnwindSafe(|| {
        let mut r = ImageReader::with_format(&mut reader, format);
        let mut limits = Limits::default();
        limits.max_image_width = Some(max_side as u32);
        limits.max_image_height = Some(max_side as u32);
        r.limits(limits);
        r.decode()
    }))
    .map_err(panicked)?
    .map_err(corrupt)?;
    Ok(img)
}

fn check_resolution(path: &Path, r: f64, what: &str) -> Result<(), MapError> {
    if r.is_finite() && r > 0.0 {
        Ok(())
    } else {
        Err(MapError::BadValue {
            path: path.to_path_buf(),
            key: "resolution",
            detail: format!("{what} must be a finite number > 0, got {r}"),
        })
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, ImageBuffer, Luma, Rgb, RgbImage, Rgba, RgbaImage};
    use std::io::Write;

    /// 3 columns × 2 rows, top row first: black, white, mid-grey / white, dark-grey, black.
    const GRAY: [u8; 6] = [0, 255, 128, 255, 40, 0];

    fn expect_gray(w: &World) {
        assert_eq!((w.width, w.height), (3, 2));
        // bottom row (y = 0) is the image's last row
        assert_eq!(w.get(0, 0), Some(Truth::Free));
        assert_eq!(w.get(1, 0), Some(Truth::Occupied));
        assert_eq!(w.get(2, 0), Some(Truth::Occupied));
        assert_eq!(w.get(0, 1), Some(Truth::Occupied));
        assert_eq!(w.get(1, 1), Some(Truth::Free));
        assert_eq!(w.get(2, 1), Some(Truth::Unknown));
    }

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let p = dir.join(name);
        let mut f = File::create(&p).unwrap();
        f.write_all(bytes).unwrap();
        p
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for &b in data {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    /// A hand-made PNG (for colour types the `image` encoder does not write).
    fn png(
        w: u32,
        h: u32,
        bit_depth: u8,
        color_type: u8,
        extra: &[(&[u8; 4], Vec<u8>)],
        rows: &[Vec<u8>],
    ) -> Vec<u8> {
        let mut out = PNG_SIGNATURE.to_vec();
        let mut chunk = |ty: &[u8; 4], data: &[u8]| {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let mut c = ty.to_vec();
            c.extend_from_slice(data);
            out.extend_from_slice(&c);
            out.extend_from_slice(&crc32(&c).to_be_bytes());
        };
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&w.to_be_bytes());
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[bit_depth, color_type, 0, 0, 0]);
        chunk(b"IHDR", &ihdr);
        for (ty, data) in extra {
            chunk(ty, data);
        }
        let mut raw = Vec::new();
        for r in rows {
            raw.push(0);
            raw.extend_from_slice(r);
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&raw).unwrap();
        chunk(b"IDAT", &z.finish().unwrap());
        chunk(b"IEND", &[]);
        out
    }

    fn gray_png_bytes() -> Vec<u8> {
        let img = GrayImage::from_raw(3, 2, GRAY.to_vec()).unwrap();
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, ImageFormat::Png).unwrap();
        buf.into_inner()
    }

    #[test]
    fn png_gray8_gray16_rgb_rgba() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "g8.png", &gray_png_bytes());
        let w = load_world(&p, None).unwrap();
        expect_gray(&w);
        assert_eq!(w.resolution_m, DEFAULT_RESOLUTION_M);
        assert_eq!(w.origin_m, (0.0, 0.0));
        assert_eq!(load_world(&p, Some(0.1)).unwrap().resolution_m, 0.1);

        let g16: ImageBuffer<Luma<u16>, Vec<u16>> =
            ImageBuffer::from_raw(3, 2, GRAY.iter().map(|&v| u16::from(v) * 257).collect())
                .unwrap();
        let p16 = dir.path().join("g16.png");
        g16.save(&p16).unwrap();
        expect_gray(&load_world(&p16, None).unwrap());

        let rgb = RgbImage::from_fn(3, 2, |x, y| {
            let v = GRAY[(y * 3 + x) as usize];
            Rgb([v, v, v])
        });
        let prgb = dir.path().join("rgb.png");
        rgb.save(&prgb).unwrap();
        expect_gray(&load_world(&prgb, None).unwrap());

        // pure red has luminance 76 → p = 0.70 → occupied; pure green 150 → p = 0.41 → unknown
        let rgba = RgbaImage::from_fn(3, 2, |x, y| match (x, y) {
            (0, 0) => Rgba([255, 0, 0, 255]),
            (1, 0) => Rgba([0, 255, 0, 255]),
            (2, 0) => Rgba([0, 0, 0, 0]),
            (0, 1) => Rgba([255, 255, 255, 1]),
            _ => Rgba([255, 255, 255, 255]),
        });
        let prgba = dir.path().join("rgba.png");
        rgba.save(&prgba).unwrap();
        let w = load_world(&prgba, None).unwrap();
        assert_eq!(w.get(0, 1), Some(Truth::Occupied));
        assert_eq!(w.get(1, 1), Some(Truth::Unknown));
        assert_eq!(w.get(2, 1), Some(Truth::Unknown)); // transparent
        assert_eq!(w.get(0, 0), Some(Truth::Free)); // nearly transparent still counts
    }

    #[test]
    fn png_palette_and_one_bit() {
        let dir = tempfile::tempdir().unwrap();
        // palette: 0 black, 1 white, 2 grey, 3 white but transparent (tRNS)
        let plte = vec![0, 0, 0, 255, 255, 255, 128, 128, 128, 255, 255, 255];
        let trns = vec![255, 255, 255, 0];
        let bytes = png(
            3,
            2,
            8,
            3,
            &[(b"PLTE", plte.clone()), (b"tRNS", trns)],
            &[vec![0, 1, 2], vec![1, 3, 0]],
        );
        let w = load_world(&write(dir.path(), "pal.png", &bytes), None).unwrap();
        assert_eq!(w.get(0, 1), Some(Truth::Occupied));
        assert_eq!(w.get(1, 1), Some(Truth::Free));
        assert_eq!(w.get(2, 1), Some(Truth::Unknown));
        assert_eq!(w.get(0, 0), Some(Truth::Free));
        assert_eq!(w.get(1, 0), Some(Truth::Unknown));
        assert_eq!(w.get(2, 0), Some(Truth::Occupied));
        // palette without transparency
        let bytes = png(
            3,
            2,
            8,
            3,
            &[(b"PLTE", plte)],
            &[vec![0, 1, 2], vec![1, 0, 0]],
        );
        let w = load_world(&write(dir.path(), "pal2.png", &bytes), None).unwrap();
        assert_eq!(w.get(2, 1), Some(Truth::Unknown));
        assert_eq!(w.get(0, 0), Some(Truth::Free));

        // 1-bit grey, 10 px wide: bits 1010000011 / 0000000000 (1 = white)
        let bytes = png(
            10,
            2,
            1,
            0,
            &[],
            &[vec![0b1010_0000, 0b1100_0000], vec![0, 0]],
        );
        let w = load_world(&write(dir.path(), "bit.png", &bytes), None).unwrap();
        assert_eq!((w.width, w.height), (10, 2));
        let top: Vec<Truth> = (0..10).map(|x| w.get(x, 1).unwrap()).collect();
        use Truth::{Free as F, Occupied as O};
        assert_eq!(top, vec![F, O, F, O, O, O, O, O, F, F]);
        assert!((0..10).all(|x| w.get(x, 0) == Some(O)));
    }

    #[test]
    fn pgm_ascii_binary_8_and_16_bit() {
        let dir = tempfile::tempdir().unwrap();
        let p2 = write(
            dir.path(),
            "a.pgm",
            b"P2\n# a comment\n3 2\n255\n0 255 128\n255 40 0\n",
        );
        expect_gray(&load_world(&p2, None).unwrap());
        let mut p5 = b"P5 3 2 255\n".to_vec();
        p5.extend_from_slice(&GRAY);
        expect_gray(&load_world(&write(dir.path(), "b.PGM", &p5), None).unwrap());
        let mut p5_16 = b"P5\n3 2\n65535\n".to_vec();
        for v in GRAY {
            p5_16.extend_from_slice(&(u16::from(v) * 257).to_be_bytes());
        }
        expect_gray(&load_world(&write(dir.path(), "c.pgm", &p5_16), None).unwrap());
        // maxval 1000 (16 bit, scaled): 0, 1000, 502, 1000, 157, 0
        let p2_16 = b"P2 3 2 1000 0 1000 502 1000 157 0".to_vec();
        expect_gray(&load_world(&write(dir.path(), "d.pgm", &p2_16), None).unwrap());
        // maxval 15 (8 bit, scaled)
        let p2_15 = b"P2 3 2 15 0 15 8 15 2 0".to_vec();
        expect_gray(&load_world(&write(dir.path(), "e.pgm", &p2_15), None).unwrap());
    }

    #[test]
    fn ros_yaml_semantics() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("maps");
        std::fs::create_dir(&sub).unwrap();
        // map_server levels: 254 free, 205 unknown, 0 occupied, 100 → p = 0.608 → unknown
        write(&sub, "m.pgm", b"P2 4 1 255 254 205 0 100");
        let y = write(
            &sub,
            "m.yaml",
            b"image: m.pgm\nresolution: 0.1\norigin: [-1.5, 2.25, 0.3]\nnegate: 0\n\
              occupied_thresh: 0.65\nfree_thresh: 0.196\n",
        );
        let w = load_world(&y, None).unwrap();
        use Truth::{Free as F, Occupied as O, Unknown as U};
        assert_eq!(w.cells, vec![F, U, O, U]);
        assert_eq!((w.resolution_m, w.origin_m), (0.1, (-1.5, 2.25)));
        assert_eq!(read_ros_yaml(&y).unwrap().origin_yaw, 0.3);
        assert_eq!(load_world(&y, Some(0.2)).unwrap().resolution_m, 0.2);

        let yn = write(
            &sub,
            "n.yml",
            b"image: m.pgm\nresolution: 1\norigin: [0, 0, 0]\nnegate: true\nmode: scale\n",
        );
        assert_eq!(load_world(&yn, None).unwrap().cells, vec![O, O, F, U]);

        // raw: value is occupancy in percent, > 100 unknown
        write(&sub, "r.pgm", b"P2 4 1 255 0 100 50 255");
        let yr = write(
            &sub,
            "r.yaml",
            b"image: r.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nmode: raw\n",
        );
        assert_eq!(load_world(&yr, None).unwrap().cells, vec![F, O, U, U]);

        // absolute image path
        let abs = sub.join("m.pgm");
        let ya = write(
            dir.path(),
            "abs.yaml",
            format!(
                "image: \"{}\"\nresolution: 0.1\norigin: [0, 0, 0]\n",
                abs.display()
            )
            .as_bytes(),
        );
        assert_eq!(load_world(&ya, None).unwrap().cells, vec![F, U, O, U]);
    }

    fn err(path: &Path, res: Option<f64>) -> String {
        let e = load_world(path, res).expect_err("should fail");
        let msg = e.to_string();
        assert!(!msg.contains('\n'), "multi-line message: {msg}");
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        assert!(msg.contains(&name), "message does not name {name}: {msg}");
        msg
    }

    #[test]
    fn bad_files_give_one_line_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let png_ok = gray_png_bytes();
        assert!(err(&d.join("nope.png"), None).contains("not found"));
        assert!(err(&d.join("nope.yaml"), None).contains("not found"));
        assert!(err(&write(d, "empty.png", b""), None).contains("empty"));
        assert!(err(&write(d, "empty.yaml", b""), None).contains("empty"));
        assert!(err(&write(d, "trunc.png", &png_ok[..png_ok.len() / 2]), None).contains("corrupt"));
        assert!(err(&write(d, "sig.png", &png_ok[..5]), None).contains("corrupt"));
        assert!(err(&write(d, "hdr.png", &png_ok[..20]), None).contains("corrupt"));
        assert!(err(&write(d, "short.pgm", b"P5 4 4 255\n\x00\x01"), None).contains("corrupt"));
        assert!(err(&write(d, "hdr.pgm", b"P5 4"), None).contains("corrupt"));
        assert!(err(&write(d, "maxval0.pgm", b"P2 1 1 0 0"), None).contains("corrupt"));
        assert!(err(&write(d, "zero.pgm", b"P5 0 3 255\n"), None).contains("corrupt"));
        assert!(err(&write(d, "pgm.png", b"P5 1 1 255\n\x00"), None).contains("found PGM"));
        assert!(err(&write(d, "png.pgm", &png_ok), None).contains("found PNG"));
        assert!(err(&write(d, "ppm.pgm", b"P6 1 1 255\n\x00\x00\x00"), None).contains("PPM"));
        assert!(err(&write(d, "text.png", b"hello world"), None).contains("found text"));
        assert!(err(&write(d, "map.jpg", b"\xff\xd8\xff\xe0"), None).contains("extension"));
        assert!(err(&write(d, "noext", b"P5 1 1 255\n\x00"), None).contains("extension"));
        assert!(err(&write(d, "big.pgm", b"P5 20001 1 255\n\x00"), None).contains("too large"));
        assert!(err(&write(d, "big2.pgm", b"P5 1 30000 255\n\x00"), None).contains("too large"));
        let ok = write(d, "ok.pgm", b"P2 1 1 255 0");
        assert!(err(&ok, Some(0.0)).contains("resolution"));
        assert!(err(&ok, Some(f64::NAN)).contains("resolution"));
        std::fs::create_dir(d.join("dir.png")).unwrap();
        assert!(err(&d.join("dir.png"), None).contains("directory"));
    }

    #[test]
    fn bad_yaml_gives_one_line_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        write(d, "m.pgm", b"P2 1 1 255 0");
        let good = "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n";
        let cases: &[(&str, &str, &str)] = &[
            ("syntax.yaml", "image: [unclosed\n", "invalid map YAML"),
            ("list.yaml", "- 1\n- 2\n", "expected a mapping"),
            ("comment.yaml", "# nothing\n", "expected a mapping"),
            ("noimg.yaml", "resolution: 0.05\norigin: [0, 0, 0]\n", "no `image`"),
            ("nores.yaml", "image: m.pgm\norigin: [0, 0, 0]\n", "no `resolution`"),
            ("noorig.yaml", "image: m.pgm\nresolution: 0.05\n", "no `origin`"),
            ("res0.yaml", "image: m.pgm\nresolution: 0\norigin: [0, 0, 0]\n", "bad `resolution`"),
            ("resneg.yaml", "image: m.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n", "bad `resolution`"),
            ("resnan.yaml", "image: m.pgm\nresolution: .nan\norigin: [0, 0, 0]\n", "bad `resolution`"),
            ("resstr.yaml", "image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\n", "bad `resolution`"),
            ("orig2.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0]\n", "bad `origin`"),
            ("originf.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, .inf, 0]\n", "bad `origin`"),
            ("imgnum.yaml", "image: 3\nresolution: 0.05\norigin: [0, 0, 0]\n", "bad `image`"),
            ("occ.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 1.5\n", "bad `occupied_thresh`"),
            ("free.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: -0.1\n", "bad `free_thresh`"),
            ("order.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.3\nfree_thresh: 0.5\n", "bad `free_thresh`"),
            ("neg.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 2\n", "bad `negate`"),
            ("mode.yaml", "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fuzzy\n", "bad `mode`"),
            ("missing.yaml", "image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "gone.pgm"),
            ("jpg.yaml", "image: m.jpg\nresolution: 0.05\norigin: [0, 0, 0]\n", "m.jpg"),
        ];
        write(d, "m.jpg", b"\xff\xd8\xff\xe0");
        for (name, text, want) in cases {
            let p = write(d, name, text.as_bytes());
            let msg = if *name == "jpg.yaml" {
                // the error names the image, the file with the problem
                load_world(&p, None).unwrap_err().to_string()
            } else {
                err(&p, None)
            };
            assert!(msg.contains(want), "{name}: {msg}");
            assert!(!msg.contains('\n'));
        }
        let ok = write(d, "good.yaml", good.as_bytes());
        assert!(load_world(&ok, None).is_ok());
        let bin = write(d, "bin.yaml", b"\xff\xfe\x00garbage");
        assert!(err(&bin, None).contains("invalid map YAML"));
    }

    /// Truncations and byte flips of valid files must give errors or worlds, never panics.
    #[test]
    fn mangled_files_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let img = RgbaImage::from_fn(17, 9, |x, y| Rgba([(x * 15) as u8, (y * 28) as u8, 7, 200]));
        let mut c = std::io::Cursor::new(Vec::new());
        img.write_to(&mut c, ImageFormat::Png).unwrap();
        let png_bytes = c.into_inner();
        let mut pgm = b"P5 17 9 255\n".to_vec();
        pgm.extend((0..17 * 9).map(|i| (i * 7 % 256) as u8));
        let mut seed = 0x1234_5678_9abc_def0u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for (name, bytes) in [("f.png", &png_bytes), ("f.pgm", &pgm)] {
            for cut in 0..bytes.len() {
                let p = write(dir.path(), name, &bytes[..cut]);
                let _ = load_world(&p, None);
            }
            for _ in 0..300 {
                let mut b = bytes.clone();
                for _ in 0..1 + next() % 4 {
                    let i = (next() as usize) % b.len();
                    b[i] = next() as u8;
                }
                let p = write(dir.path(), name, &b);
                if let Ok(w) = load_world(&p, None) {
                    assert_eq!(w.cells.len(), w.width * w.height);
                }
            }
        }
    }

    #[test]
    fn from_image_handles_other_types() {
        let img = DynamicImage::ImageRgb32F(ImageBuffer::from_fn(2, 1, |x, _| {
            if x == 0 {
                Rgb([0.0f32, 0.0, 0.0])
            } else {
                Rgb([1.0f32, 1.0, 1.0])
            }
        }));
        let w = World::from_image(&img, &ImageParams::default());
        assert_eq!(w.cells, vec![Truth::Occupied, Truth::Free]);
    }

    /// Loads every map under `../shared/data/maps` (if present) and prints a table.
    #[test]
    fn shared_data_maps_load() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/maps");
        if !root.is_dir() {
            println!(
                "skipped: ../shared/data absent ({} not found)",
                root.display()
            );
            return;
        }
        let mut files = Vec::new();
        let mut dirs = vec![root.clone()];
        while let Some(d) = dirs.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    dirs.push(p);
                } else if matches!(extension(&p).as_str(), "png" | "pgm" | "yaml" | "yml") {
                    files.push(p);
                }
            }
        }
        files.sort();
        let mut failures = Vec::new();
        for p in &files {
            let name = p.strip_prefix(&root).unwrap_or(p).display().to_string();
            match load_world(p, None) {
                Ok(w) => {
                    let c = w.counts();
                    assert_eq!(c.total(), w.width * w.height);
                    println!(
                        "{name:60} {:>5}x{:<5} {:>7} m  free {:.3}  occ {:.3}  unknown {:.3}",
                        w.width,
                        w.height,
                        w.resolution_m,
                        c.free_fraction(),
                        c.occupied_fraction(),
                        c.unknown_fraction()
                    );
                }
                // A YAML naming an image that is not there is a data problem, not ours.
                Err(e @ MapError::ImageMissing { .. }) => println!("{name:60} not loaded: {e}"),
                Err(e) => failures.push(e.to_string()),
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
        println!("{} files", files.len());
    }
}
