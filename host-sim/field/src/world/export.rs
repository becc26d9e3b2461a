//! Writing worlds and probability maps: ROS map_server PGM + YAML (trinary) and grey PNG.
//!
//! Grey levels are map_server's: [`PGM_FREE`] (254), [`PGM_OCCUPIED`] (0) and [`PGM_UNKNOWN`]
//! (205); read back with thresholds 0.65 / 0.196 they give the same cells, so
//! `load_world(write_ros_map(w))` reproduces `w` exactly (resolution and origin included).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::error::one_line;
use super::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use super::{MapError, Truth, World};

/// Grey level of free cells.
pub const PGM_FREE: u8 = 254;
/// Grey level of occupied cells.
pub const PGM_OCCUPIED: u8 = 0;
/// Grey level of unknown cells.
pub const PGM_UNKNOWN: u8 = 205;

/// The map_server grey level of a cell.
pub fn truth_to_gray(t: Truth) -> u8 {
    match t {
        Truth::Free => PGM_FREE,
        Truth::Occupied => PGM_OCCUPIED,
        Truth::Unknown => PGM_UNKNOWN,
    }
}

/// Trinary ground truth from occupancy probabilities (row-major, row 0 at the bottom, like
/// [`World::cells`]): `p ≥ occ_thresh` → Occupied, `p ≤ free_thresh` → Free, otherwise
/// Unknown. A cell at exactly 0.5 (the prior: no data) and NaN are always Unknown, as are
/// cells missing from a too-short `probs` (extra values are ignored).
pub fn probabilities_to_world(
    probs: &[f64],
    width: usize,
    height: usize,
    resolution_m: f64,
    origin_m: (f64, f64),
    occ_thresh: f64,
    free_thresh: f64,
) -> World {
    let n = width.saturating_mul(height);
    let cells = (0..n)
        .map(|i| match probs.get(i) {
            Some(&p) if p == 0.5 || p.is_nan() => Truth::Unknown,
            Some(&p) if p >= occ_thresh => Truth::Occupied,
            Some(&p) if p <= free_thresh => Truth::Free,
            _ => Truth::Unknown,
        })
        .collect();
    World {
        width,
        height,
        resolution_m,
        origin_m,
        cells,
    }
}

fn bad(path: &Path, key: &'static str, detail: String) -> MapError {
    MapError::BadValue {
        path: path.to_path_buf(),
        key,
        detail,
    }
}

/// Checks that `world` can be written, and returns its grey image rows, top row first.
fn gray_rows(path: &Path, world: &World) -> Result<Vec<u8>, MapError> {
    let (w, h) = (world.width, world.height);
    if w == 0 || h == 0 || u32::try_from(w).is_err() || u32::try_from(h).is_err() {
        return Err(bad(path, "size", format!("cannot write a {w}x{h} map")));
    }
    if world.cells.len() != w * h {
        return Err(bad(
            path,
            "size",
            format!("{w}x{h} map has {} cells", world.cells.len()),
        ));
    }
    let mut out = Vec::with_capacity(w * h);
    for row in world.cells.chunks_exact(w).rev() {
        out.extend(row.iter().map(|&t| truth_to_gray(t)));
    }
    Ok(out)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), MapError> {
    std::fs::write(path, bytes).map_err(|e| MapError::Write {
        path: path.to_path_buf(),
        detail: one_line(e),
    })
}

/// Writes `world` as a binary 8-bit PGM (P5) with map_server grey levels, top row first.
pub fn write_pgm(path: &Path, world: &World) -> Result<(), MapError> {
    let rows = gray_rows(path, world)?;
    let mut bytes = format!("P5\n{} {}\n255\n", world.width, world.height).into_bytes();
    bytes.extend_from_slice(&rows);
    write_file(path, &bytes)
}

/// Writes `world` as an 8-bit greyscale PNG with map_server grey levels, top row first.
pub fn write_png(path: &Path, world: &World) -> Result<(), MapError> {
    let rows = gray_rows(path, world)?;
    let img = image::GrayImage::from_raw(world.width as u32, world.height as u32, rows)
        .ok_or_else(|| bad(path, "size", "image buffer size mismatch".into()))?;
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| MapError::Write {
            path: path.to_path_buf(),
            detail: one_line(e),
        })
}

/// Writes `world` as a ROS map_server map: the YAML at `path_yaml` (extension `.yaml` or
/// `.yml`) and a trinary P5 PGM next to it with the same stem, named in the YAML by its
/// relative file name. The YAML has `resolution`, `origin: [x, y, 0]`, `negate: 0`,
/// `occupied_thresh: 0.65`, `free_thresh: 0.196`, `mode: trinary`; numbers are written so that
/// they read back bit-exactly. Returns the path of the PGM.
pub fn write_ros_map(path_yaml: &Path, world: &World) -> Result<PathBuf, MapError> {
    let ext = path_yaml
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("yaml" | "yml")) {
        return Err(MapError::Format {
            path: path_yaml.to_path_buf(),
            detail: "a map YAML must end in .yaml or .yml".into(),
        });
    }
    let res = world.resolution_m;
    if !(res.is_finite() && res > 0.0) {
        return Err(bad(
            path_yaml,
            "resolution",
            format!("must be finite and > 0, got {res}"),
        ));
    }
    let (ox, oy) = world.origin_m;
    if !(ox.is_finite() && oy.is_finite()) {
        return Err(bad(
            path_yaml,
            "origin",
            format!("must be finite, got ({ox}, {oy})"),
        ));
    }
    let pgm = path_yaml.with_extension("pgm");
    let name = pgm
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| bad(path_yaml, "image", "file name is not UTF-8".into()))?;
    let name_yaml = serde_yaml::to_string(name)
        .map_err(|e| bad(path_yaml, "image", one_line(e)))?
        .trim_end()
        .to_string();
    // `{:?}` prints the shortest representation that parses back to the same f64.
    let mut yaml = String::new();
    let _ = writeln!(yaml, "image: {name_yaml}");
    let _ = writeln!(yaml, "resolution: {res:?}");
    let _ = writeln!(yaml, "origin: [{ox:?}, {oy:?}, 0.0]");
    let _ = writeln!(yaml, "negate: 0");
    let _ = writeln!(yaml, "occupied_thresh: {DEFAULT_OCCUPIED_THRESH:?}");
    let _ = writeln!(yaml, "free_thresh: {DEFAULT_FREE_THRESH:?}");
    let _ = writeln!(yaml, "mode: trinary");
    write_pgm(&pgm, world)?;
    write_file(path_yaml, yaml.as_bytes())?;
    Ok(pgm)
}

/// Writes an occupancy-probability map (row-major, row 0 at the bottom) as a trinary ROS map
/// via [`probabilities_to_world`] with map_server's thresholds 0.65 / 0.196 and
/// [`write_ros_map`]; returns the trinary world written.
pub fn write_ros_probabilities(
    path_yaml: &Path,
    probs: &[f64],
    width: usize,
    height: usize,
    resolution_m: f64,
    origin_m: (f64, f64),
) -> Result<World, MapError> {
    let world = probabilities_to_world(
        probs,
        width,
        height,
        resolution_m,
        origin_m,
        DEFAULT_OCCUPIED_THRESH,
        DEFAULT_FREE_THRESH,
    );
    write_ros_map(path_yaml, &world)?;
    Ok(world)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::load_world;

    fn patterned(w: usize, h: usize, res: f64, origin: (f64, f64)) -> World {
        let mut world = World::new(w, h, res, origin, Truth::Free);
        for y in 0..h {
            for x in 0..w {
                let t = match (x * 7 + y * 3) % 5 {
                    0 => Truth::Occupied,
                    1 => Truth::Unknown,
                    _ => Truth::Free,
                };
                world.set(x as i64, y as i64, t);
            }
        }
        world
    }

    #[test]
    fn ros_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let worlds = [
            patterned(7, 3, 0.05, (-3.25, -10.0)),
            patterned(3, 11, 0.1 + 0.2, (-1e-7, 12345.678901234567)),
            patterned(1, 1, 1.0, (0.0, 0.0)),
        ];
        for (i, w) in worlds.iter().enumerate() {
            let y = dir.path().join(format!("m{i}.yaml"));
            let pgm = write_ros_map(&y, w).unwrap();
            assert_eq!(pgm, dir.path().join(format!("m{i}.pgm")));
            let text = std::fs::read_to_string(&y).unwrap();
            assert!(text.starts_with(&format!("image: m{i}.pgm\n")), "{text}");
            assert!(text.contains("mode: trinary"));
            let back = load_world(&y, None).unwrap();
            assert_eq!(&back, w, "world {i}");
            // the PGM alone and a PNG give the same cells
            let alone = load_world(&pgm, Some(w.resolution_m)).unwrap();
            assert_eq!(alone.cells, w.cells);
            let png = dir.path().join(format!("m{i}.png"));
            write_png(&png, w).unwrap();
            assert_eq!(load_world(&png, None).unwrap().cells, w.cells);
        }
    }

    #[test]
    fn pgm_bytes_are_map_server_levels_top_row_first() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = World::new(2, 2, 0.05, (0.0, 0.0), Truth::Free);
        w.set(0, 1, Truth::Occupied);
        w.set(1, 0, Truth::Unknown);
        let p = dir.path().join("x.pgm");
        write_pgm(&p, &w).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(bytes, b"P5\n2 2\n255\n\x00\xfe\xfe\xcd");
    }

    #[test]
    fn probabilities() {
        let probs = [0.0, 0.196, 0.2, 0.5, 0.64, 0.65, 1.0, f64::NAN];
        let w = probabilities_to_world(&probs, 3, 3, 0.1, (1.0, 2.0), 0.65, 0.196);
        use Truth::{Free as F, Occupied as O, Unknown as U};
        assert_eq!(w.cells, vec![F, F, U, U, U, O, O, U, U]);
        // the prior stays unknown even with thresholds that would include it
        let w = probabilities_to_world(&[0.5, 0.5], 2, 1, 0.1, (0.0, 0.0), 0.5, 0.5);
        assert_eq!(w.cells, vec![U, U]);
        let dir = tempfile::tempdir().unwrap();
        let y = dir.path().join("p.yml");
        let written = write_ros_probabilities(&y, &probs[..6], 3, 2, 0.1, (-1.0, 0.5)).unwrap();
        assert_eq!(load_world(&y, None).unwrap(), written);
    }

    #[test]
    fn bad_exports_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let w = patterned(3, 2, 0.05, (0.0, 0.0));
        let msg = |e: MapError| {
            let s = e.to_string();
            assert!(!s.contains('\n'));
            s
        };
        assert!(msg(write_ros_map(&d.join("m.pgm"), &w).unwrap_err()).contains(".yaml"));
        let mut bad_res = w.clone();
        bad_res.resolution_m = 0.0;
        assert!(msg(write_ros_map(&d.join("m.yaml"), &bad_res).unwrap_err()).contains("resolution"));
        let mut bad_origin = w.clone();
        bad_origin.origin_m.0 = f64::NAN;
        assert!(msg(write_ros_map(&d.join("m.yaml"), &bad_origin).unwrap_err()).contains("origin"));
        let empty = World::new(0, 4, 0.05, (0.0, 0.0), Truth::Free);
        assert!(msg(write_pgm(&d.join("e.pgm"), &empty).unwrap_err()).contains("0x4"));
        assert!(msg(write_png(&d.join("e.png"), &empty).unwrap_err()).contains("0x4"));
        let mut short = w.clone();
        short.cells.pop();
        assert!(write_pgm(&d.join("s.pgm"), &short).is_err());
        let nodir = d.join("no/such/dir/m.yaml");
        assert!(msg(write_ros_map(&nodir, &w).unwrap_err()).contains("cannot write"));
    }
}
