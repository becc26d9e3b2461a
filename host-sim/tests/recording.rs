//! `host-sim listen --mcap`: the session recorded for Foxglove, read back with the `mcap`
//! crate: the four topics with their schemas, the maps with the robot's dimensions, cell size
//! and origin (unknown cells −1, evidence in percent), one pose per scan report and each scan's
//! points where its ranges put them. And `listen --live`: the same maps, poses and scans from
//! the live view's WebSocket server, as a Foxglove client sees them.

use std::process::Command;

use base64::Engine;
use ogm_core::types::scan::{Beam, Range};
use ogm_core::wire::{self, DeviceMsg, Layer, ScanRanges, ScanReport, Tile};
use ogm_core::Angle;
use ogm_core::Pose;
use ogm_field::listen::{Listener, Notice};

mod stream_fixture;
use stream_fixture::{frame, half_free_tile, hello_and_config, EDGE, W};

/// The fixture's session: settings, then two scan reports at `POSES`, each followed by its
/// ranges ([`BEAMS`]) and the half-free log-odds tile at (1, 0); split after each tile.
fn session_parts() -> Vec<Vec<u8>> {
    let mut parts = Vec::new();
    let mut s = hello_and_config();
    // Tile (1, 0): free on its left half, occupied on its right half; the rest never observed.
    let lo = half_free_tile();
    for (seq, &(x_mm, y_mm, heading)) in POSES.iter().enumerate() {
        frame(
            &DeviceMsg::Scan(ScanReport {
                seq: seq as u32,
                pose: Pose {
                    x_mm,
                    y_mm,
                    heading: ogm_core::Angle(heading),
                },
                ..ScanReport::default()
            }),
            &mut s,
        );
        let mut ranges = [0u8; wire::SCAN_RANGES_LEN];
        wire::encode_ranges(&beams(), &mut ranges);
        frame(
            &DeviceMsg::Ranges(ScanRanges {
                seq: seq as u32,
                data: &ranges,
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
        parts.push(std::mem::take(&mut s));
    }
    parts
}

fn session() -> Vec<u8> {
    session_parts().concat()
}

/// The robot's pose at each scan report (mm, mm, heading in 2^16 per turn).
const POSES: [(i32, i32, u16); 2] = [(250, -120, 0), (400, 80, 16_384)];

/// The beams of every scan: (degrees, mm or no return). The 1.2 m hit at 91° is not the
/// closest of its 2° bin, the no-return at 180° gives no point.
const BEAMS: [(f64, Option<u32>); 4] = [
    (0.5, Some(1000)),
    (90.2, Some(2000)),
    (91.0, Some(2500)),
    (180.0, None),
];

fn beams() -> Vec<Beam> {
    BEAMS
        .iter()
        .map(|&(deg, r)| Beam {
            angle: Angle::from_degrees(deg),
            range: r.map_or(Range::NoReturn, Range::Hit),
        })
        .collect()
}

/// Checks the `foxglove.PointCloud` messages read back: one per scan, the closest hit of each
/// bin at its bin's centre (1°, 91°) from the scan's pose.
fn check_scans(seen: &[serde_json::Value]) {
    assert_eq!(seen.len(), POSES.len());
    for (v, &(x_mm, y_mm, heading)) in seen.iter().zip(&POSES) {
        assert_eq!(v["frame_id"], "map");
        assert_eq!(v["point_stride"], 12);
        let data = base64::engine::general_purpose::STANDARD
            .decode(v["data"].as_str().unwrap())
            .unwrap();
        let pts: Vec<(f32, f32)> = data
            .chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().unwrap());
                (f(0), f(4))
            })
            .collect();
        let yaw = f64::from(heading) * std::f64::consts::TAU / 65_536.0;
        let want: Vec<(f64, f64)> = [(1.0f64, 1.0f64), (91.0, 2.0)]
            .iter()
            .map(|&(deg, d)| {
                let th = yaw + deg.to_radians();
                (
                    f64::from(x_mm) / 1000.0 + d * th.cos(),
                    f64::from(y_mm) / 1000.0 + d * th.sin(),
                )
            })
            .collect();
        assert_eq!(pts.len(), want.len(), "{pts:?}");
        for (g, w) in pts.iter().zip(&want) {
            assert!(
                (f64::from(g.0) - w.0).abs() < 1e-3 && (f64::from(g.1) - w.1).abs() < 1e-3,
                "{g:?} vs {w:?}"
            );
        }
    }
}

/// Checks a `foxglove.Grid` message of the fixture's map (no marginal tile arrived: both layers
/// show the log-odds, in percent; unobserved cells −1).
fn check_grid(v: &serde_json::Value, topic: &str) {
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
    let pct = |l: i16| (ogm_core::LogOdds(l).probability() * 100.0).round() as i8;
    for (i, &c) in data.iter().enumerate() {
        let (x, y) = (i % W, i / W);
        let want: i8 = match (x, y) {
            (x, y) if y < EDGE && (EDGE..EDGE + EDGE / 2).contains(&x) => pct(-3072),
            (x, y) if y < EDGE && x >= EDGE + EDGE / 2 => pct(3072),
            _ => -1,
        };
        assert_eq!(c as i8, want, "{topic} cell ({x}, {y})");
    }
}

/// Checks the poses read back against [`POSES`].
fn check_poses(seen: &[(f64, f64, f64)]) {
    assert_eq!(seen.len(), POSES.len());
    for (got, &(x_mm, y_mm, heading)) in seen.iter().zip(&POSES) {
        let yaw = f64::from(heading) * std::f64::consts::TAU / 65_536.0;
        assert!((got.0 - f64::from(x_mm) / 1000.0).abs() < 1e-9, "{got:?}");
        assert!((got.1 - f64::from(y_mm) / 1000.0).abs() < 1e-9, "{got:?}");
        assert!((got.2 - yaw).abs() < 1e-9, "{got:?}");
    }
}

/// (x, y, yaw) of a `foxglove.PoseInFrame` message.
fn pose_of(v: &serde_json::Value) -> (f64, f64, f64) {
    let p = &v["pose"]["position"];
    let q = &v["pose"]["orientation"];
    let yaw = 2.0 * q["z"].as_f64().unwrap().atan2(q["w"].as_f64().unwrap());
    (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap(), yaw)
}

#[test]
fn a_listened_session_reads_back_from_its_mcap_file() {
    let s = session();
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
            ("/robot/scan".into(), "foxglove.PointCloud".into()),
        ]
    );
    let mut grids = 0;
    let mut seen_poses = Vec::new();
    let mut seen_scans = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        match m.channel.topic.as_str() {
            "/robot/pose" => seen_poses.push(pose_of(&v)),
            "/robot/scan" => seen_scans.push(v),
            topic => {
                grids += 1;
                check_grid(&v, topic);
            }
        }
    }
    // The final save writes both layers once (the map did not exist when recording began).
    assert_eq!(grids, 2);
    check_poses(&seen_poses);
    check_scans(&seen_scans);
}

/// A message a live-view client received: its topic and JSON.
type Received = (String, serde_json::Value);

#[test]
fn a_live_view_serves_the_listened_maps_and_poses() {
    use tungstenite::client::IntoClientRequest;
    use tungstenite::Message;
    let mut l = Listener::new();
    let addr = l.serve_live("127.0.0.1:0").unwrap();
    assert!(addr.ip().is_loopback());
    // A Foxglove client: the subprotocol, the offer, a subscription to every channel.
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        ogm_field::live::SUBPROTOCOL.parse().unwrap(),
    );
    let (mut ws, _) = tungstenite::connect(req).unwrap();
    let mut texts = Vec::new();
    while texts.len() < 2 {
        if let Message::Text(t) = ws.read().unwrap() {
            texts.push(serde_json::from_str::<serde_json::Value>(&t).unwrap());
        }
    }
    assert_eq!(texts[0]["op"], "serverInfo");
    let channels = texts[1]["channels"].as_array().unwrap();
    let topic_of = |id: u64| {
        channels
            .iter()
            .find(|c| c["id"] == id)
            .map(|c| c["topic"].as_str().unwrap().to_string())
            .unwrap()
    };
    let subs: Vec<serde_json::Value> = channels
        .iter()
        .map(|c| serde_json::json!({"id": c["id"].as_u64().unwrap() + 100, "channelId": c["id"]}))
        .collect();
    // The robot's first scan arrives; the listener's periodic tick sends the maps.
    let parts = session_parts();
    let notices = l.push(&parts[0]);
    assert!(notices.iter().all(|n| !matches!(n, Notice::Warning(_))));
    l.live_tick();
    ws.send(Message::text(
        serde_json::json!({"op": "subscribe", "subscriptions": subs}).to_string(),
    ))
    .unwrap();
    // Read binary messages until `done`: (topic, JSON) each.
    let mut read_until = |done: &dyn Fn(&[Received]) -> bool| {
        let mut got = Vec::new();
        while !done(&got) {
            let Message::Binary(b) = ws.read().unwrap() else {
                continue;
            };
            assert_eq!(b[0], 1, "message data opcode");
            let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
            let v: serde_json::Value = serde_json::from_slice(&b[13..]).unwrap();
            got.push((topic_of(u64::from(sub) - 100), v));
        }
        got
    };
    let count =
        |got: &[Received], topic: &str| got.iter().filter(|(t, _)| t.starts_with(topic)).count();
    // The subscriptions are answered with each channel's latest message: both maps and the
    // first scan's pose and points (published before the client subscribed)...
    let first = read_until(&|g| {
        count(g, "/map/") == 2 && count(g, "/robot/pose") == 1 && count(g, "/robot/scan") == 1
    });
    // ...and the next scan's pose and points come as they arrive.
    let notices = l.push(&parts[1]);
    assert!(notices.iter().all(|n| !matches!(n, Notice::Warning(_))));
    let next = read_until(&|g| count(g, "/robot/pose") == 1 && count(g, "/robot/scan") == 1);
    let grids: Vec<Received> = first
        .iter()
        .filter(|(t, _)| t.starts_with("/map/"))
        .cloned()
        .collect();
    let scans: Vec<serde_json::Value> = first
        .iter()
        .chain(&next)
        .filter(|(t, _)| t == "/robot/scan")
        .map(|(_, v)| v.clone())
        .collect();
    let poses: Vec<(f64, f64, f64)> = first
        .iter()
        .chain(&next)
        .filter(|(t, _)| t == "/robot/pose")
        .map(|(_, v)| pose_of(v))
        .collect();
    let mut topics: Vec<&str> = grids.iter().map(|(t, _)| t.as_str()).collect();
    topics.sort();
    assert_eq!(topics, ["/map/log_odds", "/map/marginals"]);
    for (topic, v) in &grids {
        check_grid(v, topic);
    }
    check_poses(&poses);
    check_scans(&scans);
    assert_eq!(l.live().map(|s| s.connections()), Some(1));
}
