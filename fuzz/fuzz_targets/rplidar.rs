//! The RPLIDAR parser (`ogm_core::lidar::rplidar`): arbitrary bytes through `RplidarParser` (in chunks
//! whose size the input picks), `Node::parse` / `Descriptor::parse` on every window,
//! `RplidarReader` over the same bytes, and the encoder on beams made from the
//! bytes. Invariants: nothing panics; every accepted node or descriptor re-encodes to the bytes
//! it came from; every input byte is delivered, skipped or held back (and held back < 20); the
//! counters account for every event; a scan never holds more beams than its buffer; encoded
//! beams decode within the wire resolution (±1 angle unit, exact ranges up to 16383 mm).
#![no_main]

use libfuzzer_sys::fuzz_target;
use ogm_core::lidar::rplidar::{
    beam_angle, encode_scan, scan_len, theta_q6, Descriptor, Event, Node, RplidarError,
    RplidarParser, RplidarReader, DESCRIPTOR_LEN, HEALTH_LEN, INFO_LEN, MAX_RANGE_MM, NODE_LEN,
    SAMPLERATE_LEN, TURN_Q6,
};
use ogm_core::{Angle, Beam, Range, ScanBuf};

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);

    let mut parser = RplidarParser::new();
    let (mut nodes, mut bad, mut used) = (0u32, 0u32, 0usize);
    for c in bytes.chunks(chunk) {
        parser.feed(c, |r| match r {
            Ok(Event::Node(n)) => {
                nodes += 1;
                used += NODE_LEN;
                assert_eq!(Node::parse(&n.to_bytes()), Ok(n), "re-encoding");
                let q = u32::from(n.angle_q6) % TURN_Q6;
                assert_eq!(u32::from(theta_q6(beam_angle(n.angle_q6))), q);
                let _ = n.beam();
            }
            Ok(Event::Descriptor(d)) => {
                used += DESCRIPTOR_LEN;
                assert_eq!(Descriptor::parse(&d.to_bytes()), Some(d));
            }
            Ok(Event::Info(_)) => used += INFO_LEN,
            Ok(Event::Health(_)) => used += HEALTH_LEN,
            Ok(Event::SampleRate(_)) => used += SAMPLERATE_LEN,
            Err(RplidarError::Truncated) => panic!("truncation is only reported by finish"),
            Err(_) => bad += 1,
        });
        assert!(parser.pending() < 20);
    }
    let c = parser.counters();
    assert_eq!(
        used + c.skipped_bytes as usize + parser.pending(),
        bytes.len()
    );
    let tail = parser.finish();
    let c = parser.counters();
    assert_eq!(c.nodes, nodes);
    assert_eq!(c.bad_nodes, bad);
    assert_eq!(c.truncated, u32::from(tail.is_some()));
    assert_eq!(used + c.skipped_bytes as usize, bytes.len());
    assert!(c.scans <= c.nodes);

    for w in bytes.windows(NODE_LEN).take(64) {
        let mut b = [0u8; NODE_LEN];
        b.copy_from_slice(w);
        if let Ok(n) = Node::parse(&b) {
            assert_eq!(n.to_bytes(), b, "a node that parses re-encodes to itself");
        }
    }
    for w in bytes.windows(DESCRIPTOR_LEN).take(64) {
        let mut b = [0u8; DESCRIPTOR_LEN];
        b.copy_from_slice(w);
        if let Some(d) = Descriptor::parse(&b) {
            assert_eq!(
                d.to_bytes(),
                b,
                "a descriptor that parses re-encodes to itself"
            );
        }
    }

    let mut reader = RplidarReader::new(bytes);
    let mut scan: ScanBuf<64> = ScanBuf::new();
    for _ in 0..1000 {
        if reader.read_scan(&mut scan).is_err() {
            break;
        }
        assert!(scan.beams().len() <= 64);
    }
    assert!(reader.scans() <= reader.counters().scans);

    // Encoder round trip on beams made from the input: 2 bytes angle, 4 bytes range
    // (`u32::MAX` = no return).
    let beams: Vec<Beam> = bytes
        .chunks_exact(6)
        .take(200)
        .map(|c| Beam {
            angle: Angle(u16::from_le_bytes([c[0], c[1]])),
            range: match u32::from_le_bytes([c[2], c[3], c[4], c[5]]) {
                u32::MAX => Range::NoReturn,
                mm => Range::Hit(mm),
            },
        })
        .collect();
    let with_descriptor = chunk % 2 == 0;
    let mut out = vec![0u8; scan_len(beams.len(), with_descriptor)];
    assert_eq!(
        encode_scan(&beams, with_descriptor, &mut out),
        Ok(out.len())
    );
    let mut parser = RplidarParser::new();
    let mut got = Vec::new();
    parser.feed(&out, |r| {
        if let Ok(Event::Node(n)) = r {
            got.push(n.beam());
        }
    });
    parser.finish();
    // Without the descriptor, lock-on needs a plausible scan; arbitrary angles may not be one.
    if with_descriptor {
        assert_eq!(got.len(), beams.len());
        for (g, b) in got.iter().zip(&beams) {
            assert!(g.angle.signed_diff(b.angle).abs() <= 1);
            let want = match b.range {
                Range::Hit(0) => Range::Hit(1),
                Range::Hit(mm) if mm > MAX_RANGE_MM => Range::NoReturn,
                r => r,
            };
            assert_eq!(g.range, want);
        }
    }
});
