//! The firmware's map stream as the checks read it: decoded ([`decode_captured`]) and its
//! messages grouped by scan ([`Groups`]).

use std::collections::HashMap;

use ogm_core::config::RunConfig;
use ogm_core::wire::{Counters, Done, SamplerReport, ScanReport};
use ogm_field::stream::{
    DecoderStats, DeviceEvent, OwnedHello, OwnedRanges, OwnedTile, StreamDecoder,
};
use ogm_firmware::Work;

/// The firmware's messages grouped by scan.
#[derive(Default)]
pub(super) struct Groups {
    pub(super) scans: HashMap<u32, ScanGroup>,
    pub(super) final_tiles: Vec<OwnedTile>,
    pub(super) final_sampler: Option<SamplerReport>,
    pub(super) final_counters: Option<Counters>,
    pub(super) done: Option<Done>,
    pub(super) hello: Option<OwnedHello>,
    pub(super) configured: Option<RunConfig>,
    pub(super) errors: usize,
    pub(super) all_tiles: Vec<OwnedTile>,
    /// For each of `all_tiles`, how many `Window` messages came before it: which visit of the
    /// window streamed it.
    pub(super) tile_windows: Vec<usize>,
    pub(super) idles: HashMap<u32, ogm_core::wire::IdleReport>,
    /// Every `Window` message (a shift's announcement, and the end of the run's).
    pub(super) windows: Vec<ogm_core::wire::WindowReport>,
    /// The tiles that left the window, in the order streamed (between a shift's `Window` and
    /// the scan that needed it).
    pub(super) shift_tiles: Vec<OwnedTile>,
}

#[derive(Default)]
pub(super) struct ScanGroup {
    pub(super) report: ScanReport,
    pub(super) tiles: Vec<OwnedTile>,
    pub(super) sampler: Option<SamplerReport>,
    pub(super) counters: Option<Counters>,
    pub(super) ranges: Option<OwnedRanges>,
}

impl Groups {
    pub(super) fn of(events: &[DeviceEvent]) -> Groups {
        let mut g = Groups::default();
        let mut current: Option<u32> = None;
        let mut in_shift = false;
        for ev in events {
            match ev {
                DeviceEvent::Hello(h) => g.hello = Some(h.clone()),
                DeviceEvent::Configured(c) => g.configured = Some(*c),
                DeviceEvent::Scan(r) => {
                    g.scans.insert(
                        r.seq,
                        ScanGroup {
                            report: *r,
                            ..ScanGroup::default()
                        },
                    );
                    current = Some(r.seq);
                    in_shift = false;
                }
                DeviceEvent::Tile(t) => {
                    g.all_tiles.push(t.clone());
                    g.tile_windows.push(g.windows.len());
                    match current.and_then(|s| g.scans.get_mut(&s)) {
                        Some(s) => s.tiles.push(t.clone()),
                        None if in_shift => g.shift_tiles.push(t.clone()),
                        None => g.final_tiles.push(t.clone()),
                    }
                }
                DeviceEvent::Window(w) => {
                    g.windows.push(*w);
                    current = None;
                    in_shift = true;
                }
                DeviceEvent::Sampler(r) => match current.and_then(|s| g.scans.get_mut(&s)) {
                    Some(s) => s.sampler = Some(*r),
                    None => g.final_sampler = Some(*r),
                },
                DeviceEvent::Counters(c) => {
                    match current.take().and_then(|s| g.scans.get_mut(&s)) {
                        Some(s) => s.counters = Some(*c),
                        None => g.final_counters = Some(*c),
                    }
                }
                DeviceEvent::Error(_) => g.errors += 1,
                DeviceEvent::Done(d) => g.done = Some(*d),
                DeviceEvent::Idle(r) => {
                    g.idles.insert(r.seq, *r);
                }
                DeviceEvent::Ranges(r) => {
                    if let Some(s) = g.scans.get_mut(&r.seq) {
                        s.ranges = Some(r.clone());
                    }
                }
            }
        }
        g
    }

    /// The sampler updates the firmware reported for `w`.
    pub(super) fn updates(&self, w: Work) -> Option<u32> {
        match w {
            Work::Scan(seq) => self.scans.get(&seq).map(|s| s.report.sampler_updates),
            Work::Idle(seq) => self.idles.get(&seq).map(|r| r.sampler_updates),
        }
    }
}

/// The messages of a stream captured from the board (bad frames skipped, counted in the
/// decoder's statistics).
pub(super) fn decode_captured(stream: &[u8]) -> (Vec<DeviceEvent>, DecoderStats) {
    let mut dec = StreamDecoder::new();
    let events = dec
        .push(stream)
        .into_iter()
        .filter_map(Result::ok)
        .collect();
    (events, dec.stats())
}
