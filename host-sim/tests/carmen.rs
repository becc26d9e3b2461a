//! CARMEN reader, `eval-log` and map export: a hand-made log snippet (good and malformed lines,
//! plain and gzip), a synthetic log of a simulated room run through the CLI, the ROS export round
//! trip through the loader, and — when `../shared/data` is present — the real logs.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use host_sim::eval::eval_log::{
    benchmark_truth, log_geometry, map_scans, Experiment, ReplaySensor, BENCHMARK_THRESHOLD,
};
use host_sim::export::probabilities_from_png;
use host_sim::sim::carmen::{
    flaser_angles_deg, parse_log, read_log, CarmenLog, MaxRangeSource, ReadOptions,
};
use host_sim::sim::explore::ScanRecord;
use host_sim::sim::{new_mapper, probabilities};
use ogm_core::{Angle, Beam, MapperConfig, Pose, Range, ScanBuf};
use ogm_field::export::export_world;
use ogm_field::world::{load_world, probabilities_to_world, Truth};

/// `n` readings, the pose and the standard FLASER tail.
fn flaser(ranges: &[f64], x: f64, y: f64, th: f64) -> String {
    let mut s = format!("FLASER {}", ranges.len());
    for r in ranges {
        s.push_str(&format!(" {r}"));
    }
    s.push_str(&format!(" {x} {y} {th} {x} {y} {th} 12.5 pippo 12.6"));
    s
}

fn readings(n: usize, r: f64) -> Vec<f64> {
    vec![r; n]
}

/// The snippet; `(line, what)` of each malformed line.
fn snippet() -> (String, Vec<(usize, &'static str)>) {
    let mut l: Vec<String> = Vec::new();
    let mut bad = Vec::new();
    l.push("# message formats defined: PARAM SYNC ODOM FLASER ROBOTLASER1".into()); // 1
    l.push("PARAM robot_front_laser_max 50 nohost 0".into()); // 2

    // 3: 180 beams, 12 of them at the SICK sentinel (81.91): a detected max range.
    let mut r180 = readings(180, 2.0);
    for i in 0..12 {
        r180[i * 15] = 81.91;
    }
    l.push(flaser(&r180, 1.0, 2.0, 0.0)); // 3
    l.push(String::new()); // 4: blank
    let quarter = std::f64::consts::FRAC_PI_2;
    l.push(flaser(&readings(181, 3.0), -1.5, 0.25, quarter)); // 5
    l.push(flaser(&readings(360, 4.0), 0.0, 0.0, -3.0)); // 6
    let mut r361 = readings(361, 5.0);
    r361[0] = 81.87; // a second sentinel value below the largest
    l.push(flaser(&r361, 2.0, 2.0, 0.5)); // 7

    // 8: ROBOTLASER1, 5 readings from -90 deg in 45 deg steps, max range 30 m, 2 remissions.
    l.push(
        "ROBOTLASER1 0 -1.5707963 3.1415926 0.7853982 30.0 0.01 0 5 1.0 2.0 30.0 35.0 0.5 \
         2 0.1 0.2 3.0 4.0 0.25 2.9 4.0 0.25 0.0 0.0 0.5 0.3 0.1 100.0 host 100.1"
            .into(),
    );
    // Malformed lines.
    let mut short = flaser(&readings(180, 2.0), 0.0, 0.0, 0.0);
    short = short.replacen("FLASER 180 2", "FLASER 181 2", 1); // count says 181, 180 given
    l.push(short); // 9
    bad.push((9, "fields"));
    l.push(flaser(&[1.0, 2.0, 3.0], 0.0, 0.0, 0.0).replacen(" 2 ", " abc ", 1)); // 10
    bad.push((10, "not a number"));
    l.push(flaser(&[1.0, f64::NAN, 3.0], 0.0, 0.0, 0.0)); // 11
    bad.push((11, "NaN"));
    l.push(flaser(&[1.0, f64::INFINITY, 3.0], 0.0, 0.0, 0.0)); // 12
    bad.push((12, "inf"));
    l.push("FLASER 3 1.0 2.0".into()); // 13: truncated
    bad.push((13, "fields"));
    l.push("FLASER".into()); // 14: nothing after the tag
    bad.push((14, "reading count"));
    l.push(flaser(&[], 0.0, 0.0, 0.0)); // 15: no readings
    bad.push((15, "no readings"));
    l.push("ODOM 0.1 0.2 0.3 0 0 0 1.0 host 1.0".into()); // 16
    l.push(flaser(&[1.0, 2.0, 3.0], 0.0, 0.0, 0.0).replacen(" 0 0 0 ", " 0 NaN 0 ", 1)); // 17
    bad.push((17, "y"));
    l.push("ROBOTLASER1 0 -1.57 3.14 0.78 30.0 0.01 0 5 1.0 2.0".into()); // 18: truncated
    bad.push((18, "truncated"));
    l.push(flaser(&[1.0, 2.0], 0.0, 0.0, 0.0).replacen("FLASER 2", "FLASER -2", 1)); // 19
    bad.push((19, "reading count"));
    l.push("   \t ".into()); // 20: blank
    l.push(
        "ROBOTLASER1 0 -1.57 3.14 0.78 30.0 0.01 0 2 1.0 2.0 0 1 2 x 4 5 6 0 0 0 0 0 1 h 1".into(),
    ); // 21: laser_pose_theta is `x`
    bad.push((21, "laser_pose_theta"));
    let mut text = l.join("\n");
    text.push('\n');
    (text, bad)
}

fn check_snippet(log: &CarmenLog, bad: &[(usize, &str)]) {
    let i = &log.info;
    assert_eq!(log.scans.len(), 5, "{:#?}", i.warnings);
    assert_eq!((i.flaser, i.robotlaser1), (4, 1));
    assert_eq!(i.malformed_lines, bad.len(), "{:#?}", i.warnings);
    let lines: Vec<usize> = i.warnings.iter().map(|w| w.line).collect();
    assert_eq!(lines, bad.iter().map(|b| b.0).collect::<Vec<_>>());
    for (w, (_, what)) in i.warnings.iter().zip(bad) {
        assert!(w.message.contains(what), "line {}: {}", w.line, w.message);
        assert!(w.to_string().starts_with(&format!("line {}:", w.line)));
    }
    assert_eq!(i.comments, 1);
    assert_eq!(i.blank, 2);
    assert_eq!(i.other.get("PARAM"), Some(&1));
    assert_eq!(i.other.get("ODOM"), Some(&1));
    assert_eq!(i.lines, 21);
    // Max range: the 12 readings at 81.91 are a sentinel; 81.87 is within 0.5 % of it.
    assert_eq!(i.flaser_max_range_source, Some(MaxRangeSource::Detected));
    assert!((i.flaser_max_range_m - 81.91 * 0.995).abs() < 1e-9);
    assert_eq!(i.robotlaser_max_range_m, 30.0);
    // 13 FLASER sentinels + 2 ROBOTLASER1 readings >= 30 m.
    assert_eq!(i.no_returns, 15);
    assert_eq!(i.hits, 180 + 181 + 360 + 361 + 5 - 15);
    assert_eq!(i.invalid_readings, 0);
    assert_eq!(
        i.beam_counts
            .iter()
            .map(|(k, v)| (*k, *v))
            .collect::<Vec<_>>(),
        vec![(5, 1), (180, 1), (181, 1), (360, 1), (361, 1)]
    );

    // Beam geometry: 180° from -90°, odd counts include both ends.
    let first_last = |s: &ScanRecord| (s.beams[0].angle, s.beams[s.beams.len() - 1].angle);
    let deg = Angle::from_degrees;
    assert_eq!(first_last(&log.scans[0]), (deg(-90.0), deg(89.0)));
    assert_eq!(first_last(&log.scans[1]), (deg(-90.0), deg(90.0)));
    assert_eq!(first_last(&log.scans[2]), (deg(-90.0), deg(89.5)));
    assert_eq!(first_last(&log.scans[3]), (deg(-90.0), deg(90.0)));
    assert_eq!(log.scans[2].beams[1].angle, deg(-89.5));
    // Poses: mm and binary angles.
    assert_eq!(
        log.scans[0].pose,
        Pose {
            x_mm: 1000,
            y_mm: 2000,
            heading: Angle(0)
        }
    );
    assert_eq!(
        (log.scans[1].pose.x_mm, log.scans[1].pose.y_mm),
        (-1500, 250)
    );
    assert_eq!(log.scans[1].pose.heading, Angle::QUARTER);
    assert_eq!(log.scans[2].pose.heading, Angle::from_radians(-3.0));
    // Max-range readings are no-returns, others hits in mm.
    assert_eq!(log.scans[0].beams[0].range, Range::NoReturn);
    assert_eq!(log.scans[0].beams[1].range, Range::Hit(2000));
    assert_eq!(log.scans[3].beams[0].range, Range::NoReturn);
    // ROBOTLASER1: laser pose, its own angles and range.
    let rl = &log.scans[4];
    assert_eq!((rl.pose.x_mm, rl.pose.y_mm), (3000, 4000));
    assert_eq!(rl.pose.heading, Angle::from_radians(0.25));
    let angles: Vec<Angle> = rl.beams.iter().map(|b| b.angle).collect();
    assert_eq!(
        angles,
        [-90.0, -45.0, 0.0, 45.0, 90.0].map(deg).to_vec(),
        "ROBOTLASER1 angles"
    );
    let ranges: Vec<Range> = rl.beams.iter().map(|b| b.range).collect();
    assert_eq!(
        ranges,
        vec![
            Range::Hit(1000),
            Range::Hit(2000),
            Range::NoReturn,
            Range::NoReturn,
            Range::Hit(500)
        ]
    );
}

#[test]
fn snippet_plain_and_gzip() {
    let (text, bad) = snippet();
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("snippet.log");
    std::fs::write(&plain, &text).unwrap();
    let gz = dir.path().join("snippet.log.gz");
    let mut enc = flate2::write::GzEncoder::new(
        std::fs::File::create(&gz).unwrap(),
        flate2::Compression::default(),
    );
    enc.write_all(text.as_bytes()).unwrap();
    enc.finish().unwrap();
    // A plain file with a .gz name is still read (gzip is detected by its magic bytes).
    let misnamed = dir.path().join("plain.log.gz");
    std::fs::write(&misnamed, &text).unwrap();

    let opts = ReadOptions::default();
    let a = read_log(&plain, &opts).unwrap();
    check_snippet(&a, &bad);
    let b = read_log(&gz, &opts).unwrap();
    assert_eq!(a, b);
    assert_eq!(read_log(&misnamed, &opts).unwrap(), a);
    assert_eq!(parse_log(text.as_bytes(), &opts).unwrap(), a);

    // Without a trailing newline, and with CRLF line ends, nothing changes but the counts.
    let crlf = text.replace('\n', "\r\n");
    let c = parse_log(crlf.as_bytes(), &opts).unwrap();
    assert_eq!(c.scans, a.scans);
    assert_eq!(c.info.malformed_lines, a.info.malformed_lines);

    // --max-range overrides the detection.
    let o = parse_log(
        text.as_bytes(),
        &ReadOptions {
            max_range_m: Some(3.0),
        },
    )
    .unwrap();
    assert_eq!(o.info.flaser_max_range_source, Some(MaxRangeSource::Option));
    assert_eq!(o.scans[0].beams[1].range, Range::Hit(2000));
    assert_eq!(o.scans[1].beams[0].range, Range::NoReturn); // 3.0 >= 3.0
    assert_eq!(o.scans[3].beams[0].range, Range::NoReturn);

    assert!(read_log(&dir.path().join("missing.log"), &opts).is_err());
    // A truncated gzip stream is an I/O error, not a panic.
    let bytes = std::fs::read(&gz).unwrap();
    let cut = dir.path().join("cut.log.gz");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(read_log(&cut, &opts).is_err());
}

#[test]
fn garbage_never_panics() {
    let opts = ReadOptions::default();
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let words = [
        "FLASER",
        "ROBOTLASER1",
        "3",
        "0",
        "-1",
        "1e308",
        "1e400",
        "NaN",
        "-inf",
        "x",
        "0.5",
        "99999999999999999999",
        "",
        "#",
        "\u{fffd}",
    ];
    for _ in 0..300 {
        let mut text = String::new();
        for _ in 0..(next() % 6) {
            for _ in 0..(next() % 30) {
                text.push_str(words[(next() % words.len() as u64) as usize]);
                text.push(' ');
            }
            text.push('\n');
        }
        let log = parse_log(text.as_bytes(), &opts).unwrap();
        assert!(log.info.malformed_lines <= log.info.lines);
    }
    // Invalid UTF-8 is a warning too.
    let log = parse_log(&b"FLASER 1 \xff\n"[..], &opts).unwrap();
    assert_eq!(log.info.malformed_lines, 1);
}

#[test]
fn flaser_angle_rule() {
    assert_eq!(flaser_angles_deg(180), (-90.0, 1.0));
    assert_eq!(flaser_angles_deg(361), (-90.0, 0.5));
}

// ---------------------------------------------------------------------------------------------
// A synthetic log: a simulated 8 m x 6 m room with a pillar, scanned with a 361-beam SICK.

const SEGMENTS: [((f64, f64), (f64, f64)); 8] = [
    ((0.0, 0.0), (8.0, 0.0)),
    ((8.0, 0.0), (8.0, 6.0)),
    ((8.0, 6.0), (0.0, 6.0)),
    ((0.0, 6.0), (0.0, 0.0)),
    ((3.0, 2.0), (4.0, 2.0)),
    ((4.0, 2.0), (4.0, 3.0)),
    ((4.0, 3.0), (3.0, 3.0)),
    ((3.0, 3.0), (3.0, 2.0)),
];

fn cast(x: f64, y: f64, a: f64) -> f64 {
    let (dx, dy) = (a.cos(), a.sin());
    let mut best = f64::INFINITY;
    for ((ax, ay), (bx, by)) in SEGMENTS {
        let (ex, ey) = (bx - ax, by - ay);
        let den = dx * ey - dy * ex;
        if den.abs() < 1e-12 {
            continue;
        }
        let t = ((ax - x) * ey - (ay - y) * ex) / den;
        let s = ((ax - x) * dy - (ay - y) * dx) / den;
        if t > 0.0 && (0.0..=1.0).contains(&s) {
            best = best.min(t);
        }
    }
    best
}

/// `poses` scans of 361 beams along a loop in the room; every 37th beam reads the sentinel.
fn room_log(poses: usize) -> String {
    let mut out = String::from("# synthetic room\n");
    for k in 0..poses {
        let t = k as f64 / poses as f64 * std::f64::consts::TAU;
        let (x, y) = (4.0 + 2.6 * t.cos(), 3.0 + 2.0 * t.sin());
        let th = t + std::f64::consts::FRAC_PI_2;
        let r: Vec<f64> = (0..361)
            .map(|i| {
                if (i + k) % 37 == 0 {
                    81.91
                } else {
                    let a = th + (-90.0 + 0.5 * i as f64).to_radians();
                    (cast(x, y, a) * 1000.0).round() / 1000.0
                }
            })
            .collect();
        out.push_str(&flaser(&r, x, y, th));
        out.push('\n');
    }
    out
}

#[test]
fn experiments_subsample_like_table_iii() {
    // The Intel lab's numbers: 910 poses x 180 beams.
    let scans: Vec<ScanRecord> = (0..910)
        .map(|i| ScanRecord {
            pose: Pose {
                x_mm: i,
                y_mm: 0,
                heading: Angle(0),
            },
            beams: (0..180)
                .map(|b| Beam {
                    angle: Angle::from_degrees(-90.0 + f64::from(b)),
                    range: Range::Hit(1000),
                })
                .collect(),
        })
        .collect();
    let count = |id: u8| {
        let s = Experiment::new(id).unwrap().select(&scans);
        (s.len(), s.iter().map(|s| s.beams.len()).sum::<usize>())
    };
    assert_eq!(count(0), (910, 163_800));
    assert_eq!(count(1), (910, 81_900));
    assert_eq!(count(2), (455, 40_950));
    assert_eq!(count(3), (91, 8_190));
    assert!(Experiment::new(4).is_err());
    let e3 = Experiment::new(3).unwrap().select(&scans);
    assert_eq!(e3[1].pose.x_mm, 10);
    assert_eq!(e3[0].beams[1].angle, Angle::from_degrees(-88.0));
}

#[test]
fn replay_through_the_pipeline_equals_direct_insertion() {
    let log = parse_log(room_log(12).as_bytes(), &ReadOptions::default()).unwrap();
    assert_eq!(log.info.malformed_lines, 0);
    let cfg = MapperConfig::new(20_000);
    let g = log_geometry(&log.scans, 0.05, cfg.max_range_mm, 1.0).unwrap();
    // 8 m x 6 m room + 1 m margins, at 5 cm.
    assert!((199..=202).contains(&g.width()), "{}", g.width());
    assert!((159..=162).contains(&g.height()), "{}", g.height());
    let m = map_scans(g, cfg, &log.scans).unwrap();
    let mut direct = new_mapper(g, cfg).unwrap();
    for s in &log.scans {
        direct.insert_scan(&s.pose, &s.beams).unwrap();
    }
    assert_eq!(m.map, direct.grid().cells());
    assert_eq!(m.beams_overflowed, 0);
    assert!(m.observed.iter().filter(|&&o| o).count() > 10_000);

    let mut sensor = ReplaySensor::new(&log.scans[..2]);
    let mut buf: ScanBuf<512> = ScanBuf::new();
    assert_eq!(sensor.next_pose(), Some(log.scans[0].pose));
    sensor.read_scan(&mut buf).unwrap();
    assert_eq!(buf.beams(), &log.scans[0].beams[..]);
    sensor.read_scan(&mut buf).unwrap();
    assert!(sensor.read_scan(&mut buf).is_err());
    assert_eq!(sensor.next_pose(), None);

    // The benchmark: observed cells thresholded (strictly) at 0.20, the rest unknown.
    let truth = benchmark_truth(&probabilities(&m.map), &m.observed, BENCHMARK_THRESHOLD);
    let occ = truth.iter().filter(|t| **t == Truth::Occupied).count();
    let free = truth.iter().filter(|t| **t == Truth::Free).count();
    assert!(occ > 500 && free > 10 * occ, "{occ} occupied, {free} free");
    assert_eq!(
        benchmark_truth(&[0.2, 0.2001, 0.9, 0.1], &[true, true, false, true], 0.2),
        vec![Truth::Free, Truth::Occupied, Truth::Unknown, Truth::Free]
    );
}

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn eval_log_and_export_on_a_synthetic_log() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("room.log.gz");
    let mut enc = flate2::write::GzEncoder::new(
        std::fs::File::create(&log).unwrap(),
        flate2::Compression::fast(),
    );
    enc.write_all(room_log(40).as_bytes()).unwrap();
    enc.write_all(b"FLASER 2 1.0 oops\n").unwrap(); // reported, skipped
    enc.finish().unwrap();
    let out = dir.path().join("eval");
    let stdout = run_ok(host_sim().args([
        "eval-log",
        "--log",
        log.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--methods",
        "gibbs_l9_border",
        "--sweeps",
        "3",
        "--burn-in",
        "1",
        "--export-ros",
    ]));
    assert!(stdout.contains("gibbs_l9_border"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["log"], "room");
    assert_eq!(report["reader"]["flaser"], 40);
    assert_eq!(report["reader"]["malformed_lines"], 1);
    assert_eq!(report["reader"]["warnings"][0]["line"], 42);
    assert_eq!(report["benchmark"]["poses"], 40);
    assert_eq!(report["benchmark"]["measurements"], 40 * 361);
    let exps = report["experiments"].as_array().unwrap();
    assert_eq!(exps.len(), 3);
    for (e, (poses, beams)) in exps.iter().zip([(40, 181), (20, 181), (4, 181)]) {
        assert_eq!(e["poses"], poses);
        assert_eq!(e["measurements"], poses * beams);
        let f = e["fraction_mapped"].as_f64().unwrap();
        assert!(f > 0.0 && f <= report["benchmark"]["fraction_mapped"].as_f64().unwrap());
        for key in ["methods", "methods_near_mapped"] {
            for m in ["traditional", "gibbs_l9_border"] {
                let s = &e[key][m];
                for field in ["max_f1", "max_precision", "threshold_at_max_f1"] {
                    assert!(s[field].is_number(), "{key}.{m}.{field}: {e}");
                }
            }
        }
        assert!(
            e["seconds_per_map_sample"]["gibbs_l9_border"]
                .as_f64()
                .unwrap()
                > 0.0
        );
        // Traditional OGM on all beams of all poses reproduces most of its own benchmark.
        if e["experiment"] == 1 {
            assert!(
                e["methods_near_mapped"]["traditional"]["max_f1"]
                    .as_f64()
                    .unwrap()
                    > 0.6
            );
        }
    }
    for f in [
        "benchmark.png",
        "exp1_comparison.png",
        "exp3_traditional.png",
        "exp2_gibbs_l9_border.png",
        "exp3_gibbs_l9_border_errors.png",
        "ros/benchmark.yaml",
        "ros/benchmark.pgm",
        "ros/benchmark.png",
        "ros/exp3_gibbs_l9_border.yaml",
    ] {
        assert!(out.join(f).exists(), "missing {f}");
    }
    // The exported benchmark loads back as the benchmark.
    let (w, h) = (
        report["width"].as_u64().unwrap() as usize,
        report["height"].as_u64().unwrap() as usize,
    );
    let bench = load_world(&out.join("ros/benchmark.yaml"), None).unwrap();
    assert_eq!((bench.width, bench.height), (w, h));
    assert_eq!(bench.resolution_m, 0.05);
    let origin = &report["origin_m"];
    assert_eq!(
        bench.origin_m,
        (origin[0].as_f64().unwrap(), origin[1].as_f64().unwrap())
    );
    let c = bench.counts();
    assert_eq!(c.occupied as u64, report["benchmark"]["occupied_cells"]);
    assert_eq!(c.free as u64, report["benchmark"]["free_cells"]);

    // `export --log --method benchmark` writes the same map.
    let yaml = dir.path().join("exported/bench.yaml");
    run_ok(host_sim().args([
        "export",
        "--log",
        log.to_str().unwrap(),
        "--method",
        "benchmark",
        "--out",
        yaml.to_str().unwrap(),
    ]));
    assert_eq!(load_world(&yaml, None).unwrap(), bench);
    assert_eq!(
        load_world(&yaml.with_extension("png"), Some(0.05))
            .unwrap()
            .cells,
        bench.cells
    );
    // ... and a sampler's map on experiment 3.
    let yaml3 = dir.path().join("exported/exp3.yaml");
    run_ok(host_sim().args([
        "export",
        "--log",
        log.to_str().unwrap(),
        "--experiment",
        "3",
        "--method",
        "gibbs_l9_border",
        "--sweeps",
        "2",
        "--burn-in",
        "1",
        "--out",
        yaml3.to_str().unwrap(),
    ]));
    let s3 = load_world(&yaml3, None).unwrap();
    assert_eq!((s3.width, s3.height, s3.origin_m), (w, h, bench.origin_m));

    // `export --probability-png` of one panel of the comparison strip (benchmark, traditional,
    // sampler): the traditional panel equals exp1_traditional.png's map.
    let strip = dir.path().join("exported/strip.yaml");
    run_ok(host_sim().args([
        "export",
        "--probability-png",
        out.join("exp1_comparison.png").to_str().unwrap(),
        "--panel",
        "1",
        "--panels",
        "3",
        "--resolution",
        "0.05",
        "--origin",
        &format!("{},{}", bench.origin_m.0, bench.origin_m.1),
        "--out",
        strip.to_str().unwrap(),
    ]));
    let single = dir.path().join("exported/single.yaml");
    run_ok(host_sim().args([
        "export",
        "--probability-png",
        out.join("exp1_traditional.png").to_str().unwrap(),
        "--origin",
        &format!("{},{}", bench.origin_m.0, bench.origin_m.1),
        "--out",
        single.to_str().unwrap(),
    ]));
    let (a, b) = (
        load_world(&strip, None).unwrap(),
        load_world(&single, None).unwrap(),
    );
    assert_eq!(a, b);
    assert!(a.counts().free > 1000 && a.counts().occupied > 100);

    // A bad source is an error message, not a panic.
    let out = host_sim()
        .args(["export", "--out", "x.yaml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[test]
fn ros_export_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    // Probabilities with every class, an odd size, a negative origin.
    let (w, h) = (37, 23);
    let probs: Vec<f64> = (0..w * h)
        .map(|i| match i % 7 {
            0 => 0.5,
            1 => 0.95,
            2 => 0.65,
            3 => 0.3,
            4 => 0.196,
            _ => 0.01,
        })
        .collect();
    let world = probabilities_to_world(&probs, w, h, 0.05, (-12.35, 4.2), 0.65, 0.196);
    let c = world.counts();
    assert!(c.free > 0 && c.occupied > 0 && c.unknown > 0);
    let yaml = dir.path().join("sub/map.yaml");
    let written = export_world(&yaml, &world).unwrap();
    assert_eq!(written.len(), 3);
    let text = std::fs::read_to_string(&yaml).unwrap();
    for key in [
        "image: map.pgm",
        "resolution: 0.05",
        "origin: [-12.35, 4.2, 0.0]",
        "occupied_thresh: 0.65",
        "free_thresh: 0.196",
        "mode: trinary",
        "negate: 0",
    ] {
        assert!(text.contains(key), "missing `{key}` in\n{text}");
    }
    assert_eq!(load_world(&yaml, None).unwrap(), world);
    let pgm = dir.path().join("sub/map.pgm");
    assert_eq!(load_world(&pgm, Some(0.05)).unwrap().cells, world.cells);
    let png = dir.path().join("sub/map.png");
    assert_eq!(load_world(&png, Some(0.05)).unwrap().cells, world.cells);

    // A probability PNG read back: within 1/255, rows flipped back.
    let p = dir.path().join("p.png");
    host_sim::eval::render::probability_png(&p, &probs, w, h).unwrap();
    let (back, bw, bh) = probabilities_from_png(&p, None).unwrap();
    assert_eq!((bw, bh), (w, h));
    for (a, b) in probs.iter().zip(&back) {
        assert!((a - b).abs() <= 0.5 / 255.0 + 1e-12, "{a} vs {b}");
    }
    // Panels of a strip.
    let imgs = vec![
        (
            "a",
            host_sim::eval::render::probability_image(&probs, w, h).unwrap(),
        ),
        (
            "b",
            host_sim::eval::render::probability_image(&vec![1.0; w * h], w, h).unwrap(),
        ),
    ];
    let s = dir.path().join("s.png");
    host_sim::eval::render::side_by_side_png(&s, &imgs).unwrap();
    assert_eq!(probabilities_from_png(&s, Some((0, 2))).unwrap().0, back);
    assert!(probabilities_from_png(&s, Some((1, 2)))
        .unwrap()
        .0
        .iter()
        .all(|&p| p == 1.0));
    assert!(probabilities_from_png(&s, Some((0, 3))).is_err());
    assert!(probabilities_from_png(&s, Some((2, 2))).is_err());
}

// ---------------------------------------------------------------------------------------------
// The real logs.

fn shared_logs() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/logs");
    p.is_dir().then_some(p)
}

#[test]
fn real_logs_read_cleanly() {
    let Some(dir) = shared_logs() else {
        eprintln!("SKIPPED: ../shared/data not found");
        return;
    };
    // ../shared/data/README.md: scans and beams per log.
    let expected = [
        ("csail-corrected.log.gz", 406, 361),
        ("freiburg-101-corrected.log.gz", 292, 360),
        ("seattle-corrected.log.gz", 241, 361),
        ("orebro-corrected.log.gz", 237, 181),
        ("fhw-corrected.log.gz", 488, 180),
    ];
    for (name, scans, beams) in expected {
        let path = dir.join(name);
        if !path.exists() {
            eprintln!("SKIPPED: {} not found", path.display());
            continue;
        }
        let log = read_log(&path, &ReadOptions::default()).unwrap();
        let i = &log.info;
        assert_eq!(log.scans.len(), scans, "{name}");
        assert_eq!(i.malformed_lines, 0, "{name}: {:?}", i.warnings);
        assert_eq!(i.beam_counts.len(), 1, "{name}");
        assert_eq!(i.beam_counts.get(&beams), Some(&scans), "{name}");
        assert_eq!(i.invalid_readings, 0, "{name}");
        // Every log has a max-range sentinel (SICK 81.9 m, 51.1 m, 32.767 m).
        assert_eq!(
            i.flaser_max_range_source,
            Some(MaxRangeSource::Detected),
            "{name}"
        );
        assert!(
            i.no_returns > 0 && i.max_hit_m < i.flaser_max_range_m,
            "{name}"
        );
    }
}
