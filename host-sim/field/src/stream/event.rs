//! The robot's messages as the host keeps them: [`DeviceEvent`], with owned copies of the
//! messages that borrow from their frame ([`OwnedHello`], [`OwnedTile`], [`OwnedRanges`]).

use ogm_core::config::RunConfig;
use ogm_core::wire::{
    self, Counters, DeviceError, DeviceMsg, Done, Hello, Layer, SamplerReport, ScanReport,
    WireError,
};

/// A decoded device message with owned data.
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceEvent {
    /// Boot message.
    Hello(OwnedHello),
    /// Settings accepted.
    Configured(RunConfig),
    /// A scan was processed.
    Scan(ScanReport),
    /// Map data.
    Tile(OwnedTile),
    /// Sampler statistics.
    Sampler(SamplerReport),
    /// Counters.
    Counters(Counters),
    /// An error report.
    Error(DeviceError),
    /// End of run.
    Done(Done),
    /// An idle period ended.
    Idle(wire::IdleReport),
    /// A scan's ranges.
    Ranges(OwnedRanges),
    /// The rolling window moved, or the run ends with one (wire version 6).
    Window(wire::WindowReport),
}

impl From<DeviceMsg<'_>> for DeviceEvent {
    fn from(m: DeviceMsg<'_>) -> Self {
        match m {
            DeviceMsg::Hello(h) => DeviceEvent::Hello(OwnedHello::from(&h)),
            DeviceMsg::Configured(c) => DeviceEvent::Configured(c),
            DeviceMsg::Scan(s) => DeviceEvent::Scan(s),
            DeviceMsg::Tile(t) => DeviceEvent::Tile(OwnedTile {
                layer: t.layer,
                tx: t.tx,
                ty: t.ty,
                data: t.data.to_vec(),
            }),
            DeviceMsg::Sampler(s) => DeviceEvent::Sampler(s),
            DeviceMsg::Counters(c) => DeviceEvent::Counters(c),
            DeviceMsg::Error(e) => DeviceEvent::Error(e),
            DeviceMsg::Done(d) => DeviceEvent::Done(d),
            DeviceMsg::Idle(r) => DeviceEvent::Idle(r),
            DeviceMsg::Ranges(r) => DeviceEvent::Ranges(OwnedRanges {
                seq: r.seq,
                data: r.data.to_vec(),
            }),
            DeviceMsg::Window(w) => DeviceEvent::Window(w),
        }
    }
}

/// A [`Hello`] with owned strings: the one form of the robot's boot message on the host.
///
/// [`StreamDecoder`](super::StreamDecoder) hands out events that outlive the frame they were
/// decoded from, and `Hello` borrows its two strings from that frame (ogm-core has no
/// allocator), so the decoded message needs this owned copy, made field for field by
/// `From<&Hello>`. Whatever on the host keeps a robot's `Hello` (`listen`'s status, the
/// firmware report) keeps this one.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct OwnedHello {
    /// Firmware name and version.
    pub firmware: String,
    /// Board.
    pub board: String,
    /// Timer ticks per second.
    pub tick_hz: u32,
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Tile edge, cells.
    pub tile_edge: u16,
    /// Beams per scan buffer.
    pub max_beams: u32,
    /// Ray store rays.
    pub ray_capacity: u32,
    /// Ray store scans.
    pub scan_capacity: u32,
    /// Sampler's per-tile ray list.
    pub local_capacity: u32,
    /// Largest marginal count.
    pub count_max: u32,
}

impl From<&Hello<'_>> for OwnedHello {
    fn from(h: &Hello<'_>) -> Self {
        OwnedHello {
            firmware: h.firmware.to_string(),
            board: h.board.to_string(),
            tick_hz: h.tick_hz,
            width: h.width,
            height: h.height,
            tile_edge: h.tile_edge,
            max_beams: h.max_beams,
            ray_capacity: h.ray_capacity,
            scan_capacity: h.scan_capacity,
            local_capacity: h.local_capacity,
            count_max: h.count_max,
        }
    }
}

/// A [`wire::Tile`] with owned data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedTile {
    /// Which map.
    pub layer: Layer,
    /// Tile column in the building's tiling (the grid's own with a fixed window).
    pub tx: i32,
    /// Tile row in the building's tiling.
    pub ty: i32,
    /// Cells.
    pub data: Vec<u8>,
}

/// A [`wire::ScanRanges`] with owned data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedRanges {
    /// The scan's number.
    pub seq: u32,
    /// [`wire::SCAN_RANGES_LEN`] bytes (checked by [`OwnedRanges::bins`]).
    pub data: Vec<u8>,
}

impl OwnedRanges {
    /// The bins holding a reading: (direction in the robot's frame, reading); an error if the
    /// data has the wrong length.
    pub fn bins(&self) -> Result<Vec<(ogm_core::Angle, ogm_core::types::scan::Range)>, WireError> {
        let r = wire::ScanRanges {
            seq: self.seq,
            data: &self.data,
        };
        let bins = r.bins()?.collect();
        Ok(bins)
    }
}
