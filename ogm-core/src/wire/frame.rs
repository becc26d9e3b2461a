//! One frame, `COBS(VERSION ‖ postcard(message) ‖ CRC-32) ‖ 0x00` (see the [module
//! docs](super)): the encoder, the decoder and the longest frames each way.

use serde::{Deserialize, Serialize};

use super::error::WireError;
use super::tile::MAX_TILE_BYTES;
use super::VERSION;

/// CRC-32/ISO-HDLC (the zlib/Ethernet CRC-32), table driven (1 KiB of flash).
pub static CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Longest host → device frame on the wire, both `0x00` delimiters included (a [`RunConfig`]
/// with every field at its maximum is 134 bytes; tested).
///
/// [`RunConfig`]: crate::config::RunConfig
pub const MAX_HOST_FRAME: usize = 144;

/// Fewest bytes of a [`HostMsg::Pose`] frame on the wire (a lower bound; tested): a read of
/// `n` link bytes completes at most `n / MIN_POSE_FRAME + 1` poses.
///
/// [`HostMsg::Pose`]: super::HostMsg::Pose
pub const MIN_POSE_FRAME: usize = 8;

/// Longest device → host frame on the wire (a full log-odds tile; tested), plus the few bytes
/// [`encode`] needs as working room.
pub const MAX_DEVICE_FRAME: usize = MAX_TILE_BYTES + 32;

/// Encodes `msg` as one frame (COBS, terminating `0x00` included) into `buf`; returns the bytes.
///
/// One buffer, three passes, no per-byte generic code (small in flash): postcard writes the
/// payload behind a gap at the front of `buf`, the CRC-32 is appended, and COBS then encodes
/// forwards into the front of the same buffer (the gap, ⌈len/254⌉ + 1 bytes, is what COBS adds,
/// so the writer never overtakes the reader).
pub fn encode<'b, T: Serialize + ?Sized>(
    msg: &T,
    buf: &'b mut [u8],
) -> Result<&'b mut [u8], WireError> {
    let gap = buf.len() / 254 + 2;
    let body = buf.get_mut(gap..).ok_or(WireError::BufferFull)?;
    let (version, rest) = body.split_first_mut().ok_or(WireError::BufferFull)?;
    *version = VERSION;
    let n = 1 + postcard::serialize_with_flavor(msg, Payload { buf: rest, len: 0 })
        .map_err(|_| WireError::BufferFull)?;
    let crc = CRC32.checksum(body.get(..n).ok_or(WireError::BufferFull)?);
    body.get_mut(n..n + 4)
        .ok_or(WireError::BufferFull)?
        .copy_from_slice(&crc.to_le_bytes());
    let len = cobs_encode_in_place(buf, gap, n + 4);
    let end = buf.get_mut(len).ok_or(WireError::BufferFull)?;
    *end = 0;
    buf.get_mut(..=len).ok_or(WireError::BufferFull)
}

/// postcard's output for [`encode`]: the payload's bytes written into a slice by two out-of-line
/// functions, so that each field of each message costs a call instead of postcard's inlined
/// slice bounds check and copy (which the firmware's one `encode` of every message multiplies).
struct Payload<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl postcard::ser_flavors::Flavor for Payload<'_> {
    /// The payload's length.
    type Output = usize;

    #[inline(never)]
    fn try_push(&mut self, byte: u8) -> postcard::Result<()> {
        let slot = self
            .buf
            .get_mut(self.len)
            .ok_or(postcard::Error::SerializeBufferFull)?;
        *slot = byte;
        self.len += 1;
        Ok(())
    }

    #[inline(never)]
    fn try_extend(&mut self, bytes: &[u8]) -> postcard::Result<()> {
        let end = self.len.saturating_add(bytes.len());
        let out = self
            .buf
            .get_mut(self.len..end)
            .ok_or(postcard::Error::SerializeBufferFull)?;
        // Not `copy_from_slice`: its length check's panic would pull `core::fmt` into the
        // firmware; the lengths are equal here (`end − len = bytes.len()`, never saturated since
        // the range is inside `buf`).
        for (o, b) in out.iter_mut().zip(bytes) {
            *o = *b;
        }
        self.len = end;
        Ok(())
    }

    fn finalize(self) -> postcard::Result<usize> {
        Ok(self.len)
    }
}

/// COBS-encodes `buf[src..src + len]` into `buf[0..]` (no terminator); returns the encoded
/// length. Needs `src ≥ 1 + len / 254` (then every write lands on an already-read byte).
fn cobs_encode_in_place(buf: &mut [u8], src: usize, len: usize) -> usize {
    let (mut code_at, mut w, mut code) = (0usize, 1usize, 1u8);
    for i in src..src + len {
        let b = buf.get(i).copied().unwrap_or(0);
        if b != 0 {
            if let Some(slot) = buf.get_mut(w) {
                *slot = b;
            }
            w += 1;
            code += 1;
        }
        if b == 0 || code == 0xFF {
            if let Some(slot) = buf.get_mut(code_at) {
                *slot = code;
            }
            (code_at, w, code) = (w, w + 1, 1);
        }
    }
    if let Some(slot) = buf.get_mut(code_at) {
        *slot = code;
    }
    w
}

/// Decodes COBS in place (`buf` without the terminating `0x00`); returns the decoded length.
pub fn cobs_decode_in_place(buf: &mut [u8]) -> Result<usize, WireError> {
    let (mut read, mut write) = (0usize, 0usize);
    let len = buf.len();
    while read < len {
        let code = buf.get(read).copied().unwrap_or(0);
        if code == 0 {
            return Err(WireError::Cobs);
        }
        read += 1;
        for _ in 1..code {
            let b = buf.get(read).copied().ok_or(WireError::Cobs)?;
            if b == 0 {
                return Err(WireError::Cobs);
            }
            if let Some(slot) = buf.get_mut(write) {
                *slot = b;
            }
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < len {
            if let Some(slot) = buf.get_mut(write) {
                *slot = 0;
            }
            write += 1;
        }
    }
    Ok(write)
}

/// Decodes one frame: `frame` is the COBS bytes *without* the terminating `0x00` (decoded in
/// place); checks the CRC and the version and decodes a `T` that may borrow from `frame`.
pub fn decode<'a, T: Deserialize<'a>>(frame: &'a mut [u8]) -> Result<T, WireError> {
    let n = cobs_decode_in_place(frame)?;
    let frame: &'a [u8] = frame;
    let raw = frame.get(..n).ok_or(WireError::TooShort)?;
    if raw.len() < 5 {
        return Err(WireError::TooShort);
    }
    let (body, crc) = raw.split_at(raw.len() - 4);
    let want = u32::from_le_bytes(crc.try_into().map_err(|_| WireError::TooShort)?);
    if CRC32.checksum(body) != want {
        return Err(WireError::Crc);
    }
    let (&version, payload) = body.split_first().ok_or(WireError::TooShort)?;
    if version != VERSION {
        return Err(WireError::Version(version));
    }
    match postcard::take_from_bytes(payload) {
        Ok((msg, [])) => Ok(msg),
        _ => Err(WireError::Decode),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Budget, DataTerm, Estimator, LidarModel, PoseInput, RunConfig};
    use crate::types::angle::Angle;
    use crate::types::geometry::Pose;
    use crate::wire::{DeviceMsg, HostMsg, Layer, Tile};

    fn max_config() -> RunConfig {
        RunConfig {
            origin_x_mm: i32::MIN,
            origin_y_mm: i32::MIN,
            cell_mm: u32::MAX,
            max_range_mm: u32::MAX,
            min_range_mm: u32::MAX,
            seed: u64::MAX,
            sigma_milli_cells: u32::MAX,
            outlier_ppm: u32::MAX,
            p_rand_patch_ppm: u32::MAX,
            burn_in_sweeps: u32::MAX,
            max_candidates: u8::MAX,
            sampler_tile_shift: u8::MAX,
            visit_sweeps: u8::MAX,
            budget: Budget::Time {
                period_us: u32::MAX,
                max_updates: u32::MAX,
            },
            tiles_per_scan: u16::MAX,
            count_tiles_per_scan: u16::MAX,
            face_band: true,
            data: DataTerm::Hybrid,
            evidence_gain_q8: u16::MAX,
            evidence_free_q8: u16::MAX,
            free_update_q8: u16::MAX,
            data_candidate: true,
            estimator: Estimator::Average {
                shift: u8::MAX,
                max_shift: u8::MAX,
                reset_on_change: true,
                rao_blackwell: true,
            },
            hot_share: u8::MAX,
            mount: Pose {
                x_mm: i32::MIN,
                y_mm: i32::MIN,
                heading: Angle(u16::MAX),
            },
            poses: PoseInput::Fixed,
            lidar: LidarModel::Rplidar {
                sample_us: u16::MAX,
            },
            window_margin_cells: u16::MAX,
            correction: crate::config::PoseCorrection::Match,
            window_hold: true,
            odometry: crate::config::OdometryNoise {
                trans_permille: u16::MAX,
                turn_permille: u16::MAX,
                drift_mdeg_per_m: u16::MAX,
            },
        }
    }

    #[test]
    fn min_pose_frame_is_a_lower_bound() {
        let mut buf = [0u8; MAX_HOST_FRAME];
        let smallest = HostMsg::Pose {
            t_us: 0,
            pose: Pose::default(),
        };
        let n = encode(&smallest, &mut buf).map(|b| b.len()).unwrap();
        assert!(n >= MIN_POSE_FRAME, "{n}");
    }

    #[test]
    fn round_trip_and_sizes() {
        let mut buf = [0u8; 256];
        let msgs = [
            HostMsg::Config(max_config()),
            HostMsg::ScanStart {
                seq: u32::MAX,
                pose: Pose {
                    x_mm: i32::MIN,
                    y_mm: i32::MAX,
                    heading: Angle(u16::MAX),
                },
            },
            HostMsg::ScanEnd {
                seq: u32::MAX,
                points: u32::MAX,
            },
            HostMsg::Finish,
            HostMsg::Pose {
                t_us: u64::MAX,
                pose: Pose {
                    x_mm: i32::MIN,
                    y_mm: i32::MIN,
                    heading: Angle(u16::MAX),
                },
            },
        ];
        for m in msgs {
            let n = encode(&m, &mut buf).unwrap().len();
            // + the leading 0x00 the host adds
            assert!(n < MAX_HOST_FRAME, "{m:?}: {n} bytes");
            assert_eq!(buf[n - 1], 0);
            assert!(!buf[..n - 1].contains(&0));
            let back: HostMsg = decode(&mut buf[..n - 1]).unwrap();
            assert_eq!(back, m);
        }
        let data = [0xA5u8; MAX_TILE_BYTES];
        let t = DeviceMsg::Tile(Tile {
            layer: Layer::LogOdds,
            tx: i32::MIN,
            ty: i32::MIN,
            data: &data,
        });
        let mut big = [0u8; MAX_DEVICE_FRAME];
        let n = encode(&t, &mut big).unwrap().len();
        let back: DeviceMsg = decode(&mut big[..n - 1]).unwrap();
        assert_eq!(back, t);
    }

    #[test]
    fn rejects_corruption_and_other_versions() {
        let mut buf = [0u8; 64];
        let m = HostMsg::ScanEnd {
            seq: 7,
            points: 360,
        };
        let n = encode(&m, &mut buf).unwrap().len();
        for i in 0..n - 1 {
            for bit in 0..8 {
                let mut f = buf;
                f[i] ^= 1 << bit;
                let r: Result<HostMsg, _> = decode(&mut f[..n - 1]);
                assert!(r.is_err(), "flip {i}.{bit} undetected");
            }
        }
        // A frame with another version (valid CRC) is refused by version.
        let other = VERSION.wrapping_add(1);
        let mut raw = std::vec![other];
        raw.extend_from_slice(postcard::to_slice(&m, &mut [0u8; 64]).unwrap());
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut enc = cobs_encode(&raw);
        let r: Result<HostMsg, _> = decode(&mut enc);
        assert_eq!(r, Err(WireError::Version(other)));
        // Trailing bytes after the message are refused.
        let mut raw = std::vec![VERSION];
        raw.extend_from_slice(postcard::to_slice(&m, &mut [0u8; 64]).unwrap());
        raw.push(0x11);
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut enc = cobs_encode(&raw);
        assert_eq!(decode::<HostMsg>(&mut enc), Err(WireError::Decode));
        assert_eq!(decode::<HostMsg>(&mut []), Err(WireError::TooShort));
    }

    /// Plain reference COBS encoder (without terminator).
    fn cobs_encode(data: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8];
        let mut code_at = 0;
        let mut code = 1u8;
        for &b in data {
            if b == 0 {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            } else {
                out.push(b);
                code += 1;
                if code == 0xFF {
                    out[code_at] = code;
                    code_at = out.len();
                    out.push(0);
                    code = 1;
                }
            }
        }
        out[code_at] = code;
        out
    }

    /// The frame of a postcard `payload` built step by step with the reference COBS encoder:
    /// COBS(VERSION ‖ payload ‖ CRC-32) ‖ 0x00.
    fn reference_frame(payload: &[u8]) -> Vec<u8> {
        let mut raw = vec![VERSION];
        raw.extend_from_slice(payload);
        let crc = CRC32.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut frame = cobs_encode(&raw);
        frame.push(0);
        frame
    }

    /// `encode`'s own postcard output (`Payload`) equals postcard's slice flavour's, and every
    /// buffer too short for the frame is `BufferFull`, never a panic or a cut frame.
    #[test]
    fn encode_writes_postcard_bytes_and_refuses_short_buffers() {
        let msgs = [
            HostMsg::Config(max_config()),
            HostMsg::ScanEnd {
                seq: u32::MAX,
                points: 0,
            },
            HostMsg::Finish,
        ];
        for m in msgs {
            let mut buf = [0u8; 256];
            let frame = encode(&m, &mut buf).unwrap().to_vec();
            let want = reference_frame(postcard::to_slice(&m, &mut [0u8; 256]).unwrap());
            assert_eq!(frame, want, "{m:?}");
            for len in 0..frame.len() + frame.len() / 254 + 2 {
                let mut short = vec![0u8; len];
                match encode(&m, &mut short) {
                    Ok(f) => assert_eq!(f, &frame[..], "{m:?} in {len} bytes"),
                    Err(e) => assert_eq!(e, WireError::BufferFull, "{m:?} in {len} bytes"),
                }
            }
        }
    }

    #[test]
    fn encode_matches_the_reference_cobs_at_block_boundaries() {
        for len in [
            0usize, 1, 200, 243, 244, 245, 246, 250, 253, 254, 255, 497, 498, 499, 500,
        ] {
            let data: Vec<u8> = (0..len).map(|i| (i % 7) as u8 * 40).collect();
            let msg = DeviceMsg::Tile(Tile {
                layer: Layer::Counts,
                tx: 1,
                ty: 2,
                data: &data,
            });
            let mut buf = [0u8; MAX_DEVICE_FRAME];
            let frame = encode(&msg, &mut buf).unwrap().to_vec();
            let want = reference_frame(postcard::to_slice(&msg, &mut [0u8; 600]).unwrap());
            assert_eq!(frame, want, "len {len}");
            let mut f = frame.clone();
            let back: DeviceMsg = decode(&mut f[..frame.len() - 1]).unwrap();
            assert_eq!(back, msg);
        }
    }

    #[test]
    fn cobs_matches_reference_on_edge_lengths() {
        for len in [0usize, 1, 253, 254, 255, 256, 508, 509, 600] {
            for zeros in [false, true] {
                let data: Vec<u8> = (0..len)
                    .map(|i| {
                        if zeros && i % 97 == 3 {
                            0
                        } else {
                            (i % 251 + 1) as u8
                        }
                    })
                    .collect();
                let mut enc = cobs_encode(&data);
                assert!(!enc.contains(&0));
                let n = cobs_decode_in_place(&mut enc).unwrap();
                assert_eq!(&enc[..n], &data[..], "len {len} zeros {zeros}");
            }
        }
        assert_eq!(cobs_decode_in_place(&mut [3, 1]), Err(WireError::Cobs));
        assert_eq!(cobs_decode_in_place(&mut [2, 0]), Err(WireError::Cobs));
    }
}
