//! The bad-input policy (README, "Bad input policy") for host-sim's readers: one test per row of
//! the table that is not covered where the reader lives. CARMEN logs: bad lines are skipped and
//! reported with their line number, bad readings dropped and counted, a corrupt file is an
//! error naming it. The byte-level map decoders: every failure is a one-line error naming the
//! file.

use std::path::Path;

use host_sim::sim::carmen::{parse_log, read_log, ReadOptions};
use ogm_core::Range;
use ogm_field::world::load::{decode_image_bytes, parse_ros_yaml, ImageKind};

const GOOD: &str = "FLASER 5 1.0 2.0 3.0 4.0 5.0 0.5 0.5 0.1 0.5 0.5 0.1 1.0 host 1.0";

fn parse(text: &str) -> host_sim::sim::carmen::CarmenLog {
    parse_log(
        text.as_bytes(),
        &ReadOptions {
            max_range_m: Some(4.5),
        },
    )
    .expect("only I/O problems are errors")
}

#[test]
fn carmen_truncated_and_oversized_lines_are_skipped_with_their_line_number() {
    let log = parse(&format!(
        "{GOOD}\nFLASER 5 1.0 2.0\n{}\nFLASER 99999999999999999999 1\nFLASER 18446744073709551615 1\n{GOOD}",
        &GOOD[..GOOD.len() - 12]
    ));
    assert_eq!(log.scans.len(), 2);
    assert_eq!(log.info.malformed_lines, 4);
    let lines: Vec<usize> = log.info.warnings.iter().map(|w| w.line).collect();
    assert_eq!(lines, [2, 3, 4, 5]);
}

#[test]
fn carmen_nan_and_infinite_values_reject_the_line() {
    for bad in [
        GOOD.replace("2.0", "nan"),
        GOOD.replace("3.0", "inf"),
        GOOD.replace(" 0.5 0.5 0.1 1.0", " NaN 0.5 0.1 1.0"),
        GOOD.replace("0.1 0.5", "-inf 0.5"),
    ] {
        let log = parse(&bad);
        assert!(log.scans.is_empty(), "{bad}");
        assert_eq!(log.info.malformed_lines, 1, "{bad}");
        assert!(log.info.warnings[0].message.contains("not a finite number"));
    }
}

#[test]
fn carmen_zero_negative_and_max_range_readings() {
    let log = parse("FLASER 5 0.0 -1.0 2.0 4.5 90.0 0.5 0.5 0.1 0.5 0.5 0.1 1.0 host 1.0");
    assert_eq!(log.scans.len(), 1);
    // ≤ 0: dropped and counted; ≥ the maximum range: no return; the rest: hits.
    assert_eq!(log.info.invalid_readings, 2);
    assert_eq!((log.info.hits, log.info.no_returns), (1, 2));
    let b = &log.scans[0].beams;
    assert_eq!(b.len(), 3);
    assert_eq!(b[0].range, Range::Hit(2000));
    assert!(b[1..].iter().all(|b| b.range == Range::NoReturn));
}

#[test]
fn carmen_not_utf8_line_is_skipped_and_corrupt_gzip_is_an_error() {
    let mut bytes = GOOD.as_bytes().to_vec();
    bytes.extend_from_slice(b"\nFLASER \xff\xfe\n");
    bytes.extend_from_slice(GOOD.as_bytes());
    let log = parse_log(&bytes[..], &ReadOptions::default()).unwrap();
    assert_eq!((log.scans.len(), log.info.malformed_lines), (2, 1));
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("cut.log.gz");
    std::fs::write(&f, [0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3, 0x4b, 0x4c]).unwrap();
    let e = format!("{:#}", read_log(&f, &ReadOptions::default()).unwrap_err());
    assert!(e.contains("cut.log.gz") && !e.contains('\n'), "{e}");
    let e = format!(
        "{:#}",
        read_log(&dir.path().join("none.log"), &ReadOptions::default()).unwrap_err()
    );
    assert!(e.contains("none.log"), "{e}");
}

#[test]
fn map_bytes_bad_input_gives_one_line_errors() {
    let p = Path::new("m.png");
    let png_header = |w: u32, h: u32| {
        let mut v = b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR".to_vec();
        v.extend(w.to_be_bytes());
        v.extend(h.to_be_bytes());
        v.extend([8, 0, 0, 0, 0]);
        let crc = crc32(&v[12..]);
        v.extend(crc.to_be_bytes());
        // An empty IDAT chunk, so the decoder reaches the image data.
        v.extend(b"\x00\x00\x00\x00IDAT");
        v.extend(crc32(b"IDAT").to_be_bytes());
        v
    };
    for (bytes, kind, want) in [
        (Vec::new(), ImageKind::Png, "file is empty"),
        (b"\x89PN".to_vec(), ImageKind::Png, "truncated"),
        (png_header(8, 8), ImageKind::Png, "truncated or corrupt"),
        (png_header(30_000, 2), ImageKind::Png, "too large"),
        (
            b"P5 3 3 255\n\x00".to_vec(),
            ImageKind::Pgm,
            "truncated or corrupt",
        ),
        (
            b"GIF89a".to_vec(),
            ImageKind::Png,
            "wrong or unsupported format",
        ),
        (
            b"hello".to_vec(),
            ImageKind::Pgm,
            "wrong or unsupported format",
        ),
    ] {
        let e = decode_image_bytes(p, &bytes, kind, 20_000)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.png: ") && e.contains(want), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
    for (yaml, want) in [
        ("", "file is empty"),
        (
            "image: m.pgm\nresolution: .inf\norigin: [0, 0, 0]\n",
            "bad `resolution`",
        ),
        (
            "image: m.pgm\nresolution: 0.05\norigin: [0, .nan, 0]\n",
            "bad `origin`",
        ),
        (
            "image: m.pgm\nresolution: 0.05\norigin: [0, 0]\n",
            "bad `origin`",
        ),
        (
            "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 2\n",
            "free_thresh",
        ),
        ("image: m.pgm\nresol", "invalid map YAML"),
        // Found by the map_loader fuzz target: a value quoted in the message spanned lines.
        (
            "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: \"tri\\nnary\\n\\n\"\n",
            "bad `mode`",
        ),
    ] {
        let e = parse_ros_yaml(Path::new("m.yaml"), yaml.as_bytes())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("m.yaml: ") && e.contains(want),
            "{yaml:?}: {e}"
        );
        assert!(!e.contains('\n'), "{e}");
    }
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
