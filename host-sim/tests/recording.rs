//! `host-sim listen --mcap`: the session recorded for Foxglove, read back with the `mcap`
//! crate: the three topics with their schemas, the maps with the robot's dimensions, cell size
//! and origin (unknown cells −1, evidence in percent), and one pose per scan report.

use std::process::Command;

use base64::Engine;
use ogm_core::wire::{DeviceMsg, Layer, ScanReport, Tile, WirePose};

mod stream_fixture;
use stream_fixture::{frame, half_free_tile, hello_and_config, EDGE, W};

#[test]
fn a_listened_session_reads_back_from_its_mcap_file() {
    let mut s = hello_and_config();
    // Tile (1, 0): free on its left half, occupied on its right half; the rest never observed.
    let lo = half_free_tile();
    let poses = [(250, -120, 0u16), (400, 80, 16_384)];
    for (seq, &(x_mm, y_mm, heading)) in poses.iter().enumerate() {
        frame(
            &DeviceMsg::Scan(ScanReport {
                seq: seq as u32,
                pose: WirePose {
                    x_mm,
                    y_mm,
                    heading,
                },
                ..ScanReport::default()
            }),
            &mut s,
        );
        frame(
            &DeviceMsg::Tile(Tile {
                layer: Layer::LogOdds,
                tx: 1,
                ty: 0,
                data: &lo,
            }),
            &mut s,
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("capture.bin");
    std::fs::write(&input, &s).unwrap();
    let mcap_path = dir.path().join("session.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["listen", "--quiet", "--port"])
        .arg(&input)
        .arg("--out")
        .arg(dir.path().join("out"))
        .arg("--mcap")
        .arg(&mcap_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let bytes = std::fs::read(&mcap_path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let mut topics: Vec<(String, String)> = summary
        .channels
        .values()
        .map(|c| {
            let schema = c.schema.as_ref().map_or("", |s| s.name.as_str());
            (c.topic.clone(), schema.to_string())
        })
        .collect();
    topics.sort();
    assert_eq!(
        topics,
        [
            ("/map/log_odds".into(), "foxglove.Grid".into()),
            ("/map/marginals".into(), "foxglove.Grid".into()),
            ("/robot/pose".into(), "foxglove.PoseInFrame".into()),
        ]
    );
    let mut grids = 0;
    let mut seen_poses = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        match m.channel.topic.as_str() {
            "/robot/pose" => {
                let p = &v["pose"]["position"];
                let q = &v["pose"]["orientation"];
                let yaw = 2.0 * q["z"].as_f64().unwrap().atan2(q["w"].as_f64().unwrap());
                seen_poses.push((p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap(), yaw));
            }
            _ => {
                grids += 1;
                assert_eq!(v["column_count"], W);
                assert_eq!(v["row_stride"], W);
                assert_eq!(v["cell_size"]["x"], 0.1);
                assert_eq!(v["pose"]["position"]["x"], -1.0);
                assert_eq!(v["pose"]["position"]["y"], 0.5);
                assert_eq!(v["fields"][0]["name"], "occupancy");
                let data = base64::engine::general_purpose::STANDARD
                    .decode(v["data"].as_str().unwrap())
                    .unwrap();
                assert_eq!(data.len(), W * W);
                // No marginal tile arrived: both layers show the log-odds, in percent.
                let pct = |l: i16| (ogm_core::LogOdds(l).probability() * 100.0).round() as i8;
                for (i, &c) in data.iter().enumerate() {
                    let (x, y) = (i % W, i / W);
                    let want: i8 = match (x, y) {
                        (x, y) if y < EDGE && (EDGE..EDGE + EDGE / 2).contains(&x) => pct(-3072),
                        (x, y) if y < EDGE && x >= EDGE + EDGE / 2 => pct(3072),
                        _ => -1,
                    };
                    assert_eq!(c as i8, want, "{} cell ({x}, {y})", m.channel.topic);
                }
            }
        }
    }
    // The final save writes both layers once (the map did not exist when recording began).
    assert_eq!(grids, 2);
    assert_eq!(seen_poses.len(), poses.len());
    for (got, &(x_mm, y_mm, heading)) in seen_poses.iter().zip(&poses) {
        let yaw = f64::from(heading) * std::f64::consts::TAU / 65_536.0;
        assert!((got.0 - f64::from(x_mm) / 1000.0).abs() < 1e-9, "{got:?}");
        assert!((got.1 - f64::from(y_mm) / 1000.0).abs() < 1e-9, "{got:?}");
        assert!((got.2 - yaw).abs() < 1e-9, "{got:?}");
    }
}
