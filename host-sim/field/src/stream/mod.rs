//! The robot's link seen from the host (docs/wire.md): the map stream it sends, decoded by
//! [`StreamDecoder`] (COBS frames; resynchronises at the next `0x00` after garbage or a bad
//! frame) into [`DeviceEvent`]s, the map rebuilt from its tiles ([`StreamedMap`]; the whole building of a rolling window:
//! [`BuildingMap`]), and the host
//! frames sent to it ([`host_frame`]).
//!
//! Everything framing-related is ogm-core's own code (`ogm_core::wire`), so host and robot
//! cannot disagree about the format. (`ogm_core::lidar::link` is the robot's side of the same
//! link: its demultiplexer of host frames and lidar bytes.)

mod building;
mod event;
mod map;
mod visit;

use anyhow::{anyhow, bail, ensure};
use ogm_core::wire::{self, DeviceMsg, HostMsg, WireError};

pub use building::{
    BuildingError, BuildingMap, BuildingRender, MAX_BUILDING_CELLS, MAX_BUILDING_TILES,
};
pub use event::{DeviceEvent, OwnedHello, OwnedRanges, OwnedTile};
pub use map::{counts_of_one, stream_probabilities, MapLayer, StreamedMap};
pub use visit::Revisits;

/// Decodes the robot's map stream: bytes in (any chunking), [`DeviceEvent`]s out. A bad or
/// oversized frame costs only itself: decoding resumes after the next `0x00`.
#[derive(Clone, Debug, Default)]
pub struct StreamDecoder {
    buf: Vec<u8>,
    skipping: bool,
    stats: DecoderStats,
}

impl StreamDecoder {
    /// A fresh decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Feeds bytes; returns what they completed, in order (errors included).
    pub fn push(&mut self, data: &[u8]) -> Vec<Result<DeviceEvent, WireError>> {
        let mut out = Vec::new();
        for &b in data {
            self.stats.bytes += 1;
            if b != 0 {
                if self.skipping {
                    continue;
                }
                self.buf.push(b);
                if self.buf.len() > 2 * wire::MAX_DEVICE_FRAME {
                    self.stats.oversized += 1;
                    self.buf.clear();
                    self.skipping = true;
                }
                continue;
            }
            if std::mem::take(&mut self.skipping) || self.buf.is_empty() {
                self.buf.clear();
                continue;
            }
            let mut frame = std::mem::take(&mut self.buf);
            match wire::decode::<DeviceMsg>(&mut frame) {
                Ok(m) => {
                    self.stats.frames += 1;
                    out.push(Ok(DeviceEvent::from(m)));
                }
                Err(e) => {
                    self.stats.bad_frames += 1;
                    out.push(Err(e));
                }
            }
        }
        out
    }
}

/// Decoder counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DecoderStats {
    /// Bytes received.
    pub bytes: u64,
    /// Good frames.
    pub frames: u64,
    /// Frames that failed COBS/CRC/version/postcard.
    pub bad_frames: u64,
    /// Frames longer than any valid one (skipped to the next `0x00`).
    pub oversized: u64,
}

/// Reads a captured stream file (e.g. UART1 of `scripts/firmware.sh run`) and summarises it.
pub fn decode_file(path: &std::path::Path) -> anyhow::Result<Vec<DeviceEvent>> {
    let bytes = std::fs::read(path).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    ensure!(!bytes.is_empty(), "{}: file is empty", path.display());
    let mut d = StreamDecoder::new();
    let events: Vec<DeviceEvent> = d.push(&bytes).into_iter().filter_map(Result::ok).collect();
    let s = d.stats();
    if events.is_empty() {
        bail!(
            "{}: wrong format: not a map stream (no valid frame in {} bytes)",
            path.display(),
            s.bytes
        );
    }
    println!(
        "{}: {} bytes, {} frames, {} bad, {} oversized",
        path.display(),
        s.bytes,
        s.frames,
        s.bad_frames,
        s.oversized
    );
    Ok(events)
}

/// One host frame as it goes on the wire: a `0x00` (frame start for the robot's demultiplexer)
/// and the COBS frame with its terminating `0x00`.
pub fn host_frame(msg: &HostMsg) -> Vec<u8> {
    let mut buf = [0u8; wire::MAX_HOST_FRAME];
    let mut v = vec![0u8];
    match wire::encode(msg, &mut buf) {
        Ok(f) => v.extend_from_slice(f),
        // Unreachable: every HostMsg fits (tested in ogm-core).
        Err(e) => panic!("host frame does not fit: {e}"),
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use ogm_core::wire::{Done, Layer};

    #[test]
    fn decoder_resyncs_and_rebuilds_tiles() {
        let data: Vec<u8> = (0..512).map(|i| (i % 13) as u8).collect();
        let mut buf = [0u8; wire::MAX_DEVICE_FRAME];
        let mut stream = vec![0x11, 0x22, 0x00, 0x33, 0x00]; // garbage: two bad frames
        stream.extend_from_slice(
            wire::encode(
                &DeviceMsg::Tile(wire::Tile {
                    layer: Layer::LogOdds,
                    tx: 1,
                    ty: 0,
                    data: &data,
                }),
                &mut buf,
            )
            .unwrap(),
        );
        let mut bad = wire::encode(&DeviceMsg::Done(Done::default()), &mut buf)
            .unwrap()
            .to_vec();
        bad[2] ^= 0xFF;
        stream.extend(bad);
        stream
            .extend_from_slice(wire::encode(&DeviceMsg::Done(Done::default()), &mut buf).unwrap());
        let mut d = StreamDecoder::new();
        let mut events = Vec::new();
        for c in stream.chunks(7) {
            events.extend(d.push(c));
        }
        let ok: Vec<&DeviceEvent> = events.iter().filter_map(|e| e.as_ref().ok()).collect();
        assert_eq!(ok.len(), 2);
        assert_eq!(d.stats().bad_frames, 3);
        let DeviceEvent::Tile(t) = ok[0] else {
            panic!("{ok:?}")
        };
        let mut m = StreamedMap::new(32, 16, 16);
        m.apply(t).unwrap();
        assert_eq!(m.log_odds[16], i16::from_le_bytes([0, 1]));
        assert_eq!(m.log_odds[17 + 32], i16::from_le_bytes([8, 9]));
        assert!(m.apply(&OwnedTile { tx: 2, ..t.clone() }).is_err());
    }
}
