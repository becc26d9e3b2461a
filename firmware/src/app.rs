//! The application: board-independent (it sees the board only through `embedded_io` traits,
//! [`Timer`] and [`board::stack_usage`]).
//!
//! Main loop ([`run`]): receive bytes on the link → [`LinkRx`] (LD06 packets + host frames →
//! scans with poses) → for each scan: log-odds update, seeding the cells it observed for the
//! first time into the sampler's sample, its rays into the ray store, first-occupied caches
//! refreshed (`ogm_core::pipeline::insert_and_seed`) → sampler steps for the rest of the scan
//! period (bounded, see [`Budget`]) → report the scan, stream changed tiles. `Finish` from the host: stream everything still unsent, statistics, `Done`.
//!
//! Determinism: nothing here depends on timing except the *number* of sampler updates under a
//! time budget, and that number goes into the stream ([`ScanReport::sampler_updates`]); the host
//! replays the same bytes through the same ogm-core code with those counts and must get the
//! identical map (`host-sim firmware`).

use defmt::{error, info, warn};
use embedded_io::{Read, ReadReady, Write};
use ogm_core::gibbs::{BorderPrior, Buffers as SamplerBuffers, Gibbs, LocalRay};
use ogm_core::link::{LinkError, LinkRx, Step};
use ogm_core::pipeline::insert_and_seed;
use ogm_core::ray_store::{RayStore, StoredRay, StoredScan};
use ogm_core::wire::firmware_sizes as sz;
use ogm_core::wire::{
    self, Budget, Counters, DeviceError, DeviceMsg, Done, ErrorCode, Hello, IdleReport, Layer,
    LinkCounters, RunConfig, SamplerReport, ScanReport, StoreReport, Tile,
};
use ogm_core::{Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, MapperConfig, Pose};

use crate::board::{self, Timer, TICK_HZ};
use crate::memory::{self, MapBuffers, BLOCK_WORDS, CELLS, MARK_WORDS, SAMPLE_WORDS};
use crate::selftest;

type MapperT = Mapper<&'static mut [LogOdds; CELLS], &'static mut [u32; MARK_WORDS]>;
type StoreT =
    RayStore<&'static mut [StoredScan; memory::SCANS], &'static mut [StoredRay; memory::RAYS]>;
type GibbsT = Gibbs<
    BorderPrior,
    &'static mut [u32; SAMPLE_WORDS],
    &'static mut [u8; CELLS],
    &'static mut [LocalRay; memory::LOCAL_RAYS],
    &'static mut [u32; BLOCK_WORDS],
    u8,
>;

const EDGE: usize = sz::TILE_EDGE as usize;
const WIDTH: usize = sz::WIDTH as usize;
const HEIGHT: usize = sz::HEIGHT as usize;
const TILES_X: usize = WIDTH.div_ceil(EDGE);
const TILES_Y: usize = HEIGHT.div_ceil(EDGE);
const TILES: usize = TILES_X * TILES_Y;
const DIRTY_WORDS: usize = TILES.div_ceil(32);

/// Sampler updates between two looks at the clock under a time budget (~16 × 900 instructions
/// = 14 µs at 1 GHz of QEMU icount; each call re-reads the sampler's window once).
const CHUNK: u32 = 16;

/// How long to wait at boot for the first byte from a host before running the self-test.
const HOST_WAIT_US: u64 = 100_000;

/// What the main loop does after a step.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum After {
    Nothing,
    ScanDone,
    Finish,
}

/// The mapping state, built when the host's settings arrive.
pub struct Machine {
    pub config: RunConfig,
    pub mapper: MapperT,
    pub store: StoreT,
    pub gibbs: GibbsT,
}

impl Machine {
    /// Builds the mapper, ray store and sampler over the static buffers, in
    /// [`memory::MACHINE`]; `Err(detail)` as in [`ErrorCode::BadConfig`]. Not inlined: its
    /// temporaries (copies of the sampler's 2 KiB forward-model tables) are gone before the
    /// main loop goes on.
    #[inline(never)]
    fn build(config: RunConfig, b: MapBuffers) -> Result<&'static mut Machine, u32> {
        let slot = memory::MACHINE.put_with(|| None).ok_or(5u32)?;
        let geometry = config.geometry(sz::WIDTH, sz::HEIGHT).map_err(|_| 0u32)?;
        let grid = LogOddsGrid::new(geometry, b.grid).map_err(|_| 0u32)?;
        let mapper = Mapper::new(grid, b.marks, config.mapper_config()).map_err(|_| 1u32)?;
        // The evidence term reads no rays: no forward-model tables to build.
        let forward = if config.data.uses_rays() {
            config.forward_model().map_err(|_| 2u32)?
        } else {
            ogm_core::forward_model::ForwardModel::pcsm()
        };
        let store = RayStore::new(
            geometry,
            config.max_range_mm,
            config.min_range_mm,
            b.scans,
            b.rays,
        )
        .map_err(|_| 3u32)?;
        let gibbs = Gibbs::new(
            geometry,
            BorderPrior::default(),
            forward,
            config.sampler_config(),
            SamplerBuffers {
                sample: b.sample,
                counts: b.counts,
                local: b.local,
                blocks: b.blocks,
            },
        )
        .map_err(|_| 4u32)?;
        let m = slot.insert(Machine {
            config,
            mapper,
            store,
            gibbs,
        });
        m.gibbs
            .reset(m.mapper.grid().cells(), &mut m.store)
            .map_err(|_| 4u32)?;
        Ok(m)
    }

    fn geometry(&self) -> GridGeometry {
        *self.mapper.grid().geometry()
    }
}

/// Sums for the closing defmt summary.
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

pub struct App {
    machine: Option<&'static mut Machine>,
    spare: Option<MapBuffers>,
    tx: &'static mut [u8; wire::MAX_DEVICE_FRAME],
    tile: &'static mut [u8; wire::MAX_TILE_BYTES],
    dirty: [u32; DIRTY_WORDS],
    dirty_cursor: usize,
    count_cursor: usize,
    counters: Counters,
    seq: u32,
    totals: Totals,
    stack_config: u32,
}

/// Encodes `msg` into `tx` and writes it to `link`; failures are logged and counted.
fn send<W: Write>(tx: &mut [u8], link: &mut W, msg: &DeviceMsg<'_>) {
    match wire::encode(msg, tx) {
        Ok(bytes) => {
            if link.write_all(bytes).is_err() {
                error!("link: write failed");
            }
        }
        Err(e) => error!("link: cannot encode a frame: {}", e),
    }
}

fn ticks(t0: u32, t1: u32) -> u32 {
    t1.wrapping_sub(t0)
}

impl App {
    pub fn new(
        map: MapBuffers,
        tx: &'static mut [u8; wire::MAX_DEVICE_FRAME],
        tile: &'static mut [u8; wire::MAX_TILE_BYTES],
    ) -> Self {
        App {
            machine: None,
            spare: Some(map),
            tx,
            tile,
            dirty: [0; DIRTY_WORDS],
            dirty_cursor: 0,
            count_cursor: 0,
            counters: Counters::default(),
            seq: 0,
            totals: Totals::default(),
            stack_config: 0,
        }
    }

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

    /// The boot message with the compile-time sizes.
    pub fn hello<W: Write>(&mut self, link: &mut W) {
        let hello = Hello {
            firmware: concat!("ogm-firmware ", env!("CARGO_PKG_VERSION")),
            board: board::BOARD_NAME,
            tick_hz: TICK_HZ,
            width: sz::WIDTH,
            height: sz::HEIGHT,
            tile_edge: sz::TILE_EDGE,
            max_beams: sz::MAX_BEAMS as u32,
            ray_capacity: memory::RAYS as u32,
            scan_capacity: memory::SCANS as u32,
            local_capacity: memory::LOCAL_RAYS as u32,
            count_max: u32::from(u8::MAX),
        };
        self.send(link, &DeviceMsg::Hello(hello));
    }

    /// Applies the host's settings (once; a repeat of the settings in use is ignored — the host
    /// repeats its frames on a noisy link).
    pub fn configure<W: Write>(&mut self, link: &mut W, config: RunConfig) {
        let Some(bufs) = self.spare.take() else {
            if self.machine.as_ref().is_some_and(|m| m.config == config) {
                return;
            }
            self.report_error(link, ErrorCode::ConfigTwice, 0);
            return;
        };
        match Machine::build(config, bufs) {
            Ok(m) => {
                info!("config: {}", config);
                self.machine = Some(m);
                // Building the sampler is the deepest the stack ever gets (copies of its 2 KiB
                // forward-model tables); note it, then measure the mapping loop on its own.
                self.stack_config = board::stack_usage().used;
                board::repaint_stack();
                self.send(link, &DeviceMsg::Configured(config));
            }
            Err(detail) => self.report_error(link, ErrorCode::BadConfig, detail),
        }
    }

    /// One step from the link.
    pub fn on_step<W: Write>(&mut self, step: Step<'_>, link: &mut W, timer: &Timer) -> After {
        match step {
            Step::Config(c) => {
                self.configure(link, c);
                After::Nothing
            }
            Step::Scan {
                seq,
                pose,
                beams,
                overflow,
            } => {
                self.seq = seq;
                self.process_scan(link, timer, seq, &pose, beams, overflow);
                After::ScanDone
            }
            Step::Finish => After::Finish,
            Step::Idle { seq, period_us } => {
                self.idle(link, timer, seq, period_us);
                After::ScanDone
            }
            Step::Error(e) => {
                let (code, detail) = match e {
                    LinkError::Ld06(ogm_core::ld06::Ld06Error::Crc) => (ErrorCode::Link, 0),
                    LinkError::Ld06(ogm_core::ld06::Ld06Error::Truncated) => (ErrorCode::Link, 1),
                    LinkError::Ld06(ogm_core::ld06::Ld06Error::BadHeader) => (ErrorCode::Link, 2),
                    LinkError::Frame(_) => (ErrorCode::Link, 3),
                    LinkError::FrameTooLong => (ErrorCode::Link, 4),
                    LinkError::ScanSequence { seq } => (ErrorCode::ScanSequence, seq),
                    LinkError::PointsLost { lost, .. } => (ErrorCode::PointsLost, lost),
                    LinkError::PointsOutsideScan => (ErrorCode::Link, 5),
                };
                self.report_error(link, code, detail);
                After::Nothing
            }
        }
    }

    /// An idle period: the sampler alone for `period_us` of board time, then its report.
    pub fn idle<W: Write>(&mut self, link: &mut W, timer: &Timer, seq: u32, period_us: u32) {
        let Some(m) = self.machine.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        let t0 = timer.now();
        let updates = sample_until(m, timer, t0, period_us, u32::MAX);
        let ticks = ticks(t0, timer.now());
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

    /// Counts a UART receive error.
    pub fn uart_error<W: Write>(&mut self, link: &mut W) {
        self.counters.uart_errors = self.counters.uart_errors.saturating_add(1);
        self.report_error(link, ErrorCode::Uart, 0);
    }

    /// Ingests one scan: log-odds update with seeding, ray store, sampler, report, tiles.
    pub fn process_scan<W: Write>(
        &mut self,
        link: &mut W,
        timer: &Timer,
        seq: u32,
        pose: &Pose,
        beams: &[Beam],
        overflow: u32,
    ) {
        if overflow > 0 {
            self.counters.beams_overflowed =
                self.counters.beams_overflowed.saturating_add(overflow);
            self.report_error(link, ErrorCode::ScanOverflow, overflow);
        }
        let Some(m) = self.machine.as_deref_mut() else {
            self.report_error(link, ErrorCode::NoConfig, 0);
            return;
        };
        let mut report = ScanReport {
            seq,
            pose: (*pose).into(),
            beams: beams.len() as u32,
            beams_overflowed: overflow,
            ..ScanReport::default()
        };
        let t0 = timer.now();
        // Log-odds update, seeding of the cells observed for the first time, ray store and
        // first-occupied refresh in one step (the host replay makes the same call).
        let inserted = insert_and_seed(&mut m.mapper, &mut m.store, &mut m.gibbs, pose, beams);
        let t1 = timer.now();
        let updates = run_budget(m, timer, t0);
        let t2 = timer.now();
        // `store_ticks` stays 0: the ray store and the cache refresh are inside `insert_ticks`.
        (report.insert_ticks, report.sampler_ticks) = (ticks(t0, t1), ticks(t1, t2));
        report.sampler_updates = updates;
        let geometry = m.geometry();
        let mapper_config = *m.mapper.config();
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
        mark_dirty(&mut self.dirty, &geometry, &mapper_config, pose, beams);
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
        self.stream_tiles(link, false);
    }

    /// Sends changed log-odds tiles and marginal-count tiles: the per-scan quota, or (`all`)
    /// every changed log-odds tile and every count and sample tile.
    fn stream_tiles<W: Write>(&mut self, link: &mut W, all: bool) {
        let Some(m) = self.machine.as_deref() else {
            return;
        };
        let (quota, count_quota) = if all {
            (TILES, TILES)
        } else {
            (
                usize::from(m.config.tiles_per_scan),
                usize::from(m.config.count_tiles_per_scan),
            )
        };
        let mut sent = 0;
        let start = self.dirty_cursor;
        for k in 0..TILES {
            if sent >= quota {
                break;
            }
            let t = (start + k) % TILES;
            let (w, bit) = (t / 32, 1u32 << (t % 32));
            if self.dirty.get(w).is_some_and(|d| d & bit != 0) {
                send_tile(
                    &mut self.tx[..],
                    &mut self.tile[..],
                    link,
                    m,
                    Layer::LogOdds,
                    t,
                );
                if let Some(d) = self.dirty.get_mut(w) {
                    *d &= !bit;
                }
                sent += 1;
                self.dirty_cursor = (t + 1) % TILES;
            }
        }
        for _ in 0..count_quota.min(TILES) {
            let t = self.count_cursor;
            send_tile(
                &mut self.tx[..],
                &mut self.tile[..],
                link,
                m,
                Layer::Counts,
                t,
            );
            self.count_cursor = (t + 1) % TILES;
        }
        if all {
            for t in 0..TILES {
                send_tile(
                    &mut self.tx[..],
                    &mut self.tile[..],
                    link,
                    m,
                    Layer::Sample,
                    t,
                );
            }
        }
    }

    /// Sampler/store statistics and counters.
    pub fn report<W: Write>(&mut self, link: &mut W, link_counters: LinkCounters) {
        self.counters.link = link_counters;
        if let Some(m) = self.machine.as_deref() {
            let store = StoreReport::new(
                &m.store.stats(),
                m.store.decimation(),
                m.store.scans().len(),
                m.store.rays().len(),
            );
            let r = SamplerReport::new(&m.gibbs.stats(), m.gibbs.samples(), store);
            send(&mut self.tx[..], link, &DeviceMsg::Sampler(r));
        }
        let c = self.counters;
        self.send(link, &DeviceMsg::Counters(c));
    }

    /// End of the run: everything still unsent, statistics, `Done`; returns the exit code.
    pub fn finish<W: Write>(&mut self, link: &mut W, link_counters: LinkCounters) -> i32 {
        self.stream_tiles(link, true);
        self.report(link, link_counters);
        let stack = board::stack_usage();
        let mut done = Done {
            scans: self.counters.scans,
            stack_used: stack.used,
            stack_size: stack.size,
            stack_config: self.stack_config,
            ..Done::default()
        };
        if let Some(m) = self.machine.as_deref() {
            done.grid_fnv = wire::grid_fnv(m.mapper.grid().cells());
            done.counts_fnv = (0..CELLS).fold(wire::FNV_START, |h, i| {
                wire::fnv1a(h, &[m.gibbs.count(i) as u8])
            });
        }
        self.send(link, &DeviceMsg::Done(done));
        let _ = link.flush();
        self.summary(&done);
        0
    }

    fn summary(&self, done: &Done) {
        let t = &self.totals;
        let ns = |ticks: u64| ticks * Timer::ticks_to_ns(1);
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
        if let Some(m) = self.machine.as_deref() {
            info!("sampler: {}", m.gibbs.stats());
            info!("ray store: {}", m.store.stats());
        }
    }
}

/// Sampler updates for one scan; `t0` = when the scan was complete.
fn run_budget(m: &mut Machine, timer: &Timer, t0: u32) -> u32 {
    match m.config.budget {
        Budget::Fixed { updates } => m.gibbs.step(&mut m.store, m.mapper.grid().cells(), updates),
        Budget::Time {
            period_us,
            max_updates,
        } => sample_until(m, timer, t0, period_us, max_updates),
    }
}

/// Sampler updates until `period_us` of board time after `t0` or `max_updates`, whichever comes
/// first; returns how many.
fn sample_until(m: &mut Machine, timer: &Timer, t0: u32, period_us: u32, max_updates: u32) -> u32 {
    // Ticks fit a u32 for periods up to 171 s at 25 MHz; longer ones are cut there.
    let period =
        (u64::from(period_us) * u64::from(TICK_HZ) / 1_000_000).min(u64::from(u32::MAX)) as u32;
    let mut done = 0u32;
    while done < max_updates && timer.now().wrapping_sub(t0) < period {
        done += m.gibbs.step(
            &mut m.store,
            m.mapper.grid().cells(),
            CHUNK.min(max_updates - done),
        );
    }
    done
}

/// Marks the tiles a scan can have changed: the box around the pose's cell and every beam's end
/// cell (the ray model changes nothing outside it), clipped to the grid.
fn mark_dirty(
    dirty: &mut [u32],
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
) {
    let (lo, hi) = ogm_core::mapper::scan_box(g, cfg, pose, beams);
    let (x0, y0, x1, y1) = (lo.x, lo.y, hi.x, hi.y);
    let (w, h) = (i32::from(g.width()), i32::from(g.height()));
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

/// Encodes tile `t` of `layer` and sends it.
fn send_tile<W: Write>(
    tx: &mut [u8],
    buf: &mut [u8],
    link: &mut W,
    m: &Machine,
    layer: Layer,
    t: usize,
) {
    let (tx0, ty0) = ((t % TILES_X) * EDGE, (t / TILES_X) * EDGE);
    let (tw, th) = (EDGE.min(WIDTH - tx0), EDGE.min(HEIGHT - ty0));
    let cells = m.mapper.grid().cells();
    let mut n = 0;
    match layer {
        Layer::LogOdds => {
            for y in ty0..ty0 + th {
                for x in tx0..tx0 + tw {
                    let v = cells.get(y * WIDTH + x).map_or(0, |c| c.raw());
                    if let Some(d) = buf.get_mut(n..n + 2) {
                        d.copy_from_slice(&v.to_le_bytes());
                    }
                    n += 2;
                }
            }
        }
        Layer::Counts => {
            for y in ty0..ty0 + th {
                for x in tx0..tx0 + tw {
                    if let Some(d) = buf.get_mut(n) {
                        *d = m.gibbs.count(y * WIDTH + x) as u8;
                    }
                    n += 1;
                }
            }
        }
        Layer::Sample => {
            let bytes = (tw * th).div_ceil(8);
            if let Some(d) = buf.get_mut(..bytes) {
                d.fill(0);
            }
            let mut k = 0;
            for y in ty0..ty0 + th {
                for x in tx0..tx0 + tw {
                    if m.gibbs.occupied(y * WIDTH + x) {
                        if let Some(d) = buf.get_mut(k / 8) {
                            *d |= 1 << (k % 8);
                        }
                    }
                    k += 1;
                }
            }
            n = bytes;
        }
    }
    let data = buf.get(..n).unwrap_or(&[]);
    let tile = Tile {
        layer,
        tx: (tx0 / EDGE) as u16,
        ty: (ty0 / EDGE) as u16,
        data,
    };
    send(tx, link, &DeviceMsg::Tile(tile));
}

/// Waits up to [`HOST_WAIT_US`] for the first byte from a host.
fn wait_for_host<L: ReadReady>(link: &mut L, timer: &Timer) -> bool {
    let limit = (HOST_WAIT_US * u64::from(TICK_HZ) / 1_000_000) as u32;
    let t0 = timer.now();
    while timer.now().wrapping_sub(t0) < limit {
        if link.read_ready().unwrap_or(false) {
            return true;
        }
    }
    false
}

/// The firmware: hello, then the host-driven main loop (or the self-test if no host speaks
/// within [`HOST_WAIT_US`]). Returns the exit code.
pub fn run<L: Read + ReadReady + Write>(link: &mut L, timer: &Timer) -> i32 {
    let Some(memory::Buffers {
        map,
        scan,
        tx,
        tile,
    }) = memory::take()
    else {
        defmt::panic!("buffers taken twice");
    };
    let mut app = App::new(map, tx, tile);
    info!(
        "memory: {=usize} B grid, {=usize} B counts, {=usize} rays, {=usize} scans, {=usize} local rays, {=usize} beams/scan",
        core::mem::size_of::<[LogOdds; CELLS]>(),
        CELLS,
        memory::RAYS,
        memory::SCANS,
        memory::LOCAL_RAYS,
        sz::MAX_BEAMS
    );
    app.hello(link);
    if !wait_for_host(link, timer) {
        info!("no host on the link: self-test");
        return selftest::run(&mut app, link, timer, scan);
    }
    info!("host connected");
    let mut rx = LinkRx::new();
    let mut chunk = [0u8; 64];
    loop {
        let n = match link.read(&mut chunk) {
            Ok(n) => n,
            Err(_) => {
                app.uart_error(link);
                continue;
            }
        };
        for &b in chunk.get(..n).unwrap_or(&[]) {
            let mut after = After::Nothing;
            rx.feed(core::slice::from_ref(&b), scan, |step| {
                after = after.max(app.on_step(step, link, timer));
            });
            match after {
                After::Nothing => {}
                After::ScanDone => app.report(link, rx.counters()),
                After::Finish => return app.finish(link, rx.counters()),
            }
        }
    }
}
