//! What the device says about itself (`Hello`) and the settings it takes: the engine is built
//! once, from the first valid settings, in the slot the board gave it; and the settings a robot
//! without a host maps with ([`STORED_CONFIG`]).

use embedded_io::Write;
use ogm_core::config::{PoseInput, RunConfig};
use ogm_core::session::{Buffers, Session, Storage};
use ogm_core::wire::{ConfigFault, DeviceMsg, ErrorCode, Hello};

use super::lidar::{built_for, Lidar};
use super::{State, EDGE, HEIGHT, MAX_BEAMS, SIZES, WIDTH};
use crate::platform::Platform;

impl<S: Storage> State<'_, S> {
    pub(super) fn hello<W: Write, P: Platform>(&mut self, link: &mut W) {
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
        // A rolling window moves by whole streamed tiles and needs its hysteresis band
        // (`Session::window_fits`).
        let margin = usize::from(config.window_margin_cells);
        if margin > 0
            && !(WIDTH % EDGE == 0 && HEIGHT % EDGE == 0 && margin + EDGE <= WIDTH.min(HEIGHT) / 2)
        {
            let detail = ConfigFault::Window.detail();
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

    /// Applies settings to the engine and, if they were taken now, to the lidar's turns.
    pub(super) fn apply<W: Write, P: Platform>(
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
}

/// Builds the engine in `slot`. Not inlined: its temporaries (copies of the sampler's 2 KiB
/// forward-model tables) are gone before the main loop goes on.
#[inline(never)]
fn build<S: Storage>(
    slot: &mut Option<Session<S>>,
    config: RunConfig,
    bufs: Buffers<S>,
) -> Result<&mut Session<S>, ogm_core::session::SessionError> {
    Session::new_in(slot, config, bufs)
}

/// The settings a robot maps with when no host configures it: [`RunConfig::ROBOT`] (an LD06's
/// range, 12 m; a sampler budget of one LD06 turn, 100 ms; seed 1) on a grid centred on where
/// it was switched on, and no poses (it maps as a standing sensor: [`PoseInput::Fixed`]). A
/// constant (a test checks it equals `RunConfig::ROBOT`).
pub const STORED_CONFIG: RunConfig = {
    let cell_mm = RunConfig::ROBOT.cell_mm as i64;
    let half_w = -((WIDTH as i64 * cell_mm / 2) as i32);
    let half_h = -((HEIGHT as i64 * cell_mm / 2) as i32);
    RunConfig::ROBOT
        .with_origin_mm(half_w, half_h)
        .with_poses(PoseInput::Fixed)
};
