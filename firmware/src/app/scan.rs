//! One step from the link, and the mapping of a scan or lidar turn: [`Session::insert`], the
//! sampler for the rest of the scan period (its budget, [`Budget`]), the scan's report and
//! tiles.

use embedded_io::Write;
use ogm_core::config::Budget;
use ogm_core::lidar::link::Step;
use ogm_core::lidar::turn::{Taken, Turn};
use ogm_core::localize::Correction;
use ogm_core::session::{Session, Storage};
use ogm_core::wire::{self, DeviceMsg, ErrorCode, IdleReport, ScanRanges, ScanReport};
use ogm_core::Pose;

use super::lidar::Lidar;
use super::stream::mark_dirty;
use super::{After, Hold, State, EDGE};
use crate::platform::{Platform, Work};

/// Sampler updates in the first call of a time budget, and the fewest in any call after it.
const CHUNK: u32 = 16;

/// The most sampler updates in one call under a time budget (~1.6 M instructions): the clock
/// is read at least this often.
const MAX_CHUNK: u32 = 4096;

impl<S: Storage> State<'_, S> {
    /// A pose from the link: placed into the lidar's track; maps the turns it completes.
    fn on_pose<W: Write, P: Platform>(
        &mut self,
        lidar: &mut Lidar<'_>,
        link: &mut W,
        platform: &mut P,
        t_us: u64,
        pose: Pose,
    ) -> After {
        if self.session.is_none() {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return After::Nothing;
        }
        // A held turn waits for the host's `Resume`; a pose the track cannot keep without
        // forgetting one the lidar's packets still need means the host is not answering.
        if self.hold.is_some() && !lidar.turns.wants_poses() {
            self.release_hold(false);
        }
        let mut after = After::Nothing;
        let pushed = lidar.turns.push_pose(t_us, pose, lidar.turn, |turn| {
            let taken = self.process_turn(link, platform, &turn);
            if taken == Taken::Taken {
                after = After::Scan(turn.seq);
            }
            taken
        });
        if pushed.is_err() {
            let ms = u32::try_from(t_us / 1000).unwrap_or(u32::MAX);
            self.report_error(link, ErrorCode::PoseOrder, ms);
        }
        after
    }

    /// Maps a lidar turn like a host's scan, or holds it ([`Taken::Held`]): with
    /// [`ogm_core::config::RunConfig::window_hold`], a turn whose pose shifts the window waits,
    /// matched but unmapped, until the host has sent the entering tiles back (`Resume`,
    /// [`State::release_hold`]); [`ogm_core::lidar::turn::Turns`] then hands it out again.
    pub(super) fn process_turn<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        turn: &Turn<'_>,
    ) -> Taken {
        if let Some(h) = self.hold {
            if h.seq == turn.seq {
                let Some(answered) = h.answered else {
                    return Taken::Held;
                };
                self.hold = None;
                if let Some(m) = self.session.as_deref_mut() {
                    m.count_held_turn(answered);
                }
                // Its period starts now: the wait was not the sampler's.
                let now = platform.now();
                let prepared = Prepared {
                    t0: now.wrapping_sub(ticks(h.prepared.t0, h.prepared.tm)),
                    tm: now,
                    ..h.prepared
                };
                self.map_scan(link, platform, turn, prepared);
                return Taken::Taken;
            }
            // `Turns` hands out the held turn until it is taken; another one means the turns
            // started over (new settings): the hold is void.
            self.hold = None;
        }
        self.seq = turn.seq;
        let prepared = self.prepare_scan(link, platform, turn);
        let holds = self
            .session
            .as_deref()
            .is_some_and(|m| m.config().window_hold);
        if prepared.shifted && holds {
            self.hold = Some(Hold {
                seq: turn.seq,
                prepared,
                since: platform.now(),
                answered: None,
            });
            info!("turn {=u32}: held for the host's tiles", turn.seq);
            return Taken::Held;
        }
        self.map_scan(link, platform, turn, prepared);
        Taken::Taken
    }

    /// Lets the held turn be mapped the next time it is handed out (`answered`: the host's
    /// `Resume` came).
    pub(super) fn release_hold(&mut self, answered: bool) {
        if let Some(h) = &mut self.hold {
            h.answered.get_or_insert(answered);
        }
    }

    /// Ends a hold and maps the held turn now, with whatever came back (`answered`: because
    /// of the host's `Resume`); returns its number.
    pub(super) fn end_hold<W: Write, P: Platform>(
        &mut self,
        lidar: &mut Lidar<'_>,
        link: &mut W,
        platform: &mut P,
        answered: bool,
    ) -> Option<u32> {
        self.hold?;
        self.release_hold(answered);
        let mut mapped = None;
        lidar.turns.retry(lidar.turn, |turn| {
            let taken = self.process_turn(link, platform, &turn);
            if taken == Taken::Taken {
                mapped = Some(turn.seq);
            }
            taken
        });
        mapped
    }

    /// One step from the link.
    pub(super) fn on_step<W: Write, P: Platform>(
        &mut self,
        step: Step<'_>,
        lidar: &mut Lidar<'_>,
        link: &mut W,
        platform: &mut P,
    ) -> After {
        // A held turn waits through poses, stored tiles and damaged frames; anything else from
        // the host comes after it (`Resume`: the host has answered).
        let mut after = After::Nothing;
        match &step {
            Step::Host(wire::HostMsg::Pose { .. } | wire::HostMsg::Restore { .. })
            | Step::Error(_) => {}
            Step::Host(wire::HostMsg::Resume) => {
                return self
                    .end_hold(lidar, link, platform, true)
                    .map_or(After::Nothing, After::Scan);
            }
            _ => {
                if let Some(seq) = self.end_hold(lidar, link, platform, false) {
                    after = After::Scan(seq);
                }
            }
        }
        after.max(self.on_host_step(step, lidar, link, platform))
    }

    /// One step from the link, with no turn held.
    fn on_host_step<W: Write, P: Platform>(
        &mut self,
        step: Step<'_>,
        lidar: &mut Lidar<'_>,
        link: &mut W,
        platform: &mut P,
    ) -> After {
        match step {
            Step::Host(wire::HostMsg::Config(c)) => {
                self.apply(lidar, link, platform, c);
                After::Nothing
            }
            Step::Host(wire::HostMsg::Pose { t_us, pose }) => {
                self.on_pose(lidar, link, platform, t_us, pose)
            }
            Step::Scan {
                seq,
                pose,
                beams,
                overflow,
            } => {
                self.seq = seq;
                let scan = Turn {
                    seq,
                    pose,
                    t_us: 0,
                    beams,
                    overflow,
                };
                self.process_scan(link, platform, &scan);
                After::Scan(seq)
            }
            Step::Host(wire::HostMsg::Restore {
                tx,
                ty,
                layer,
                row,
                data,
            }) => {
                self.on_restore(link, tx, ty, layer, row, data.as_slice());
                After::Nothing
            }
            Step::Host(wire::HostMsg::Finish) => After::Finish,
            Step::Host(wire::HostMsg::Resume) => After::Nothing, // nothing held
            Step::Host(wire::HostMsg::Idle { seq, period_us }) => {
                self.idle(link, platform, seq, period_us);
                After::Idle(seq)
            }
            // `LinkRx` turns the scan framing into `Step::Scan`; it never hands it on.
            Step::Host(wire::HostMsg::ScanStart { .. } | wire::HostMsg::ScanEnd { .. }) => {
                After::Nothing
            }
            Step::Error(e) => {
                let (code, detail) = e.code();
                self.report_error(link, code, detail);
                After::Nothing
            }
        }
    }

    /// A part of a stored tile from the host: checked, assembled, and the tile restored once
    /// complete ([`Session::restore_part`]: only a tile inside the window that the robot has not
    /// mapped since it entered). Work: one part's copy, and one pass over the tile's 256 cells
    /// when it completes. Every refusal is counted in the session's `WindowReport` and reported
    /// (`ErrorCode::Restore`, a [`wire::RestoreFault`]).
    fn on_restore<W: Write>(
        &mut self,
        link: &mut W,
        tx: i32,
        ty: i32,
        layer: wire::Layer,
        row: u8,
        data: &[u8],
    ) {
        let Some(m) = self.session.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        match m.restore_part(self.restore, EDGE as u16, tx, ty, layer, row, data) {
            Ok(step) => {
                if step.dropped.is_some() {
                    let detail = wire::RestoreFault::Dropped.detail();
                    self.report_error(link, ErrorCode::Restore, detail);
                }
                if let Some((x, y)) = step.restored {
                    info!("restored tile ({=i32}, {=i32})", x, y);
                }
            }
            Err(e) => {
                warn!("restore ({=i32}, {=i32}): {}", tx, ty, e.fault());
                self.report_error(link, ErrorCode::Restore, e.fault().detail());
            }
        }
    }

    /// An idle period: the sampler alone for `period_us` of board time, then its report.
    fn idle<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        seq: u32,
        period_us: u32,
    ) {
        let Some(m) = self.session.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        let t0 = platform.now();
        let updates = match platform.fixed_updates(Work::Idle(seq)) {
            Some(n) => m.step(n),
            None => sample_until(m, platform, t0, period_us, u32::MAX),
        };
        let ticks = ticks(t0, platform.now());
        self.totals.updates += u64::from(updates);
        self.totals.sampler_ticks += u64::from(ticks);
        info!(
            "idle {=u32}: {=u32} sampler updates in {=u32} ticks",
            seq, updates, ticks
        );
        self.send(
            link,
            &DeviceMsg::Idle(IdleReport {
                seq,
                sampler_updates: updates,
                sampler_ticks: ticks,
            }),
        );
    }

    /// Ingests one scan: log-odds update with seeding, ray store, sampler, report, tiles.
    pub(crate) fn process_scan<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        scan: &Turn<'_>,
    ) {
        let prepared = self.prepare_scan(link, platform, scan);
        self.map_scan(link, platform, scan, prepared);
    }

    /// What comes before a scan is mapped: its overflow counted, its pose corrected, and the
    /// rolling window moved if the corrected pose needs it.
    fn prepare_scan<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        scan: &Turn<'_>,
    ) -> Prepared {
        let Turn {
            seq,
            ref pose,
            beams,
            overflow,
            ..
        } = *scan;
        if overflow > 0 {
            self.counters.beams_overflowed =
                self.counters.beams_overflowed.saturating_add(overflow);
            self.report_error(link, ErrorCode::ScanOverflow, overflow);
        }
        let t0 = platform.now();
        // The pose correction first (the map before this scan; `pose` is odometry): a rolling
        // window follows the corrected pose, and the insert maps at it.
        let correction = self.session.as_deref_mut().map(|m| m.correct(pose, beams));
        let tm = platform.now();
        let corrected = correction.map_or(*pose, |c| c.pose);
        // A rolling window moves before the scan that needs it is mapped (so that scan's rays
        // stay inside it), its leaving tiles streamed first.
        let shift = self
            .session
            .as_deref_mut()
            .and_then(|m| m.check_shift(&corrected, EDGE as u16));
        if let Some(shift) = &shift {
            self.shift_window(link, shift);
            let t = ticks(tm, platform.now());
            self.totals.shifts += 1;
            self.totals.max_shift_ticks = self.totals.max_shift_ticks.max(t);
            info!(
                "scan {=u32}: window shift ({=i32}, {=i32}) in {=u32} ticks",
                seq, shift.dx, shift.dy, t
            );
        }
        Prepared {
            correction,
            t0,
            tm,
            shifted: shift.is_some(),
        }
    }

    /// Maps a prepared scan: log-odds update with seeding, ray store, sampler for the rest of
    /// its period, report, tiles.
    fn map_scan<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        scan: &Turn<'_>,
        prepared: Prepared,
    ) {
        let Turn {
            seq,
            ref pose,
            t_us,
            beams,
            overflow,
        } = *scan;
        let Prepared {
            correction, t0, tm, ..
        } = prepared;
        let Some(m) = self.session.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        let corrected = correction.map_or(*pose, |c| c.pose);
        let mut report = ScanReport {
            seq,
            pose: corrected,
            odometry: *pose,
            beams: beams.len() as u32,
            beams_overflowed: overflow,
            t_us,
            match_ticks: ticks(t0, tm),
            ..ScanReport::default()
        };
        if let Some(c) = &correction {
            report.correction = m.correction_report(c);
        }
        // Log-odds update, seeding of the cells observed for the first time, ray store and
        // first-occupied refresh in one step.
        let inserted = m.insert(pose, beams);
        let t1 = platform.now();
        let updates = match platform.fixed_updates(Work::Scan(seq)) {
            Some(n) => m.step(n),
            None => run_budget(m, platform, t0),
        };
        let t2 = platform.now();
        // `store_ticks` stays 0: the ray store and the cache refresh are inside `insert_ticks`
        // (with a window shift's, as before); the match is `match_ticks`.
        (report.insert_ticks, report.sampler_ticks) = (ticks(tm, t1), ticks(t1, t2));
        report.sampler_updates = updates;
        match inserted {
            Ok(inserted) => {
                report.mapper = inserted.stats;
                report.rays_stored = inserted.rays.len() as u32;
                // The ray model changes nothing outside the box around the pose's cell and
                // every beam's end cell (computed here, after the sampler's budget).
                let (lo, hi) = inserted.changed_box();
                mark_dirty(&mut self.dirty, (lo.x, lo.y), (hi.x, hi.y));
            }
            Err(e) => {
                error!("scan {=u32}: mapper: {}", seq, e);
                self.report_error(link, ErrorCode::Map, 0);
            }
        }
        self.counters.scans = self.counters.scans.saturating_add(1);
        let t = &mut self.totals;
        t.scans += 1;
        t.beams += u64::from(report.beams);
        t.cells += u64::from(report.mapper.cells_hit + report.mapper.cells_freed);
        t.insert_ticks += u64::from(report.insert_ticks);
        t.max_insert_ticks = t.max_insert_ticks.max(report.insert_ticks);
        t.sampler_ticks += u64::from(report.sampler_ticks);
        t.updates += u64::from(updates);
        info!(
            "scan {=u32}: {=u32} beams, {=u32} cells, {=u32} rays stored in {=u32} ticks; {=u32} sampler updates in {=u32} ticks",
            seq,
            report.beams,
            report.mapper.cells_hit + report.mapper.cells_freed,
            report.rays_stored,
            report.insert_ticks,
            updates,
            report.sampler_ticks
        );
        self.send(link, &DeviceMsg::Scan(report));
        // What the lidar saw, for a live view: 360 bytes, every scan.
        let mut ranges = [0u8; wire::SCAN_RANGES_LEN];
        wire::encode_ranges(beams, &mut ranges);
        self.send(link, &DeviceMsg::Ranges(ScanRanges { seq, data: &ranges }));
        self.stream_tiles(link, false);
    }
}

/// A scan matched and its window shift made, not yet mapped.
#[derive(Clone, Copy)]
pub(super) struct Prepared {
    correction: Option<Correction>,
    /// When the scan was complete (its sampler period counts from here), and when its match
    /// was done, board ticks.
    t0: u32,
    tm: u32,
    shifted: bool,
}

fn ticks(t0: u32, t1: u32) -> u32 {
    t1.wrapping_sub(t0)
}

/// Sampler updates for one scan under the run's budget; `t0` = when the scan was complete.
fn run_budget<S: Storage, P: Platform>(m: &mut Session<S>, platform: &P, t0: u32) -> u32 {
    match m.config().budget {
        Budget::Fixed { updates } => m.step(updates),
        Budget::Time {
            period_us,
            max_updates,
        } => sample_until(m, platform, t0, period_us, max_updates),
    }
}

/// Sampler updates until `period_us` of board time after `t0` or `max_updates`, whichever comes
/// first; returns how many.
///
/// Each call re-reads the sampler's window (its segment's rows, ~400 instructions), so calls
/// of [`CHUNK`] updates cost ~10 % more per update than the sampler's own rate; after the first
/// call, each asks for the updates that fit in half of the time left at the rate measured so
/// far (at least [`CHUNK`], at most [`MAX_CHUNK`]): about a dozen calls per budget, and the
/// period is overrun by at most one call's worth of the rate's error.
fn sample_until<S: Storage, P: Platform>(
    m: &mut Session<S>,
    platform: &P,
    t0: u32,
    period_us: u32,
    max_updates: u32,
) -> u32 {
    // Ticks fit a u32 for periods up to 171 s at 25 MHz; longer ones are cut there.
    let period = P::ticks_in_us(u64::from(period_us));
    let start = platform.now();
    let mut done = 0u32;
    loop {
        let now = platform.now();
        let elapsed = now.wrapping_sub(t0);
        if done >= max_updates || elapsed >= period {
            return done;
        }
        // Ticks per update so far (in 32 bits: no 64-bit division in the image); none before
        // the first call returns. elapsed < period, so the time left is positive.
        let n = match now.wrapping_sub(start).checked_div(done) {
            Some(per_update) => {
                ((period - elapsed) / per_update.max(1).saturating_mul(2)).clamp(CHUNK, MAX_CHUNK)
            }
            None => CHUNK,
        };
        done += m.step(n.min(max_updates - done));
    }
}
