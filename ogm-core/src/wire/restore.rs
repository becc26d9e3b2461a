//! Host → device: a stored tile sent back in parts ([`HostMsg::Restore`]), and the checks a
//! device applies to every part before it keeps one byte of it.
//!
//! A host frame is at most [`MAX_HOST_FRAME`] bytes, so a tile travels in parts of whole rows:
//! a `LogOdds` part holds `RESTORE_PART_BYTES / (2·edge)` rows, a `Counts` part
//! `RESTORE_PART_BYTES / edge` (16-cell tiles: 2 and 4 rows, 64 bytes each; 8 + 4 parts per
//! tile).
//!
//! [`HostMsg::Restore`]: super::HostMsg::Restore
//! [`MAX_HOST_FRAME`]: super::MAX_HOST_FRAME

use serde::de::{Error as _, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{HostMsg, Layer, RestoreFault};

/// The payload of one restore part, bytes (the last part of a tile may be shorter only when
/// the tile's rows do not divide evenly).
pub const RESTORE_PART_BYTES: usize = 64;

/// The bytes of one restore part: at most [`RESTORE_PART_BYTES`], held inline so that
/// [`HostMsg`] stays `Copy` and needs no lifetime. On the wire it is a postcard byte slice
/// (varint length, then the bytes); a longer slice fails to decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RestoreData {
    len: u8,
    // Invariant: every byte from `len` on is 0 (so the derived equality is the slices').
    bytes: [u8; RESTORE_PART_BYTES],
}

impl RestoreData {
    /// `data` as a part, if it fits.
    pub fn new(data: &[u8]) -> Option<Self> {
        let len = u8::try_from(data.len())
            .ok()
            .filter(|&n| usize::from(n) <= RESTORE_PART_BYTES)?;
        let mut bytes = [0; RESTORE_PART_BYTES];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(RestoreData { len, bytes })
    }

    /// The bytes.
    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

impl Serialize for RestoreData {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(self.as_slice())
    }
}

impl<'de> Deserialize<'de> for RestoreData {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Bytes;
        impl<'v> Visitor<'v> for Bytes {
            type Value = RestoreData;
            fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                write!(f, "at most {RESTORE_PART_BYTES} bytes")
            }
            fn visit_bytes<E: serde::de::Error>(self, v: &[u8]) -> Result<RestoreData, E> {
                RestoreData::new(v).ok_or_else(|| E::invalid_length(v.len(), &self))
            }
            // Self-describing formats (JSON) write bytes as a sequence of numbers.
            fn visit_seq<A: serde::de::SeqAccess<'v>>(
                self,
                mut seq: A,
            ) -> Result<RestoreData, A::Error> {
                let mut bytes = [0u8; RESTORE_PART_BYTES];
                let mut len = 0usize;
                while let Some(b) = seq.next_element::<u8>()? {
                    let slot = bytes
                        .get_mut(len)
                        .ok_or_else(|| A::Error::invalid_length(len.saturating_add(1), &self))?;
                    *slot = b;
                    len = len.saturating_add(1);
                }
                RestoreData::new(bytes.get(..len).unwrap_or(&[]))
                    .ok_or_else(|| A::Error::invalid_length(len, &self))
            }
        }
        d.deserialize_bytes(Bytes).map_err(D::Error::custom)
    }
}

/// Bytes per cell of a restorable layer; `None` for any other.
pub const fn restore_cell_bytes(layer: Layer) -> Option<usize> {
    match layer {
        Layer::LogOdds => Some(2),
        Layer::Counts => Some(1),
        Layer::Sample => None,
    }
}

/// The rows of an `edge`-cell tile one part of `layer` carries, if that layer can be restored
/// and one row fits a part.
pub const fn restore_rows_per_part(layer: Layer, edge: u16) -> Option<u16> {
    let Some(cell) = restore_cell_bytes(layer) else {
        return None;
    };
    let row = edge as usize * cell;
    if edge == 0 || row > RESTORE_PART_BYTES {
        return None;
    }
    // row ≤ 64, so the quotient is ≤ 64.
    Some((RESTORE_PART_BYTES / row) as u16)
}

/// How many parts an `edge`-cell tile of `layer` takes, if it can be restored (at most 32, so
/// a device tracks them in one `u32`).
pub const fn restore_parts(layer: Layer, edge: u16) -> Option<u32> {
    match restore_rows_per_part(layer, edge) {
        Some(rows) => {
            let n = (edge as u32).div_ceil(rows as u32);
            if n <= 32 {
                Some(n)
            } else {
                None
            }
        }
        None => None,
    }
}

/// The message checks of a restore part for tiles of `edge` cells: the layer is `LogOdds` or
/// `Counts`, `row` starts a part inside the tile, and `len` is exactly that part's bytes.
/// Returns the part's index in its layer.
pub fn check_restore_part(
    layer: Layer,
    row: u8,
    len: usize,
    edge: u16,
) -> Result<u32, RestoreFault> {
    let cell = restore_cell_bytes(layer).ok_or(RestoreFault::Layer)?;
    let rows = restore_rows_per_part(layer, edge).ok_or(RestoreFault::Edge)?;
    restore_parts(layer, edge).ok_or(RestoreFault::Edge)?;
    let row = u16::from(row);
    if row >= edge || row % rows != 0 {
        return Err(RestoreFault::Row);
    }
    // Bounded: rows ≤ 64 and edge ≤ 64 here (a row fits 64 bytes).
    let n = usize::from(rows.min(edge - row)) * usize::from(edge) * cell;
    if len != n {
        return Err(RestoreFault::Length);
    }
    Ok(u32::from(row / rows))
}

/// The [`HostMsg::Restore`] parts that carry building tile (`tx`, `ty`)'s `layer` (`data`: the
/// tile's cells as a [`super::Tile`] of that layer carries them, `edge × edge` cells), in
/// order. Empty if the layer or edge cannot be restored or `data` has the wrong length.
pub fn restore_msgs(
    tx: i32,
    ty: i32,
    layer: Layer,
    edge: u16,
    data: &[u8],
) -> impl Iterator<Item = HostMsg> + '_ {
    let cell = restore_cell_bytes(layer).unwrap_or(0);
    let rows = restore_rows_per_part(layer, edge).unwrap_or(0);
    let whole = usize::from(edge) * usize::from(edge) * cell;
    let ok = rows > 0 && data.len() == whole;
    let step = usize::from(rows) * usize::from(edge) * cell;
    data.chunks(step.max(1))
        .take(if ok { usize::MAX } else { 0 })
        .enumerate()
        .filter_map(move |(k, part)| {
            let row = u8::try_from(k.saturating_mul(usize::from(rows))).ok()?;
            Some(HostMsg::Restore {
                tx,
                ty,
                layer,
                row,
                data: RestoreData::new(part)?,
            })
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{decode, encode, MAX_HOST_FRAME};
    use proptest::prelude::*;

    #[test]
    fn sixteen_cell_tiles_take_eight_and_four_parts() {
        assert_eq!(restore_rows_per_part(Layer::LogOdds, 16), Some(2));
        assert_eq!(restore_rows_per_part(Layer::Counts, 16), Some(4));
        assert_eq!(restore_parts(Layer::LogOdds, 16), Some(8));
        assert_eq!(restore_parts(Layer::Counts, 16), Some(4));
        assert_eq!(restore_parts(Layer::Sample, 16), None);
        assert_eq!(restore_parts(Layer::LogOdds, 33), None);
        assert_eq!(check_restore_part(Layer::LogOdds, 14, 64, 16), Ok(7));
        assert_eq!(check_restore_part(Layer::Counts, 12, 64, 16), Ok(3));
        assert_eq!(
            check_restore_part(Layer::Sample, 0, 32, 16),
            Err(RestoreFault::Layer)
        );
        assert_eq!(
            check_restore_part(Layer::LogOdds, 1, 64, 16),
            Err(RestoreFault::Row)
        );
        assert_eq!(
            check_restore_part(Layer::LogOdds, 16, 64, 16),
            Err(RestoreFault::Row)
        );
        assert_eq!(
            check_restore_part(Layer::Counts, 4, 63, 16),
            Err(RestoreFault::Length)
        );
        assert_eq!(
            check_restore_part(Layer::LogOdds, 0, 0, 0),
            Err(RestoreFault::Edge)
        );
        // An edge whose rows do not divide: the last part is shorter.
        assert_eq!(restore_rows_per_part(Layer::LogOdds, 12), Some(2));
        assert_eq!(check_restore_part(Layer::Counts, 10, 24, 12), Ok(2));
    }

    #[test]
    fn a_full_restore_part_fits_a_host_frame_and_round_trips() {
        let m = HostMsg::Restore {
            tx: i32::MIN,
            ty: i32::MAX,
            layer: Layer::LogOdds,
            row: u8::MAX,
            data: RestoreData::new(&[0xFF; RESTORE_PART_BYTES]).unwrap(),
        };
        let mut buf = [0u8; MAX_HOST_FRAME];
        let f = encode(&m, &mut buf).unwrap();
        // Without its terminator; the host adds a leading 0x00.
        let n = f.len() - 1;
        assert!(n + 2 <= MAX_HOST_FRAME, "{n} bytes");
        assert_eq!(decode::<HostMsg>(&mut buf[..n]), Ok(m));
        assert!(RestoreData::new(&[0; RESTORE_PART_BYTES + 1]).is_none());
    }

    #[test]
    fn a_tile_splits_into_parts_that_pass_the_checks_and_cover_it() {
        let data: Vec<u8> = (0..512u32).map(|i| (i * 7) as u8).collect();
        let parts: Vec<_> = restore_msgs(-3, 5, Layer::LogOdds, 16, &data).collect();
        assert_eq!(parts.len(), 8);
        let mut back = Vec::new();
        for (k, p) in parts.iter().enumerate() {
            let HostMsg::Restore {
                tx,
                ty,
                layer,
                row,
                data: d,
            } = p
            else {
                panic!("{p:?}");
            };
            assert_eq!((*tx, *ty, *layer), (-3, 5, Layer::LogOdds));
            assert_eq!(
                check_restore_part(*layer, *row, d.as_slice().len(), 16),
                Ok(k as u32)
            );
            back.extend_from_slice(d.as_slice());
        }
        assert_eq!(back, data);
        assert_eq!(
            restore_msgs(0, 0, Layer::LogOdds, 16, &data[1..]).count(),
            0
        );
        assert_eq!(
            restore_msgs(0, 0, Layer::Sample, 16, &data[..32]).count(),
            0
        );
    }

    proptest! {
        /// Arbitrary bytes never panic the decoder or the checks, and what decodes re-encodes
        /// into a host frame.
        #[test]
        fn arbitrary_restore_bytes_never_panic(
            body in prop::collection::vec(any::<u8>(), 0..120), edge in 0u16..80,
        ) {
            let mut payload = vec![6u8]; // variant index of Restore
            payload.extend_from_slice(&body);
            let m: Result<HostMsg, _> = postcard::from_bytes(&payload);
            if let Ok(HostMsg::Restore { layer, row, data, .. }) = m {
                prop_assert!(data.as_slice().len() <= RESTORE_PART_BYTES);
                if let Ok(k) = check_restore_part(layer, row, data.as_slice().len(), edge) {
                    prop_assert!(k < restore_parts(layer, edge).unwrap());
                }
                let mut buf = [0u8; MAX_HOST_FRAME];
                prop_assert!(encode(&m.unwrap(), &mut buf).is_ok());
            }
        }

        /// The checks accept exactly the parts `restore_msgs` makes.
        #[test]
        fn checks_accept_exactly_well_formed_parts(
            layer in prop::sample::select(vec![Layer::LogOdds, Layer::Counts, Layer::Sample]),
            row: u8, len in 0usize..80, edge in 1u16..40,
        ) {
            let ok = check_restore_part(layer, row, len, edge);
            let data = vec![0u8; usize::from(edge) * usize::from(edge)
                * restore_cell_bytes(layer).unwrap_or(0)];
            let made = restore_msgs(0, 0, layer, edge, &data).any(|m| matches!(m,
                HostMsg::Restore { row: r, data: d, .. } if r == row && d.as_slice().len() == len));
            prop_assert_eq!(ok.is_ok(), made);
        }
    }
}
