//! The firmware's application (`ogm_firmware::App`, the library every board binary runs) on
//! the host: its protocol behaviour without QEMU — settings, errors and their documented
//! details, and a run whose stream rebuilds exactly the engine's map.

use host_sim::firmware::HostMemory;
use host_sim::link::{host_frame, scan_packets, DeviceEvent, StreamDecoder, StreamedMap};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{
    self, firmware_sizes as fw, Budget, ConfigFault, ErrorCode, HostMsg, LinkFault, RunConfig,
    TileSource,
};
use ogm_core::{Angle, Beam, Pose, Range};
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
    RunConfig::robot((-6400, -6400), 8000, 7, Budget::Fixed { updates: 200 })
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
    let mut v = host_frame(&HostMsg::ScanStart {
        seq,
        pose: pose.into(),
    });
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
    let (w, h) = (usize::from(fw::WIDTH), usize::from(fw::HEIGHT));
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
        .all(|r| r.beams == 360 && r.sampler_updates == 200 && r.cells_hit > 0));
    let mut map = StreamedMap::new(w, h, usize::from(fw::TILE_EDGE));
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
