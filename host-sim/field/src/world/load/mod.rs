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
//!
//! Files: `semantics` (pixels to cells: [`ImageParams`]) and `file` (opening a file) below
//! `image_file` (PNG / PGM decoding, content checked against the extension) and `ros_yaml`
//! (the map_server YAML), and the entry points here.

mod file;
mod image_file;
mod ros_yaml;
mod semantics;
#[cfg(test)]
mod tests;

use std::path::Path;

use crate::world::{MapError, World};
use file::{check_exists, extension};
use image_file::decode_image;

pub use image_file::{decode_image_bytes, ImageKind};
pub use ros_yaml::{parse_ros_yaml, read_ros_yaml, RosMapMeta};
pub use semantics::{
    ImageParams, MapMode, DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH, DEFAULT_RESOLUTION_M,
};

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
