//! The firmware's application (`ogm_firmware::App`, the library every board binary runs) on
//! the host: its protocol behaviour without QEMU — settings, errors and their documented
//! details, and a run whose stream rebuilds exactly the engine's map.

use host_sim::firmware::input::scan_packets;
use host_sim::firmware::HostMemory;
use ogm_core::config::{Budget, RunConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{self, ConfigFault, ErrorCode, HostMsg, LinkFault, TileSource};
use ogm_core::{Angle, Beam, Pose, Range};
use ogm_field::stream::{host_frame, DeviceEvent, StreamDecoder, StreamedMap};
use ogm_firmware::sizes::MPS2_AN386 as FW;
use ogm_firmware::{Fed, Platform, Work};

/// No clock; a fixed number of sampler updates per scan and idle period.
struct Fixed(u32);

impl Platform for Fixed {
    const NAME: &'static str = "test";
    const TICK_HZ: u32 = 1_000_000;

    fn now(&self) -> u32 {
        0
    }

    fn fixed_updates(&mut self, _: Work) -> Option<u32> {
        Some(self.0)
    }
}

/// Feeds `input` to a fresh application (sizes: `sizes`); returns what it streamed (decoded),
/// the last [`Fed`], and `inspect`'s view of the final engine.
fn run<R>(
    sizes: Sizes,
    input: &[u8],
    inspect: impl FnOnce(Option<&Session<Owned<u8>>>) -> R,
) -> (Vec<DeviceEvent>, Fed, R) {
    let mut mem = HostMemory::<u8>::new();
    let mut app = mem.app(&sizes);
    let (mut out, mut platform) = (Vec::new(), Fixed(200));
    app.hello(&mut out, &platform);
    let fed = app.feed(input, &mut out, &mut platform);
    let r = inspect(app.session());
    let mut d = StreamDecoder::new();
    let events = d
        .push(&out)
        .into_iter()
        .collect::<Result<Vec<_>, _>>()
        .expect("the application's stream decodes");
    (events, fed, r)
}

fn errors(events: &[DeviceEvent]) -> Vec<(ErrorCode, u32)> {
    events
        .iter()
        .filter_map(|e| match e {
            DeviceEvent::Error(e) => Some((e.code, e.detail)),
            _ => None,
        })
        .collect()
}

fn config() -> RunConfig {
    RunConfig::ROBOT
        .with_origin_mm(-6400, -6400)
        .with_max_range_mm(8000)
        .with_seed(7)
        .with_budget(Budget::Fixed { updates: 200 })
}

/// A scan of a 4 m square room seen from `pose`: 360 beams, as LD06 packets in frames.
fn scan_input(seq: u32, pose: Pose, ts: &mut u16) -> Vec<u8> {
    let beams: Vec<Beam> = (0..360u32)
        .map(|d| {
            let angle = Angle::from_centidegrees(100 * d);
            let t = f64::from(d).to_radians()
                + f64::from(pose.heading.0) / 65536.0 * std::f64::consts::TAU;
            let (c, s) = (t.cos(), t.sin());
            let wall = |p: i32, dir: f64| {
                if dir.abs() < 1e-9 {
                    f64::INFINITY
                } else {
                    ((if dir > 0.0 { 2000.0 } else { -2000.0 }) - f64::from(p)) / dir
                }
            };
            let r = wall(pose.x_mm, c).min(wall(pose.y_mm, s));
            Beam {
                angle,
                range: Range::Hit(r as u32),
            }
        })
        .collect();
    let mut v = host_frame(&HostMsg::ScanStart { seq, pose });
    v.extend(scan_packets(&beams, ts).expect("360 beams"));
    v.extend(host_frame(&HostMsg::ScanEnd { seq, points: 360 }));
    v
}

#[test]
fn a_scan_before_the_settings_is_reported_not_mapped() {
    let mut ts = 0;
    let input = scan_input(0, Pose::default(), &mut ts);
    let (events, fed, session) = run(Sizes::default(), &input, |s| s.is_some());
    assert!(!session);
    assert_eq!(fed, Fed::Scan(0));
    assert_eq!(errors(&events), vec![(ErrorCode::NoConfig, 0)]);
    assert!(!events.iter().any(|e| matches!(e, DeviceEvent::Scan(_))));
}

#[test]
fn rejected_settings_name_the_part_that_rejected_them() {
    let bad = RunConfig {
        cell_mm: 0,
        ..config()
    };
    let (events, _, session) = run(Sizes::default(), &host_frame(&HostMsg::Config(bad)), |s| {
        s.is_some()
    });
    assert!(!session);
    let e = errors(&events);
    assert_eq!(
        e,
        vec![(ErrorCode::BadConfig, ConfigFault::Geometry.detail())]
    );
    assert_eq!(
        ConfigFault::from_detail(e[0].1),
        Some(ConfigFault::Geometry)
    );
    // A grid other than the one the tile stream is cut for.
    let small = Sizes {
        width: 64,
        height: 64,
        ..Sizes::default()
    };
    let (events, _, _) = run(small, &host_frame(&HostMsg::Config(config())), |_| ());
    assert_eq!(
        errors(&events),
        vec![(ErrorCode::BadConfig, ConfigFault::Geometry.detail())]
    );
}

#[test]
fn repeated_settings_are_ignored_and_different_ones_refused() {
    let mut input = host_frame(&HostMsg::Config(config()));
    input.extend(host_frame(&HostMsg::Config(config())));
    let (events, _, _) = run(Sizes::default(), &input, |_| ());
    assert!(errors(&events).is_empty());
    assert_eq!(
        events
            .iter()
            .filter(|e| matches!(e, DeviceEvent::Configured(_)))
            .count(),
        1
    );
    input.extend(host_frame(&HostMsg::Config(RunConfig {
        seed: 8,
        ..config()
    })));
    let (events, _, _) = run(Sizes::default(), &input, |_| ());
    assert_eq!(errors(&events), vec![(ErrorCode::ConfigTwice, 0)]);
}

#[test]
fn a_broken_host_frame_is_a_documented_link_fault() {
    let mut frame = host_frame(&HostMsg::Config(config()));
    let mid = frame.len() / 2;
    frame[mid] ^= 0x5a;
    let (events, _, _) = run(Sizes::default(), &frame, |_| ());
    let e = errors(&events);
    assert_eq!(e, vec![(ErrorCode::Link, LinkFault::Frame.detail())]);
    assert_eq!(LinkFault::from_detail(e[0].1), Some(LinkFault::Frame));
    assert_eq!(LinkFault::from_detail(99), None);
}

#[test]
fn a_run_streams_exactly_the_engine_map() {
    let mut input = host_frame(&HostMsg::Config(config()));
    let mut ts = 0;
    let poses = [
        Pose::default(),
        Pose {
            x_mm: 600,
            y_mm: -400,
            heading: Angle(9000),
        },
        Pose {
            x_mm: -700,
            y_mm: 500,
            heading: Angle(40000),
        },
    ];
    for (k, p) in poses.iter().enumerate() {
        input.extend(scan_input(k as u32, *p, &mut ts));
    }
    input.extend(host_frame(&HostMsg::Finish));
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    let (events, fed, engine) = run(Sizes::default(), &input, |s| {
        let s = s.expect("configured");
        (
            s.log_odds().iter().map(|l| l.raw()).collect::<Vec<_>>(),
            (0..w * h).map(|i| s.count(i)).collect::<Vec<_>>(),
            (0..w * h).map(|i| s.occupied(i)).collect::<Vec<_>>(),
            wire::grid_fnv(s.log_odds()),
        )
    });
    assert_eq!(fed, Fed::Finished(0));
    assert!(errors(&events).is_empty(), "{:?}", errors(&events));
    let reports: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            DeviceEvent::Scan(r) => Some(*r),
            _ => None,
        })
        .collect();
    assert_eq!(reports.len(), 3);
    assert!(reports
        .iter()
        .all(|r| r.beams == 360 && r.sampler_updates == 200 && r.mapper.cells_hit > 0));
    let mut map = StreamedMap::new(w, h, usize::from(FW.tile_edge));
    for e in &events {
        if let DeviceEvent::Tile(t) = e {
            map.apply(t).expect("a valid tile");
        }
    }
    let (lo, counts, sample, fnv) = engine;
    assert!(lo.iter().any(|&v| v > 0), "walls were mapped");
    assert_eq!(map.log_odds, lo);
    assert_eq!(map.counts, counts);
    assert_eq!(map.sample, sample);
    let done = events.iter().find_map(|e| match e {
        DeviceEvent::Done(d) => Some(*d),
        _ => None,
    });
    assert_eq!(done.map(|d| (d.scans, d.grid_fnv)), Some((3, fnv)));
}

/// The 360 beams of [`scan_input`]'s room from `pose`, as bare LD06 packets (the lidar's UART).
fn room_packets(pose: Pose, ts: &mut u16) -> Vec<u8> {
    let framed = scan_input(0, pose, ts);
    let start = host_frame(&HostMsg::ScanStart { seq: 0, pose }).len();
    let end = host_frame(&HostMsg::ScanEnd {
        seq: 0,
        points: 360,
    })
    .len();
    framed[start..framed.len() - end].to_vec()
}

/// Feeds link bytes and lidar bytes to one application, up to `chunk` bytes of each in turn,
/// each only while the application wants it (as the firmware's main loop reads its UARTs);
/// returns the decoded stream and the final log-odds map.
fn run_robot(link_in: &[u8], lidar_in: &[u8], chunk: usize) -> (Vec<DeviceEvent>, Vec<i16>) {
    let mut mem = HostMemory::<u8>::new();
    let mut app = mem.app(&Sizes::default());
    let (mut out, mut platform) = (Vec::new(), Fixed(200));
    app.hello(&mut out, &platform);
    let (mut l, mut r) = (link_in, lidar_in);
    while !l.is_empty() || !r.is_empty() {
        let mut moved = false;
        if app.wants_lidar() && !r.is_empty() {
            let (now, rest) = r.split_at(chunk.min(r.len()));
            app.feed_lidar(now, &mut out, &mut platform);
            (r, moved) = (rest, true);
        }
        // The link waits for the lidar only while the lidar has bytes left (the firmware's
        // silent-lidar timeout).
        if (app.wants_link() || r.is_empty()) && !l.is_empty() {
            let (now, rest) = l.split_at(chunk.min(l.len()));
            app.feed(now, &mut out, &mut platform);
            (l, moved) = (rest, true);
        }
        if !moved {
            break; // the lidar's bytes are refused (no settings): the rest stays unread
        }
    }
    let lo = app
        .session()
        .map(|s| s.log_odds().iter().map(|l| l.raw()).collect())
        .unwrap_or_default();
    let events = StreamDecoder::new()
        .push(&out)
        .into_iter()
        .collect::<Result<Vec<_>, _>>()
        .expect("the application's stream decodes");
    (events, lo)
}

fn scan_reports(events: &[DeviceEvent]) -> Vec<wire::ScanReport> {
    events
        .iter()
        .filter_map(|e| match e {
            DeviceEvent::Scan(r) => Some(*r),
            _ => None,
        })
        .collect()
}

#[test]
fn a_standing_robot_maps_its_lidar_uart_like_tunnelled_scans() {
    let at = Pose {
        x_mm: 300,
        y_mm: -200,
        heading: Angle(5000),
    };
    // Tunnelled: two scans with their pose.
    let mut ts = 0;
    let mut tunnelled = host_frame(&HostMsg::Config(config()));
    tunnelled.extend(scan_input(0, at, &mut ts));
    tunnelled.extend(scan_input(1, at, &mut ts));
    let (ev_a, lo_a) = run_robot(&tunnelled, &[], 64);
    // The robot loop: the same packets on the lidar's UART (plus a third turn, whose first
    // packet closes the second), poses on the link every 30 ms that never move.
    let mut ts = 0;
    let lidar: Vec<u8> = (0..3).flat_map(|_| room_packets(at, &mut ts)).collect();
    let mut link = host_frame(&HostMsg::Config(config()));
    for k in 0..12u64 {
        link.extend(host_frame(&HostMsg::Pose {
            t_us: k * 30_000,
            pose: at,
        }));
    }
    for chunk in [1, 7, 47, 500] {
        let (ev_b, lo_b) = run_robot(&link, &lidar, chunk);
        assert!(errors(&ev_b).is_empty(), "{:?}", errors(&ev_b));
        let reports = scan_reports(&ev_b);
        // Turns 0 and 1 are closed (turn 2's last packet waits for its pose at 300 ms).
        assert!(reports.len() >= 2, "chunk {chunk}: {reports:?}");
        assert_eq!(reports[0].pose, at);
        assert_eq!((reports[0].t_us, reports[1].t_us), (0, 100_000));
        assert_eq!(scan_reports(&ev_a)[1].beams, reports[1].beams);
        // The first two turns are the tunnelled scans, bit for bit; the third adds to them.
        if reports.len() == 2 {
            assert_eq!(lo_a, lo_b, "chunk {chunk}");
        }
    }
    // Nothing but the stored settings (standing sensor at the origin): it maps.
    let stored = ogm_firmware::app::STORED_CONFIG;
    let link = host_frame(&HostMsg::Config(stored));
    let (ev, lo) = run_robot(&link, &lidar, 47);
    assert_eq!(scan_reports(&ev).len(), 2, "{:?}", errors(&ev));
    assert!(lo.iter().any(|&v| v > 0));
    let counters = ev.iter().rev().find_map(|e| match e {
        DeviceEvent::Counters(c) => Some(*c),
        _ => None,
    });
    // As of the second turn's report: its closing packet was the 61st.
    let c = counters.expect("counters").lidar;
    assert_eq!((c.packets, c.turns, c.poses, c.bad_packets), (61, 2, 0, 0));
}

#[test]
fn the_stored_settings_are_the_robot_settings() {
    use ogm_firmware::app::STORED_CONFIG;
    let robot = RunConfig::ROBOT
        .with_origin_mm(STORED_CONFIG.origin_x_mm, STORED_CONFIG.origin_y_mm)
        .with_max_range_mm(STORED_CONFIG.max_range_mm)
        .with_seed(STORED_CONFIG.seed)
        .with_budget(STORED_CONFIG.budget)
        .with_noise_matched(3.0);
    assert_eq!(
        STORED_CONFIG,
        RunConfig {
            poses: ogm_core::config::PoseInput::Fixed,
            ..robot
        }
    );
    // Centred on the start.
    let g = STORED_CONFIG.geometry(FW.width, FW.height).unwrap();
    assert_eq!(g.cell_of_point(0, 0).x, i32::from(FW.width) / 2);
}

#[test]
fn a_moving_robot_places_each_turn_at_the_interpolated_pose() {
    // Driving +x at 0.5 m/s, turning 30°/s; poses every 40 ms; packets every 100/30 ms.
    let truth = |t_us: u64| {
        let t = t_us as f64 / 1e6;
        Pose {
            x_mm: (500.0 * t) as i32,
            y_mm: 0,
            heading: Angle::from_degrees(30.0 * t),
        }
    };
    let mount = ogm_core::Pose {
        x_mm: 80,
        y_mm: 0,
        heading: ogm_core::Angle(0),
    };
    let cfg = RunConfig { mount, ..config() };
    let mut lidar = Vec::new();
    let mut ts = 0u16;
    for _ in 0..4 {
        lidar.extend(room_packets(Pose::default(), &mut ts));
    }
    let mut link = host_frame(&HostMsg::Config(cfg));
    for k in 0..12u64 {
        link.extend(host_frame(&HostMsg::Pose {
            t_us: k * 40_000,
            pose: truth(k * 40_000),
        }));
    }
    let (ev, _) = run_robot(&link, &lidar, 47);
    assert!(errors(&ev).is_empty(), "{:?}", errors(&ev));
    let reports = scan_reports(&ev);
    assert!(reports.len() >= 3, "{reports:?}");
    let m = ogm_core::lidar::pose_track::Mount {
        x_mm: 80,
        y_mm: 0,
        yaw: Angle(0),
    };
    for r in &reports {
        // Linear interpolation of a straight line: exact to the mm; heading within 2 units.
        // (`odometry`: the pose the turn came with; `pose` is where the scan matcher put it.)
        let want = m.sensor_pose(&truth(r.t_us));
        let got = r.odometry;
        assert!((got.x_mm - want.x_mm).abs() <= 1, "{got:?} {want:?}");
        assert!((got.y_mm - want.y_mm).abs() <= 1, "{got:?} {want:?}");
        assert!(
            got.heading.signed_diff(want.heading).abs() <= 2,
            "{got:?} {want:?}"
        );
    }
}
