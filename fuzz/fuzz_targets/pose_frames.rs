//! Pose frames and scans end to end, as the robot sees them: an input-chosen sequence of host
//! frames (`Config` with any field values, `ScanStart` with any pose — far outside the map
//! included —, `ScanEnd`, `Finish`), LD06 packets (any distance, zero = no return, more than a
//! scan buffer holds), raw bytes and flipped bits, through `ogm_core::lidar::link::LinkRx` into the
//! firmware's engine, `ogm_core::session::Session`: `insert` (mapper, seeding, ray store, cache
//! refresh), sampler steps, and the box of changed cells the firmware's `mark_dirty` takes
//! (`Inserted::changed_box`), with pose correction on or off (the session's scan matcher against
//! its own map, `Session::correct` before the insert or inside it). A 64 × 64 grid and small buffers keep
//! an input fast. Invariants: nothing panics; log-odds stay within the clamp; the sampler's
//! counts never exceed its samples. The same bytes also go through the robot loop's lidar
//! path (`ogm_core::lidar::ld06::Ld06Parser` → `ogm_core::lidar::turn::Turns`, placed by the `Pose` frames
//! among them, with any mounting) into the engine. `Restore` parts (any tile, layer, row and
//! length, and whole tiles) go through `Session::restore_part`: every refusal is counted.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use ogm_core::config::{Budget, LidarModel, OdometryNoise, PoseCorrection, PoseInput, RunConfig};
use ogm_core::config::{DataTerm, Estimator};
use ogm_core::lidar::ld06::Ld06Parser;
use ogm_core::lidar::ld06::{Packet, Point, POINTS};
use ogm_core::lidar::link::{LinkRx, Step};
use ogm_core::lidar::pose_track::Mount;
use ogm_core::lidar::turn::{Taken, Turn, Turns};
use ogm_core::session::TileRestore;
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::{self, HostMsg, Layer, MAX_HOST_FRAME};
use ogm_core::ScanBuf;

const W: u16 = 64;
const H: u16 = 64;
const MAX_BEAMS: usize = 96;

#[derive(Arbitrary, Debug)]
enum Item {
    Config {
        origin_x_mm: i32,
        origin_y_mm: i32,
        cell_mm: u32,
        max_range_mm: u32,
        min_range_mm: u32,
        seed: u64,
        sigma_milli_cells: u32,
        outlier_ppm: u32,
        p_rand_patch_ppm: u32,
        burn_in_sweeps: u32,
        max_candidates: u8,
        sampler_tile_shift: u8,
        visit_sweeps: u8,
        updates: u8,
        data: u8,
        evidence_gain_q8: u16,
        evidence_free_q8: u16,
        free_update_q8: u16,
        data_candidate: bool,
        shift: u8,
        reset_on_change: bool,
        rao_blackwell: bool,
        hot_share: u8,
        mount_x_mm: i32,
        mount_y_mm: i32,
        mount_yaw: u16,
        fixed_poses: bool,
        /// `Some`: an RPLIDAR with this sample period (0 is refused), else an LD06.
        rplidar_sample_us: Option<u16>,
        face_band: bool,
        window_margin_cells: u16,
        /// Pose correction: the session's scan matcher on every scan.
        correction: bool,
        window_hold: bool,
        /// The robot's odometry noise (the pose filter's process noise), any values.
        odometry: (u16, u16, u16),
    },
    PaperConfig {
        origin_x_mm: i16,
        origin_y_mm: i16,
        max_range_mm: u16,
        updates: u8,
    },
    Start {
        seq: u8,
        x_mm: i32,
        y_mm: i32,
        heading: u16,
    },
    NearStart {
        seq: u8,
        x_mm: i16,
        y_mm: i16,
        heading: u16,
    },
    End {
        seq: u8,
        points: u32,
    },
    Finish,
    /// `Resume`: the held turn (every third, below) is mapped.
    Resume,
    Pose {
        t_us: u64,
        x_mm: i32,
        y_mm: i32,
        heading: u16,
    },
    Packet {
        speed_dps: u16,
        start_cdeg: u16,
        end_cdeg: u16,
        timestamp_ms: u16,
        distance_mm: [u16; POINTS],
    },
    Packets {
        count: u8,
        distance_mm: u16,
    },
    /// One `Restore` part: any tile, layer, row and length.
    Restore {
        tx: i8,
        ty: i8,
        layer: u8,
        row: u8,
        len: u8,
        fill: u8,
    },
    /// A whole tile's 12 `Restore` parts (16-cell tiles), log-odds `value` in every cell.
    RestoreTile {
        tx: i8,
        ty: i8,
        value: i16,
    },
    Raw(Vec<u8>),
    Flip {
        at: u16,
        xor: u8,
    },
}

fn frame(out: &mut Vec<u8>, m: &HostMsg) {
    let mut buf = [0u8; MAX_HOST_FRAME];
    if let Ok(f) = wire::encode(m, &mut buf) {
        out.push(0);
        out.extend_from_slice(f);
    }
}

fn packet(out: &mut Vec<u8>, p: Packet) {
    out.extend_from_slice(&p.to_bytes());
}

/// The firmware's engine (small buffers).
fn build(config: RunConfig) -> Option<Session<Owned<u8>>> {
    let sizes = Sizes {
        width: W,
        height: H,
        rays: 256,
        scans: 8,
        local: 32,
    };
    Session::new(config, Owned::buffers(&sizes)).ok()
}

fuzz_target!(|items: Vec<Item>| {
    let mut bytes = Vec::new();
    for it in items.iter().take(64) {
        match *it {
            Item::Config {
                origin_x_mm,
                origin_y_mm,
                cell_mm,
                max_range_mm,
                min_range_mm,
                seed,
                sigma_milli_cells,
                outlier_ppm,
                p_rand_patch_ppm,
                burn_in_sweeps,
                max_candidates,
                sampler_tile_shift,
                visit_sweeps,
                updates,
                data,
                evidence_gain_q8,
                evidence_free_q8,
                free_update_q8,
                data_candidate,
                shift,
                reset_on_change,
                rao_blackwell,
                hot_share,
                mount_x_mm,
                mount_y_mm,
                mount_yaw,
                fixed_poses,
                rplidar_sample_us,
                face_band,
                window_margin_cells,
                correction,
                window_hold,
                odometry,
            } => frame(
                &mut bytes,
                &HostMsg::Config(RunConfig {
                    origin_x_mm,
                    origin_y_mm,
                    cell_mm,
                    max_range_mm,
                    min_range_mm,
                    seed,
                    sigma_milli_cells,
                    outlier_ppm,
                    p_rand_patch_ppm,
                    burn_in_sweeps,
                    max_candidates,
                    sampler_tile_shift,
                    visit_sweeps,
                    budget: Budget::Fixed {
                        updates: u32::from(updates),
                    },
                    tiles_per_scan: 8,
                    count_tiles_per_scan: 8,
                    data: match data % 3 {
                        0 => DataTerm::Rays,
                        1 => DataTerm::Evidence,
                        _ => DataTerm::Hybrid,
                    },
                    evidence_gain_q8,
                    evidence_free_q8,
                    free_update_q8,
                    data_candidate,
                    estimator: if shift == 0 {
                        Estimator::Counts
                    } else {
                        Estimator::Average {
                            shift,
                            max_shift: shift,
                            reset_on_change,
                            rao_blackwell,
                        }
                    },
                    hot_share,
                    mount: ogm_core::Pose {
                        x_mm: mount_x_mm,
                        y_mm: mount_y_mm,
                        heading: ogm_core::Angle(mount_yaw),
                    },
                    poses: if fixed_poses {
                        PoseInput::Fixed
                    } else {
                        PoseInput::Link
                    },
                    lidar: match rplidar_sample_us {
                        Some(sample_us) => LidarModel::Rplidar { sample_us },
                        None => LidarModel::Ld06,
                    },
                    face_band,
                    window_margin_cells,
                    correction: if correction {
                        PoseCorrection::Match
                    } else {
                        PoseCorrection::Off
                    },
                    window_hold,
                    odometry: OdometryNoise {
                        trans_permille: odometry.0,
                        turn_permille: odometry.1,
                        drift_mdeg_per_m: odometry.2,
                    },
                }),
            ),
            Item::PaperConfig {
                origin_x_mm,
                origin_y_mm,
                max_range_mm,
                updates,
            } => frame(
                &mut bytes,
                &HostMsg::Config(
                    RunConfig::PAPER
                        .with_origin_mm(i32::from(origin_x_mm), i32::from(origin_y_mm))
                        .with_max_range_mm(u32::from(max_range_mm))
                        .with_budget(Budget::Fixed {
                            updates: u32::from(updates),
                        }),
                ),
            ),
            Item::Start {
                seq,
                x_mm,
                y_mm,
                heading,
            } => frame(
                &mut bytes,
                &HostMsg::ScanStart {
                    seq: u32::from(seq),
                    pose: ogm_core::Pose {
                        x_mm,
                        y_mm,
                        heading: ogm_core::Angle(heading),
                    },
                },
            ),
            Item::NearStart {
                seq,
                x_mm,
                y_mm,
                heading,
            } => frame(
                &mut bytes,
                &HostMsg::ScanStart {
                    seq: u32::from(seq),
                    pose: ogm_core::Pose {
                        x_mm: i32::from(x_mm) / 8 + 1600,
                        y_mm: i32::from(y_mm) / 8 + 1600,
                        heading: ogm_core::Angle(heading),
                    },
                },
            ),
            Item::End { seq, points } => frame(
                &mut bytes,
                &HostMsg::ScanEnd {
                    seq: u32::from(seq),
                    points,
                },
            ),
            Item::Finish => frame(&mut bytes, &HostMsg::Finish),
            Item::Resume => frame(&mut bytes, &HostMsg::Resume),
            Item::Pose {
                t_us,
                x_mm,
                y_mm,
                heading,
            } => frame(
                &mut bytes,
                &HostMsg::Pose {
                    t_us,
                    pose: ogm_core::Pose {
                        x_mm,
                        y_mm,
                        heading: ogm_core::Angle(heading),
                    },
                },
            ),
            Item::Packet {
                speed_dps,
                start_cdeg,
                end_cdeg,
                timestamp_ms,
                distance_mm,
            } => packet(
                &mut bytes,
                Packet {
                    speed_dps,
                    start_cdeg,
                    end_cdeg,
                    timestamp_ms,
                    points: distance_mm.map(|d| Point {
                        distance_mm: d,
                        intensity: 200,
                    }),
                },
            ),
            Item::Packets { count, distance_mm } => {
                for k in 0..u16::from(count % 16) {
                    let start = (k * 2400) % 36_000;
                    packet(
                        &mut bytes,
                        Packet {
                            speed_dps: 3600,
                            start_cdeg: start,
                            end_cdeg: (start + 2200) % 36_000,
                            timestamp_ms: k,
                            points: [Point {
                                distance_mm: distance_mm.wrapping_add(k * 37),
                                intensity: 200,
                            }; POINTS],
                        },
                    );
                }
            }
            Item::Restore {
                tx,
                ty,
                layer,
                row,
                len,
                fill,
            } => {
                let n = usize::from(len) % (wire::RESTORE_PART_BYTES + 1);
                let data = [fill; wire::RESTORE_PART_BYTES];
                if let Some(data) = wire::RestoreData::new(&data[..n]) {
                    frame(
                        &mut bytes,
                        &HostMsg::Restore {
                            tx: i32::from(tx),
                            ty: i32::from(ty),
                            layer: [Layer::LogOdds, Layer::Counts, Layer::Sample]
                                [usize::from(layer % 3)],
                            row,
                            data,
                        },
                    );
                }
            }
            Item::RestoreTile { tx, ty, value } => {
                let lo: Vec<u8> = (0..256).flat_map(|_| value.to_le_bytes()).collect();
                let est = [128u8; 256];
                let (tx, ty) = (i32::from(tx), i32::from(ty));
                for m in wire::restore_msgs(tx, ty, Layer::LogOdds, 16, &lo)
                    .chain(wire::restore_msgs(tx, ty, Layer::Counts, 16, &est))
                {
                    frame(&mut bytes, &m);
                }
            }
            Item::Raw(ref v) => bytes.extend(v.iter().take(256)),
            Item::Flip { at, xor } => {
                if !bytes.is_empty() {
                    let i = usize::from(at) % bytes.len();
                    bytes[i] ^= xor;
                }
            }
        }
    }

    let mut rx = LinkRx::new();
    let mut scan: ScanBuf<MAX_BEAMS> = ScanBuf::new();
    let mut machine: Option<Session<Owned<u8>>> = None;
    let mut configured = false;
    let mut scans = 0u32;
    // The robot loop's lidar path: every LD06 packet among the bytes, placed by the poses.
    let mut turns = Turns::new(Mount::ZERO, false);
    let mut turn_buf: ScanBuf<MAX_BEAMS> = ScanBuf::new();
    let mut parser = Ld06Parser::new();
    let mut turn_maps = 0u32;
    let mut asm = TileRestore::new();
    let mut restore_refusals = 0u32;
    // Every third turn is held, as the firmware holds one for a window shift, until `Resume`
    // (or the end of the input) releases it.
    let map_turn = |m: &mut Option<Session<Owned<u8>>>, t: Turn<'_>, n: &mut u32, release: bool| {
        assert!(t.beams.len() <= MAX_BEAMS);
        if t.seq % 3 == 1 && !release {
            return Taken::Held;
        }
        if let Some(m) = m.as_mut() {
            *n += 1;
            let _ = m.insert(&t.pose, t.beams);
            m.step(16);
        }
        Taken::Taken
    };
    rx.feed(&bytes, &mut scan, |step| match step {
        Step::Host(HostMsg::Config(c)) => {
            if !configured {
                configured = true;
                turns = Turns::configured(&c);
                machine = build(c);
            }
        }
        Step::Scan { pose, beams, .. } => {
            assert!(beams.len() <= MAX_BEAMS);
            let Some(m) = machine.as_mut() else {
                return;
            };
            scans += 1;
            // The correction first, as a rolling window's caller does (every other scan), or
            // inside the insert: the scan matcher against the session's map, its points in
            // the mapper's marks.
            let first = (scans % 2 == 0).then(|| m.correct(&pose, beams));
            let inserted = m.insert(&pose, beams);
            if let (Some(c), Ok(i)) = (first, &inserted) {
                assert_eq!(i.correction, c);
            }
            if let Ok(i) = &inserted {
                assert_eq!(i.correction.odometry, pose);
                if m.config().correction == PoseCorrection::Off {
                    assert_eq!(i.correction.pose, pose);
                }
                if let Some(r) = i.correction.matched {
                    if !r.verdict.is_usable() {
                        assert_eq!(i.correction.pose, i.correction.predicted);
                    }
                }
            }
            if let Budget::Fixed { updates } = m.config().budget {
                m.step(updates.min(256));
            }
            // The firmware's `mark_dirty` box (the pose and every beam end).
            if let Ok(inserted) = inserted {
                let (lo, hi) = inserted.changed_box();
                assert!(lo.x <= hi.x && lo.y <= hi.y);
            }
        }
        Step::Host(HostMsg::Pose { t_us, pose }) => {
            let _ = turns.push_pose(t_us, pose, &mut turn_buf, |t| {
                map_turn(&mut machine, t, &mut turn_maps, false)
            });
        }
        Step::Host(HostMsg::Resume) => {
            turns.retry(&mut turn_buf, |t| {
                map_turn(&mut machine, t, &mut turn_maps, true)
            });
        }
        Step::Host(HostMsg::Restore {
            tx,
            ty,
            layer,
            row,
            data,
        }) => {
            if let Some(m) = machine.as_mut() {
                let before = m.window().restore_refused;
                match m.restore_part(&mut asm, 16, tx, ty, layer, row, data.as_slice()) {
                    Err(_) => {
                        restore_refusals += 1;
                        assert!(m.window().restore_refused > before, "a refusal not counted");
                    }
                    Ok(step) => {
                        let counted = u32::from(step.dropped.is_some());
                        assert_eq!(m.window().restore_refused, before + counted);
                    }
                }
            }
        }
        Step::Host(_) | Step::Error(_) => {}
    });
    if let Some(m) = machine.as_ref() {
        assert!(m.window().restore_refused >= restore_refusals);
    }
    rx.finish(|_| {});
    parser.feed(&bytes, |p| {
        if let Ok(p) = p {
            turns.push_packet(&p, &mut turn_buf, |t| {
                map_turn(&mut machine, t, &mut turn_maps, false)
            });
        }
    });
    turns.retry(&mut turn_buf, |t| {
        map_turn(&mut machine, t, &mut turn_maps, true)
    });
    let tc = turns.counters();
    assert!(tc.turns <= tc.packets && turns.waiting() <= ogm_core::lidar::turn::QUEUE);
    let _ = turn_maps;
    if let Some(m) = machine.as_ref() {
        let (mapper, gibbs) = (m.mapper(), m.gibbs());
        let clamp = mapper.config().clamp;
        for l in mapper.grid().cells() {
            assert!(
                *l >= clamp.min() && *l <= clamp.max(),
                "log-odds {l:?} outside the clamp"
            );
        }
        for i in 0..mapper.grid().cells().len() {
            assert!(gibbs.count(i) <= gibbs.samples().max(255));
        }
    }
    let k = rx.counters();
    assert_eq!(k.rx_bytes as usize, bytes.len());
    let _ = scans;
});
