//! The loaders' tests: every image kind and YAML key, and bad input of every sort.

use super::file::extension;
use super::image_file::PNG_SIGNATURE;
use super::*;
use crate::world::Truth;
use image::{
    DynamicImage, GrayImage, ImageBuffer, ImageFormat, Luma, Rgb, RgbImage, Rgba, RgbaImage,
};
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;

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
        ImageBuffer::from_raw(3, 2, GRAY.iter().map(|&v| u16::from(v) * 257).collect()).unwrap();
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
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/maps");
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
