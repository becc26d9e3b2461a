//! `host-sim listen --mcap`: the session recorded for Foxglove, read back with the `mcap`
//! crate: the three topics with their schemas, the maps with the robot's dimensions, cell size
//! and origin (unknown cells −1, evidence in percent), and one pose per scan report. And
//! `listen --live`: the same maps and poses from the live view's WebSocket server, as a
//! Foxglove client sees them.

use std::process::Command;

use base64::Engine;
use host_sim::listen::{Listener, Notice};
use ogm_core::wire::{DeviceMsg, Layer, ScanReport, Tile, WirePose};

mod stream_fixture;
use stream_fixture::{frame, half_free_tile, hello_and_config, EDGE, W};

/// The fixture's session: settings, then two scan reports at `POSES`, each followed by the
/// half-free log-odds tile at (1, 0); split after each tile.
fn session_parts() -> Vec<Vec<u8>> {
    let mut parts = Vec::new();
    let mut s = hello_and_config();
    // Tile (1, 0): free on its left half, occupied on its right half; the rest never observed.
    let lo = half_free_tile();
    for (seq, &(x_mm, y_mm, heading)) in POSES.iter().enumerate() {
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
        parts.push(std::mem::take(&mut s));
    }
    parts
}

fn session() -> Vec<u8> {
    session_parts().concat()
}

/// The robot's pose at each scan report (mm, mm, heading in 2^16 per turn).
const POSES: [(i32, i32, u16); 2] = [(250, -120, 0), (400, 80, 16_384)];

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
        ]
    );
    let mut grids = 0;
    let mut seen_poses = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        match m.channel.topic.as_str() {
            "/robot/pose" => seen_poses.push(pose_of(&v)),
            topic => {
                grids += 1;
                check_grid(&v, topic);
            }
        }
    }
    // The final save writes both layers once (the map did not exist when recording began).
    assert_eq!(grids, 2);
    check_poses(&seen_poses);
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
        host_sim::live::SUBPROTOCOL.parse().unwrap(),
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
    let count = |got: &[Received], grid: bool| {
        got.iter()
            .filter(|(t, _)| (t != "/robot/pose") == grid)
            .count()
    };
    // The subscriptions are answered with each channel's latest message: both maps and the
    // first scan's pose (published before the client subscribed)...
    let first = read_until(&|g| count(g, true) == 2 && count(g, false) == 1);
    // ...and the next scan's pose comes as it arrives.
    let notices = l.push(&parts[1]);
    assert!(notices.iter().all(|n| !matches!(n, Notice::Warning(_))));
    let next = read_until(&|g| count(g, false) == 1);
    let grids: Vec<Received> = first
        .iter()
        .filter(|(t, _)| t != "/robot/pose")
        .cloned()
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
    assert_eq!(l.live().map(|s| s.connections()), Some(1));
}
