//! `host-sim listen`: watch a robot over its serial link (docs/listen.md).
//!
//! The robot streams its map as COBS frames (docs/wire.md). The listener
//!
//! * decodes the stream with the one decoder ([`StreamDecoder`]) and keeps the map
//!   ([`BuildingMap`]: the newest tile per building tile, so a rolling window's stream gives the
//!   whole building; a fixed grid's, the grid), whatever the chunking of the bytes;
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
//! * sends host messages (settings, scan poses, raw lidar bytes, `Finish`) from a file or stdin,
//!   and sends stored tiles back when a rolling window comes back to them (`Restore` parts,
//!   unless `--no-restore`; the map then replaces, else merges, the region's earlier visits);
//! * survives unplug/replug: on a read error it reopens the device with a back-off and goes on.
//!
//! Untrusted bytes from the port go only through [`StreamDecoder`] and [`BuildingMap::apply`]
//! (which checks every tile's size and caps how far the building grows); a `Hello` announcing
//! an absurd grid is refused.
//!
//! The core ([`Listener`]) takes bytes and is I/O free; [`run`] is the loop around a serial port
//! (or a captured file), [`cli`] the command.
//!
//! Files: `stats` (what it counts and reports) and `args` (the command's options); the core
//! ([`Listener`]) and its state here, `decode` (bytes → map and counters) and `output` (the map
//! into files, the recording and the live view); `port` (the serial device), `control`
//! ([`Control`]), `send` (host messages to the robot), `run` (the I/O loop and the command).
//! Each imports only those before it.

mod args;
mod control;
mod decode;
mod output;
mod port;
mod run;
mod send;
mod stats;
#[cfg(test)]
mod test_stream;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};

use crate::stream::{BuildingMap, BuildingRender, StreamDecoder, StreamedMap};

pub use args::{default_config, ListenArgs};
pub use control::Control;
pub use output::LIVE_PERIOD;
pub use port::open_port;
pub use run::{cli, run};
pub use send::{parse_send_line, read_send_file, SendSource};
pub use stats::{Gap, ListenStats, Notice};

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

/// The listener's core: bytes in (any chunking), map and counters out. No I/O but the capture.
pub struct Listener {
    decoder: StreamDecoder,
    /// Bytes of the frame being received (since the last `0x00`).
    pending: u64,
    capture: Option<(PathBuf, std::fs::File)>,
    /// The building as the tiles give it (a rolling window's: all of it).
    map: Option<BuildingMap>,
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
    /// Whether stored tiles go back to the robot when its window returns to them, and the
    /// frames waiting to be sent ([`Listener::take_outgoing`]).
    send_back: bool,
    outgoing: Vec<Vec<u8>>,
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
            send_back: true,
            outgoing: Vec::new(),
        }
    }

    /// Whether stored tiles are sent back to the robot (`Restore` parts, when a `Window`
    /// brings them back into its window); on by default.
    pub fn set_send_back(&mut self, on: bool) {
        self.send_back = on;
    }

    /// The host frames to send the robot now (stored tiles going back), oldest first.
    pub fn take_outgoing(&mut self) -> Vec<Vec<u8>> {
        std::mem::take(&mut self.outgoing)
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
        // A replayed capture's answers were due to a robot long gone.
        l.outgoing.clear();
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

    /// The building so far, rendered (none before the first `Hello` or tile): the `Hello`'s
    /// grid, grown by every tile that lies outside it (a rolling window's stream).
    pub fn render(&self) -> Option<BuildingRender> {
        self.map.as_ref().map(BuildingMap::render)
    }

    /// The map so far (none before the first `Hello` or tile); see [`Listener::render`].
    pub fn map(&self) -> Option<StreamedMap> {
        self.render().map(|r| r.map)
    }

    /// Cells of [`Listener::map`] whose marginal tile has arrived.
    pub fn have_counts(&self) -> Vec<bool> {
        self.render().map(|r| r.have_counts).unwrap_or_default()
    }

    /// Whether anything changed since the last save.
    pub fn dirty(&self) -> bool {
        self.dirty
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
        let c = &s.corrections;
        if c.corrected + c.cannot_tell > 0 {
            line += &format!(
                " | poses corrected {}, odometry kept {}",
                c.corrected, c.cannot_tell
            );
        }
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
