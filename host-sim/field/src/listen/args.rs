//! The options of `host-sim listen` and the default settings it can send.

use std::path::PathBuf;

use ogm_core::config::{Budget, RunConfig};
use ogm_firmware::sizes::MPS2_AN386 as FW;

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
    /// at every scan, into this MCAP file (replaced; `ogm_field::recording`).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Also serve a live view for Foxglove Studio (its WebSocket protocol) on this address
    /// (default 127.0.0.1:8765, localhost only): both maps twice a second while tiles arrive,
    /// the robot's pose at every scan (`ogm_field::live`).
    #[arg(long, num_args = 0..=1, default_missing_value = crate::live::DEFAULT_ADDR)]
    pub live: Option<String>,
    /// Do not send stored tiles back when the robot's rolling window comes back to them (by
    /// default the listener sends them, docs/wire.md "Restoring stored tiles"); the robot then
    /// starts the region from unknown and the map merges the visits. Each shift is still
    /// answered with `Resume` (nothing to send), so a robot with `window_hold` does not wait.
    #[arg(long)]
    pub no_restore: bool,
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
            no_restore: false,
        }
    }
}

/// The default settings for `--default-config`: the robot's (`RunConfig::ROBOT`) on a grid
/// centred on the world origin (the robot's start), LD06 range 12 m, seed 1, the time budget of
/// `host-sim firmware` (6.4 ms of board time per scan, at most 20 000 updates).
pub fn default_config() -> RunConfig {
    let cell_mm = 50;
    let half = |n: u16| -(i32::from(n) * cell_mm / 2);
    RunConfig::ROBOT
        .with_origin_mm(half(FW.width), half(FW.height))
        .with_max_range_mm(12_000)
        .with_seed(1)
        .with_budget(Budget::Time {
            period_us: 6400,
            max_updates: 20_000,
        })
}
