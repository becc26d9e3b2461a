//! The firmware's stream checked against the host replay: compared message for message and
//! cell for cell ([`compare`]), and with a noisy link, the replay of only what survived
//! ([`noise_report`]).

use anyhow::{ensure, Context};
use ogm_core::wire::Counters;
use ogm_field::stream::StreamedMap;
use ogm_firmware::sizes::MPS2_AN386 as FW;

use super::groups::Groups;
use super::input::{RunInput, Unit, UnitKind};
use super::replay::{decode_own, replay, sizes_of, FIRMWARE_SIZES};
use super::report::NoiseReport;

/// Collects mismatches (bounded) and counts checks.
#[derive(Default)]
pub(super) struct Checker {
    pub(super) mismatches: Vec<String>,
    pub(super) checks: u64,
}

impl Checker {
    pub(super) fn eq<T: PartialEq + std::fmt::Debug>(
        &mut self,
        what: impl FnOnce() -> String,
        fw: &T,
        host: &T,
    ) {
        self.checks += 1;
        if fw != host && self.mismatches.len() < 50 {
            self.mismatches
                .push(format!("{}: firmware {fw:?}, host {host:?}", what()));
        }
    }

    pub(super) fn fail(&mut self, msg: String) {
        if self.mismatches.len() < 50 {
            self.mismatches.push(msg);
        }
    }
}

/// Compares the firmware's stream with the host's run of the same application on the same
/// input: every message equal except the board's timing and stack figures, and the streamed
/// map equal to the host's engine cell for cell.
pub(super) fn compare(
    input: &[u8],
    lidar: &[u8],
    g: &Groups,
    c: &mut Checker,
) -> anyhow::Result<()> {
    let hello = g.hello.as_ref().context("no Hello from the firmware")?;
    ensure!(
        (hello.width, hello.height, hello.tile_edge) == (FW.width, FW.height, FW.tile_edge)
            && hello.max_beams as usize == FW.max_beams
            && hello.count_max == 255,
        "the firmware's sizes {hello:?} are not ogm_firmware::sizes::MPS2_AN386 (rebuild it?)"
    );
    let edge = usize::from(FW.tile_edge);
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    let (stream, state) = replay::<u8, _>(
        input,
        lidar,
        sizes_of(hello),
        |w| g.updates(w),
        |_, _| {},
        |m, out| {
            let state = m.map(|m| {
                (
                    *m.config(),
                    m.log_odds().iter().map(|l| l.raw()).collect::<Vec<_>>(),
                    (0..w * h)
                        .map(|i| ogm_core::wire::TileSource::count(m, i))
                        .collect::<Vec<_>>(),
                    (0..w * h)
                        .map(|i| ogm_core::wire::TileSource::occupied(m, i))
                        .collect::<Vec<_>>(),
                )
            });
            (out.to_vec(), state)
        },
    )?;
    let (config, host_lo, host_counts, host_sample) =
        state.context("the replay never got a valid Config")?;
    let host = Groups::of(&decode_own(&stream)?);
    c.eq(|| "configured".into(), &g.configured, &host.configured);
    c.eq(|| "configured".into(), &g.configured, &Some(config));
    c.eq(|| "scans".into(), &g.scans.len(), &host.scans.len());
    c.eq(|| "error reports".into(), &g.errors, &host.errors);
    let mut seqs: Vec<u32> = g.scans.keys().copied().collect();
    seqs.sort_unstable();
    for seq in seqs {
        let (fwg, hg) = (&g.scans[&seq], host.scans.get(&seq));
        let Some(hg) = hg else {
            c.fail(format!("scan {seq}: the host did not map it"));
            continue;
        };
        let mut fr = fwg.report;
        // Timing is the firmware's own business.
        (
            fr.insert_ticks,
            fr.store_ticks,
            fr.sampler_ticks,
            fr.match_ticks,
        ) = (0, 0, 0, 0);
        c.eq(|| format!("scan {seq} report"), &fr, &hg.report);
        c.eq(
            || format!("scan {seq} tiles"),
            &fwg.tiles.len(),
            &hg.tiles.len(),
        );
        for (a, b) in fwg.tiles.iter().zip(&hg.tiles) {
            c.checks += 1;
            if a != b {
                let n = a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count()
                    + a.data.len().abs_diff(b.data.len());
                c.fail(format!(
                    "scan {seq}: tile {:?} ({}, {}) differs from the host's {:?} ({}, {}) in {n} bytes",
                    a.layer, a.tx, a.ty, b.layer, b.tx, b.ty
                ));
            }
        }
        c.eq(
            || format!("scan {seq} sampler report"),
            &fwg.sampler,
            &hg.sampler,
        );
        c.eq(|| format!("scan {seq} ranges"), &fwg.ranges, &hg.ranges);
        // With the robot's two lines, how far each had been read when a turn finished is
        // timing (QEMU's scheduling of two sockets), not behaviour: what was counted of the
        // turns themselves must agree, the bytes and packets read so far need not (the final
        // counters, after everything was read, are compared in full below).
        if !lidar.is_empty() {
            let settled = |c: &Option<Counters>| {
                c.map(|c| {
                    let l = c.lidar;
                    (c.scans, c.beams_overflowed, l.turns, l.packets_overflowed)
                })
            };
            c.eq(
                || {
                    format!(
                        "scan {seq} counters (scans, beams overflowed, turns, packets overflowed)"
                    )
                },
                &settled(&fwg.counters),
                &settled(&hg.counters),
            );
        } else {
            c.eq(
                || format!("scan {seq} counters"),
                &fwg.counters,
                &hg.counters,
            );
        }
    }
    for (seq, r) in &g.idles {
        let host_updates = host.idles.get(seq).map(|r| r.sampler_updates);
        c.eq(
            || format!("idle {seq} updates"),
            &Some(r.sampler_updates),
            &host_updates,
        );
    }
    // A rolling window: every shift announced alike, every leaving tile alike.
    c.eq(|| "window reports".into(), &g.windows, &host.windows);
    c.eq(
        || "tiles that left the window".into(),
        &g.shift_tiles.len(),
        &host.shift_tiles.len(),
    );
    if g.shift_tiles != host.shift_tiles {
        c.fail("the tiles that left the window differ from the host's".into());
    }
    c.checks += g.shift_tiles.len() as u64;
    c.eq(
        || "final tiles".into(),
        &g.final_tiles.len(),
        &host.final_tiles.len(),
    );
    if g.final_tiles != host.final_tiles {
        c.fail("the final tiles differ from the host's".into());
    }
    c.checks += g.final_tiles.len() as u64;
    c.eq(
        || "final sampler report".into(),
        &g.final_sampler,
        &host.final_sampler,
    );
    c.eq(
        || "final counters".into(),
        &g.final_counters,
        &host.final_counters,
    );
    let done = g.done.as_ref().context("no Done from the firmware")?;
    let host_done = host.done.as_ref().context("no Done from the host")?;
    c.eq(
        || "Done (scans, grid FNV, counts FNV)".into(),
        &(done.scans, done.grid_fnv, done.counts_fnv),
        &(host_done.scans, host_done.grid_fnv, host_done.counts_fnv),
    );
    // The map as streamed, cell for cell, against the host's engine: the tiles of the final
    // window (tiles carry building coordinates; the window's origin is the last `Window`'s).
    let mut streamed = StreamedMap::new(w, h, edge);
    let e = i32::from(FW.tile_edge);
    let (ox, oy) = g
        .windows
        .last()
        .map_or((0, 0), |r| (r.origin_x / e, r.origin_y / e));
    let (tiles_x, tiles_y) = (i32::from(FW.width) / e, i32::from(FW.height) / e);
    // A tile the window left and came back over holds this visit's data only: unless the host
    // sent the stored tile back, what was streamed before it entered again is not on the
    // robot (a region re-entered but not mapped again is unknown there).
    let restored = g.windows.last().is_some_and(|r| r.tiles_restored > 0);
    let entered = |tx: i32, ty: i32| last_entry(&g.windows, e, tiles_x, tiles_y, tx, ty);
    for (t, &seen) in g.all_tiles.iter().zip(&g.tile_windows) {
        let (x, y) = (t.tx - ox, t.ty - oy);
        let current = restored || seen >= entered(t.tx, t.ty);
        if current && (0..tiles_x).contains(&x) && (0..tiles_y).contains(&y) {
            streamed.apply(&ogm_field::stream::OwnedTile {
                tx: x,
                ty: y,
                ..t.clone()
            })?;
        }
    }
    for (name, diff) in [
        ("log-odds", first_diff(&streamed.log_odds, &host_lo)),
        (
            "marginal counts",
            first_diff(&streamed.counts, &host_counts),
        ),
        ("sample", first_diff(&streamed.sample, &host_sample)),
    ] {
        c.checks += (w * h) as u64;
        if let Some((i, n, a, b)) = diff {
            c.fail(format!(
                "streamed {name}: {n} cells differ, first at ({}, {}): firmware {a}, host {b}",
                i % w,
                i / w
            ));
        }
    }
    Ok(())
}

/// How many `Window` messages had come when the window last came over building tile (`tx`,
/// `ty`) (0: it has been inside since the start, whose window's origin is the building's
/// origin). Each `Window` carries the origin (cells) after its shift.
fn last_entry(
    windows: &[ogm_core::wire::WindowReport],
    edge: i32,
    tiles_x: i32,
    tiles_y: i32,
    tx: i32,
    ty: i32,
) -> usize {
    let inside = |o: (i32, i32)| {
        let (x, y) = (tx - o.0 / edge, ty - o.1 / edge);
        (0..tiles_x).contains(&x) && (0..tiles_y).contains(&y)
    };
    let mut before = inside((0, 0));
    let mut entry = 0;
    for (i, w) in windows.iter().enumerate() {
        let now = inside((w.origin_x, w.origin_y));
        if now && !before {
            entry = i + 1;
        }
        before = now;
    }
    entry
}

fn first_diff<T: PartialEq + std::fmt::Display>(
    a: &[T],
    b: &[T],
) -> Option<(usize, usize, String, String)> {
    let n = a.iter().zip(b).filter(|(x, y)| x != y).count() + a.len().abs_diff(b.len());
    let i = a.iter().zip(b).position(|(x, y)| x != y)?;
    Some((i, n, a[i].to_string(), b[i].to_string()))
}

/// The streamed map: every tile the firmware sent, applied in order.
fn streamed_map(g: &Groups) -> anyhow::Result<StreamedMap> {
    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
    let mut m = StreamedMap::new(w, h, usize::from(FW.tile_edge));
    for t in &g.all_tiles {
        m.apply(t)?;
    }
    Ok(m)
}

/// `--noise-ppm`: which packets and frames were damaged, and whether a host replay of only the
/// ones the firmware can accept (intact, or damaged past the LD06's 8-bit CRC; in order;
/// garbage dropped) gives the firmware's final map.
pub(super) fn noise_report(
    input: &RunInput,
    corrupted: &[usize],
    g: &Groups,
) -> anyhow::Result<NoiseReport> {
    let mut n = NoiseReport {
        corrupted_bytes: corrupted.len(),
        ..NoiseReport::default()
    };
    let damaged = |u: &Unit| {
        let i = corrupted.partition_point(|&p| p < u.start);
        corrupted.get(i).is_some_and(|&p| p < u.start + u.len)
    };
    let mut surviving = Vec::new();
    let mut finished = false;
    // Per scan: its intact-framing state and damaged packets.
    let (mut in_scan, mut scan_damaged) = (false, 0u64);
    for u in &input.units {
        let mut bad = damaged(u);
        let bytes = &input.bytes[u.start..u.start + u.len];
        match u.kind {
            UnitKind::Garbage => continue,
            UnitKind::Packet => {
                n.packets += 1;
                if bad {
                    n.damaged_packets += 1;
                    let valid = <&[u8; ogm_core::lidar::ld06::PACKET_LEN]>::try_from(bytes)
                        .is_ok_and(|b| ogm_core::lidar::ld06::Packet::parse(b).is_ok());
                    if valid {
                        // Past the LD06's own checks: the robot cannot tell, nor lose it.
                        n.undetected_packets += 1;
                        bad = false;
                    } else {
                        scan_damaged += ogm_core::lidar::ld06::POINTS as u64;
                    }
                }
                if !bad && !finished {
                    n.intact_packets_before_finish += 1;
                }
            }
            UnitKind::Frame => {
                n.frames += 1;
                if bad {
                    n.damaged_frames += 1;
                } else {
                    let mut body = bytes[1..bytes.len() - 1].to_vec();
                    match ogm_core::wire::decode::<ogm_core::wire::HostMsg>(&mut body) {
                        Ok(ogm_core::wire::HostMsg::ScanStart { .. }) => {
                            in_scan = true;
                            scan_damaged = 0;
                        }
                        Ok(ogm_core::wire::HostMsg::ScanEnd { .. }) if in_scan => {
                            n.points_in_damaged_packets += scan_damaged;
                            in_scan = false;
                        }
                        Ok(ogm_core::wire::HostMsg::Finish) => {
                            if !finished {
                                n.intact_frames_before_finish += 1;
                            }
                            finished = true;
                        }
                        _ => {}
                    }
                    if !finished {
                        n.intact_frames_before_finish += 1;
                    }
                }
            }
        }
        if !bad {
            surviving.extend_from_slice(bytes);
        }
    }
    let sizes = g.hello.as_ref().map_or(FIRMWARE_SIZES, sizes_of);
    let streamed = streamed_map(g)?;
    let identical = replay::<u8, _>(
        &surviving,
        &[],
        sizes,
        |w| g.updates(w),
        |_, _| {},
        |m, _| {
            m.map(|m| {
                use ogm_core::wire::TileSource;
                let cells = streamed.log_odds.len();
                m.log_odds()
                    .iter()
                    .map(|l| l.raw())
                    .eq(streamed.log_odds.iter().copied())
                    && (0..cells).all(|i| m.count(i) == streamed.counts[i])
                    && (0..cells).all(|i| m.occupied(i) == streamed.sample[i])
            })
        },
    )?;
    n.surviving_replay_identical =
        identical.context("the surviving packets carry no valid Config")?;
    Ok(n)
}
