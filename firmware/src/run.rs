//! Boot and the main loop, above the application and the self-test: hello; then a host, the
//! stored settings (a robot whose lidar is talking) or the self-test; then the loop over the
//! host link and the lidar's UART.

use embedded_io::{Read, ReadReady, Write};
use ogm_core::config::LidarModel;
use ogm_core::session::Storage;

use crate::app::{write_all, App, Fed, Memory, STORED_CONFIG};
use crate::platform::{LidarPort, Platform};
use crate::selftest;

/// How long to wait at boot for the first byte from a host before running the self-test.
const HOST_WAIT_US: u64 = 100_000;

/// Waits up to [`HOST_WAIT_US`] for the first byte from a host.
fn wait_for_host<L: ReadReady, P: Platform>(link: &mut L, platform: &P) -> bool {
    let limit = P::ticks_in_us(HOST_WAIT_US);
    let t0 = platform.now();
    while platform.now().wrapping_sub(t0) < limit {
        if link.read_ready().unwrap_or(false) {
            return true;
        }
    }
    false
}

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
    let silent = P::ticks_in_us(LIDAR_SILENT_US);
    let mut heard = platform.now();
    // One LD06 packet at a time (a read completes at most one), so the turn queue's room is
    // checked before every packet.
    let mut chunk = [0u8; ogm_core::lidar::ld06::PACKET_LEN];
    loop {
        app.check_hold(link, platform);
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
        let wait = P::ticks_in_us(2_000);
        while platform.now().wrapping_sub(t0) < wait {}
        if !(ok && write_all(lidar, &ogm_core::lidar::rplidar::REQ_SCAN) && lidar.flush().is_ok()) {
            error!("lidar: cannot send the RPLIDAR its requests");
        }
    }
}
