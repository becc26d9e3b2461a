//! The postcard/COBS frame decoders (`ogm_core::wire`): arbitrary bytes as a host → robot frame
//! (`HostMsg`, what the robot decodes) and as a robot → host frame (`DeviceMsg`), through the
//! robot's demultiplexer (`ogm_core::lidar::link::LinkDemux`) and the host's stream decoder
//! (`ogm_field::stream::StreamDecoder`) in input-chosen chunks. Invariants: nothing panics; a frame
//! that decodes re-encodes into one that decodes to the same message (a scan's ranges into at
//! most `SCAN_BINS` bins, or refused for their length); the demultiplexer's
//! counters add up to the bytes it saw.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ogm_core::lidar::link::{LinkDemux, LinkEvent};
use ogm_core::wire::{self, DeviceMsg, HostMsg, MAX_DEVICE_FRAME, MAX_HOST_FRAME};
use ogm_field::stream::StreamDecoder;

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);

    // One frame, without its terminating 0x00, as each side decodes it.
    let mut a = bytes.to_vec();
    if let Ok(m) = wire::decode::<HostMsg>(&mut a) {
        let mut out = [0u8; MAX_HOST_FRAME];
        let f = wire::encode(&m, &mut out).expect("every HostMsg fits MAX_HOST_FRAME");
        let n = f.len() - 1;
        assert!(n + 2 <= MAX_HOST_FRAME, "HostMsg frame of {n} bytes");
        assert_eq!(wire::decode::<HostMsg>(&mut f[..n]), Ok(m));
    }
    let mut b = bytes.to_vec();
    if let Ok(m) = wire::decode::<DeviceMsg>(&mut b) {
        let mut out = vec![0u8; 2 * MAX_DEVICE_FRAME + bytes.len()];
        let f = wire::encode(&m, &mut out).expect("a decoded DeviceMsg re-encodes");
        let n = f.len() - 1;
        assert_eq!(wire::decode::<DeviceMsg>(&mut f[..n]), Ok(m));
        // A scan's ranges: the bins of exactly SCAN_RANGES_LEN bytes, anything else refused.
        if let DeviceMsg::Ranges(r) = m {
            match r.bins() {
                Ok(bins) => assert!(bins.count() <= wire::SCAN_BINS),
                Err(_) => assert_ne!(r.data.len(), wire::SCAN_RANGES_LEN),
            }
        }
    }
    let mut c = bytes.to_vec();
    let _ = wire::cobs_decode_in_place(&mut c);

    // A stream of them: the robot's demultiplexer and the host's decoder.
    let mut demux = LinkDemux::new();
    let (mut packets, mut frames) = (0u32, 0u32);
    for c in bytes.chunks(chunk) {
        demux.feed(c, |ev| match ev {
            LinkEvent::Packet(_) => packets += 1,
            LinkEvent::Host(_) => frames += 1,
            LinkEvent::Error(_) => {}
        });
    }
    demux.finish(&mut |_| {});
    let k = demux.counters();
    assert_eq!(k.rx_bytes as usize, bytes.len());
    assert_eq!((k.ld06_packets, k.frames), (packets, frames));

    let mut dec = StreamDecoder::new();
    let mut events = 0u64;
    for c in bytes.chunks(chunk) {
        events += dec.push(c).len() as u64;
    }
    let s = dec.stats();
    assert_eq!(s.bytes as usize, bytes.len());
    assert_eq!(s.frames + s.bad_frames, events);
});
