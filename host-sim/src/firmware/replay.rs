//! The host replay: the robot's input through the firmware's own application
//! (`ogm_firmware::App`) on the host, with the sampler work the firmware reported.

use anyhow::{bail, Context};
use ogm_core::sampler::gibbs::Count;
use ogm_core::session::{Owned, Session, Sizes};
use ogm_core::wire::SamplerReport;
use ogm_core::ScanBuf;
use ogm_field::stream::{DeviceEvent, OwnedHello, StreamedMap};
use ogm_firmware::app::MAX_BEAMS;
use ogm_firmware::sizes::MPS2_AN386 as FW;
use ogm_firmware::{App, Fed, Memory, Platform, Work};

use super::groups::Groups;

/// Runs the robot's input through **the firmware's own application** (`ogm_firmware::App`, the
/// library every board binary runs) on the host, byte by byte, with `sizes` and
/// `updates(work)` sampler updates for each scan and idle period; `hook` sees the engine after
/// every scan and idle period, `end` the final engine (`None` if no valid `Config` arrived) and
/// everything the application streamed (its `Hello` first).
///
/// `input` is the link; `lidar` what the lidar's own UART carried (empty when a host tunnels
/// the scans). The two are read as the firmware's main loop reads its UARTs — the lidar
/// whenever the application wants it, the link when the application wants it or the lidar has
/// nothing left — and the application's result does not depend on how they interleave
/// (`ogm_core::lidar::turn`), so this gives the board's map.
pub(super) fn replay<N: Count, R>(
    input: &[u8],
    lidar: &[u8],
    sizes: Sizes,
    updates: impl Fn(Work) -> Option<u32>,
    mut hook: impl FnMut(Fed, &ReplaySession<N>),
    end: impl FnOnce(Option<&ReplaySession<N>>, &[u8]) -> R,
) -> anyhow::Result<R> {
    let mut memory = HostMemory::<N>::new();
    let mut app = memory.app(&sizes);
    let mut platform = HostPlatform {
        updates,
        missing: None,
    };
    let mut out = Vec::new();
    app.hello(&mut out, &platform);
    let (mut link, mut lidar) = (input, lidar);
    loop {
        let fed = if app.wants_lidar() && !lidar.is_empty() {
            let (b, rest) = lidar.split_at(1);
            lidar = rest;
            app.feed_lidar(b, &mut out, &mut platform)
        } else if let Some((b, rest)) = link.split_first() {
            link = rest;
            app.feed(std::slice::from_ref(b), &mut out, &mut platform)
        } else {
            break;
        };
        if let Some(w) = platform.missing {
            bail!("the firmware did not report {w:?}");
        }
        match (fed, app.session()) {
            (Fed::Scan(_) | Fed::Idle(_), Some(s)) => hook(fed, s),
            (Fed::Finished(_), _) => break,
            _ => {}
        }
    }
    Ok(end(app.session(), &out))
}

/// The firmware's application on the host with a fixed `updates` sampler updates per scan and
/// idle period (`--host-only`): what it streamed, and that stream decoded.
pub(super) fn replay_fixed(
    input: &[u8],
    lidar: &[u8],
    updates: u32,
) -> anyhow::Result<(Vec<u8>, Vec<DeviceEvent>)> {
    let stream = replay::<u8, _>(
        input,
        lidar,
        FIRMWARE_SIZES,
        |_| Some(updates),
        |_, _| {},
        |_, out| out.to_vec(),
    )?;
    let events = decode_own(&stream)?;
    Ok((stream, events))
}

/// A stream the host's replay made, decoded (every frame must decode: the host made it).
pub(super) fn decode_own(stream: &[u8]) -> anyhow::Result<Vec<DeviceEvent>> {
    ogm_field::stream::StreamDecoder::new()
        .push(stream)
        .into_iter()
        .collect::<Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("the host's own stream does not decode: {e}"))
}

/// The map the firmware's application ends with on `input` (its `Config`, scans, idle periods),
/// with the sampler work the firmware reported in `events` (its decoded stream, which must
/// hold its `Hello`): the host replay as a [`StreamedMap`], and its final sampler report.
pub fn replay_map(
    input: &[u8],
    events: &[DeviceEvent],
) -> anyhow::Result<(StreamedMap, SamplerReport)> {
    use ogm_core::wire::TileSource;
    let g = Groups::of(events);
    let hello = g
        .hello
        .as_ref()
        .context("no Hello in the firmware's stream")?;
    let (w, h) = (usize::from(hello.width), usize::from(hello.height));
    let edge = usize::from(hello.tile_edge);
    let state = replay::<u8, _>(
        input,
        &[],
        sizes_of(hello),
        |work| g.updates(work),
        |_, _| {},
        |m, _| {
            m.map(|m| {
                let mut map = StreamedMap::new(w, h, edge);
                map.log_odds = m.log_odds().iter().map(|l| l.raw()).collect();
                map.counts = (0..w * h).map(|i| m.count(i)).collect();
                map.sample = (0..w * h).map(|i| m.occupied(i)).collect();
                (map, m.sampler_report())
            })
        },
    )?;
    state.context("the input carries no valid Config")
}

/// The firmware application's memory on the host, as a board places it in statics.
pub struct HostMemory<N: Count> {
    session: Option<ReplaySession<N>>,
    scan: ScanBuf<MAX_BEAMS>,
    turn: ScanBuf<MAX_BEAMS>,
    turns: ogm_core::lidar::turn::Turns,
    tx: [u8; ogm_core::wire::MAX_DEVICE_FRAME],
    tile: [u8; ogm_core::wire::MAX_TILE_BYTES],
    restore: ogm_core::session::TileRestore,
}

impl<N: Count> HostMemory<N> {
    /// Empty memory (boxed: the scan buffer is ~5.5 KiB).
    pub fn new() -> Box<Self> {
        Box::new(HostMemory {
            session: None,
            scan: ScanBuf::new(),
            turn: ScanBuf::new(),
            turns: ogm_core::lidar::turn::Turns::new(
                ogm_core::lidar::pose_track::Mount::ZERO,
                false,
            ),
            tx: [0; ogm_core::wire::MAX_DEVICE_FRAME],
            tile: [0; ogm_core::wire::MAX_TILE_BYTES],
            restore: ogm_core::session::TileRestore::new(),
        })
    }

    /// The firmware's application over this memory and engine buffers of `sizes`, not yet
    /// configured.
    pub fn app(&mut self, sizes: &Sizes) -> App<'_, Owned<N>> {
        App::new(Memory {
            buffers: Owned::<N>::buffers(sizes),
            session: &mut self.session,
            scan: &mut self.scan,
            turn: &mut self.turn,
            turns: &mut self.turns,
            tx: &mut self.tx,
            tile: &mut self.tile,
            restore: &mut self.restore,
        })
    }
}

/// The host as the firmware application's platform: no clock, and exactly the sampler updates
/// the firmware reported for each scan and idle period.
pub(super) struct HostPlatform<F> {
    pub(super) updates: F,
    pub(super) missing: Option<Work>,
}

impl<F: Fn(Work) -> Option<u32>> Platform for HostPlatform<F> {
    const NAME: &'static str = "host replay";
    const TICK_HZ: u32 = 1_000_000_000;

    fn now(&self) -> u32 {
        0
    }

    fn fixed_updates(&mut self, work: Work) -> Option<u32> {
        let n = (self.updates)(work);
        if n.is_none() {
            self.missing.get_or_insert(work);
        }
        Some(n.unwrap_or(0))
    }
}

/// The engine of a replay: the firmware's, over `Vec`s with counters of type `N`.
pub type ReplaySession<N> = Session<Owned<N>>;

/// Marginal p(occupied) per cell of `s` as the robot streams it: 0.5 (unknown) where no
/// measurement reached the cell (log-odds 0, the rule of `ogm_field::stream::stream_probabilities`)
/// or before the first sample.
pub fn marginals<N: Count>(s: &ReplaySession<N>) -> Vec<f64> {
    s.log_odds()
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if l.0 == 0 {
                0.5
            } else {
                s.marginal(i).map_or(0.5, f64::from)
            }
        })
        .collect()
}

/// The ray store's sizes as a firmware reports them in its Hello (one of each without its
/// `rays` feature).
pub fn sizes_of(hello: &OwnedHello) -> Sizes {
    Sizes {
        width: hello.width,
        height: hello.height,
        rays: (hello.ray_capacity as usize).max(1),
        scans: (hello.scan_capacity as usize).max(1),
        local: (hello.local_capacity as usize).max(1),
    }
}

/// The compile-time sizes of the firmware built with its `rays` feature.
pub const FIRMWARE_SIZES: Sizes = Sizes {
    width: FW.width,
    height: FW.height,
    rays: FW.rays,
    scans: FW.scans,
    local: FW.local_rays,
};
