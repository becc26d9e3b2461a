//! The robot's input for a simulated run, as the host sends it on the link (docs/wire.md): the
//! simulator's scans as LD06 packets plus the host frames (settings, `ScanStart`/`ScanEnd` with
//! the known pose, `Finish`) on one byte stream ([`RunInput`], [`encode_run`]), optionally with
//! garbage, repeated frames and idle periods, and where each of its units lies (for the noisy
//! link's accounting). [`send_lines`] writes it as `host-sim listen --send` lines.
//!
//! The frames are ogm-core's own encoding through [`host_frame`] (the one the field tools send
//! with), so host and robot cannot disagree about the format.

use anyhow::anyhow;
use ogm_core::config::RunConfig;
use ogm_core::lidar::ld06::{self, theta_cdeg, PACKET_LEN};
use ogm_core::wire::HostMsg;
use ogm_core::Beam;
use ogm_field::stream::host_frame;

use crate::sim::explore::ScanRecord;

/// The robot's whole input for a run, and where each of its units lies.
#[derive(Clone, Debug, Default)]
pub struct RunInput {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Scans sent.
    pub scans: usize,
    /// LD06 points sent inside scans.
    pub points: u64,
    /// Bytes of deliberate garbage mixed in.
    pub garbage_bytes: usize,
    /// Every frame, packet and garbage burst, in order (they tile `bytes`).
    pub units: Vec<Unit>,
}

impl RunInput {
    fn push(&mut self, kind: UnitKind, bytes: &[u8]) {
        self.units.push(Unit {
            kind,
            start: self.bytes.len(),
            len: bytes.len(),
        });
        self.bytes.extend_from_slice(bytes);
    }

    fn frame(&mut self, msg: &HostMsg, repeat: usize) {
        let f = host_frame(msg);
        for _ in 0..repeat.max(1) {
            self.push(UnitKind::Frame, &f);
        }
    }
}

/// What a span of the robot's input is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnitKind {
    /// A host frame (leading `0x00` included).
    Frame,
    /// An LD06 packet of a scan.
    Packet,
    /// Deliberate garbage (`encode_run`'s `garbage`).
    Garbage,
}

/// One packet, frame or garbage burst of the input: `bytes[start..start + len]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// What it is.
    pub kind: UnitKind,
    /// First byte.
    pub start: usize,
    /// Length.
    pub len: usize,
}

/// Builds the input: `Config`, then per scan `ScanStart`, its LD06 packets and `ScanEnd`, then
/// `Finish`. With `garbage`, every fifth gap between scans also carries junk — random bytes,
/// stray `0x54`/`0x2C`/`0x00`, a truncated LD06 packet and a corrupted frame — which the robot
/// must skip (the replay on the host sees the same bytes).
pub fn encode_run(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
) -> anyhow::Result<RunInput> {
    encode_run_with(config, scans, garbage, 1)
}

/// [`encode_run`] sending every host frame `repeat_frames` times in a row (for a noisy link:
/// a frame is lost only if all its copies are; the robot ignores exact repeats, see
/// `ogm_core::lidar::link`).
pub fn encode_run_with(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
    repeat_frames: usize,
) -> anyhow::Result<RunInput> {
    encode_run_idle(config, scans, garbage, repeat_frames, &[])
}

/// [`encode_run_with`] with idle periods (`HostMsg::Idle`, µs of board time each) after the
/// last scan, before `Finish`.
pub fn encode_run_idle(
    config: &RunConfig,
    scans: &[ScanRecord],
    garbage: bool,
    repeat_frames: usize,
    idle_us: &[u32],
) -> anyhow::Result<RunInput> {
    let mut input = RunInput::default();
    input.frame(&HostMsg::Config(*config), repeat_frames);
    let mut ts = 0u16;
    let mut x = 0x2545_F491u32;
    for (k, s) in scans.iter().enumerate() {
        let seq = u32::try_from(k)?;
        let packets = scan_packets(&s.beams, &mut ts)?;
        if garbage && k % 5 == 2 {
            // A truncated LD06 packet first, then random bytes, then a corrupted frame: the
            // 47-byte candidate the truncated header opens ends inside the random bytes. (Right
            // before a frame, it would take the frame's first bytes with it, and an 8-bit CRC
            // accepts such a false packet once in 256 — a limit of sharing one UART between
            // the lidar and the host, measured in docs/firmware.md.)
            let mut junk = packets[..20.min(packets.len())].to_vec();
            for _ in 0..64 {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                junk.push(match x % 9 {
                    0 => 0x54,
                    1 => 0x2C,
                    2 => 0x00,
                    _ => (x >> 16) as u8,
                });
            }
            let mut bad = host_frame(&HostMsg::ScanEnd {
                seq,
                points: 12_345,
            });
            if let Some(b) = bad.get_mut(4) {
                *b ^= 0x21;
            }
            junk.extend(bad);
            input.garbage_bytes += junk.len();
            input.push(UnitKind::Garbage, &junk);
        }
        input.frame(&HostMsg::ScanStart { seq, pose: s.pose }, repeat_frames);
        for p in packets.chunks(PACKET_LEN) {
            input.push(UnitKind::Packet, p);
        }
        input.frame(
            &HostMsg::ScanEnd {
                seq,
                points: s.beams.len() as u32,
            },
            repeat_frames,
        );
        input.scans += 1;
        input.points += s.beams.len() as u64;
    }
    for (seq, &period_us) in idle_us.iter().enumerate() {
        let seq = u32::try_from(seq)?;
        input.frame(&HostMsg::Idle { seq, period_us }, repeat_frames);
    }
    input.frame(&HostMsg::Finish, repeat_frames);
    Ok(input)
}

/// A scan's beams as LD06 packets, in the sensor's (clockwise) order. Needs a multiple of 12
/// beams, evenly spaced (as the simulator's are).
pub fn scan_packets(beams: &[Beam], timestamp_ms: &mut u16) -> anyhow::Result<Vec<u8>> {
    let mut sorted = beams.to_vec();
    sorted.sort_by_key(|b| theta_cdeg(b.angle));
    let packets = sorted.len() / ld06::POINTS;
    // 10 Hz: one turn in 100 ms.
    let ms = (100 / packets.max(1)).max(1) as u16;
    let mut out = Vec::with_capacity(packets * PACKET_LEN);
    let n = ld06::encode_scan(&sorted, 3600, *timestamp_ms, ms, |p| {
        out.extend_from_slice(p)
    })
    .map_err(|_| {
        anyhow!(
            "{} beams per scan: the LD06 format needs a multiple of 12",
            beams.len()
        )
    })?;
    *timestamp_ms = ((u32::from(*timestamp_ms) + 100) % 30_000) as u16;
    debug_assert_eq!(n, packets);
    Ok(out)
}

/// A scan's beams as the firmware reads them: through [`scan_packets`] and the LD06 parser
/// (clockwise, at the packets' resolution). What a host map that must equal the robot's inserts.
pub fn beams_as_read(beams: &[Beam], timestamp_ms: &mut u16) -> anyhow::Result<Vec<Beam>> {
    let bytes = scan_packets(beams, timestamp_ms)?;
    let mut read = Vec::with_capacity(beams.len());
    let mut bad = 0usize;
    ld06::Ld06Parser::new().feed(&bytes, |p| match p {
        Ok(p) => read.extend((0..ld06::POINTS).filter_map(|i| p.beam(i))),
        Err(_) => bad += 1,
    });
    anyhow::ensure!(
        bad == 0,
        "{bad} of the scan's own LD06 packets did not parse"
    );
    Ok(read)
}

/// A robot input ([`RunInput`], e.g. from [`encode_run`]) as `host-sim listen --send` lines: each
/// host frame as its JSON message, each LD06 packet and garbage burst as a raw line. Sent, the
/// lines give exactly `input.bytes`.
pub fn send_lines(input: &RunInput) -> String {
    let mut out = String::new();
    for u in &input.units {
        let bytes = input.bytes.get(u.start..u.start + u.len).unwrap_or(&[]);
        let msg = match (u.kind, bytes) {
            (UnitKind::Frame, [0, body @ .., 0]) => {
                let mut body = body.to_vec();
                ogm_core::wire::decode::<HostMsg>(&mut body)
                    .ok()
                    .filter(|m| host_frame(m) == bytes)
            }
            _ => None,
        };
        match msg.and_then(|m| serde_json::to_string(&m).ok()) {
            Some(json) => out += &json,
            None => out += &format!("{{\"raw\":\"{}\"}}", to_hex(bytes)),
        }
        out.push('\n');
    }
    out
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Corrupts `ppm` of every million bytes of `bytes` (distinct positions, each XORed with a
/// random non-zero byte; seeded); returns the positions in ascending order.
pub fn corrupt(bytes: &mut [u8], ppm: u32, seed: u64) -> Vec<usize> {
    use rand::{RngExt, SeedableRng};
    let n = (bytes.len() as u64 * u64::from(ppm)).div_ceil(1_000_000) as usize;
    let n = n.min(bytes.len());
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x006e_6f69_7379);
    let mut positions = std::collections::BTreeSet::new();
    while positions.len() < n {
        positions.insert(rng.random_range(0..bytes.len()));
    }
    for &p in &positions {
        bytes[p] ^= rng.random_range(1..=255u8);
    }
    positions.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::config::Budget;
    use ogm_core::lidar::link::{LinkRx, Step};
    use ogm_core::{Angle, Pose, Range, ScanBuf};

    fn record(k: u32) -> ScanRecord {
        ScanRecord {
            pose: Pose {
                x_mm: 100 * k as i32,
                y_mm: 0,
                heading: Angle(1000 * k as u16),
            },
            beams: (0..360u32)
                .map(|i| Beam {
                    angle: Angle(((u64::from(i) << 16) / 360) as u16),
                    range: if i % 11 == 0 {
                        Range::NoReturn
                    } else {
                        Range::Hit(500 + 7 * i + k)
                    },
                })
                .collect(),
        }
    }

    #[test]
    fn input_round_trips_through_the_robots_demux_with_garbage() {
        let scans: Vec<ScanRecord> = (0..8).map(record).collect();
        let cfg = RunConfig::PAPER
            .with_max_range_mm(3750)
            .with_seed(3)
            .with_budget(Budget::Fixed { updates: 10 });
        let input = encode_run(&cfg, &scans, true).unwrap();
        assert!(input.garbage_bytes > 0);
        let mut rx = LinkRx::new();
        let mut buf: ScanBuf<512> = ScanBuf::new();
        let mut got = Vec::new();
        let mut config = None;
        let mut finished = false;
        for c in input.bytes.chunks(13) {
            rx.feed(c, &mut buf, |s| match s {
                Step::Scan {
                    seq, pose, beams, ..
                } => got.push((seq, pose, beams.to_vec())),
                Step::Host(HostMsg::Config(c)) => config = Some(c),
                Step::Host(HostMsg::Finish) => finished = true,
                Step::Host(_) | Step::Error(_) => {}
            });
        }
        assert!(finished);
        assert_eq!(config, Some(cfg));
        assert_eq!(got.len(), 8);
        for ((seq, pose, beams), s) in got.iter().zip(&scans) {
            assert_eq!(*pose, s.pose, "scan {seq}");
            assert_eq!(beams.len(), 360);
            // Same multiset of ranges; angles within the wire resolution.
            let mut a: Vec<(u16, Range)> = beams.iter().map(|b| (b.angle.0, b.range)).collect();
            let mut b: Vec<(u16, Range)> = s.beams.iter().map(|b| (b.angle.0, b.range)).collect();
            a.sort_by_key(|x| x.0);
            b.sort_by_key(|x| x.0);
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(x.1, y.1);
                assert!(Angle(x.0).signed_diff(Angle(y.0)).abs() <= 2);
            }
        }
        let c = rx.counters();
        assert!(c.garbage_bytes > 0 && c.frame_errors + c.frames_too_long > 0);
        assert_eq!(c.points_lost, 0);
    }

    #[test]
    fn send_lines_round_trip_through_a_send_file() {
        let scans: Vec<ScanRecord> = (0..3)
            .map(|k| ScanRecord {
                pose: Pose {
                    x_mm: 100 * k,
                    y_mm: -7,
                    heading: Angle(900 * k as u16),
                },
                beams: (0..360u32)
                    .map(|i| Beam {
                        angle: Angle(((u64::from(i) << 16) / 360) as u16),
                        range: Range::Hit(500 + i),
                    })
                    .collect(),
            })
            .collect();
        // `host-sim listen`'s default settings, placed elsewhere.
        let config = RunConfig {
            origin_x_mm: -1000,
            origin_y_mm: 500,
            ..ogm_field::listen::default_config()
        };
        let input = encode_run(&config, &scans, true).unwrap();
        let text = send_lines(&input);
        assert!(text.starts_with("{\"Config\":{"));
        assert!(text.contains("{\"ScanStart\":{\"seq\":2,"));
        assert!(text.trim_end().ends_with("\"Finish\""));
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("send.jsonl");
        std::fs::write(&f, format!("# a comment\n\n{text}")).unwrap();
        let items = ogm_field::listen::read_send_file(&f).unwrap();
        assert_eq!(items.concat(), input.bytes);
    }
}
