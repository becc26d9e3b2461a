//! The LD06 parser (`ogm_core::lidar::ld06`): arbitrary bytes through `Ld06Parser` (in chunks whose size
//! the input picks), `Packet::parse` on every 47-byte window and `Ld06Reader` (the blocking
//! reader) over the same bytes. Invariants: nothing panics; every accepted packet
//! re-encodes to the bytes it came from; the counters account for every completed packet; a
//! scan never holds more beams than its buffer.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ogm_core::lidar::ld06::{Ld06Parser, Ld06Reader, Packet, PACKET_LEN, POINTS};
use ogm_core::ScanBuf;

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);

    let mut parser = Ld06Parser::new();
    let (mut good, mut bad) = (0u32, 0u32);
    for c in bytes.chunks(chunk) {
        parser.feed(c, |r| match r {
            Ok(p) => {
                good += 1;
                assert_eq!(Packet::parse(&p.to_bytes()), Ok(p), "re-encoding");
                for i in 0..POINTS {
                    let _ = p.beam(i);
                    let _ = p.angle_cdeg(i);
                }
            }
            Err(_) => bad += 1,
        });
        assert!(parser.pending() < PACKET_LEN);
    }
    let tail = parser.finish();
    let c = parser.counters();
    assert_eq!(c.packets, good);
    assert_eq!(
        c.crc_errors + c.bad_headers + c.truncated,
        bad + u32::from(tail.is_some())
    );

    for w in bytes.windows(PACKET_LEN).take(64) {
        let mut b = [0u8; PACKET_LEN];
        b.copy_from_slice(w);
        if let Ok(p) = Packet::parse(&b) {
            assert_eq!(p.to_bytes(), b, "a packet that parses re-encodes to itself");
        }
    }

    let mut reader = Ld06Reader::new(bytes);
    let mut scan: ScanBuf<64> = ScanBuf::new();
    for _ in 0..1000 {
        if reader.read_scan(&mut scan).is_err() {
            break;
        }
        assert!(scan.beams().len() <= 64);
    }
});
