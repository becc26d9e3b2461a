//! The bad-input policy (README, "Bad input policy") for ogm-core's interfaces: one test per row
//! of the table, named in it. LD06 packets, host frames, poses, ranges and settings: each bad
//! input is dropped and counted, clamped, or rejected with an error — never a panic.

use ogm_core::config::{Budget, RunConfig};
use ogm_core::lidar::ld06::{encode_scan, Ld06Parser, Packet, Point, PACKET_LEN, POINTS};
use ogm_core::lidar::link::{LinkError, LinkRx, Step};
use ogm_core::map::mapper::marks_len;
use ogm_core::sampler::gibbs::{block_words, BorderPrior, Buffers, Gibbs, LocalRay, SamplerConfig};
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{self, HostMsg, LinkCounters, MAX_HOST_FRAME};
use ogm_core::{Angle, Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose};
use ogm_core::{Range, ScanBuf};

fn frame(m: &HostMsg) -> Vec<u8> {
    let mut buf = [0u8; MAX_HOST_FRAME];
    let mut v = vec![0u8];
    v.extend_from_slice(wire::encode(m, &mut buf).unwrap());
    v
}

fn packet(start_cdeg: u16, end_cdeg: u16, distance_mm: u16) -> [u8; PACKET_LEN] {
    Packet {
        speed_dps: 3600,
        start_cdeg,
        end_cdeg,
        timestamp_ms: 0,
        points: [Point {
            distance_mm,
            intensity: 200,
        }; POINTS],
    }
    .to_bytes()
}

/// What a `LinkRx` delivered: scans (pose, beams, overflow), errors, counters.
type Delivered = (Vec<(Pose, Vec<Beam>, u32)>, Vec<LinkError>, LinkCounters);

/// Feeds `bytes` to a `LinkRx` with an `N`-beam scan buffer.
fn link<const N: usize>(bytes: &[u8]) -> Delivered {
    let mut rx = LinkRx::new();
    let mut buf: ScanBuf<N> = ScanBuf::new();
    let (mut scans, mut errors) = (Vec::new(), Vec::new());
    for c in bytes.chunks(5) {
        rx.feed(c, &mut buf, |s| match s {
            Step::Scan {
                pose,
                beams,
                overflow,
                ..
            } => scans.push((pose, beams.to_vec(), overflow)),
            Step::Error(e) => errors.push(e),
            Step::Host(_) => {}
        });
    }
    rx.finish(|s| {
        if let Step::Error(e) = s {
            errors.push(e)
        }
    });
    (scans, errors, rx.counters())
}

fn scan_around(pkts: &[[u8; PACKET_LEN]]) -> Vec<u8> {
    let mut v = frame(&HostMsg::ScanStart {
        seq: 0,
        pose: Pose::default(),
    });
    for p in pkts {
        v.extend_from_slice(p);
    }
    v.extend(frame(&HostMsg::ScanEnd {
        seq: 0,
        points: (pkts.len() * POINTS) as u32,
    }));
    v
}

#[test]
fn ld06_truncated_packet_is_dropped_and_counted() {
    let good = packet(0, 3300, 1000);
    // A good packet, one cut after 20 bytes, another good one: only the cut one is lost.
    let mut v = frame(&HostMsg::ScanStart {
        seq: 0,
        pose: Pose::default(),
    });
    v.extend_from_slice(&good);
    v.extend_from_slice(&good[..20]);
    v.extend_from_slice(&packet(3600, 6900, 1200));
    v.extend(frame(&HostMsg::ScanEnd { seq: 0, points: 36 }));
    let (scans, errors, c) = link::<64>(&v);
    assert_eq!(c.ld06_truncated, 1);
    assert_eq!(c.ld06_packets, 2);
    assert_eq!(c.points_lost, 12);
    assert_eq!(scans.len(), 1);
    assert_eq!(scans[0].1.len(), 24);
    assert!(errors.contains(&LinkError::PointsLost { seq: 0, lost: 12 }));
    // The parser on its own: the cut packet is reported when the stream ends.
    let mut p = Ld06Parser::new();
    p.feed(&good[..20], |_| {});
    assert!(p.finish().is_some());
    assert_eq!(p.counters().truncated, 1);
}

#[test]
fn ld06_corrupted_packet_is_dropped_and_counted() {
    let mut bad = packet(0, 3300, 1000);
    bad[17] ^= 0x10;
    let v = scan_around(&[bad, packet(3600, 6900, 1500)]);
    let (scans, _, c) = link::<64>(&v);
    assert_eq!(c.ld06_crc_errors, 1);
    assert_eq!((c.ld06_packets, c.points_lost), (1, 12));
    assert!(scans[0].1.iter().all(|b| b.range == Range::Hit(1500)));
    // A bad second header byte: counted as a bad header.
    let mut hdr = packet(0, 3300, 1000);
    hdr[1] = 0x2D;
    let (_, _, c) = link::<64>(&scan_around(&[hdr]));
    assert_eq!(c.ld06_bad_headers, 1);
}

#[test]
fn ld06_zero_distance_is_no_return() {
    let v = scan_around(&[packet(0, 3300, 0)]);
    let (scans, _, _) = link::<64>(&v);
    assert_eq!(scans[0].1.len(), 12);
    assert!(scans[0].1.iter().all(|b| b.range == Range::NoReturn));
    // … which frees cells up to the maximum range and marks nothing occupied.
    let (mut m, _) = mapper(0);
    let s = m.insert_scan(&centre(), &scans[0].1).unwrap();
    assert_eq!(s.cells_hit, 0);
    assert!(s.cells_freed > 0);
}

#[test]
fn ld06_out_of_range_angles_wrap() {
    // Angles ≥ 360.00° (up to 655.35°) are taken modulo 360°; an end before the start wraps.
    let p = Packet::parse(&packet(65_535, 40_000, 900)).unwrap();
    for i in 0..POINTS {
        assert!(p.angle_cdeg(i) < 36_000);
        assert!(p.beam(i).is_some());
    }
    assert_eq!(p.angle_cdeg(0), 65_535 % 36_000);
    assert!(p.beam(POINTS).is_none());
}

#[test]
fn range_beyond_max_range_frees_only() {
    let (mut m, g) = mapper(0);
    let beams: Vec<Beam> = (0..36)
        .map(|i| Beam {
            angle: Angle::from_centidegrees(i * 1000),
            range: Range::Hit(u32::MAX),
        })
        .collect();
    let s = m.insert_scan(&centre(), &beams).unwrap();
    assert_eq!((s.cells_hit, s.beams_used), (0, 36));
    let occupied = m.grid().cells().iter().filter(|l| l.0 > 0).count();
    assert_eq!(occupied, 0, "{g:?}");
}

#[test]
fn range_below_min_range_is_dropped_and_counted() {
    let (mut m, _) = mapper(200);
    let beams = [
        Beam {
            angle: Angle(0),
            range: Range::Hit(0),
        },
        Beam {
            angle: Angle(100),
            range: Range::Hit(199),
        },
        Beam {
            angle: Angle(200),
            range: Range::Hit(1000),
        },
    ];
    let s = m.insert_scan(&centre(), &beams).unwrap();
    assert_eq!((s.beams_dropped, s.beams_used, s.cells_hit), (2, 1, 1));
}

#[test]
fn oversized_scan_is_cut_and_counted() {
    // 5 packets (60 points) into a 32-beam buffer: 28 beams dropped and reported.
    let pkts: Vec<[u8; PACKET_LEN]> = (0..5)
        .map(|k| packet(k * 3000, k * 3000 + 2750, 800))
        .collect();
    let (scans, _, c) = link::<32>(&scan_around(&pkts));
    assert_eq!(scans.len(), 1);
    assert_eq!((scans[0].1.len(), scans[0].2), (32, 28));
    assert_eq!(c.points_lost, 0);
}

#[test]
fn bad_frames_are_dropped_and_counted() {
    let start = frame(&HostMsg::ScanStart {
        seq: 7,
        pose: Pose {
            x_mm: 10,
            y_mm: 20,
            heading: ogm_core::Angle(30),
        },
    });
    // Truncated: the frame's second half is missing (the next frame's 0x00 ends it).
    let mut v = start[..start.len() / 2].to_vec();
    // Corrupted: one byte flipped (CRC-32).
    let mut bad = start.clone();
    bad[4] ^= 0x01;
    v.extend(bad);
    // Another schema version (valid COBS and CRC).
    v.extend(cobs_frame(&[wire::VERSION + 1, 3])); // `Finish` is variant 3

    // A valid CRC over bytes that are no message (postcard fails): an unknown variant.
    v.extend(cobs_frame(&[wire::VERSION, 0x7F, 1, 2, 3]));
    // Oversized: no frame end within MAX_HOST_FRAME bytes.
    v.push(0);
    v.extend(std::iter::repeat_n(0x41, MAX_HOST_FRAME + 10));
    // And a good frame after all that is still found.
    v.extend(&start);
    let mut rx = LinkRx::new();
    let mut buf: ScanBuf<8> = ScanBuf::new();
    rx.feed(&v, &mut buf, |_| {});
    let c = rx.counters();
    assert_eq!(c.frames_bad_version, 1);
    assert!(c.frame_errors >= 3, "{c:?}"); // truncated, CRC, undecodable
    assert!(c.frames_too_long >= 1, "{c:?}");
    assert_eq!(c.frames, 1);
    assert_eq!(rx.open_scan().map(|(s, _)| s), Some(7));
}

/// `0x00 ‖ COBS(raw ‖ CRC-32) ‖ 0x00`, i.e. a host frame around arbitrary bytes.
fn cobs_frame(raw: &[u8]) -> Vec<u8> {
    let mut body = raw.to_vec();
    body.extend(wire::CRC32.checksum(raw).to_le_bytes());
    let mut out = vec![0u8];
    let (mut code_at, mut code) = (out.len(), 1u8);
    out.push(0);
    for &b in &body {
        if b == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(b);
            code += 1;
        }
    }
    out[code_at] = code;
    out.push(0);
    out
}

#[test]
fn scan_framing_errors_are_counted() {
    let p = packet(0, 3300, 1000);
    let mut v = p.to_vec(); // points outside a scan
    v.extend(frame(&HostMsg::ScanStart {
        seq: 1,
        pose: Pose::default(),
    }));
    v.extend(frame(&HostMsg::ScanEnd { seq: 2, points: 12 })); // wrong seq
    let (scans, errors, c) = link::<64>(&v);
    assert!(scans.is_empty());
    assert_eq!((c.points_outside_scan, c.scan_seq_errors), (12, 1));
    assert!(errors.contains(&LinkError::PointsOutsideScan));
}

fn centre() -> Pose {
    Pose {
        x_mm: 3200,
        y_mm: 3200,
        heading: Angle(0),
    }
}

fn mapper(min_range_mm: u32) -> (Mapper<Vec<LogOdds>, Vec<u32>>, GridGeometry) {
    let g = GridGeometry::new(64, 64, 100, 0, 0).unwrap();
    let grid = LogOddsGrid::new(g, vec![LogOdds::ZERO; g.len()]).unwrap();
    let cfg = MapperConfig {
        min_range_mm,
        ..MapperConfig::new(5000)
    };
    (
        Mapper::new(grid, vec![0; marks_len(g.len())], cfg).unwrap(),
        g,
    )
}

#[test]
fn pose_outside_the_map_is_clipped() {
    let cfg = RunConfig::PAPER
        .with_max_range_mm(12_000)
        .with_budget(Budget::Fixed { updates: 50 });
    let sizes = Sizes {
        width: 64,
        height: 64,
        rays: 256,
        scans: 4,
        local: 32,
    };
    let mut session = Session::new(cfg, Owned::<u8>::buffers(&sizes)).unwrap();
    let cells = session.log_odds().len();
    let beams: Vec<Beam> = (0..360u32)
        .map(|i| Beam {
            angle: Angle::from_centidegrees(i * 100),
            range: if i % 3 == 0 {
                Range::NoReturn
            } else {
                Range::Hit(i * 97)
            },
        })
        .collect();
    // Just outside (rays cross the map), far away, and at the i32 extremes: no panic, no
    // overflow, and nothing outside the clamp.
    for (x, y) in [
        (-500, 1600),
        (1600, 3300),
        (-1_000_000, -1_000_000),
        (i32::MAX, i32::MIN),
        (i32::MIN, i32::MAX),
        (i32::MAX, i32::MAX),
    ] {
        let pose = Pose {
            x_mm: x,
            y_mm: y,
            heading: Angle(12_345),
        };
        let s = session.insert(&pose, &beams).unwrap().stats;
        assert!(s.cells_hit + s.cells_freed <= cells as u32);
        session.step(50);
    }
    let clamp = cfg.mapper_config().unwrap().clamp;
    assert!(
        session.log_odds().iter().any(|l| l.0 != 0),
        "rays from just outside reach in"
    );
    assert!(session
        .log_odds()
        .iter()
        .all(|l| *l >= clamp.min() && *l <= clamp.max()));
}

#[test]
fn bad_settings_are_rejected_with_an_error() {
    let good = RunConfig::PAPER
        .with_max_range_mm(12_000)
        .with_budget(Budget::Fixed { updates: 50 });
    assert!(good.geometry(256, 256).is_ok() && good.forward_model().is_ok());
    // Zero cell size: no geometry.
    let c = RunConfig { cell_mm: 0, ..good };
    assert!(c.geometry(256, 256).is_err());
    // σ = 0, outliers ≥ 100 %, range shorter than a cell: no forward model.
    for c in [
        RunConfig {
            sigma_milli_cells: 0,
            ..good
        },
        RunConfig {
            outlier_ppm: 1_000_000,
            ..good
        },
        RunConfig {
            max_range_mm: 10,
            ..good
        },
    ] {
        assert!(c.forward_model().is_err(), "{c:?}");
    }
    // No candidates or an impossible tile size: no sampler.
    let g = good.geometry(64, 64).unwrap();
    for sc in [
        SamplerConfig {
            max_candidates: 0,
            ..good.sampler_config()
        },
        SamplerConfig {
            tile_shift: 0,
            ..good.sampler_config()
        },
        SamplerConfig {
            p_rand_patch: f32::NAN,
            ..good.sampler_config()
        },
    ] {
        let r = Gibbs::new(
            g,
            BorderPrior::default(),
            good.forward_model().unwrap(),
            sc,
            Buffers {
                sample: vec![0u32; g.len().div_ceil(32)],
                counts: vec![0u8; g.len()],
                local: vec![LocalRay::default(); 32],
                blocks: vec![0u32; block_words(32, 8)],
            },
        );
        assert!(r.is_err(), "{sc:?}");
    }
}

#[test]
fn nan_and_infinite_model_parameters_are_rejected() {
    use ogm_core::sampler::forward_model::ForwardModel;
    for (s, w, r) in [
        (f64::NAN, 0.01, 100.0),
        (3.0, f64::NAN, 100.0),
        (3.0, 0.01, f64::INFINITY),
        (f64::INFINITY, 0.01, 100.0),
        (-1.0, 0.01, 100.0),
    ] {
        assert!(ForwardModel::gaussian(s, w, r).is_err(), "{s} {w} {r}");
    }
    // Angles from non-finite radians are 0, not a panic or a garbage value.
    assert_eq!(Angle::from_radians(f64::NAN), Angle(0));
    assert_eq!(Angle::from_radians(f64::NEG_INFINITY), Angle(0));
    // And the LD06 encoder rejects what it cannot encode instead of truncating silently.
    let beams = [Beam {
        angle: Angle(0),
        range: Range::Hit(1),
    }; 5];
    assert!(encode_scan(&beams, 3600, 0, 3, |_| {}).is_err());
}
