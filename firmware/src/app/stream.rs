//! Frames out to the host: the scan's tiles (changed log-odds, marginal counts round robin),
//! sampler/store reports and counters, errors, and the end of the run (everything unsent,
//! `Done`, the closing summary in the log).

use embedded_io::Write;
use ogm_core::session::{Session, Storage};
use ogm_core::wire::{
    self, DeviceError, DeviceMsg, Done, ErrorCode, Layer, LidarCounters, LinkCounters, Tile,
    TileRect,
};

use super::{State, EDGE, HEIGHT, TILES, TILES_X, WIDTH};
use crate::platform::Platform;

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
pub(crate) fn write_all<W: Write>(w: &mut W, mut bytes: &[u8]) -> bool {
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

impl<S: Storage> State<'_, S> {
    pub(super) fn send<W: Write>(&mut self, link: &mut W, msg: &DeviceMsg<'_>) {
        send(&mut self.tx[..], link, msg);
    }

    pub(super) fn report_error<W: Write>(&mut self, link: &mut W, code: ErrorCode, detail: u32) {
        self.counters.errors = self.counters.errors.saturating_add(1);
        warn!(
            "error {} (scan {=u32}, detail {=u32})",
            code, self.seq, detail
        );
        let seq = self.seq;
        self.send(link, &DeviceMsg::Error(DeviceError { code, seq, detail }));
    }

    /// Sends changed log-odds tiles and marginal-count tiles: the per-scan quota, or (`all`)
    /// every changed log-odds tile and every count and sample tile.
    pub(super) fn stream_tiles<W: Write>(&mut self, link: &mut W, all: bool) {
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
    pub(super) fn report<W: Write>(
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
    pub(super) fn finish<W: Write, P: Platform>(
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

/// Marks the tiles that overlap the cell box `lo ..= hi` (clipped to the grid) as changed.
pub(super) fn mark_dirty(dirty: &mut [u32], lo: (i32, i32), hi: (i32, i32)) {
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
