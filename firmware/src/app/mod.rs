//! The application: board-independent. It sees the board only through `embedded_io` traits and
//! [`Platform`], its memory only through [`Memory`].
//!
//! Main loop ([`crate::run`]): bytes from the lidar's UART →
//! [`ogm_core::lidar::ld06::Ld06Parser`] or [`ogm_core::lidar::rplidar::RplidarParser`], as the
//! settings say ([`RunConfig::lidar`]) → [`ogm_core::lidar::turn::Turns`] (packets or nodes
//! placed by the timestamped poses from the link, motion-compensated turns), and bytes from the
//! link → [`LinkRx`] (settings, poses, and scans a host tunnels with their own pose) → for each
//! scan or turn: [`Session::insert`] (log-odds update, seeding of newly observed cells into the
//! sampler, rays into the store when the data term reads them) → sampler steps for the rest of
//! the scan period (bounded, see [`ogm_core::config::Budget`]) → report the scan, stream changed
//! tiles. `Finish` from the host: stream everything still unsent, statistics, `Done`.
//!
//! Determinism: nothing here depends on timing except the *number* of sampler updates under a
//! time budget, and that number goes into the stream ([`ogm_core::wire::ScanReport::sampler_updates`]);
//! the host runs this same code on the same bytes with those counts
//! ([`Platform::fixed_updates`]) and must stream the identical map (`host-sim firmware`).
//!
//! * this module — [`App`] and [`Memory`]: what the main loop calls;
//! * `lidar` — the lidar on the robot's own UART: its parser, turns and counters;
//! * `config` — `Hello`, the settings (the engine built once), [`STORED_CONFIG`];
//! * `scan` — a step from the link, a scan or turn mapped, the sampler under its budget;
//! * `stream` — frames out: reports, errors, tiles, the closing summary.

mod config;
mod lidar;
mod scan;
mod stream;

use crate::sizes::APP as SIZES;
use embedded_io::Write;
use ogm_core::config::{LidarModel, RunConfig};
use ogm_core::lidar::link::LinkRx;
use ogm_core::lidar::turn::Turns;
use ogm_core::session::{Buffers, Session, Sizes, Storage, TileRestore};
use ogm_core::wire::{self, Counters, ErrorCode};
use ogm_core::ScanBuf;

use crate::platform::Platform;
use lidar::Lidar;

pub use config::STORED_CONFIG;
pub(crate) use stream::write_all;

/// The application: the link receiver, the lidar's parser and turns, their buffers and the
/// [`State`].
pub struct App<'a, S: Storage> {
    rx: LinkRx,
    pub(crate) scan: &'a mut ScanBuf<MAX_BEAMS>,
    lidar: Lidar<'a>,
    pub(crate) state: State<'a, S>,
}

impl<'a, S: Storage> App<'a, S> {
    /// The application over `memory`, not yet configured.
    pub fn new(memory: Memory<'a, S>) -> Self {
        let sizes = memory.buffers.sizes();
        App {
            rx: LinkRx::new(),
            scan: memory.scan,
            lidar: Lidar::new(memory.turns, memory.turn),
            state: State {
                session: None,
                slot: Some(memory.session),
                spare: Some(memory.buffers),
                sizes,
                tx: memory.tx,
                tile: memory.tile,
                restore: memory.restore,
                dirty: [0; DIRTY_WORDS],
                dirty_cursor: 0,
                count_cursor: 0,
                counters: Counters::default(),
                seq: 0,
                totals: Totals::default(),
                stack_config: 0,
                hold: None,
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
    /// still need (see [`Turns::wants_poses`]), or a turn is held for the host's answer.
    pub fn wants_link(&self) -> bool {
        self.state.hold.is_some() || self.lidar.turns.wants_poses()
    }

    /// Maps a turn held for longer than [`HOLD_US`] without the host's answer; returns its
    /// number if it did. The main loop calls it every time round.
    pub fn check_hold<W: Write, P: Platform>(&mut self, link: &mut W, platform: &mut P) -> Fed {
        let Some(h) = self.state.hold else {
            return Fed::Nothing;
        };
        if platform.now().wrapping_sub(h.since) < P::ticks_in_us(HOLD_US) {
            return Fed::Nothing;
        }
        warn!(
            "turn {=u32}: no answer from the host, mapped without it",
            h.seq
        );
        match self.state.end_hold(&mut self.lidar, link, platform, false) {
            Some(seq) => {
                self.report(link);
                Fed::Scan(seq)
            }
            None => Fed::Nothing,
        }
    }

    /// The lidar the settings just named, once: the main loop sets its UART's baud rate and
    /// starts it (`run::start_lidar`).
    pub fn take_lidar_setup(&mut self) -> Option<LidarModel> {
        self.lidar.setup.take()
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
    /// A stored tile the host is sending back, being assembled (768 B of cells).
    pub restore: &'a mut TileRestore,
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

/// Everything but the receiver.
pub(crate) struct State<'a, S: Storage> {
    session: Option<&'a mut Session<S>>,
    slot: Option<&'a mut Option<Session<S>>>,
    spare: Option<Buffers<S>>,
    sizes: Sizes,
    tx: &'a mut [u8; wire::MAX_DEVICE_FRAME],
    tile: &'a mut [u8; wire::MAX_TILE_BYTES],
    restore: &'a mut TileRestore,
    dirty: [u32; DIRTY_WORDS],
    dirty_cursor: usize,
    count_cursor: usize,
    counters: Counters,
    seq: u32,
    totals: Totals,
    stack_config: u32,
    /// The lidar turn held for the host's answer to a window shift, if any.
    hold: Option<Hold>,
}

/// A lidar turn held after its window shift ([`RunConfig::window_hold`]): matched, the shift
/// made and announced, waiting for the host's stored tiles and `Resume`.
#[derive(Clone, Copy)]
struct Hold {
    seq: u32,
    prepared: scan::Prepared,
    /// When the hold began, board ticks ([`HOLD_US`] later it ends unanswered).
    since: u32,
    /// `Some` once released: whether the host answered.
    answered: Option<bool>,
}

/// The longest a turn waits for the host's answer to a window shift, µs: a host that sends
/// the tiles back at 921 600 baud needs ~0.7 s for a shift's 64 tiles; past this the robot
/// maps without them (counted in `WindowReport::holds_unanswered`). The lidar waits in the
/// turn queue (~140 ms of LD06) and the UART's ring meanwhile.
pub const HOLD_US: u64 = 1_000_000;

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
    /// Window shifts, and the dearest one (streaming its leaving tiles and moving the
    /// window), ticks.
    shifts: u32,
    max_shift_ticks: u32,
}

/// Beams per scan buffer.
pub const MAX_BEAMS: usize = SIZES.max_beams;
const EDGE: usize = SIZES.tile_edge as usize;
const WIDTH: usize = SIZES.width as usize;
const HEIGHT: usize = SIZES.height as usize;
const TILES_X: usize = WIDTH.div_ceil(EDGE);
const TILES_Y: usize = HEIGHT.div_ceil(EDGE);
const TILES: usize = TILES_X * TILES_Y;
const DIRTY_WORDS: usize = TILES.div_ceil(32);
