//! The application: board-independent. It sees the board only through `embedded_io` traits and
//! [`Platform`], its memory only through [`Memory`].
//!
//! Main loop ([`run`]): bytes from the lidar's UART → [`Ld06Parser`] or [`RplidarParser`], as
//! the settings say ([`RunConfig::lidar`]) → [`Turns`] (packets or nodes placed by the
//! timestamped poses from the link, motion-compensated turns), and bytes from the
//! link → [`LinkRx`] (settings, poses, and scans a host tunnels with their own pose) → for each
//! scan or turn: [`Session::insert`] (log-odds update, seeding of newly
//! observed cells into the sampler, rays into the store when the data term reads them) →
//! sampler steps for the rest of the scan period (bounded, see [`Budget`]) → report the scan,
//! stream changed tiles. `Finish` from the host: stream everything still unsent, statistics,
//! `Done`.
//!
//! Determinism: nothing here depends on timing except the *number* of sampler updates under a
//! time budget, and that number goes into the stream ([`ScanReport::sampler_updates`]); the host
//! runs this same code on the same bytes with those counts ([`Platform::fixed_updates`]) and
//! must stream the identical map (`host-sim firmware`).

use crate::sizes::APP as SIZES;
use embedded_io::{Read, ReadReady, Write};
use ogm_core::config::{Budget, LidarModel, PoseInput, RunConfig};
use ogm_core::lidar::ld06::Ld06Parser;
use ogm_core::lidar::link::{LinkRx, Step};
#[cfg(feature = "rplidar")]
use ogm_core::lidar::rplidar::{self, RplidarParser};
use ogm_core::lidar::turn::{Turn, Turns};
use ogm_core::session::{Buffers, Session, Sizes, Storage};
use ogm_core::wire::{
    self, ConfigFault, Counters, DeviceError, DeviceMsg, Done, ErrorCode, Hello, IdleReport, Layer,
    LidarCounters, LinkCounters, ScanRanges, ScanReport, Tile, TileRect,
};
use ogm_core::{Pose, ScanBuf};

use crate::platform::{LidarPort, Platform, Work};
use crate::selftest;

/// Beams per scan buffer.
pub const MAX_BEAMS: usize = SIZES.max_beams;
const EDGE: usize = SIZES.tile_edge as usize;
const WIDTH: usize = SIZES.width as usize;
const HEIGHT: usize = SIZES.height as usize;
const TILES_X: usize = WIDTH.div_ceil(EDGE);
const TILES_Y: usize = HEIGHT.div_ceil(EDGE);
const TILES: usize = TILES_X * TILES_Y;
const DIRTY_WORDS: usize = TILES.div_ceil(32);

/// Sampler updates in the first call of a time budget, and the fewest in any call after it.
const CHUNK: u32 = 16;

/// The most sampler updates in one call under a time budget (~1.6 M instructions): the clock
/// is read at least this often.
const MAX_CHUNK: u32 = 4096;

/// How long to wait at boot for the first byte from a host before running the self-test.
const HOST_WAIT_US: u64 = 100_000;

/// Everything the application works in, placed by the board (`static`s there, `Box`es on the
/// host). The grid is [`crate::sizes::APP`]'s `width × height`.
pub struct Memory<'a, S: Storage> {
    /// The engine's buffers.
    pub buffers: Buffers<S>,
    /// Where the engine is built once the settings arrive (its ~2.5 KiB stay off the stack).
    pub session: &'a mut Option<Session<S>>,
    /// The scan being received from the host.
    pub scan: &'a mut ScanBuf<MAX_BEAMS>,
    /// The lidar turn being assembled.
    pub turn: &'a mut ScanBuf<MAX_BEAMS>,
    /// Lidar packets waiting for their pose, and the poses.
    pub turns: &'a mut Turns,
    /// One encoded outgoing frame.
    pub tx: &'a mut [u8; wire::MAX_DEVICE_FRAME],
    /// One tile's cells, before encoding.
    pub tile: &'a mut [u8; wire::MAX_TILE_BYTES],
}

/// What [`App::feed`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fed {
    /// Nothing that ends a step.
    Nothing,
    /// Scan `seq` was mapped, reported and streamed.
    Scan(u32),
    /// Idle period `seq` was sampled and reported.
    Idle(u32),
    /// The host sent `Finish`; the run is over with this exit code.
    Finished(i32),
}

/// What one link step asks of the main loop.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum After {
    Nothing,
    Scan(u32),
    Idle(u32),
    Finish,
}

/// Sums for the closing summary.
#[derive(Default)]
struct Totals {
    scans: u32,
    beams: u64,
    cells: u64,
    insert_ticks: u64,
    sampler_ticks: u64,
    updates: u64,
    max_insert_ticks: u32,
}

/// The application: the link receiver, the lidar's parser and turns, their buffers and the
/// [`State`].
pub struct App<'a, S: Storage> {
    rx: LinkRx,
    pub(crate) scan: &'a mut ScanBuf<MAX_BEAMS>,
    lidar: Lidar<'a>,
    pub(crate) state: State<'a, S>,
}

/// The lidar on the robot's own UART.
struct Lidar<'a> {
    parser: Parser,
    turns: &'a mut Turns,
    turn: &'a mut ScanBuf<MAX_BEAMS>,
    bad_packets: u32,
    before_config: u32,
    /// Settings the UART has not been set up for yet ([`App::take_lidar_setup`]).
    setup: Option<LidarModel>,
}

/// The parser of the lidar the settings name (an LD06's until they arrive).
#[cfg_attr(not(feature = "rplidar"), allow(dead_code))] // `Rplidar` holds no value then
enum Parser {
    Ld06(Ld06Parser),
    Rplidar(RplidarSlot),
}

/// An RPLIDAR parser in an image built with the `rplidar` feature; without it, a type with no
/// values, so the compiler drops the RPLIDAR code (its settings are refused:
/// [`ConfigFault::Lidar`]).
#[cfg(feature = "rplidar")]
type RplidarSlot = RplidarParser;
#[cfg(not(feature = "rplidar"))]
type RplidarSlot = core::convert::Infallible;

/// Whether this image can read `model`.
const fn built_for(model: &LidarModel) -> bool {
    match model {
        LidarModel::Ld06 => true,
        LidarModel::Rplidar { .. } => cfg!(feature = "rplidar"),
    }
}

/// What a lidar parser handed out.
enum Unit {
    Packet(ogm_core::lidar::ld06::Packet),
    #[cfg(feature = "rplidar")]
    Node(rplidar::Node),
}

impl Lidar<'_> {
    /// Starts over with the settings' lidar, mounting and pose source.
    fn configure(&mut self, config: &RunConfig) {
        *self.turns = Turns::configured(config);
        self.turn.clear();
        self.parser = match config.lidar {
            #[cfg(feature = "rplidar")]
            LidarModel::Rplidar { .. } => Parser::Rplidar(RplidarParser::new()),
            // Refused before this (`built_for`) when the image has no RPLIDAR parser.
            _ => Parser::Ld06(Ld06Parser::new()),
        };
        self.setup = Some(config.lidar);
    }

    fn counters(&self) -> LidarCounters {
        let t = self.turns.counters();
        LidarCounters {
            packets: t.packets.saturating_add(self.before_config),
            bad_packets: self.bad_packets,
            packets_before_config: self.before_config,
            turns: t.turns,
            packets_without_pose: t.packets_without_pose,
            packets_overflowed: t.packets_overflowed,
            poses: t.poses,
            poses_out_of_order: t.poses_out_of_order,
        }
    }
}

/// Everything but the receiver.
pub(crate) struct State<'a, S: Storage> {
    session: Option<&'a mut Session<S>>,
    slot: Option<&'a mut Option<Session<S>>>,
    spare: Option<Buffers<S>>,
    sizes: Sizes,
    tx: &'a mut [u8; wire::MAX_DEVICE_FRAME],
    tile: &'a mut [u8; wire::MAX_TILE_BYTES],
    dirty: [u32; DIRTY_WORDS],
    dirty_cursor: usize,
    count_cursor: usize,
    counters: Counters,
    seq: u32,
    totals: Totals,
    stack_config: u32,
}

/// Encodes `msg` into `tx` and writes it to `link`; failures are logged.
fn send<W: Write>(tx: &mut [u8], link: &mut W, msg: &DeviceMsg<'_>) {
    match wire::encode(msg, tx) {
        Ok(bytes) => {
            if !write_all(link, bytes) {
                error!("link: write failed");
            }
        }
        Err(e) => error!("link: cannot encode a frame: {}", e),
    }
}

/// Writes all of `bytes`; `false` if the writer failed, wrote nothing or claimed more than it was
/// given. Not `embedded_io::Write::write_all`: that one panics on a writer's `Ok(0)` and slices
/// with the writer's count, and its panic messages alone pull `core::fmt` (~2.3 KiB) into the
/// image.
fn write_all<W: Write>(w: &mut W, mut bytes: &[u8]) -> bool {
    while !bytes.is_empty() {
        match w.write(bytes) {
            Ok(n) if n > 0 => match bytes.get(n..) {
                Some(rest) => bytes = rest,
                None => return false,
            },
            _ => return false,
        }
    }
    true
}

fn ticks(t0: u32, t1: u32) -> u32 {
    t1.wrapping_sub(t0)
}

impl<'a, S: Storage> App<'a, S> {
    /// The application over `memory`, not yet configured.
    pub fn new(memory: Memory<'a, S>) -> Self {
        let sizes = memory.buffers.sizes();
        App {
            rx: LinkRx::new(),
            scan: memory.scan,
            lidar: Lidar {
                parser: Parser::Ld06(Ld06Parser::new()),
                turns: memory.turns,
                turn: memory.turn,
                bad_packets: 0,
                before_config: 0,
                setup: None,
            },
            state: State {
                session: None,
                slot: Some(memory.session),
                spare: Some(memory.buffers),
                sizes,
                tx: memory.tx,
                tile: memory.tile,
                dirty: [0; DIRTY_WORDS],
                dirty_cursor: 0,
                count_cursor: 0,
                counters: Counters::default(),
                seq: 0,
                totals: Totals::default(),
                stack_config: 0,
            },
        }
    }

    /// The engine, once configured.
    pub fn session(&self) -> Option<&Session<S>> {
        self.state.session.as_deref()
    }

    /// The device's counters so far.
    pub fn counters(&self) -> Counters {
        self.state.counters
    }

    /// The boot message with the compile-time sizes.
    pub fn hello<W: Write, P: Platform>(&mut self, link: &mut W, platform: &P) {
        let _ = platform; // only its type: name and tick rate
        self.state.hello::<W, P>(link);
    }

    /// Applies settings as if the host had sent them (the self-test; a robot's stored
    /// defaults).
    pub fn configure<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        config: RunConfig,
    ) {
        self.state.apply(&mut self.lidar, link, platform, config);
    }

    /// Whether the lidar's UART may be read: the settings are in, and its packets have room to
    /// wait for their poses (otherwise the board leaves the bytes in its receive buffer, so
    /// none is lost where the UART holds them back, as QEMU's does).
    pub fn wants_lidar(&self) -> bool {
        self.state.session.is_some() && self.lidar.turns.wants_packets()
    }

    /// How many link bytes the main loop may read at once (at most `chunk`): all of them while
    /// the pose track has room for every pose they can hold, else one, so that
    /// [`App::wants_link`] is asked again before each pose that could push out one the lidar
    /// still needs.
    pub fn link_read_len(&self, chunk: usize) -> usize {
        if self.lidar.turns.pose_room() > chunk / wire::MIN_POSE_FRAME + 1 {
            chunk
        } else {
            1
        }
    }

    /// Whether the link may be read: a pose from it would not push out one the lidar's packets
    /// still need (see [`Turns::wants_poses`]).
    pub fn wants_link(&self) -> bool {
        self.lidar.turns.wants_poses()
    }

    /// The lidar the settings just named, once: the main loop sets its UART's baud rate and
    /// starts it ([`start_lidar`]).
    pub fn take_lidar_setup(&mut self) -> Option<LidarModel> {
        self.lidar.setup.take()
    }

    /// Feeds bytes from the lidar's UART: packets or nodes are placed by the poses from the
    /// link, and each finished turn is mapped, sampled, reported and streamed like a host's
    /// scan. Returns the last turn completed, if any.
    pub fn feed_lidar<W: Write, P: Platform>(
        &mut self,
        bytes: &[u8],
        link: &mut W,
        platform: &mut P,
    ) -> Fed {
        let mut fed = Fed::Nothing;
        let (state, lidar) = (&mut self.state, &mut self.lidar);
        let mut done = None;
        for &b in bytes {
            let Lidar {
                parser,
                turns,
                turn,
                bad_packets,
                before_config,
                ..
            } = &mut *lidar;
            // One copy of the mapping path, whichever parser calls it (flash).
            let unit: &mut dyn FnMut(Result<Unit, ()>) = &mut |u| {
                let u = match u {
                    Ok(u) => u,
                    Err(()) => return *bad_packets = bad_packets.saturating_add(1),
                };
                if state.session.is_none() {
                    return *before_config = before_config.saturating_add(1);
                }
                let mut f = |t: Turn<'_>| done = Some(state.process_turn(link, platform, &t));
                match u {
                    Unit::Packet(p) => turns.push_packet(&p, turn, &mut f),
                    #[cfg(feature = "rplidar")]
                    Unit::Node(n) => turns.push_node(&n, turn, &mut f),
                }
            };
            match parser {
                Parser::Ld06(p) => match p.push(b) {
                    None => {}
                    Some(r) => unit(r.map(Unit::Packet).map_err(drop)),
                },
                #[cfg(feature = "rplidar")]
                Parser::Rplidar(p) => p.push(b, |e| match e {
                    Ok(rplidar::Event::Node(n)) => unit(Ok(Unit::Node(n))),
                    Ok(_) => {} // descriptors and responses: nothing to map
                    Err(_) => unit(Err(())),
                }),
                #[cfg(not(feature = "rplidar"))]
                Parser::Rplidar(never) => match *never {},
            }
            if let Some(seq) = done.take() {
                let (l, d) = (self.rx.counters(), lidar.counters());
                state.report(link, l, d);
                fed = Fed::Scan(seq);
            }
        }
        fed
    }

    /// Sampler/store statistics and every counter (link and lidar as of now).
    pub(crate) fn report<W: Write>(&mut self, link: &mut W) {
        let (l, d) = (self.rx.counters(), self.lidar.counters());
        self.state.report(link, l, d);
    }

    /// End of the run (see [`State::finish`]) with every counter as of now.
    pub(crate) fn finish<W: Write, P: Platform>(&mut self, link: &mut W, platform: &P) -> i32 {
        let (l, d) = (self.rx.counters(), self.lidar.counters());
        self.state.finish(link, platform, l, d)
    }

    /// Counts a UART receive error and reports it.
    pub fn uart_error<W: Write>(&mut self, link: &mut W) {
        let s = &mut self.state;
        s.counters.uart_errors = s.counters.uart_errors.saturating_add(1);
        s.report_error(link, ErrorCode::Uart, 0);
    }

    /// Feeds bytes from the link: maps, samples, reports and streams whatever they complete.
    /// Stops at `Finish` (the rest of `bytes` is ignored) and returns [`Fed::Finished`];
    /// otherwise the last scan or idle period completed, if any.
    pub fn feed<W: Write, P: Platform>(
        &mut self,
        bytes: &[u8],
        link: &mut W,
        platform: &mut P,
    ) -> Fed {
        let mut fed = Fed::Nothing;
        for &b in bytes {
            let mut after = After::Nothing;
            let (state, lidar) = (&mut self.state, &mut self.lidar);
            self.rx.feed(core::slice::from_ref(&b), self.scan, |step| {
                after = after.max(state.on_step(step, lidar, link, platform));
            });
            match after {
                After::Nothing => {}
                After::Scan(seq) | After::Idle(seq) => {
                    self.report(link);
                    fed = if matches!(after, After::Scan(_)) {
                        Fed::Scan(seq)
                    } else {
                        Fed::Idle(seq)
                    };
                }
                After::Finish => return Fed::Finished(self.finish(link, platform)),
            }
        }
        fed
    }
}

impl<S: Storage> State<'_, S> {
    fn send<W: Write>(&mut self, link: &mut W, msg: &DeviceMsg<'_>) {
        send(&mut self.tx[..], link, msg);
    }

    fn report_error<W: Write>(&mut self, link: &mut W, code: ErrorCode, detail: u32) {
        self.counters.errors = self.counters.errors.saturating_add(1);
        warn!(
            "error {} (scan {=u32}, detail {=u32})",
            code, self.seq, detail
        );
        let seq = self.seq;
        self.send(link, &DeviceMsg::Error(DeviceError { code, seq, detail }));
    }

    fn hello<W: Write, P: Platform>(&mut self, link: &mut W) {
        let hello = Hello {
            firmware: concat!("ogm-firmware ", env!("CARGO_PKG_VERSION")),
            board: P::NAME,
            tick_hz: P::TICK_HZ,
            width: self.sizes.width,
            height: self.sizes.height,
            tile_edge: SIZES.tile_edge,
            max_beams: MAX_BEAMS as u32,
            ray_capacity: self.sizes.rays as u32,
            scan_capacity: self.sizes.scans as u32,
            local_capacity: self.sizes.local as u32,
            count_max: u32::from(u8::MAX),
        };
        self.send(link, &DeviceMsg::Hello(hello));
    }

    /// Applies the host's settings (once; a repeat of the settings in use is ignored — the host
    /// repeats its frames on a noisy link). Whether they were applied now.
    fn configure<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        config: RunConfig,
    ) -> bool {
        let Some(bufs) = self.spare.take() else {
            if self.session.as_ref().is_some_and(|m| *m.config() == config) {
                return false;
            }
            self.report_error(link, ErrorCode::ConfigTwice, 0);
            return false;
        };
        // The tile stream is cut for the firmware's grid.
        if (usize::from(bufs.width), usize::from(bufs.height)) != (WIDTH, HEIGHT) {
            let detail = ConfigFault::Geometry.detail();
            self.report_error(link, ErrorCode::BadConfig, detail);
            return false;
        }
        if !(config.lidar.is_valid() && built_for(&config.lidar)) {
            let detail = ConfigFault::Lidar.detail();
            self.report_error(link, ErrorCode::BadConfig, detail);
            return false;
        }
        let Some(slot) = self.slot.take() else {
            let detail = ConfigFault::NoRoom.detail();
            self.report_error(link, ErrorCode::BadConfig, detail);
            return false;
        };
        match build(slot, config, bufs) {
            Ok(m) => {
                // The fields a log reader needs (the whole settings' formatter is ~0.7 KiB of
                // flash; the host has them anyway, echoed in `Configured`).
                info!(
                    "config: {=u32} mm cells, seed {=u64}, {}, {}",
                    config.cell_mm, config.seed, config.lidar, config.budget
                );
                self.session = Some(m);
                // Building the sampler is the deepest the stack ever gets (copies of its 2 KiB
                // forward-model tables); note it, then measure the mapping loop on its own.
                self.stack_config = platform.stack_usage().used;
                platform.repaint_stack();
                self.send(link, &DeviceMsg::Configured(config));
                true
            }
            Err(e) => {
                // The part, not the whole error (its formatter is ~0.2 KiB of flash).
                error!("config rejected: {}", e.fault());
                self.report_error(link, ErrorCode::BadConfig, e.fault().detail());
                false
            }
        }
    }

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
        let mut after = After::Nothing;
        let pushed = lidar.turns.push_pose(t_us, pose, lidar.turn, |turn| {
            after = After::Scan(self.process_turn(link, platform, &turn));
        });
        if pushed.is_err() {
            let ms = u32::try_from(t_us / 1000).unwrap_or(u32::MAX);
            self.report_error(link, ErrorCode::PoseOrder, ms);
        }
        after
    }

    /// Maps a lidar turn like a host's scan; returns its number.
    fn process_turn<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &mut P,
        turn: &Turn<'_>,
    ) -> u32 {
        self.seq = turn.seq;
        self.process_scan(link, platform, turn);
        turn.seq
    }

    /// Applies settings to the engine and, if they were taken now, to the lidar's turns.
    fn apply<W: Write, P: Platform>(
        &mut self,
        lidar: &mut Lidar<'_>,
        link: &mut W,
        platform: &mut P,
        config: RunConfig,
    ) {
        if self.configure(link, platform, config) {
            lidar.configure(&config);
        }
    }

    /// One step from the link.
    fn on_step<W: Write, P: Platform>(
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
            Step::Host(wire::HostMsg::Finish) => After::Finish,
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
        let Turn {
            seq,
            ref pose,
            t_us,
            beams,
            overflow,
        } = *scan;
        if overflow > 0 {
            self.counters.beams_overflowed =
                self.counters.beams_overflowed.saturating_add(overflow);
            self.report_error(link, ErrorCode::ScanOverflow, overflow);
        }
        let Some(m) = self.session.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        let mut report = ScanReport {
            seq,
            pose: *pose,
            beams: beams.len() as u32,
            beams_overflowed: overflow,
            t_us,
            ..ScanReport::default()
        };
        let t0 = platform.now();
        // Log-odds update, seeding of the cells observed for the first time, ray store and
        // first-occupied refresh in one step.
        let inserted = m.insert_rays(pose, beams);
        let t1 = platform.now();
        let updates = match platform.fixed_updates(Work::Scan(seq)) {
            Some(n) => m.step(n),
            None => run_budget(m, platform, t0),
        };
        let t2 = platform.now();
        // `store_ticks` stays 0: the ray store and the cache refresh are inside `insert_ticks`.
        (report.insert_ticks, report.sampler_ticks) = (ticks(t0, t1), ticks(t1, t2));
        report.sampler_updates = updates;
        let geometry = m.geometry();
        let mapper_config = *m.mapper().config();
        match inserted {
            Ok((stats, range)) => {
                report.set_scan_stats(&stats);
                report.rays_stored = range.len() as u32;
            }
            Err(e) => {
                error!("scan {=u32}: mapper: {}", seq, e);
                self.report_error(link, ErrorCode::Map, 0);
            }
        }
        // The ray model changes nothing outside the box around the pose's cell and every
        // beam's end cell.
        let (lo, hi) = ogm_core::map::mapper::scan_box(&geometry, &mapper_config, pose, beams);
        mark_dirty(&mut self.dirty, (lo.x, lo.y), (hi.x, hi.y));
        self.counters.scans = self.counters.scans.saturating_add(1);
        let t = &mut self.totals;
        t.scans += 1;
        t.beams += u64::from(report.beams);
        t.cells += u64::from(report.cells_hit + report.cells_freed);
        t.insert_ticks += u64::from(report.insert_ticks);
        t.max_insert_ticks = t.max_insert_ticks.max(report.insert_ticks);
        t.sampler_ticks += u64::from(report.sampler_ticks);
        t.updates += u64::from(updates);
        info!(
            "scan {=u32}: {=u32} beams, {=u32} cells, {=u32} rays stored in {=u32} ticks; {=u32} sampler updates in {=u32} ticks",
            seq,
            report.beams,
            report.cells_hit + report.cells_freed,
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

    /// Sends changed log-odds tiles and marginal-count tiles: the per-scan quota, or (`all`)
    /// every changed log-odds tile and every count and sample tile.
    fn stream_tiles<W: Write>(&mut self, link: &mut W, all: bool) {
        let Some(m) = self.session.as_deref() else {
            return;
        };
        let (quota, count_quota) = if all {
            (TILES, TILES)
        } else {
            (
                usize::from(m.config().tiles_per_scan),
                usize::from(m.config().count_tiles_per_scan),
            )
        };
        let (tx, tile) = (&mut self.tx[..], &mut self.tile[..]);
        let mut sent = 0;
        let start = self.dirty_cursor;
        for k in 0..TILES {
            if sent >= quota {
                break;
            }
            let t = (start + k) % TILES;
            let (w, bit) = (t / 32, 1u32 << (t % 32));
            if self.dirty.get(w).is_some_and(|d| d & bit != 0) {
                send_tile(tx, tile, link, m, Layer::LogOdds, t);
                if let Some(d) = self.dirty.get_mut(w) {
                    *d &= !bit;
                }
                sent += 1;
                self.dirty_cursor = (t + 1) % TILES;
            }
        }
        for _ in 0..count_quota.min(TILES) {
            let t = self.count_cursor;
            send_tile(tx, tile, link, m, Layer::Counts, t);
            self.count_cursor = (t + 1) % TILES;
        }
        if all {
            for t in 0..TILES {
                send_tile(tx, tile, link, m, Layer::Sample, t);
            }
        }
    }

    /// Sampler/store statistics and counters.
    fn report<W: Write>(
        &mut self,
        link: &mut W,
        link_counters: LinkCounters,
        lidar: LidarCounters,
    ) {
        self.counters.link = link_counters;
        self.counters.lidar = lidar;
        if let Some(m) = self.session.as_deref() {
            let r = m.sampler_report();
            send(&mut self.tx[..], link, &DeviceMsg::Sampler(r));
        }
        let c = self.counters;
        self.send(link, &DeviceMsg::Counters(c));
    }

    /// End of the run: everything still unsent, statistics, `Done`; returns the exit code.
    fn finish<W: Write, P: Platform>(
        &mut self,
        link: &mut W,
        platform: &P,
        link_counters: LinkCounters,
        lidar: LidarCounters,
    ) -> i32 {
        self.stream_tiles(link, true);
        self.report(link, link_counters, lidar);
        let stack = platform.stack_usage();
        let mut done = Done {
            scans: self.counters.scans,
            stack_used: stack.used,
            stack_size: stack.size,
            stack_config: self.stack_config,
            ..Done::default()
        };
        if let Some(m) = self.session.as_deref() {
            done.grid_fnv = wire::grid_fnv(m.log_odds());
            done.counts_fnv = (0..m.log_odds().len()).fold(wire::FNV_START, |h, i| {
                wire::fnv1a(h, &[wire::TileSource::count(m, i)])
            });
        }
        self.send(link, &DeviceMsg::Done(done));
        let _ = link.flush();
        self.summary::<P>(&done);
        0
    }

    fn summary<P: Platform>(&self, done: &Done) {
        let t = &self.totals;
        let ns = |ticks: u64| P::ticks_to_ns(ticks);
        let n = u64::from(t.scans.max(1));
        info!(
            "done: {=u32} scans, {=u32} errors; grid fnv {=u32:08x}, counts fnv {=u32:08x}",
            done.scans, self.counters.errors, done.grid_fnv, done.counts_fnv
        );
        info!(
            "stack: {=u32} B peak while building the sampler, {=u32} B in the mapping loop, of {=u32} B",
            done.stack_config, done.stack_used, done.stack_size
        );
        // Under `qemu -icount shift=0` 1 ns = 1 instruction (docs/firmware.md).
        info!(
            "insert+seed+store+refresh: {=u64} ns/scan (max {=u64}), {=u64} beams/scan, {=u64} cells/scan, {=u64} ps per updated cell",
            ns(t.insert_ticks) / n,
            ns(u64::from(t.max_insert_ticks)),
            t.beams / n,
            t.cells / n,
            ns(t.insert_ticks) * 1000 / t.cells.max(1)
        );
        info!(
            "sampler: {=u64} updates, {=u64} ps per patch update",
            t.updates,
            ns(t.sampler_ticks) * 1000 / t.updates.max(1)
        );
        if let Some(m) = self.session.as_deref() {
            info!("sampler: {}", m.sampler_report());
        }
    }
}

/// Builds the engine in `slot`. Not inlined: its temporaries (copies of the sampler's 2 KiB
/// forward-model tables) are gone before the main loop goes on.
#[inline(never)]
fn build<S: Storage>(
    slot: &mut Option<Session<S>>,
    config: RunConfig,
    bufs: Buffers<S>,
) -> Result<&mut Session<S>, ogm_core::session::SessionError> {
    Ok(slot.insert(Session::new(config, bufs)?))
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
    let period =
        (u64::from(period_us) * u64::from(P::TICK_HZ) / 1_000_000).min(u64::from(u32::MAX)) as u32;
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

/// Marks the tiles that overlap the cell box `lo ..= hi` (clipped to the grid) as changed.
fn mark_dirty(dirty: &mut [u32], lo: (i32, i32), hi: (i32, i32)) {
    let ((x0, y0), (x1, y1)) = (lo, hi);
    let (w, h) = (WIDTH as i32, HEIGHT as i32);
    if x1 < 0 || y1 < 0 || x0 >= w || y0 >= h {
        return;
    }
    let clamp = |v: i32, hi: i32| v.clamp(0, hi - 1) as usize / EDGE;
    for ty in clamp(y0, h)..=clamp(y1, h) {
        for tx in clamp(x0, w)..=clamp(x1, w) {
            let t = ty * TILES_X + tx;
            if let Some(d) = dirty.get_mut(t / 32) {
                *d |= 1 << (t % 32);
            }
        }
    }
}

/// Encodes tile `t` of `layer` ([`wire::encode_tile`]) and sends it.
fn send_tile<W: Write, S: Storage>(
    tx: &mut [u8],
    buf: &mut [u8],
    link: &mut W,
    m: &Session<S>,
    layer: Layer,
    t: usize,
) {
    let Some(rect) = TileRect::nth(WIDTH, HEIGHT, EDGE, t) else {
        return;
    };
    let data = match wire::encode_tile(m, layer, &rect, buf) {
        Ok(d) => d,
        Err(e) => {
            error!("tile {=usize}: {}", t, e);
            return;
        }
    };
    let (tx_, ty_) = rect.coords();
    let tile = Tile {
        layer,
        tx: tx_,
        ty: ty_,
        data,
    };
    send(tx, link, &DeviceMsg::Tile(tile));
}

/// Waits up to [`HOST_WAIT_US`] for the first byte from a host.
fn wait_for_host<L: ReadReady, P: Platform>(link: &mut L, platform: &P) -> bool {
    let limit = (HOST_WAIT_US * u64::from(P::TICK_HZ) / 1_000_000) as u32;
    let t0 = platform.now();
    while platform.now().wrapping_sub(t0) < limit {
        if link.read_ready().unwrap_or(false) {
            return true;
        }
    }
    false
}

/// The settings a robot maps with when no host configures it: [`RunConfig::robot`] on a grid
/// centred on where it was switched on, an LD06's range (12 m), a sampler budget of one LD06
/// turn (100 ms), and no poses (it maps as a standing sensor: [`PoseInput::Fixed`]). A
/// constant ([`RunConfig::robot_at_paper_sigma`]; a test checks it equals `RunConfig::robot`).
pub const STORED_CONFIG: RunConfig = {
    let half_w = -((WIDTH as i64 * 50 / 2) as i32);
    let half_h = -((HEIGHT as i64 * 50 / 2) as i32);
    let budget = Budget::Time {
        period_us: 100_000,
        max_updates: u32::MAX,
    };
    let robot = RunConfig::robot_at_paper_sigma((half_w, half_h), 12_000, 1, budget);
    RunConfig {
        poses: PoseInput::Fixed,
        ..robot
    }
};

/// How long the link is held back for a lidar that sends nothing before poses are taken anyway
/// (so a host is never locked out by a silent lidar), µs.
const LIDAR_SILENT_US: u64 = 200_000;

/// The firmware: hello, then the main loop over the host link and the lidar's UART. With no
/// host within [`HOST_WAIT_US`]: a robot whose lidar is talking maps with [`STORED_CONFIG`];
/// a board with neither runs the self-test. Returns the exit code (when a host sends
/// `Finish`).
pub fn run<L, R, S, P>(memory: Memory<'_, S>, link: &mut L, lidar: &mut R, platform: &mut P) -> i32
where
    L: Read + ReadReady + Write,
    R: LidarPort,
    S: Storage,
    P: Platform,
{
    let mut app = App::new(memory);
    app.hello(link, platform);
    if wait_for_host(link, platform) {
        info!("host connected");
    } else if lidar.read_ready().unwrap_or(false) {
        info!("no host on the link, lidar talking: stored settings");
        app.configure(link, platform, STORED_CONFIG);
    } else {
        info!("no host on the link: self-test");
        return selftest::run(&mut app, link, platform);
    }
    let silent = (LIDAR_SILENT_US * u64::from(P::TICK_HZ) / 1_000_000) as u32;
    let mut heard = platform.now();
    // One LD06 packet at a time (a read completes at most one), so the turn queue's room is
    // checked before every packet.
    let mut chunk = [0u8; ogm_core::lidar::ld06::PACKET_LEN];
    loop {
        if app.wants_lidar() && lidar.read_ready().unwrap_or(false) {
            match lidar.read(&mut chunk) {
                Ok(n) => {
                    app.feed_lidar(chunk.get(..n).unwrap_or(&[]), link, platform);
                    // After the turn it may have completed (mapping and sampling take time).
                    heard = platform.now();
                }
                Err(_) => app.uart_error(link),
            }
        }
        let link_open = app.wants_link() || platform.now().wrapping_sub(heard) > silent;
        if link_open && link.read_ready().unwrap_or(false) {
            let len = app.link_read_len(chunk.len());
            let n = match link.read(chunk.get_mut(..len).unwrap_or(&mut [])) {
                Ok(n) => n,
                Err(_) => {
                    app.uart_error(link);
                    continue;
                }
            };
            if let Fed::Finished(code) = app.feed(chunk.get(..n).unwrap_or(&[]), link, platform) {
                return code;
            }
        }
        if let Some(model) = app.take_lidar_setup() {
            start_lidar(lidar, platform, model);
        }
    }
}

/// Sets the lidar's UART to `model`'s baud rate and starts the sensor: an RPLIDAR gets `STOP`
/// (in case it still streams from before a reset), then after the 1 ms the protocol asks for,
/// `SCAN`; an LD06 streams on its own. A failed write is logged: the run goes on, and its
/// counters show no turns.
fn start_lidar<R: LidarPort, P: Platform>(lidar: &mut R, platform: &P, model: LidarModel) {
    lidar.set_baud(model.baud());
    if cfg!(feature = "rplidar") && matches!(model, LidarModel::Rplidar { .. }) {
        let ok = write_all(lidar, &ogm_core::lidar::rplidar::REQ_STOP) && lidar.flush().is_ok();
        // ≥ 1 ms after STOP (2 ms: the byte may still be on the wire when `flush` returns).
        let t0 = platform.now();
        let wait = (2_000 * u64::from(P::TICK_HZ) / 1_000_000) as u32;
        while platform.now().wrapping_sub(t0) < wait {}
        if !(ok && write_all(lidar, &ogm_core::lidar::rplidar::REQ_SCAN) && lidar.flush().is_ok()) {
            error!("lidar: cannot send the RPLIDAR its requests");
        }
    }
}
