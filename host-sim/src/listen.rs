//! `host-sim listen`: watch a robot over its serial link (docs/listen.md).
//!
//! The robot streams its map as COBS frames (docs/wire.md). The listener
//!
//! * decodes the stream with the one decoder ([`StreamDecoder`]) and keeps the map
//!   ([`StreamedMap`], every tile applied in order), whatever the chunking of the bytes;
//! * counts the link: good frames, bad frames (COBS, CRC-32, version, postcard), CRC errors among
//!   them, oversized runs, garbage bytes (everything outside a good frame), scans reported and
//!   scans **missed** (gaps in the scan sequence numbers), reconnects and the time spent
//!   disconnected;
//! * keeps a capture of every byte it received (`stream.bin`, appended): a listener that is killed
//!   and started again replays it, so it keeps the map and counters it had and counts exactly the
//!   scans it did not see while it was away;
//! * saves the map (PNG + ROS map_server PGM/YAML, through the writer `host-sim export` uses)
//!   every `--save-every` seconds, at the end of the input, and on Ctrl-C; files are written to a
//!   temporary directory and renamed into place, so a reader never sees half a map;
//! * sends host messages (settings, scan poses, raw lidar bytes, `Finish`) from a file or stdin;
//! * survives unplug/replug: on a read error it reopens the device with a back-off and goes on.
//!
//! Untrusted bytes from the port go only through [`StreamDecoder`] and [`StreamedMap::apply`]
//! (which checks every tile against the grid); a `Hello` announcing an absurd grid is refused.
//!
//! The core ([`Listener`]) takes bytes and is I/O free; [`run`] is the loop around a serial port
//! (or a captured file), [`cli`] the command.

use ogm_firmware::sizes::MPS2_AN386 as FW;
use std::collections::VecDeque;
use std::fmt;
use std::io::{BufRead, IsTerminal, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use ogm_core::config::{Budget, RunConfig};
use ogm_core::wire::{Counters, DeviceError, Done, HostMsg, Layer, WireError};
use serde::Serialize;

use crate::link::{host_frame, DeviceEvent, HelloInfo, RunInput, StreamDecoder, StreamedMap};
use crate::map_export::export_world;
use crate::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use crate::world::{probabilities_to_world, World};

/// The capture of every received byte, in the output directory.
pub const CAPTURE_FILE: &str = "stream.bin";
/// The counters and state, rewritten at every save.
pub const STATUS_FILE: &str = "status.json";
/// The sampler's map (the robot's product): `map.yaml`, `map.pgm`, `map.png`.
pub const MAP_STEM: &str = "map";
/// The log-odds (traditional) map: `log_odds.yaml`, `.pgm`, `.png`.
pub const LOG_ODDS_STEM: &str = "log_odds";
/// Largest grid a `Hello` may announce (cells); the reference firmware's is 65 536.
pub const MAX_CELLS: usize = 1 << 24;
/// Gaps kept in [`ListenStats::gaps`] (the count in `scans_missed` is complete).
pub const MAX_GAPS_KEPT: usize = 1000;

/// Command-line options of `host-sim listen`.
#[derive(clap::Args, Clone, Debug)]
pub struct ListenArgs {
    /// Serial device of the robot's link (`/dev/ttyUSB0`, `/dev/ttyACM0`, a pseudo-terminal such
    /// as `/dev/pts/3`). A regular file is read to its end as a captured stream.
    #[arg(long, required_unless_present = "print_config")]
    pub port: Option<PathBuf>,
    /// Baud rate (ignored with a warning where the device cannot set it, e.g. a pseudo-terminal).
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// Output directory: map.{yaml,pgm,png}, log_odds.{yaml,pgm,png}, status.json, stream.bin.
    #[arg(long, default_value = "out/listen")]
    pub out: PathBuf,
    /// Save the map every SECS seconds (0: only at the end and on Ctrl-C).
    #[arg(long, default_value_t = 5.0)]
    pub save_every: f64,
    /// Host messages to send, one JSON value per line (`-`: stdin); docs/listen.md.
    #[arg(long)]
    pub send: Option<PathBuf>,
    /// Bytes to send as they are (e.g. `input.bin` of `host-sim firmware --out DIR`).
    #[arg(long, conflicts_with = "send")]
    pub send_raw: Option<PathBuf>,
    /// When the robot says Hello (boots) and no Config was sent since, send the default settings
    /// first (`--print-config` shows them); not for a robot that is already running.
    #[arg(long)]
    pub default_config: bool,
    /// Seconds to wait for the robot's Hello before sending anyway (a running robot says none).
    #[arg(long, default_value_t = 2.0)]
    pub hello_wait: f64,
    /// Stop (and save) when the robot reports Done.
    #[arg(long)]
    pub until_done: bool,
    /// Start a new capture instead of resuming the one in the output directory.
    #[arg(long)]
    pub fresh: bool,
    /// No status line.
    #[arg(long)]
    pub quiet: bool,
    /// Print the default settings as a `--send` line and exit.
    #[arg(long)]
    pub print_config: bool,
    /// Also record the session for Foxglove Studio: both maps at every save, the robot's pose
    /// at every scan, into this MCAP file (replaced; `host_sim::recording`).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Also serve a live view for Foxglove Studio (its WebSocket protocol) on this address
    /// (default 127.0.0.1:8765, localhost only): both maps twice a second while tiles arrive,
    /// the robot's pose at every scan (`host_sim::live`).
    #[arg(long, num_args = 0..=1, default_missing_value = crate::live::DEFAULT_ADDR)]
    pub live: Option<String>,
}

impl ListenArgs {
    /// Options for `port` with every other setting at its default.
    pub fn new(port: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        ListenArgs {
            port: Some(port.into()),
            baud: 921_600,
            out: out.into(),
            save_every: 5.0,
            send: None,
            send_raw: None,
            default_config: false,
            hello_wait: 2.0,
            until_done: false,
            fresh: false,
            quiet: false,
            print_config: false,
            mcap: None,
            live: None,
        }
    }
}

/// One map layer, owned, for the recording and the live view ([`Listener::map_layers`]).
struct LayerCells {
    /// The sampler's marginals (else the log-odds).
    marginals: bool,
    /// p(occupied), or `None` where nothing was observed; row-major, row 0 at the bottom.
    cells: Vec<Option<f64>>,
    width: usize,
    height: usize,
    cell_m: f64,
    origin_m: (f64, f64),
}

impl LayerCells {
    fn frame(&self) -> crate::recording::GridFrame<'_> {
        crate::recording::GridFrame {
            width: self.width,
            height: self.height,
            cell_m: self.cell_m,
            origin_m: self.origin_m,
            cells: &self.cells,
        }
    }
}

/// How often the live view gets the maps while tiles arrive.
pub const LIVE_PERIOD: Duration = Duration::from_millis(500);

/// Scans `first..=last` were never reported to the listener.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Gap {
    /// First missing sequence number.
    pub first: u32,
    /// Last missing sequence number.
    pub last: u32,
}

impl Gap {
    /// Scans missing.
    pub fn len(&self) -> u64 {
        u64::from(self.last - self.first) + 1
    }

    /// Never true (a gap has at least one scan); for clippy's `len_without_is_empty`.
    pub fn is_empty(&self) -> bool {
        false
    }
}

/// Everything the listener counts (written to `status.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct ListenStats {
    /// Bytes through the decoder (capture replay included).
    pub bytes: u64,
    /// Good frames.
    pub frames: u64,
    /// Frames dropped: bad COBS, CRC-32, schema version or postcard (a frame cut by a
    /// disconnect is one of these).
    pub bad_frames: u64,
    /// Of `bad_frames`, those whose CRC-32 did not match.
    pub crc_errors: u64,
    /// Runs of bytes longer than any frame without a `0x00` (skipped).
    pub oversized: u64,
    /// Bytes outside good frames (bad frames, oversized runs).
    pub garbage_bytes: u64,
    /// Robot boots seen (`Hello`); each starts a new map.
    pub hellos: u64,
    /// `Hello`s refused (a grid larger than [`MAX_CELLS`] or empty).
    pub bad_hellos: u64,
    /// Scan reports received.
    pub scans_seen: u64,
    /// Sequence number of the last scan report.
    pub last_seq: Option<u32>,
    /// Scans whose report never arrived (sum of the gaps).
    pub scans_missed: u64,
    /// The gaps (the last [`MAX_GAPS_KEPT`]).
    pub gaps: Vec<Gap>,
    /// Scan numbers that went backwards without a new `Hello` (the host restarted its count).
    pub seq_restarts: u64,
    /// Tiles applied.
    pub tiles: u64,
    /// Tiles that did not fit the grid (dropped).
    pub bad_tiles: u64,
    /// Scan ranges of the wrong size (dropped).
    pub bad_ranges: u64,
    /// Scans whose ranges were placed at their report's pose (recorded, shown live).
    pub ranges_placed: u64,
    /// Points of the latest of them.
    pub scan_points: usize,
    /// `Error` messages from the robot.
    pub device_errors: u64,
    /// The last of them.
    pub last_device_error: Option<DeviceError>,
    /// The robot's own counters (its last `Counters`).
    pub robot: Option<Counters>,
    /// The robot's `Done`, once it came.
    pub done: Option<Done>,
    /// The robot's `Hello`.
    pub hello: Option<HelloInfo>,
    /// The settings the robot runs with (its `Configured`).
    pub config: Option<RunConfig>,
    /// Times the device was reopened after an error (unplug/replug), by this listener.
    pub reconnects: u64,
    /// Seconds without an open device (between a loss and the reopen), this listener.
    pub disconnected_secs: f64,
    /// Times a listener resumed this capture (restarts after a kill or an exit).
    pub restarts: u64,
    /// Host messages (lines) sent by this listener.
    pub sent: u64,
    /// Saves by this listener.
    pub saves: u64,
}

/// Something worth a line of its own.
#[derive(Clone, Debug, PartialEq)]
pub enum Notice {
    /// The robot booted: a new map.
    Hello(HelloInfo),
    /// The robot took its settings.
    Configured(RunConfig),
    /// Scans were missed.
    Gap(Gap),
    /// The first good frame after a reconnect or a restart, after this many garbage bytes (the
    /// frame the cut interrupted included).
    Resynced(u64),
    /// The robot reported an error.
    DeviceError(DeviceError),
    /// The robot finished its run.
    Done(Done),
    /// Something odd (a refused `Hello`, a tile off the grid, no `Hello` yet, …).
    Warning(String),
}

impl fmt::Display for Notice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Notice::Hello(h) => write!(
                f,
                "robot: {} on {}, {}x{} grid, {}-cell tiles (a new map)",
                h.firmware, h.board, h.width, h.height, h.tile_edge
            ),
            Notice::Configured(c) => write!(
                f,
                "robot configured: {} mm cells, origin ({}, {}) mm",
                c.cell_mm, c.origin_x_mm, c.origin_y_mm
            ),
            Notice::Gap(g) if g.first == g.last => write!(f, "missed scan {}", g.first),
            Notice::Gap(g) => write!(
                f,
                "missed scans {}..={} ({} scans)",
                g.first,
                g.last,
                g.len()
            ),
            Notice::Resynced(n) => write!(f, "resynchronised ({n} garbage bytes skipped)"),
            Notice::DeviceError(e) => write!(
                f,
                "robot error: {:?} (scan {}, detail {})",
                e.code, e.seq, e.detail
            ),
            Notice::Done(d) => write!(
                f,
                "robot done: {} scans, grid FNV {:#010x}",
                d.scans, d.grid_fnv
            ),
            Notice::Warning(w) => write!(f, "warning: {w}"),
        }
    }
}

pub use crate::map_export::{counts_of_one, stream_probabilities, MapLayer};

/// An I/O error that only means "nothing yet, try again" on a serial port.
fn transient(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::Interrupted
    )
}

/// The listener's core: bytes in (any chunking), map and counters out. No I/O but the capture.
pub struct Listener {
    decoder: StreamDecoder,
    /// Bytes of the frame being received (since the last `0x00`).
    pending: u64,
    capture: Option<(PathBuf, std::fs::File)>,
    map: Option<StreamedMap>,
    have_counts: Vec<bool>,
    samples: u32,
    stats: ListenStats,
    /// Garbage bytes when the link was last cut (a reconnect or a restart), until a good frame.
    resync_from: Option<u64>,
    /// Warned that tiles arrive before any `Hello`.
    warned_no_hello: bool,
    dirty: bool,
    /// `--mcap`: the session being recorded.
    recording: Option<crate::recording::Recording>,
    /// `--live`: the live view's server, whether tiles arrived since it last got the maps, and
    /// when that was.
    live: Option<crate::live::LiveServer>,
    live_dirty: bool,
    live_sent: Option<Instant>,
    /// The last scan report's number and pose (x, y in m, heading in rad), where its ranges
    /// are placed.
    last_pose: Option<(u32, (f64, f64, f64))>,
}

impl Default for Listener {
    fn default() -> Self {
        Self::new()
    }
}

impl Listener {
    /// A listener without a capture.
    pub fn new() -> Self {
        Listener {
            decoder: StreamDecoder::new(),
            pending: 0,
            capture: None,
            map: None,
            have_counts: Vec::new(),
            samples: 0,
            stats: ListenStats::default(),
            resync_from: None,
            warned_no_hello: false,
            dirty: false,
            recording: None,
            live: None,
            live_dirty: false,
            live_sent: None,
            last_pose: None,
        }
    }

    /// Serves the live view on `addr` from now on (`crate::live`); the address it listens on.
    pub fn serve_live(&mut self, addr: &str) -> anyhow::Result<std::net::SocketAddr> {
        let server = crate::live::LiveServer::start(addr)?;
        let a = server.local_addr();
        self.live = Some(server);
        self.live_dirty = true;
        Ok(a)
    }

    /// The live view's server, if any.
    pub fn live(&self) -> Option<&crate::live::LiveServer> {
        self.live.as_ref()
    }

    /// Sends both maps to the live view if tiles arrived since it last got them, at most every
    /// [`LIVE_PERIOD`] (a map is a few hundred KiB of JSON; the viewer needs no more).
    pub fn live_tick(&mut self) {
        if self.live.is_none()
            || !self.live_dirty
            || self.live_sent.is_some_and(|t| t.elapsed() < LIVE_PERIOD)
        {
            return;
        }
        self.live_dirty = false;
        self.live_sent = Some(Instant::now());
        let t = crate::recording::now_ns();
        for layer in self.map_layers() {
            let channel = if layer.marginals {
                crate::recording::Channel::Marginals
            } else {
                crate::recording::Channel::LogOdds
            };
            if let Some(live) = self.live.as_ref() {
                live.publish(
                    channel,
                    t,
                    &crate::recording::grid_message(&layer.frame(), t),
                );
            }
        }
    }

    /// Records from now on into the MCAP file `path` (replaced), starting with the map as it
    /// stands (a resumed capture's).
    pub fn record_to(&mut self, path: &Path) -> anyhow::Result<()> {
        self.recording = Some(crate::recording::Recording::create(path)?);
        self.record_maps();
        Ok(())
    }

    /// Closes the recording (summary and index written); its path, if there was one.
    pub fn finish_recording(&mut self) -> anyhow::Result<Option<PathBuf>> {
        self.recording.take().map(|r| r.finish()).transpose()
    }

    /// Both layers into the recording, if any. A write error ends the recording with a warning
    /// (the maps on disk are unaffected).
    fn record_maps(&mut self) {
        if self.recording.is_none() {
            return;
        }
        let t = crate::recording::now_ns();
        for layer in self.map_layers() {
            if let Some(r) = self.recording.as_mut() {
                if let Err(e) = r.grid(layer.marginals, &layer.frame(), t) {
                    eprintln!("warning: {e:#}; recording stopped");
                    self.recording = None;
                }
            }
        }
    }

    /// Both layers as the recording and the live view send them.
    fn map_layers(&self) -> Vec<LayerCells> {
        let Some(map) = self.map.as_ref() else {
            return Vec::new();
        };
        let (width, height) = (map.width, map.height);
        let known: Vec<bool> = (0..width * height)
            .map(|i| map.log_odds.get(i).is_some_and(|&l| l != 0))
            .collect();
        let (cell_m, origin_m) = self.geometry();
        let mut out = Vec::new();
        for (marginals, layer) in [(true, MapLayer::Marginals), (false, MapLayer::LogOdds)] {
            let Some(probs) = self.probabilities(layer) else {
                continue;
            };
            let cells: Vec<Option<f64>> = probs
                .iter()
                .zip(&known)
                .map(|(&p, &k)| k.then_some(p))
                .collect();
            out.push(LayerCells {
                marginals,
                cells,
                width,
                height,
                cell_m,
                origin_m,
            });
        }
        out
    }

    /// A listener that keeps its capture at `path`: unless `fresh`, an existing capture is
    /// replayed first (map and counters as the previous listener left them) and the new bytes
    /// are appended after a `0x00` (which ends a frame the previous listener was cut off in).
    pub fn with_capture(path: &Path, fresh: bool) -> anyhow::Result<Self> {
        let mut l = Listener::new();
        let mut resumed = false;
        if !fresh {
            match std::fs::File::open(path) {
                Ok(mut f) => {
                    let mut buf = vec![0u8; 1 << 20];
                    loop {
                        let n = f.read(&mut buf).with_context(|| {
                            format!("{}: cannot read the capture", path.display())
                        })?;
                        if n == 0 {
                            break;
                        }
                        // What the replay says again was said when it was live.
                        let _ = l.push(&buf[..n]);
                        resumed = true;
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => bail!("{}: cannot read the capture: {e}", path.display()),
            }
        }
        let mut opts = std::fs::OpenOptions::new();
        opts.create(true);
        if fresh {
            opts.write(true).truncate(true);
        } else {
            opts.append(true);
        }
        let file = opts
            .open(path)
            .with_context(|| format!("{}: cannot write the capture", path.display()))?;
        l.capture = Some((path.to_path_buf(), file));
        if resumed {
            l.stats.restarts = previous_restarts(path) + 1;
            l.cut();
        }
        l.dirty = true;
        Ok(l)
    }

    /// The link was cut (device reopened): the frame in progress is lost and counted as a bad
    /// frame; a gap in the scan numbers that follows is counted when the next report arrives.
    pub fn reconnected(&mut self) {
        self.stats.reconnects += 1;
        self.cut();
    }

    fn cut(&mut self) {
        // The cut frame's bytes count as skipped on the way back to a good frame.
        let before = self.stats.garbage_bytes;
        let _ = self.push(&[0]);
        self.resync_from = Some(before);
    }

    /// Counters and state.
    pub fn stats(&self) -> &ListenStats {
        &self.stats
    }

    /// Mutable counters (the I/O loop adds `disconnected_secs`, `sent`).
    pub fn stats_mut(&mut self) -> &mut ListenStats {
        &mut self.stats
    }

    /// The map so far (none before the first `Hello` or tile).
    pub fn map(&self) -> Option<&StreamedMap> {
        self.map.as_ref()
    }

    /// Cells whose marginal tile has arrived.
    pub fn have_counts(&self) -> &[bool] {
        &self.have_counts
    }

    /// Whether anything changed since the last save.
    pub fn dirty(&self) -> bool {
        self.dirty
    }

    /// Feeds bytes from the robot; returns what deserves a line of its own.
    pub fn push(&mut self, data: &[u8]) -> Vec<Notice> {
        if let Some((path, file)) = &mut self.capture {
            if let Err(e) = file.write_all(data) {
                let msg = format!(
                    "{}: capture write failed ({e}); capture stopped (the map goes on)",
                    path.display()
                );
                self.capture = None;
                let mut out = vec![Notice::Warning(msg)];
                out.extend(self.decode(data));
                return out;
            }
        }
        self.decode(data)
    }

    fn decode(&mut self, data: &[u8]) -> Vec<Notice> {
        let mut notices = Vec::new();
        if data.is_empty() {
            return notices;
        }
        self.dirty = true;
        self.live_dirty = true;
        // Split at each 0x00 so that every frame's bytes are known (for the garbage count).
        for segment in data.split_inclusive(|&b| b == 0) {
            let before = self.decoder.stats();
            let results = self.decoder.push(segment);
            self.pending += segment.len() as u64;
            let ended = segment.last() == Some(&0);
            let after = self.decoder.stats();
            self.stats.bytes = after.bytes;
            self.stats.frames = after.frames;
            self.stats.bad_frames = after.bad_frames;
            self.stats.oversized = after.oversized;
            let mut good = false;
            for r in results {
                match r {
                    Ok(ev) => {
                        good = true;
                        self.event(ev, &mut notices);
                    }
                    Err(WireError::Crc) => self.stats.crc_errors += 1,
                    Err(_) => {}
                }
            }
            if ended {
                // A lone 0x00 is a delimiter, not garbage; a run that ended an oversized skip or
                // a bad frame is.
                if !good && (self.pending > 1 || after.oversized > before.oversized) {
                    self.stats.garbage_bytes += self.pending;
                }
                self.pending = 0;
            }
            if good {
                if let Some(g0) = self.resync_from.take() {
                    notices.push(Notice::Resynced(self.stats.garbage_bytes - g0));
                }
            }
        }
        notices
    }

    fn event(&mut self, ev: DeviceEvent, notices: &mut Vec<Notice>) {
        match ev {
            DeviceEvent::Hello(h) => {
                let cells = usize::from(h.width) * usize::from(h.height);
                if cells == 0 || cells > MAX_CELLS || h.tile_edge == 0 {
                    self.stats.bad_hellos += 1;
                    notices.push(Notice::Warning(format!(
                        "Hello announces a {}x{} grid of {}-cell tiles: refused",
                        h.width, h.height, h.tile_edge
                    )));
                    return;
                }
                self.stats.hellos += 1;
                self.map = Some(StreamedMap::new(
                    usize::from(h.width),
                    usize::from(h.height),
                    usize::from(h.tile_edge),
                ));
                self.have_counts = vec![false; cells];
                self.samples = 0;
                self.stats.last_seq = None;
                self.stats.config = None;
                self.stats.robot = None;
                self.stats.done = None;
                self.stats.hello = Some(h.clone());
                self.last_pose = None;
                notices.push(Notice::Hello(h));
            }
            DeviceEvent::Configured(c) => {
                self.stats.config = Some(c);
                notices.push(Notice::Configured(c));
            }
            DeviceEvent::Scan(r) => {
                self.stats.scans_seen += 1;
                let p = r.pose;
                let heading = f64::from(p.heading.0) * std::f64::consts::TAU / 65_536.0;
                let (x, y) = (f64::from(p.x_mm) / 1000.0, f64::from(p.y_mm) / 1000.0);
                let t = crate::recording::now_ns();
                if let Some(rec) = self.recording.as_mut() {
                    if let Err(e) = rec.pose(x, y, heading, t) {
                        notices.push(Notice::Warning(format!("{e:#}; recording stopped")));
                        self.recording = None;
                    }
                }
                if let Some(live) = self.live.as_ref() {
                    let m = crate::recording::pose_message(x, y, heading, t);
                    live.publish(crate::recording::Channel::Pose, t, &m);
                }
                self.last_pose = Some((r.seq, (x, y, heading)));
                let expected = self.stats.last_seq.map_or(0, |s| s.wrapping_add(1));
                if r.seq > expected {
                    let gap = Gap {
                        first: expected,
                        last: r.seq - 1,
                    };
                    self.stats.scans_missed += gap.len();
                    if self.stats.gaps.len() >= MAX_GAPS_KEPT {
                        self.stats.gaps.remove(0);
                    }
                    self.stats.gaps.push(gap);
                    notices.push(Notice::Gap(gap));
                } else if self.stats.last_seq.is_some_and(|s| r.seq < s) {
                    self.stats.seq_restarts += 1;
                }
                self.stats.last_seq = Some(r.seq);
            }
            DeviceEvent::Tile(t) => {
                if self.map.is_none() {
                    // Started mid-run with no capture: assume the reference firmware's grid.
                    let (w, h) = (usize::from(FW.width), usize::from(FW.height));
                    self.map = Some(StreamedMap::new(w, h, usize::from(FW.tile_edge)));
                    self.have_counts = vec![false; w * h];
                    if !self.warned_no_hello {
                        self.warned_no_hello = true;
                        notices.push(Notice::Warning(format!(
                            "tiles before any Hello: assuming the firmware's {w}x{h} grid of {}-cell tiles",
                            FW.tile_edge
                        )));
                    }
                }
                let Some(map) = self.map.as_mut() else { return };
                match map.apply(&t) {
                    Ok(rect) => {
                        self.stats.tiles += 1;
                        if t.layer == Layer::Counts {
                            for c in rect.cells() {
                                if let Some(x) = self.have_counts.get_mut(c) {
                                    *x = true;
                                }
                            }
                        }
                    }
                    Err(e) => {
                        self.stats.bad_tiles += 1;
                        if self.stats.bad_tiles <= 3 {
                            notices.push(Notice::Warning(format!("tile dropped: {e}")));
                        }
                    }
                }
            }
            DeviceEvent::Sampler(s) => self.samples = s.samples,
            DeviceEvent::Counters(c) => self.stats.robot = Some(c),
            DeviceEvent::Error(e) => {
                self.stats.device_errors += 1;
                self.stats.last_device_error = Some(e);
                notices.push(Notice::DeviceError(e));
            }
            DeviceEvent::Done(d) => {
                self.stats.done = Some(d);
                notices.push(Notice::Done(d));
            }
            DeviceEvent::Idle(_) => {}
            DeviceEvent::Ranges(r) => self.scan_ranges(&r, notices),
        }
    }

    /// A scan's ranges: its points, placed at the pose of the report with the same `seq`, to
    /// the recording and the live view (dropped if that report was missed).
    fn scan_ranges(&mut self, r: &crate::link::OwnedRanges, notices: &mut Vec<Notice>) {
        let bins = match r.bins() {
            Ok(b) => b,
            Err(e) => {
                self.stats.bad_ranges += 1;
                if self.stats.bad_ranges <= 3 {
                    notices.push(Notice::Warning(format!("scan {}: {e}", r.seq)));
                }
                return;
            }
        };
        let Some((_, (x, y, heading))) = self.last_pose.filter(|(seq, _)| *seq == r.seq) else {
            return;
        };
        let points = crate::recording::scan_points(&bins, x, y, heading);
        self.stats.ranges_placed += 1;
        self.stats.scan_points = points.len();
        let t = crate::recording::now_ns();
        if let Some(rec) = self.recording.as_mut() {
            if let Err(e) = rec.scan(&points, t) {
                notices.push(Notice::Warning(format!("{e:#}; recording stopped")));
                self.recording = None;
            }
        }
        if let Some(live) = self.live.as_ref() {
            let m = crate::recording::points_message(&points, t);
            live.publish(crate::recording::Channel::Scan, t, &m);
        }
    }

    /// Probabilities of `layer` (none before the first `Hello` or tile).
    pub fn probabilities(&self, layer: MapLayer) -> Option<Vec<f64>> {
        let map = self.map.as_ref()?;
        let one = counts_of_one(
            self.stats.config.as_ref(),
            self.stats.hello.as_ref(),
            self.samples,
        );
        Some(stream_probabilities(map, &self.have_counts, one, layer))
    }

    /// Cell size (m) and the world position of cell (0, 0) (m): from the robot's
    /// `Configured`, else 5 cm at (0, 0).
    fn geometry(&self) -> (f64, (f64, f64)) {
        match &self.stats.config {
            Some(c) if c.cell_mm > 0 => (
                f64::from(c.cell_mm) / 1000.0,
                (
                    f64::from(c.origin_x_mm) / 1000.0,
                    f64::from(c.origin_y_mm) / 1000.0,
                ),
            ),
            _ => (0.05, (0.0, 0.0)),
        }
    }

    /// The map of `layer` as a trinary world (export's thresholds); cell size and origin from
    /// the robot's `Configured`, else 5 cm at (0, 0).
    pub fn world(&self, layer: MapLayer) -> Option<World> {
        let map = self.map.as_ref()?;
        let probs = self.probabilities(layer)?;
        let (res, origin) = self.geometry();
        Some(probabilities_to_world(
            &probs,
            map.width,
            map.height,
            res,
            origin,
            DEFAULT_OCCUPIED_THRESH,
            DEFAULT_FREE_THRESH,
        ))
    }

    /// Writes `map.*`, `log_odds.*` (when there is a map) and `status.json` into `dir`, each
    /// file first into `dir/.saving/` and then renamed into place (images before their YAML).
    /// Returns the files written.
    pub fn save(&mut self, dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create directory", dir.display()))?;
        let tmp = dir.join(".saving");
        std::fs::create_dir_all(&tmp)
            .with_context(|| format!("{}: cannot create directory", tmp.display()))?;
        self.stats.saves += 1;
        let mut written = Vec::new();
        let mut rename = |name: &str| -> anyhow::Result<()> {
            let to = dir.join(name);
            std::fs::rename(tmp.join(name), &to)
                .with_context(|| format!("{}: cannot write", to.display()))?;
            written.push(to);
            Ok(())
        };
        for (stem, layer) in [
            (MAP_STEM, MapLayer::Marginals),
            (LOG_ODDS_STEM, MapLayer::LogOdds),
        ] {
            let Some(world) = self.world(layer) else {
                continue;
            };
            export_world(&tmp.join(format!("{stem}.yaml")), &world)?;
            for ext in ["pgm", "png", "yaml"] {
                rename(&format!("{stem}.{ext}"))?;
            }
        }
        self.record_maps();
        let json = serde_json::to_string_pretty(&self.stats)?;
        std::fs::write(tmp.join(STATUS_FILE), json + "\n")
            .with_context(|| format!("{}: cannot write", tmp.display()))?;
        rename(STATUS_FILE)?;
        let _ = std::fs::remove_dir(&tmp);
        self.dirty = false;
        Ok(written)
    }

    /// One status line.
    pub fn status_line(&self) -> String {
        let s = &self.stats;
        let mut line = format!(
            "{} B, {} frames, {} bad ({} CRC), {} garbage B | scans {} (last {}), missed {}",
            s.bytes,
            s.frames,
            s.bad_frames,
            s.crc_errors,
            s.garbage_bytes,
            s.scans_seen,
            s.last_seq.map_or("-".into(), |q| q.to_string()),
            s.scans_missed
        );
        if let Some(r) = &s.robot {
            line += &format!(" | robot: {} scans, {} errors", r.scans, r.errors);
        }
        line += &format!(" | {} tiles", s.tiles);
        if s.reconnects > 0 {
            line += &format!(
                " | {} reconnects, {:.1} s down",
                s.reconnects, s.disconnected_secs
            );
        }
        if s.sent > 0 {
            line += &format!(" | sent {}", s.sent);
        }
        if s.done.is_some() {
            line += " | DONE";
        }
        line
    }
}

/// `restarts` of the `status.json` beside a capture (0 if there is none or it is unreadable).
fn previous_restarts(capture: &Path) -> u64 {
    let status = capture.with_file_name(STATUS_FILE);
    std::fs::read_to_string(status)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v.get("restarts").and_then(serde_json::Value::as_u64))
        .unwrap_or(0)
}

/// The default settings for `--default-config`: the robot's (`RunConfig::robot`) on a grid
/// centred on the world origin (the robot's start), LD06 range 12 m, seed 1, the time budget of
/// `host-sim firmware` (6.4 ms of board time per scan, at most 20 000 updates).
pub fn default_config() -> RunConfig {
    let cell_mm = 50;
    let half = |n: u16| -(i32::from(n) * cell_mm / 2);
    RunConfig::robot(
        (half(FW.width), half(FW.height)),
        12_000,
        1,
        Budget::Time {
            period_us: 6400,
            max_updates: 20_000,
        },
    )
}

/// One line of a `--send` file: a host message as JSON (serde's encoding of
/// [`HostMsg`]: `{"Config":{…}}`, `{"ScanStart":{"seq":0,"pose":{"x_mm":0,"y_mm":0,"heading":0}}}`,
/// `{"ScanEnd":{"seq":0,"points":360}}`, `{"Idle":{"seq":0,"period_us":1000000}}`, `"Finish"`),
/// or `{"raw":"HEX"}` for bytes sent as they are (LD06 packets). Blank lines and lines starting
/// with `#` are nothing (`Ok(None)`).
pub fn parse_send_line(line: &str) -> anyhow::Result<Option<Vec<u8>>> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(None);
    }
    let v: serde_json::Value =
        serde_json::from_str(line).map_err(|e| anyhow::anyhow!("not JSON: {e}"))?;
    if let Some(obj) = v.as_object() {
        if let Some(raw) = obj.get("raw") {
            ensure!(obj.len() == 1, "a raw line has only the key \"raw\"");
            let hex = raw
                .as_str()
                .ok_or_else(|| anyhow::anyhow!("\"raw\" must be a string of hex digits"))?;
            return Ok(Some(parse_hex(hex)?));
        }
    }
    let msg: HostMsg = serde_json::from_value(v).map_err(|e| {
        anyhow::anyhow!(
            "not a host message ({e}); expected Config, ScanStart, ScanEnd, Idle, \"Finish\" or {{\"raw\":\"HEX\"}}"
        )
    })?;
    Ok(Some(host_frame(&msg)))
}

fn parse_hex(s: &str) -> anyhow::Result<Vec<u8>> {
    let s: String = s.chars().filter(|c| !c.is_ascii_whitespace()).collect();
    ensure!(s.len() % 2 == 0, "odd number of hex digits");
    let digit = |c: u8| -> anyhow::Result<u8> {
        match c {
            b'0'..=b'9' => Ok(c - b'0'),
            b'a'..=b'f' => Ok(c - b'a' + 10),
            b'A'..=b'F' => Ok(c - b'A' + 10),
            _ => bail!("`{}` is not a hex digit", char::from(c)),
        }
    };
    s.as_bytes()
        .chunks(2)
        .map(|p| Ok(digit(p[0])? << 4 | digit(p[1])?))
        .collect()
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Reads a `--send` file: one entry per non-empty line; the first bad line is an error naming
/// the file and the line.
pub fn read_send_file(path: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let text = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{}: file not found", path.display())
        }
        Err(e) => bail!("{}: cannot read: {e}", path.display()),
    };
    let text = String::from_utf8(text)
        .map_err(|e| anyhow::anyhow!("{}: not UTF-8 text: {e}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        match parse_send_line(line) {
            Ok(Some(b)) => out.push(b),
            Ok(None) => {}
            Err(e) => bail!("{}:{}: {e}", path.display(), i + 1),
        }
    }
    ensure!(!out.is_empty(), "{}: no message to send", path.display());
    Ok(out)
}

/// A robot input ([`RunInput`], e.g. from [`crate::link::encode_run`]) as `--send` lines: each
/// host frame as its JSON message, each LD06 packet and garbage burst as a raw line. Sent, the
/// lines give exactly `input.bytes`.
pub fn send_lines(input: &RunInput) -> String {
    let mut out = String::new();
    for u in &input.units {
        let bytes = input.bytes.get(u.start..u.start + u.len).unwrap_or(&[]);
        let msg = match (u.kind, bytes) {
            (crate::link::UnitKind::Frame, [0, body @ .., 0]) => {
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

/// What to send to the robot.
#[derive(Clone, Debug)]
pub enum SendSource {
    /// Nothing.
    Nothing,
    /// These byte strings, in order (lines of a file, or a raw file as one).
    Items(Vec<Vec<u8>>),
    /// `--send` lines read from stdin as they come (a bad line is reported and skipped).
    Stdin,
}

impl SendSource {
    /// The source `--send` / `--send-raw` give (files are read and checked now).
    pub fn of(args: &ListenArgs) -> anyhow::Result<SendSource> {
        if let Some(p) = &args.send {
            if p.as_os_str() == "-" {
                return Ok(SendSource::Stdin);
            }
            return Ok(SendSource::Items(read_send_file(p)?));
        }
        if let Some(p) = &args.send_raw {
            let b = match std::fs::read(p) {
                Ok(b) => b,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    bail!("{}: file not found", p.display())
                }
                Err(e) => bail!("{}: cannot read: {e}", p.display()),
            };
            ensure!(!b.is_empty(), "{}: file is empty", p.display());
            return Ok(SendSource::Items(vec![b]));
        }
        Ok(SendSource::Nothing)
    }
}

/// Shared between [`run`] and whoever controls it (the CLI's signal handler, a test).
#[derive(Debug, Default)]
pub struct Control {
    /// Stop: save and return (Ctrl-C).
    pub stop: Arc<AtomicBool>,
    /// Return at once without saving (as if killed; the capture has every byte received).
    pub abort: AtomicBool,
    /// The device is open.
    pub connected: AtomicBool,
    sent: AtomicU64,
    snapshot: Mutex<Option<ListenStats>>,
}

impl Control {
    /// A fresh control.
    pub fn new() -> Arc<Control> {
        Arc::new(Control::default())
    }

    /// The listener's counters after its last read.
    pub fn stats(&self) -> Option<ListenStats> {
        self.snapshot.lock().ok().and_then(|s| s.clone())
    }

    fn publish(&self, l: &Listener) {
        if let Ok(mut s) = self.snapshot.lock() {
            *s = Some(l.stats().clone());
        }
    }

    fn stopping(&self) -> bool {
        self.stop.load(Ordering::SeqCst) || self.abort.load(Ordering::SeqCst)
    }
}

/// Opens a serial device for the link (raw 8N1, `timeout` per read/write). A pseudo-terminal
/// that refuses the baud rate is opened without setting it, with a warning on stderr.
pub fn open_port(
    path: &Path,
    baud: u32,
    timeout: Duration,
) -> anyhow::Result<Box<dyn serialport::SerialPort>> {
    let name = path.display().to_string();
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{name}: no such file or device")
        }
        Err(e) => bail!("{name}: {e}"),
        Ok(m) if m.is_dir() => bail!("{name}: is a directory, not a serial device"),
        Ok(_) => {}
    }
    let Some(path_str) = path.to_str() else {
        bail!("{name}: device path is not UTF-8");
    };
    let open = |baud: u32| serialport::new(path_str, baud).timeout(timeout).open();
    let describe = |e: &serialport::Error| -> String {
        use serialport::ErrorKind as K;
        match e.kind() {
            K::NoDevice => format!("{name}: busy or gone ({e})"),
            K::Io(std::io::ErrorKind::NotFound) => format!("{name}: no such file or device"),
            K::Io(std::io::ErrorKind::PermissionDenied) => format!(
                "{name}: permission denied (is your user in the device's group, e.g. dialout?)"
            ),
            _ => format!("{name}: cannot open as a serial port: {e}"),
        }
    };
    match open(baud) {
        Ok(p) => Ok(p),
        Err(e)
            if matches!(
                e.kind(),
                serialport::ErrorKind::NoDevice
                    | serialport::ErrorKind::Io(
                        std::io::ErrorKind::NotFound | std::io::ErrorKind::PermissionDenied
                    )
            ) =>
        {
            bail!("{}", describe(&e))
        }
        Err(e) => match open(0) {
            Ok(p) => {
                eprintln!(
                    "warning: {name}: cannot set {baud} baud ({e}); using the device's own speed"
                );
                Ok(p)
            }
            Err(_) => bail!("{}", describe(&e)),
        },
    }
}

/// Messages to the sender thread.
enum ToSender {
    /// A (new) device to write to.
    Port(Box<dyn serialport::SerialPort>),
    /// Start sending: the robot said Hello (`true`), or none came in time.
    Go(bool),
    /// The robot said Hello (again).
    Hello,
    /// One more item (from stdin).
    Item(Vec<u8>),
    /// Stop.
    Stop,
}

/// The sender: writes the items in order once told to go; after a write error it waits for
/// the next device and sends the interrupted item again, whole (the robot ignores repeated
/// frames, and a cut one is garbage it skips).
fn sender(
    rx: Receiver<ToSender>,
    mut queue: VecDeque<Vec<u8>>,
    default_config: Option<RunConfig>,
    ctl: Arc<Control>,
) {
    let mut port: Option<Box<dyn serialport::SerialPort>> = None;
    let mut go = false;
    // A Config went out since the last Hello (or the default one is due).
    let mut config_sent = false;
    let mut config_due = false;
    let is_config = |b: &[u8]| {
        matches!(b, [0, body @ .., 0] if {
            let mut body = body.to_vec();
            matches!(ogm_core::wire::decode::<HostMsg>(&mut body), Ok(HostMsg::Config(_)))
        })
    };
    loop {
        if ctl.stopping() {
            return;
        }
        let busy = go && port.is_some() && (!queue.is_empty() || config_due);
        let msg = if busy {
            match rx.try_recv() {
                Ok(m) => Some(m),
                Err(TryRecvError::Empty) => None,
                Err(TryRecvError::Disconnected) => return,
            }
        } else {
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(m) => Some(m),
                Err(RecvTimeoutError::Timeout) => None,
                Err(RecvTimeoutError::Disconnected) => return,
            }
        };
        match msg {
            Some(ToSender::Port(p)) => port = Some(p),
            Some(ToSender::Go(hello)) => {
                go = true;
                config_due = hello && default_config.is_some() && !config_sent;
            }
            Some(ToSender::Hello) => {
                config_sent = false;
                config_due = default_config.is_some();
            }
            Some(ToSender::Item(b)) => queue.push_back(b),
            Some(ToSender::Stop) => return,
            None => {}
        }
        if !(go && port.is_some()) {
            continue;
        }
        let (item, is_default) = match (config_due, default_config) {
            (true, Some(c)) if !queue.front().is_some_and(|b| is_config(b)) => {
                (host_frame(&HostMsg::Config(c)), true)
            }
            _ => match queue.front() {
                Some(b) => (b.clone(), false),
                None => {
                    config_due = false;
                    continue;
                }
            },
        };
        let Some(p) = port.as_mut() else { continue };
        match write_item(p.as_mut(), &item, &ctl) {
            Ok(true) => {
                if is_config(&item) {
                    config_sent = true;
                    config_due = false;
                }
                if !is_default {
                    queue.pop_front();
                    ctl.sent.fetch_add(1, Ordering::SeqCst);
                }
            }
            Ok(false) => return,
            Err(_) => port = None, // the reader reopens the device and hands it over
        }
    }
}

/// Writes `item` whole, retrying while the device is full; `Ok(false)` if told to stop.
fn write_item(
    port: &mut dyn serialport::SerialPort,
    item: &[u8],
    ctl: &Control,
) -> std::io::Result<bool> {
    let mut off = 0;
    while off < item.len() {
        if ctl.stopping() {
            return Ok(false);
        }
        match port.write(&item[off..]) {
            Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
            Ok(n) => off += n,
            Err(e) if transient(&e) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(true)
}

/// What the loop reads from.
enum Source {
    Serial(Box<dyn serialport::SerialPort>),
    File(std::fs::File),
}

/// Prints notices and the status line on stderr.
struct Console {
    quiet: bool,
    tty: bool,
    last: Instant,
    shown: bool,
}

impl Console {
    fn line(&mut self, text: &str) {
        if self.tty && self.shown {
            eprint!("\r\x1b[K");
            self.shown = false;
        }
        eprintln!("{text}");
    }

    fn status(&mut self, l: &Listener, force: bool) {
        if self.quiet {
            return;
        }
        let every = if self.tty {
            Duration::from_millis(250)
        } else {
            Duration::from_secs(10)
        };
        if !force && self.last.elapsed() < every {
            return;
        }
        self.last = Instant::now();
        if self.tty {
            eprint!("\r\x1b[K{}", l.status_line());
            let _ = std::io::stderr().flush();
            self.shown = true;
        } else {
            eprintln!("{}", l.status_line());
        }
    }

    fn finish(&mut self) {
        if self.tty && self.shown {
            eprintln!();
            self.shown = false;
        }
    }
}

/// Runs the listener until the input ends (a regular file), the robot is done (`until_done`),
/// or `ctl` says stop (save) or abort (no save). Returns the final counters.
pub fn run(args: &ListenArgs, ctl: Arc<Control>) -> anyhow::Result<ListenStats> {
    let port_path = args
        .port
        .clone()
        .ok_or_else(|| anyhow::anyhow!("--port DEV is required"))?;
    ensure!(
        args.save_every.is_finite() && args.save_every >= 0.0,
        "--save-every must be 0 or more seconds"
    );
    ensure!(
        args.hello_wait.is_finite() && args.hello_wait >= 0.0,
        "--hello-wait must be 0 or more seconds"
    );
    ensure!(args.baud > 0, "--baud must be positive");
    let source = SendSource::of(args)?;
    let is_file = std::fs::metadata(&port_path).is_ok_and(|m| m.is_file());
    if is_file {
        ensure!(
            matches!(source, SendSource::Nothing),
            "{}: a file, not a device: nothing can be sent to it",
            port_path.display()
        );
        // A capture must be one: checked before anything is written.
        let bytes = std::fs::read(&port_path)
            .with_context(|| format!("{}: cannot read", port_path.display()))?;
        ensure!(!bytes.is_empty(), "{}: file is empty", port_path.display());
        ensure!(
            StreamDecoder::new().push(&bytes).iter().any(Result::is_ok),
            "{}: wrong format: not a map stream (no valid frame in {} bytes)",
            port_path.display(),
            bytes.len()
        );
    }
    let capture = args.out.join(CAPTURE_FILE);
    if is_file && std::fs::canonicalize(&port_path).ok() == std::fs::canonicalize(&capture).ok() {
        bail!(
            "{}: is the listener's own capture; read a copy, or use `host-sim export --stream`",
            port_path.display()
        );
    }
    // Open first: a wrong device is an error before anything is written.
    let timeout = Duration::from_millis(100);
    let mut src = Some(if is_file {
        Source::File(
            std::fs::File::open(&port_path)
                .with_context(|| format!("{}: cannot read", port_path.display()))?,
        )
    } else {
        Source::Serial(open_port(&port_path, args.baud, timeout)?)
    });
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create directory", args.out.display()))?;
    let mut l = Listener::with_capture(&capture, args.fresh)?;
    if let Some(path) = &args.mcap {
        l.record_to(path)?;
    }
    let live_addr = match &args.live {
        Some(addr) => Some(l.serve_live(addr)?),
        None => None,
    };
    let mut con = Console {
        quiet: args.quiet,
        tty: std::io::stderr().is_terminal(),
        last: Instant::now(),
        shown: false,
    };
    if let Some(a) = live_addr {
        con.line(&format!(
            "live view: ws://{a} (Foxglove Studio: Open connection → Foxglove WebSocket)"
        ));
    }
    if l.stats().restarts > 0 {
        con.line(&format!(
            "resumed {}: {} bytes, {} scans seen (last {}); restart {}",
            capture.display(),
            l.stats().bytes,
            l.stats().scans_seen,
            l.stats()
                .last_seq
                .map_or("-".into(), |s: u32| s.to_string()),
            l.stats().restarts
        ));
    }
    ctl.connected.store(true, Ordering::SeqCst);
    ctl.publish(&l);

    // The sender thread, with its own handle on the device.
    let (tx, rx) = std::sync::mpsc::channel::<ToSender>();
    let sending = !matches!(source, SendSource::Nothing) || args.default_config;
    let mut sender_thread = None;
    if sending {
        let queue: VecDeque<Vec<u8>> = match &source {
            SendSource::Items(v) => v.iter().cloned().collect(),
            _ => VecDeque::new(),
        };
        if let Some(Source::Serial(p)) = &src {
            let clone = p
                .try_clone()
                .with_context(|| format!("{}: cannot clone the port", port_path.display()))?;
            let _ = tx.send(ToSender::Port(clone));
        }
        let default = args.default_config.then(default_config);
        let c = ctl.clone();
        sender_thread = Some(std::thread::spawn(move || sender(rx, queue, default, c)));
        if matches!(source, SendSource::Stdin) {
            let tx = tx.clone();
            // Detached: it may block on stdin forever; it holds no device.
            std::thread::spawn(move || {
                let stdin = std::io::stdin();
                for (i, line) in stdin.lock().lines().enumerate() {
                    let Ok(line) = line else { break };
                    match parse_send_line(&line) {
                        Ok(Some(b)) => {
                            if tx.send(ToSender::Item(b)).is_err() {
                                break;
                            }
                        }
                        Ok(None) => {}
                        Err(e) => eprintln!("error: stdin:{}: {e} (line skipped)", i + 1),
                    }
                }
            });
        }
    }

    let result = read_loop(args, &port_path, &ctl, &mut l, &mut src, &tx, &mut con);
    // Stop the sender and wait for it, so that the device is closed when this returns.
    let _ = tx.send(ToSender::Stop);
    drop(tx);
    if let Some(t) = sender_thread {
        let _ = t.join();
    }
    drop(src);
    ctl.connected.store(false, Ordering::SeqCst);
    l.stats_mut().sent = ctl.sent.load(Ordering::SeqCst);
    ctl.publish(&l);
    if ctl.abort.load(Ordering::SeqCst) {
        return Ok(l.stats().clone());
    }
    // Whatever ended the loop, save what arrived.
    let saved = l.save(&args.out);
    let recorded = l.finish_recording();
    con.status(&l, true);
    con.finish();
    match recorded {
        Ok(Some(f)) => con.line(&format!("wrote {}", f.display())),
        Ok(None) => {}
        Err(e) => con.line(&format!("warning: {e:#}")),
    }
    match saved {
        Ok(files) => {
            for f in files {
                con.line(&format!("wrote {}", f.display()));
            }
        }
        Err(e) => {
            result?;
            return Err(e);
        }
    }
    result?;
    Ok(l.stats().clone())
}

fn read_loop(
    args: &ListenArgs,
    port_path: &Path,
    ctl: &Arc<Control>,
    l: &mut Listener,
    src: &mut Option<Source>,
    tx: &Sender<ToSender>,
    con: &mut Console,
) -> anyhow::Result<()> {
    let name = port_path.display().to_string();
    let opened = Instant::now();
    let mut go_sent = false;
    let mut last_save = Instant::now();
    let mut lost_at: Option<Instant> = None;
    let mut backoff = Duration::from_millis(100);
    let mut next_try = Instant::now();
    let mut last_error = String::new();
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        if ctl.stopping() {
            if let Some(t) = lost_at {
                l.stats_mut().disconnected_secs += t.elapsed().as_secs_f64();
            }
            return Ok(());
        }
        if !go_sent && opened.elapsed().as_secs_f64() >= args.hello_wait {
            go_sent = true;
            let _ = tx.send(ToSender::Go(false));
        }
        l.live_tick();
        if args.save_every > 0.0
            && last_save.elapsed().as_secs_f64() >= args.save_every
            && l.dirty()
        {
            l.stats_mut().sent = ctl.sent.load(Ordering::SeqCst);
            if let Err(e) = l.save(&args.out) {
                con.line(&format!("error: saving: {e:#}"));
            }
            last_save = Instant::now();
        }
        let Some(s) = src.as_mut() else {
            // Disconnected: reopen with a back-off.
            if Instant::now() < next_try {
                std::thread::sleep(Duration::from_millis(20));
                con.status(l, false);
                continue;
            }
            match open_port(port_path, args.baud, Duration::from_millis(100)) {
                Ok(p) => {
                    if let Some(t) = lost_at.take() {
                        l.stats_mut().disconnected_secs += t.elapsed().as_secs_f64();
                    }
                    l.reconnected();
                    if let Ok(c) = p.try_clone() {
                        let _ = tx.send(ToSender::Port(c));
                    }
                    con.line(&format!(
                        "{name}: reopened (reconnect {})",
                        l.stats().reconnects
                    ));
                    *src = Some(Source::Serial(p));
                    ctl.connected.store(true, Ordering::SeqCst);
                    backoff = Duration::from_millis(100);
                }
                Err(e) => {
                    let msg = format!("{e:#}");
                    if msg != last_error {
                        con.line(&format!("{msg}; retrying"));
                        last_error = msg;
                    }
                    next_try = Instant::now() + backoff;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                }
            }
            continue;
        };
        let got = match s {
            Source::Serial(p) => p.read(&mut buf),
            Source::File(f) => f.read(&mut buf),
        };
        match got {
            Ok(0) => {
                if matches!(s, Source::File(_)) {
                    return Ok(()); // end of the capture
                }
                lose(src, &mut lost_at, ctl, con, &format!("{name}: hung up"));
                last_error.clear();
            }
            Ok(n) => {
                for notice in l.push(&buf[..n]) {
                    con.line(&notice.to_string());
                    match notice {
                        Notice::Hello(_) => {
                            if go_sent {
                                let _ = tx.send(ToSender::Hello);
                            } else {
                                go_sent = true;
                                let _ = tx.send(ToSender::Go(true));
                            }
                        }
                        Notice::Done(_) if args.until_done => {
                            ctl.publish(l);
                            return Ok(());
                        }
                        _ => {}
                    }
                }
                ctl.publish(l);
            }
            Err(e) if transient(&e) => {}
            Err(e) => {
                if matches!(s, Source::File(_)) {
                    bail!("{name}: read error: {e}");
                }
                lose(src, &mut lost_at, ctl, con, &format!("{name}: lost ({e})"));
                last_error.clear();
            }
        }
        if src.is_none() {
            next_try = Instant::now() + Duration::from_millis(100);
        }
        con.status(l, false);
    }
}

fn lose(
    src: &mut Option<Source>,
    lost_at: &mut Option<Instant>,
    ctl: &Control,
    con: &mut Console,
    why: &str,
) {
    *src = None;
    *lost_at = Some(Instant::now());
    ctl.connected.store(false, Ordering::SeqCst);
    con.line(&format!("{why}; reopening"));
}

/// `host-sim listen`.
pub fn cli(args: &ListenArgs) -> anyhow::Result<()> {
    if args.print_config {
        println!(
            "{}",
            serde_json::to_string(&HostMsg::Config(default_config()))?
        );
        return Ok(());
    }
    let ctl = Control::new();
    // Ctrl-C / SIGTERM: save and stop; a second Ctrl-C exits at once.
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 130, ctl.stop.clone())
            .context("installing the signal handler")?;
        signal_hook::flag::register(sig, ctl.stop.clone())
            .context("installing the signal handler")?;
    }
    let stats = run(args, ctl)?;
    println!(
        "{} frames, {} bad ({} CRC), {} garbage bytes; {} scans seen, {} missed; {} reconnects, {} restarts",
        stats.frames,
        stats.bad_frames,
        stats.crc_errors,
        stats.garbage_bytes,
        stats.scans_seen,
        stats.scans_missed,
        stats.reconnects,
        stats.restarts
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::wire::{self, DeviceMsg, Hello, SamplerReport, ScanReport, Tile};

    fn frame(msg: &DeviceMsg<'_>) -> Vec<u8> {
        let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
        wire::encode(msg, &mut buf).unwrap().to_vec()
    }

    /// COBS with the terminating 0x00.
    fn cobs(raw: &[u8]) -> Vec<u8> {
        let mut out = vec![0];
        let mut code_at = 0;
        for &b in raw {
            if b == 0 {
                out[code_at] = (out.len() - code_at) as u8;
                code_at = out.len();
                out.push(0);
                continue;
            }
            out.push(b);
            if out.len() - code_at == 255 {
                out[code_at] = 255;
                code_at = out.len();
                out.push(0);
            }
        }
        out[code_at] = (out.len() - code_at) as u8;
        out.push(0);
        out
    }

    fn hello() -> Vec<u8> {
        frame(&DeviceMsg::Hello(Hello {
            firmware: "test",
            board: "host",
            tick_hz: 1000,
            width: 40,
            height: 24,
            tile_edge: 16,
            max_beams: 456,
            ray_capacity: 1,
            scan_capacity: 1,
            local_capacity: 1,
            count_max: 255,
        }))
    }

    fn config() -> RunConfig {
        RunConfig {
            origin_x_mm: -1000,
            origin_y_mm: 500,
            ..default_config()
        }
    }

    /// A run of `seqs` scans on a 40 x 24 grid (3 x 2 tiles): each scan sends one log-odds and
    /// one counts tile; values depend on the scan.
    fn stream(seqs: &[u32]) -> Vec<u8> {
        let mut s = hello();
        s.extend(frame(&DeviceMsg::Configured(config())));
        for &q in seqs {
            s.extend(frame(&DeviceMsg::Scan(ScanReport {
                seq: q,
                ..ScanReport::default()
            })));
            let (tx, ty) = ((q % 3) as u16, ((q / 3) % 2) as u16);
            let w = if tx == 2 { 8 } else { 16 };
            let h = if ty == 1 { 8 } else { 16 };
            let lo: Vec<u8> = (0..w * h)
                .flat_map(|i| (((i as i16) * 37 + q as i16 * 101) % 3000 - 1500).to_le_bytes())
                .collect();
            let counts: Vec<u8> = (0..w * h)
                .map(|i| ((i * 7 + q as usize) % 256) as u8)
                .collect();
            for (layer, data) in [(Layer::LogOdds, &lo), (Layer::Counts, &counts)] {
                s.extend(frame(&DeviceMsg::Tile(Tile {
                    layer,
                    tx,
                    ty,
                    data,
                })));
            }
            s.extend(frame(&DeviceMsg::Sampler(SamplerReport {
                samples: 9,
                ..SamplerReport::default()
            })));
            s.extend(frame(&DeviceMsg::Counters(Counters {
                scans: q + 1,
                ..Counters::default()
            })));
        }
        s
    }

    #[test]
    fn any_chunking_gives_the_same_map_and_counters() {
        let s = stream(&[0, 1, 2, 3, 4, 5, 6]);
        let mut whole = Listener::new();
        whole.push(&s);
        assert_eq!(whole.stats().frames, 2 + 7 * 5);
        assert_eq!(whole.stats().scans_seen, 7);
        assert_eq!(whole.stats().tiles, 14);
        assert_eq!(
            (whole.stats().bad_frames, whole.stats().garbage_bytes),
            (0, 0)
        );
        for n in [1, 2, 7, 100, 545] {
            let mut l = Listener::new();
            for c in s.chunks(n) {
                l.push(c);
            }
            assert_eq!(l.map(), whole.map(), "chunks of {n}");
            assert_eq!(l.have_counts(), whole.have_counts());
            assert_eq!(
                serde_json::to_string(l.stats()).unwrap(),
                serde_json::to_string(whole.stats()).unwrap(),
                "chunks of {n}"
            );
        }
        // The map is the tiles: tile (1, 0) was last sent by scan 1, tile (1, 1) by scan 4.
        let m = whole.map().unwrap();
        assert_eq!((m.width, m.height), (40, 24));
        assert_eq!(m.log_odds[16], 101 - 1500);
        assert_eq!(m.log_odds[16 * 40 + 16], 4 * 101 - 1500);
    }

    #[test]
    fn corrupted_bytes_are_dropped_and_counted() {
        let clean = stream(&[0, 1, 2]);
        let mut s = vec![0x11, 0x22, 0x33, 0x00]; // garbage: a bad frame of 4 bytes
        s.extend(&clean);
        // Scan 1's report with one payload bit flipped: a CRC error (its tiles still apply).
        let scan1 = frame(&DeviceMsg::Scan(ScanReport {
            seq: 1,
            ..ScanReport::default()
        }));
        let at = s.windows(scan1.len()).position(|w| w == scan1).unwrap();
        let mut raw = scan1[..scan1.len() - 1].to_vec();
        let n = wire::cobs_decode_in_place(&mut raw).unwrap();
        raw.truncate(n);
        raw[2] ^= 0x40;
        let bad = cobs(&raw);
        s.splice(at..at + scan1.len(), bad.iter().copied());
        // An oversized run with no 0x00, then a clean Done.
        s.extend(std::iter::repeat_n(0x55u8, 3 * wire::MAX_DEVICE_FRAME));
        s.push(0);
        s.extend(frame(&DeviceMsg::Done(Done::default())));
        let mut l = Listener::new();
        let mut notices = Vec::new();
        for c in s.chunks(5) {
            notices.extend(l.push(c));
        }
        let st = l.stats();
        assert_eq!(st.bad_frames, 2, "{st:?}");
        assert_eq!(st.crc_errors, 1);
        assert_eq!(st.oversized, 1);
        assert_eq!(
            st.garbage_bytes,
            4 + bad.len() as u64 + 3 * wire::MAX_DEVICE_FRAME as u64 + 1
        );
        assert_eq!(st.frames, 2 + 3 * 5 - 1 + 1);
        // The lost report leaves a hole in the scan numbers that is not a gap: scan 2 follows
        // scan 0, so scan 1 counts as missed (its report did not arrive).
        assert_eq!(st.scans_missed, 1);
        assert!(notices.iter().any(|n| matches!(n, Notice::Done(_))));
        assert_eq!(st.tiles, 6);
    }

    #[test]
    fn gaps_are_counted_and_reconnects_resync() {
        let s = stream(&[0, 1, 2, 6, 7]);
        let mut l = Listener::new();
        let notices = l.push(&s);
        assert_eq!(l.stats().scans_missed, 3);
        assert_eq!(l.stats().gaps, vec![Gap { first: 3, last: 5 }]);
        assert!(notices.contains(&Notice::Gap(Gap { first: 3, last: 5 })));
        // Cut mid-frame, reconnect, resume mid-frame of another scan: the two halves are bad
        // frames, scans 8..=9 are missed, scan 10 resynchronises.
        let later = stream(&[10, 11]);
        let hello_len = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        let tail = &later[hello_len..];
        let scan8 = stream(&[8]);
        let cut = &scan8[hello_len..hello_len + 7];
        l.push(cut);
        l.reconnected();
        let junk_tail = [0x42u8, 0x17, 0x99];
        l.push(&junk_tail);
        l.push(&[0]);
        let n = l.push(tail);
        let st = l.stats();
        assert_eq!(st.reconnects, 1);
        assert_eq!(st.bad_frames, 2, "{st:?}");
        assert_eq!(st.garbage_bytes, 8 + 4);
        assert!(n.contains(&Notice::Resynced(8 + 4)), "{n:?}");
        assert!(n.contains(&Notice::Gap(Gap { first: 8, last: 9 })));
        assert_eq!(st.scans_missed, 5);
        assert_eq!(st.scans_seen, 7);
        assert_eq!(st.last_seq, Some(11));
        // A new boot starts a new map and a new count.
        l.push(&stream(&[0]));
        assert_eq!(l.stats().hellos, 2);
        assert_eq!(l.stats().scans_missed, 5);
        assert_eq!(l.map().unwrap().tiles, 2);
    }

    #[test]
    fn absurd_hello_is_refused_and_tiles_without_hello_assume_the_firmware_grid() {
        let big = frame(&DeviceMsg::Hello(Hello {
            firmware: "x",
            board: "y",
            tick_hz: 1,
            width: u16::MAX,
            height: u16::MAX,
            tile_edge: 16,
            max_beams: 1,
            ray_capacity: 1,
            scan_capacity: 1,
            local_capacity: 1,
            count_max: 255,
        }));
        let mut l = Listener::new();
        let n = l.push(&big);
        assert_eq!(l.stats().bad_hellos, 1);
        assert!(l.map().is_none());
        assert!(matches!(n.as_slice(), [Notice::Warning(_)]));
        // A tile off the firmware grid is dropped, one on it applied.
        let data = vec![1u8; 256];
        let off = frame(&DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: 99,
            ty: 0,
            data: &data,
        }));
        let on = frame(&DeviceMsg::Tile(Tile {
            layer: Layer::Counts,
            tx: 15,
            ty: 15,
            data: &data,
        }));
        l.push(&off);
        l.push(&on);
        let m = l.map().unwrap();
        assert_eq!((m.width, m.height), (256, 256));
        assert_eq!((l.stats().tiles, l.stats().bad_tiles), (1, 1));
        assert_eq!(m.counts[255 * 256 + 255], 1);
    }

    fn export_stream(capture: &Path, out: &Path) {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct W {
            #[command(flatten)]
            a: crate::map_export::ExportArgs,
        }
        let w = W::try_parse_from([
            "x".as_ref(),
            "--stream".as_ref(),
            capture.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
        .unwrap();
        crate::map_export::run(&w.a).unwrap();
    }

    #[test]
    fn saved_files_equal_export_of_the_capture_and_a_restart_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("listen");
        std::fs::create_dir_all(&out).unwrap();
        let capture = out.join(CAPTURE_FILE);
        let s = stream(&[0, 1, 2, 3, 4, 5]);
        // First listener: scans 0..=2 and 5 bytes of scan 3's report, then it is killed (no
        // save).
        let first = stream(&[0, 1, 2]);
        let k = first.len() + 5;
        {
            let mut a = Listener::with_capture(&capture, false).unwrap();
            for c in s[..k].chunks(64) {
                a.push(c);
            }
            assert_eq!(a.stats().scans_seen, 3);
        }
        // Scans 3 and 4 happen while nobody listens; the second listener gets scan 5 on.
        let hello_len = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        let only5 = stream(&[5]);
        let mut b = Listener::with_capture(&capture, false).unwrap();
        assert_eq!(b.stats().restarts, 1);
        assert_eq!(b.stats().scans_seen, 3);
        let n = b.push(&only5[hello_len..]);
        assert!(n.contains(&Notice::Gap(Gap { first: 3, last: 4 })), "{n:?}");
        assert!(n.iter().any(|x| matches!(x, Notice::Resynced(_))), "{n:?}");
        assert_eq!(b.stats().scans_missed, 2);
        assert_eq!(b.stats().bad_frames, 1); // scan 3's cut report
        let files = b.save(&out).unwrap();
        assert_eq!(files.len(), 7, "{files:?}");
        assert!(!out.join(".saving").exists());
        // The same files as `host-sim export --stream` on the capture.
        let exp = dir.path().join("export");
        export_stream(&capture, &exp.join("map.yaml"));
        for f in ["map.pgm", "map.yaml", "map.png"] {
            assert_eq!(
                std::fs::read(out.join(f)).unwrap(),
                std::fs::read(exp.join(f)).unwrap(),
                "{f}"
            );
        }
        let yaml = std::fs::read_to_string(out.join("map.yaml")).unwrap();
        assert!(yaml.contains("image: map.pgm") && yaml.contains("origin: [-1.0, 0.5, 0.0]"));
        // status.json carries the counters; a third start counts restart 2.
        let st: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join(STATUS_FILE)).unwrap()).unwrap();
        assert_eq!(st["scans_missed"], 2);
        assert_eq!(st["gaps"][0]["first"], 3);
        let c = Listener::with_capture(&capture, false).unwrap();
        assert_eq!(c.stats().restarts, 2);
        assert_eq!(c.map(), b.map());
        // --fresh starts over.
        let d = Listener::with_capture(&capture, true).unwrap();
        assert!(d.map().is_none());
        assert_eq!(std::fs::metadata(&capture).unwrap().len(), 0);
    }

    #[test]
    fn run_on_a_captured_file_saves_at_its_end() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("capture.bin");
        std::fs::write(&input, stream(&[0, 1, 2, 3])).unwrap();
        let out = dir.path().join("out");
        let mut args = ListenArgs::new(&input, &out);
        args.quiet = true;
        let st = run(&args, Control::new()).unwrap();
        assert_eq!(st.scans_seen, 4);
        assert_eq!(st.saves, 1);
        for f in [
            "map.yaml",
            "map.pgm",
            "map.png",
            "log_odds.yaml",
            "log_odds.pgm",
            "log_odds.png",
            STATUS_FILE,
            CAPTURE_FILE,
        ] {
            assert!(out.join(f).exists(), "{f}");
        }
        assert_eq!(
            std::fs::read(out.join(CAPTURE_FILE)).unwrap(),
            std::fs::read(&input).unwrap()
        );
        // Bad input: clear one-line errors, no panic.
        let e = run(
            &ListenArgs::new(dir.path().join("nope"), &out),
            Control::new(),
        )
        .unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            format!(
                "{}: no such file or device",
                dir.path().join("nope").display()
            )
        );
        let mut a = ListenArgs::new(&input, &out);
        a.send = Some(dir.path().join("missing.jsonl"));
        let e = run(&a, Control::new()).unwrap_err();
        assert!(
            format!("{e:#}").ends_with("missing.jsonl: file not found"),
            "{e:#}"
        );
        let e = run(&ListenArgs::new(dir.path(), &out), Control::new()).unwrap_err();
        assert!(format!("{e:#}").contains("is a directory"), "{e:#}");
        // Empty, truncated and wrong-format inputs: one line naming the file.
        let f = dir.path().join("f");
        let out2 = dir.path().join("out2");
        let err = |a: &ListenArgs| format!("{:#}", run(a, Control::new()).unwrap_err());
        let fp = f.display().to_string();
        std::fs::write(&f, b"").unwrap();
        assert_eq!(
            err(&ListenArgs::new(&f, &out2)),
            format!("{fp}: file is empty")
        );
        std::fs::write(&f, b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR").unwrap();
        assert!(err(&ListenArgs::new(&f, &out2))
            .starts_with(&format!("{fp}: wrong format: not a map stream")));
        assert!(!out2.exists(), "nothing written for a bad capture");
        let dev = ListenArgs::new("/dev/null", &out2);
        assert!(err(&dev).starts_with("/dev/null: cannot open as a serial port"));
        for (content, why) in [
            (&b""[..], "no message to send"),
            (&b"{\"ScanEnd\":{\"seq\":1,\"poi"[..], "1: not JSON"),
            (&b"\xff\xfe\x00binary"[..], "not UTF-8"),
        ] {
            std::fs::write(&f, content).unwrap();
            let mut a = ListenArgs::new("/dev/null", &out2);
            a.send = Some(f.clone());
            let e = err(&a);
            assert!(e.starts_with(&fp) && e.contains(why), "{e}");
            let mut a = ListenArgs::new("/dev/null", &out2);
            a.send_raw = Some(f.clone());
            if content.is_empty() {
                assert_eq!(err(&a), format!("{fp}: file is empty"));
            }
        }
    }

    #[test]
    fn send_lines_round_trip_and_bad_lines_name_their_line() {
        use crate::explore::ScanRecord;
        use ogm_core::{Angle, Beam, Pose, Range};
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
        let input = crate::link::encode_run(&config(), &scans, true).unwrap();
        let text = send_lines(&input);
        assert!(text.starts_with("{\"Config\":{"));
        assert!(text.contains("{\"ScanStart\":{\"seq\":2,"));
        assert!(text.trim_end().ends_with("\"Finish\""));
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("send.jsonl");
        std::fs::write(&f, format!("# a comment\n\n{text}")).unwrap();
        let items = read_send_file(&f).unwrap();
        assert_eq!(items.concat(), input.bytes);
        for (bad, why) in [
            ("{\"Config\":{\"cell_mm\":50}}", "missing field"),
            ("{\"Fly\":1}", "unknown variant"),
            ("{\"raw\":\"54f\"}", "odd number"),
            ("{\"raw\":\"zz\"}", "not a hex digit"),
            ("{\"raw\":7}", "string of hex"),
            ("{\"ScanEnd\":{\"seq\":-1,\"points\":3}}", "host message"),
            ("Finish", "not JSON"),
        ] {
            std::fs::write(&f, format!("\"Finish\"\n{bad}\n")).unwrap();
            let e = format!("{:#}", read_send_file(&f).unwrap_err());
            assert!(
                e.starts_with(&format!("{}:2: ", f.display())) && e.contains(why),
                "{bad}: {e}"
            );
        }
        std::fs::write(&f, "\n# nothing\n").unwrap();
        assert!(format!("{:#}", read_send_file(&f).unwrap_err()).contains("no message"));
        // The default settings print as a line that parses back.
        let line = serde_json::to_string(&HostMsg::Config(default_config())).unwrap();
        assert_eq!(
            parse_send_line(&line).unwrap(),
            Some(host_frame(&HostMsg::Config(default_config())))
        );
        // A settings file from before `free_update_q8` existed reads as the textbook model.
        let old = line.replace(
            &format!(",\"free_update_q8\":{}", default_config().free_update_q8),
            "",
        );
        assert!(!old.contains("free_update_q8"), "{old}");
        let want = RunConfig {
            free_update_q8: 256,
            ..default_config()
        };
        assert_eq!(
            parse_send_line(&old).unwrap(),
            Some(host_frame(&HostMsg::Config(want)))
        );
    }

    /// Reads from `port` until `n` bytes came (or 10 s passed).
    fn read_n(port: &mut dyn serialport::SerialPort, n: usize) -> Vec<u8> {
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        let t0 = Instant::now();
        while got.len() < n && t0.elapsed() < Duration::from_secs(10) {
            if let Ok(k) = port.read(&mut buf) {
                got.extend_from_slice(&buf[..k]);
            }
        }
        got
    }

    fn wait(what: &str, f: impl Fn() -> bool) {
        let t0 = Instant::now();
        while !f() {
            assert!(t0.elapsed() < Duration::from_secs(20), "{what}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// A pseudo-terminal pair stands in for a USB serial adapter: the listener opens the device
    /// through a symlink (as udev's /dev/serial/by-id links), "unplug" closes the robot's end
    /// and removes the link, "replug" makes a new pair behind the same link.
    #[test]
    fn unplug_and_replug_reopens_counts_the_gap_and_keeps_sending() {
        use serialport::{SerialPort, TTYPort};
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("robot");
        let plug = || -> TTYPort {
            let (mut robot, dev) = TTYPort::pair().expect("a pseudo-terminal pair");
            let name = dev.name().expect("the pty's name");
            drop(dev);
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink(name, &link).unwrap();
            robot.set_timeout(Duration::from_millis(50)).unwrap();
            robot
        };
        let mut robot = plug();
        let send = dir.path().join("send.jsonl");
        std::fs::write(&send, "{\"raw\":\"0102\"}\n\"Finish\"\n").unwrap();
        let out = dir.path().join("out");
        let mut args = ListenArgs::new(&link, &out);
        args.send = Some(send);
        args.default_config = true;
        args.hello_wait = 60.0; // send only after the Hello
        args.save_every = 0.0;
        args.quiet = true;
        let ctl = Control::new();
        let c = ctl.clone();
        let t = std::thread::spawn(move || run(&args, c));
        wait("listener open", || ctl.connected.load(Ordering::SeqCst));
        let stats = || ctl.stats().unwrap_or_default();

        // Boot: the Hello makes it send the default settings, then the file's lines.
        let s = stream(&[0, 1, 2, 3]);
        let first = stream(&[0, 1, 2]);
        robot.write_all(&first).unwrap();
        let cfg_frame = host_frame(&HostMsg::Config(default_config()));
        let finish = host_frame(&HostMsg::Finish);
        let expected = [cfg_frame.clone(), vec![1, 2], finish].concat();
        assert_eq!(read_n(&mut robot, expected.len()), expected);
        wait("scan 2", || stats().last_seq == Some(2));

        // Unplugged in the middle of scan 3's frames.
        robot.write_all(&s[first.len()..first.len() + 9]).unwrap();
        wait("9 more bytes", || {
            stats().bytes == s.len().min(first.len() + 9) as u64
        });
        drop(robot);
        std::fs::remove_file(&link).unwrap();
        wait("loss noticed", || !ctl.connected.load(Ordering::SeqCst));
        std::thread::sleep(Duration::from_millis(300)); // "no such device; retrying"

        // Replugged: scans 3-5 went nowhere; 6 and 7 arrive.
        let mut robot = plug();
        wait("reopened", || ctl.connected.load(Ordering::SeqCst));
        let hl = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        robot.write_all(&stream(&[6, 7])[hl..]).unwrap();
        wait("scan 7", || stats().last_seq == Some(7));
        // The robot reboots: the sender (on the new device) sends the default settings again.
        robot.write_all(&hello()).unwrap();
        assert_eq!(read_n(&mut robot, cfg_frame.len()), cfg_frame);
        wait("second Hello", || stats().hellos == 2);

        ctl.stop.store(true, Ordering::SeqCst); // Ctrl-C
        let st = t.join().unwrap().unwrap();
        assert_eq!(st.reconnects, 1);
        assert!(st.disconnected_secs >= 0.3, "{}", st.disconnected_secs);
        assert_eq!(st.gaps, vec![Gap { first: 3, last: 5 }]);
        assert_eq!(st.scans_missed, 3);
        assert_eq!(st.scans_seen, 5);
        assert_eq!(st.bad_frames, 1, "scan 3's cut report");
        assert_eq!(st.garbage_bytes, 10);
        assert_eq!(st.sent, 2);
        assert_eq!(st.saves, 1, "saved on stop");
        // The new boot's (still empty) map and the counters were saved.
        assert!(out.join(STATUS_FILE).exists() && out.join("map.pgm").exists());
    }
}
