//! The command line with bad input files: every subcommand that reads a file, given a missing,
//! an empty, a truncated or a wrong-format one, exits non-zero with a one-line error that names
//! the file (README, "Bad input policy"). Runs the built `host-sim` binary; each case fails
//! before any real work starts, so the whole file takes a few seconds.

use std::path::{Path, PathBuf};
use std::process::Command;

use ogm_core::wire::{self, Counters, DeviceMsg, Hello};

/// The four kinds of bad file.
#[derive(Clone, Copy, Debug)]
enum Bad {
    Missing,
    Empty,
    Truncated,
    WrongFormat,
}

const ALL: [Bad; 4] = [Bad::Missing, Bad::Empty, Bad::Truncated, Bad::WrongFormat];

/// What a subcommand reads.
#[derive(Clone, Copy, Debug)]
enum Kind {
    /// A ground-truth map (PNG).
    Map,
    /// A map_server YAML.
    Yaml,
    /// A CARMEN log (gzip).
    Log,
    /// A captured map stream.
    Stream,
    /// A firmware ELF.
    Elf,
}

/// A small valid PNG (8 × 8 grey).
fn png() -> Vec<u8> {
    let mut img = image::GrayImage::new(8, 8);
    for (x, y, p) in img.enumerate_pixels_mut() {
        p.0 = [if x == 0 || y == 0 { 0 } else { 255 }];
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn gzip(text: &str) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(text.as_bytes()).unwrap();
    e.finish().unwrap()
}

/// A map stream with a Hello and counters but no `Done` (a capture cut short).
fn stream() -> Vec<u8> {
    let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
    let mut v = Vec::new();
    let hello = Hello {
        firmware: "ogm-firmware test",
        board: "none",
        tick_hz: 25_000_000,
        width: 256,
        height: 256,
        tile_edge: 16,
        max_beams: 456,
        ray_capacity: 3072,
        scan_capacity: 128,
        local_capacity: 128,
        count_max: 255,
    };
    v.extend_from_slice(wire::encode(&DeviceMsg::Hello(hello), &mut buf).unwrap());
    v.extend_from_slice(wire::encode(&DeviceMsg::Counters(Counters::default()), &mut buf).unwrap());
    v
}

/// A file of `kind` spoiled in the way `bad` says (None for missing).
fn bad_file(dir: &Path, kind: Kind, bad: Bad) -> PathBuf {
    let (name, good): (&str, Vec<u8>) = match kind {
        Kind::Map => ("map.png", png()),
        Kind::Yaml => (
            "map.yaml",
            b"image: map.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n".to_vec(),
        ),
        Kind::Log => (
            "run.log.gz",
            gzip(&"FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 host 1.0\n".repeat(50)),
        ),
        Kind::Stream => ("stream.bin", stream()),
        Kind::Elf => (
            "fw.elf",
            [b"\x7fELF\x01\x01\x01".as_slice(), &[0u8; 200]].concat(),
        ),
    };
    let path = dir.join(format!("{bad:?}-{name}"));
    let bytes: Vec<u8> = match (bad, kind) {
        (Bad::Missing, _) => return path,
        (Bad::Empty, _) => Vec::new(),
        // The YAML is cut in the middle of a key; everything else keeps its first bytes.
        (Bad::Truncated, Kind::Yaml) => good[..20].to_vec(),
        (Bad::Truncated, Kind::Stream) => good,
        (Bad::Truncated, _) => good[..good.len().min(30)].to_vec(),
        (Bad::WrongFormat, Kind::Map | Kind::Log | Kind::Elf) => {
            b"this is a text file, not what was asked for\n".to_vec()
        }
        (Bad::WrongFormat, Kind::Yaml) => b"- just\n- a list\n".to_vec(),
        (Bad::WrongFormat, Kind::Stream) => png(),
    };
    std::fs::write(&path, bytes).unwrap();
    path
}

/// Runs `host-sim ARGS`; asserts the failure mode of the policy and returns stderr.
fn fails_with_one_line(args: &[String], file: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .expect("running host-sim");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        !out.status.success(),
        "host-sim {args:?} succeeded with a bad file\nstderr: {stderr}"
    );
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(
        errors.len(),
        1,
        "host-sim {args:?}: want exactly one error line, got:\n{stderr}"
    );
    for l in stderr.lines() {
        assert!(
            l.starts_with("error:") || l.starts_with("warning:"),
            "host-sim {args:?}: stray stderr line {l:?}"
        );
    }
    let name = file.file_name().unwrap().to_string_lossy();
    assert!(
        errors[0].contains(name.as_ref()),
        "host-sim {args:?}: the error does not name {name}: {}",
        errors[0]
    );
    errors[0].to_string()
}

fn check(kind: Kind, args: impl Fn(&Path, &Path) -> Vec<String>) {
    check_some(kind, &ALL, args);
}

fn check_some(kind: Kind, bads: &[Bad], args: impl Fn(&Path, &Path) -> Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    for &bad in bads {
        let f = bad_file(dir.path(), kind, bad);
        let e = fails_with_one_line(&args(&f, &out), &f);
        if let Bad::Missing = bad {
            let l = e.to_lowercase();
            assert!(
                l.contains("not found") || l.contains("no such file"),
                "{kind:?}/{bad:?}: {e}"
            );
        }
        eprintln!("{kind:?}/{bad:?}: {e}");
    }
}

fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

fn p(path: &Path) -> String {
    path.display().to_string()
}

#[test]
fn eval_sim_maps() {
    for kind in [Kind::Map, Kind::Yaml] {
        check(kind, |f, out| {
            let mut a = s(&["eval-sim", "--methods", "none", "--maps"]);
            a.extend([p(f), "--out".into(), p(out)]);
            a
        });
    }
}

#[test]
fn firmware_map_elf_and_decode() {
    check(Kind::Map, |f, _| {
        let mut a = s(&["firmware", "--host-only", "--accuracy", "--map"]);
        a.push(p(f));
        a
    });
    check(Kind::Elf, |f, _| {
        vec!["firmware".into(), "--elf".into(), p(f)]
    });
    check(Kind::Stream, |f, _| {
        vec!["firmware".into(), "--decode".into(), p(f)]
    });
    // `listen` reads a captured stream given as its port (a cut-off one, here without tiles,
    // is fine: a live link has no map before its first tile either).
    let bads = [Bad::Missing, Bad::Empty, Bad::WrongFormat];
    check_some(Kind::Stream, &bads, |f, out| {
        let mut a = s(&["listen", "--quiet", "--port"]);
        a.extend([p(f), "--out".into(), p(out)]);
        a
    });
}

#[test]
fn eval_log_and_export_logs() {
    check(Kind::Log, |f, out| {
        let mut a = s(&["eval-log", "--methods", "none", "--log"]);
        a.extend([p(f), "--out".into(), p(out)]);
        a
    });
    check(Kind::Log, |f, out| {
        vec![
            "export".into(),
            "--out".into(),
            p(&out.join("x.yaml")),
            "--log".into(),
            p(f),
        ]
    });
}

#[test]
fn export_maps() {
    for (flag, kind) in [
        ("--world", Kind::Map),
        ("--world", Kind::Yaml),
        ("--probability-png", Kind::Map),
        ("--stream", Kind::Stream),
    ] {
        check(kind, |f, out| {
            vec![
                "export".into(),
                "--out".into(),
                p(&out.join("x.yaml")),
                flag.into(),
                p(f),
            ]
        });
    }
}

#[test]
fn train_prior_corpus() {
    let dir = tempfile::tempdir().unwrap();
    // A missing corpus, and a file where the corpus folder should be.
    for f in [dir.path().join("nothere"), {
        let f = dir.path().join("corpus.png");
        std::fs::write(&f, png()).unwrap();
        f
    }] {
        let mut a = s(&["train-prior", "--check", "--corpus"]);
        a.push(p(&f));
        let e = fails_with_one_line(&a, &f);
        eprintln!("train-prior: {e}");
    }
}

#[test]
fn output_path_that_is_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let map = bad_file(dir.path(), Kind::Map, Bad::Truncated);
    std::fs::write(&map, png()).unwrap();
    let out = dir.path().join("out-is-a-file");
    std::fs::write(&out, b"x").unwrap();
    let mut a = s(&["eval-sim", "--methods", "none", "--maps"]);
    a.extend([p(&map), "--out".into(), p(&out)]);
    fails_with_one_line(&a, &out);
}
