//! Properties of the RPLIDAR parser, reader and encoder (`ogm_core::lidar::rplidar`): encoder → parser
//! round trips within the wire resolution, chunking independence, garbage before and between
//! turns, truncation, bit flips (never a panic, always counted), rejection of a node with a bad
//! check bit followed by resynchronisation, and the scan reader's turn boundaries.
//!
//! Resolution (the tolerance every round trip is checked against): a beam angle comes back within
//! ±1 `Angle` unit (1/65536 turn, ≈ 0.0055°; the wire step is 1/64° ≈ 2.84 units); a wire angle
//! comes back exactly; `Hit(mm)` comes back exactly for 1 ≤ mm ≤ 16383, `Hit(0)` as `Hit(1)`,
//! longer hits as `NoReturn` (the node format cannot carry them).

use ogm_core::lidar::rplidar::{
    beam_angle, encode_scan, scan_len, Event, Node, RplidarCounters, RplidarError, RplidarParser,
    RplidarReader, DESCRIPTOR_LEN, HEALTH_LEN, INFO_LEN, LOCK_NODES, MAX_LOCK_STEP_Q6,
    MAX_RANGE_MM, NODE_LEN, SAMPLERATE_LEN, SCAN_DESCRIPTOR, TURN_Q6,
};
use ogm_core::lidar::source::ReadError;
use ogm_core::{Angle, Beam, Range, ScanBuf};
use proptest::prelude::*;

/// Everything one parser run produced.
#[derive(Debug, Default, PartialEq)]
struct Out {
    events: Vec<Result<Event, RplidarError>>,
    tail: Option<RplidarError>,
    counters: RplidarCounters,
    /// Bytes accounted for by delivered events.
    used: usize,
    /// Bytes held back before `finish`.
    pending: usize,
}

impl Out {
    fn nodes(&self) -> Vec<Node> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Ok(Event::Node(n)) => Some(*n),
                _ => None,
            })
            .collect()
    }

    fn errors(&self) -> Vec<RplidarError> {
        self.events.iter().filter_map(|e| e.err()).collect()
    }
}

/// Feeds `bytes` in chunks of the given sizes (cycled; the rest in one piece if empty), then
/// finishes, checking the invariants that hold for any input.
fn run(bytes: &[u8], chunks: &[usize]) -> Out {
    let mut p = RplidarParser::new();
    let mut out = Out::default();
    let mut rest = bytes;
    let mut k = 0;
    while !rest.is_empty() {
        let n = chunks
            .get(k % chunks.len().max(1))
            .copied()
            .unwrap_or(rest.len());
        let (c, r) = rest.split_at(n.clamp(1, rest.len()));
        p.feed(c, |e| {
            out.used += match e {
                Ok(Event::Node(_)) => NODE_LEN,
                Ok(Event::Descriptor(_)) => DESCRIPTOR_LEN,
                Ok(Event::Info(_)) => INFO_LEN,
                Ok(Event::Health(_)) => HEALTH_LEN,
                Ok(Event::SampleRate(_)) => SAMPLERATE_LEN,
                Err(_) => 0,
            };
            out.events.push(e);
        });
        assert!(p.pending() < 20);
        rest = r;
        k += 1;
    }
    out.pending = p.pending();
    let c = p.counters();
    // Every byte is in a delivered event, skipped, or held back.
    assert_eq!(
        out.used + c.skipped_bytes as usize + out.pending,
        bytes.len()
    );
    out.tail = p.finish();
    out.counters = p.counters();
    let c = out.counters;
    assert_eq!(c.nodes as usize, out.nodes().len());
    let bad = out
        .errors()
        .iter()
        .filter(|e| **e != RplidarError::Truncated)
        .count();
    assert_eq!(c.bad_nodes as usize, bad);
    assert_eq!(c.truncated, u32::from(out.tail.is_some()));
    assert_eq!(
        out.used + c.skipped_bytes as usize,
        bytes.len(),
        "finish drops what was held back"
    );
    assert_eq!(p.pending(), 0);
    out
}

/// What a beam reads as after the wire.
fn expect_range(r: Range) -> Range {
    match r {
        Range::Hit(0) => Range::Hit(1),
        Range::Hit(mm) if mm > MAX_RANGE_MM => Range::NoReturn,
        r => r,
    }
}

fn encode(beams: &[Beam], descriptor: bool) -> Vec<u8> {
    let mut v = vec![0u8; scan_len(beams.len(), descriptor)];
    let n = encode_scan(beams, descriptor, &mut v).unwrap();
    assert_eq!(n, v.len());
    v
}

fn nodes_of(bytes: &[u8]) -> Vec<Node> {
    bytes
        .chunks_exact(NODE_LEN)
        .map(|c| Node::parse(c.try_into().unwrap()).unwrap())
        .collect()
}

fn range_strategy() -> impl Strategy<Value = Range> {
    prop_oneof![
        1 => Just(Range::NoReturn),
        1 => (0u32..=2).prop_map(Range::Hit),
        6 => (1u32..=MAX_RANGE_MM).prop_map(Range::Hit),
        1 => (MAX_RANGE_MM + 1..=u32::MAX).prop_map(Range::Hit),
    ]
}

/// Beams at any angles, in any order.
fn any_beams(max: usize) -> impl Strategy<Value = Vec<Beam>> {
    prop::collection::vec(
        (any::<u16>(), range_strategy()).prop_map(|(a, range)| Beam {
            angle: Angle(a),
            range,
        }),
        0..max,
    )
}

/// A turn as a sensor sends it: clockwise steps of 1…`MAX_LOCK_STEP_Q6` wire units from a random
/// start, which is what lock-on without a descriptor expects.
fn turn(len: std::ops::Range<usize>) -> impl Strategy<Value = Vec<Beam>> {
    (
        0..TURN_Q6,
        prop::collection::vec((1..=MAX_LOCK_STEP_Q6, range_strategy()), len),
    )
        .prop_map(|(start, steps)| {
            let mut theta = start;
            steps
                .into_iter()
                .map(|(step, range)| {
                    theta = (theta + step) % TURN_Q6;
                    Beam {
                        angle: beam_angle(theta as u16),
                        range,
                    }
                })
                .collect()
        })
}

/// Garbage that cannot start a node (bit 1 equals bit 0, so never `0xA5` either): every byte
/// is rejected where it stands, which makes the expected output exact.
fn clean_garbage(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        any::<u8>().prop_map(|b| (b & !3) | if b & 1 == 1 { 3 } else { 0 }),
        0..max,
    )
}

fn chunks() -> impl Strategy<Value = Vec<usize>> {
    prop::collection::vec(1usize..40, 0..8)
}

fn flag_start(nodes: &[Node]) -> bool {
    nodes.first().is_none_or(|n| n.start) && nodes.iter().skip(1).all(|n| !n.start)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Encoder → parser: every beam comes back, in order, within the stated resolution; the
    /// first node starts the scan; any chunking.
    #[test]
    fn round_trip(beams in any_beams(200), chunks in chunks()) {
        let bytes = encode(&beams, true);
        let out = run(&bytes, &chunks);
        let nodes = out.nodes();
        prop_assert_eq!(nodes.len(), beams.len());
        prop_assert!(flag_start(&nodes));
        for (n, b) in nodes.iter().zip(&beams) {
            let got = n.beam();
            prop_assert!(got.angle.signed_diff(b.angle).abs() <= 1, "{:?} vs {:?}", got, b);
            prop_assert_eq!(got.range, expect_range(b.range));
            // The wire form is canonical: decoding and re-encoding gives the same node.
            prop_assert_eq!(Node::from_beam(&got, n.start), *n);
        }
        let c = out.counters;
        prop_assert_eq!((c.descriptors, c.bad_nodes, c.skipped_bytes, c.locks), (1, 0, 0, 0));
        prop_assert_eq!(c.scans, u32::from(!beams.is_empty()));
        prop_assert_eq!(out.tail, None);
    }

    /// The chunking never changes what comes out, whatever the bytes.
    #[test]
    fn chunking_is_irrelevant(
        noise in prop::collection::vec(any::<u8>(), 0..300),
        beams in turn(0..40),
        at in any::<prop::sample::Index>(),
        chunks in chunks(),
    ) {
        let mut bytes = noise;
        let cut = at.index(bytes.len() + 1);
        let tail = bytes.split_off(cut);
        bytes.extend(encode(&beams, true));
        bytes.extend(tail);
        prop_assert_eq!(run(&bytes, &chunks), run(&bytes, &[]));
    }

    /// Garbage before (with or without the descriptor) and between two turns: every node of
    /// both turns comes back exactly, the garbage is skipped byte for byte, and the interruption
    /// of a locked stream is one bad node.
    #[test]
    fn clean_garbage_before_and_between(
        before in clean_garbage(50),
        between in clean_garbage(50),
        a in turn(LOCK_NODES..60),
        b in turn(LOCK_NODES..60),
        descriptor in any::<bool>(),
        chunks in chunks(),
    ) {
        let mut bytes = before.clone();
        let ta = encode(&a, descriptor);
        let tb = encode(&b, false);
        bytes.extend_from_slice(&ta);
        bytes.extend_from_slice(&between);
        bytes.extend_from_slice(&tb);
        let out = run(&bytes, &chunks);
        let mut want = nodes_of(&ta[if descriptor { DESCRIPTOR_LEN } else { 0 }..]);
        want.extend(nodes_of(&tb));
        prop_assert_eq!(out.nodes(), want);
        let c = out.counters;
        prop_assert_eq!(c.skipped_bytes as usize, before.len() + between.len());
        prop_assert_eq!(c.bad_nodes, u32::from(!between.is_empty()));
        prop_assert_eq!(c.descriptors, u32::from(descriptor));
        prop_assert_eq!(c.locks, u32::from(!descriptor) + u32::from(!between.is_empty()));
        prop_assert_eq!(c.scans, 2);
        prop_assert_eq!(out.tail, None);
    }

    /// Arbitrary garbage before and between: never a panic, every byte accounted for (in
    /// `run`), and the parser recovers — the end of the second turn comes back exactly. (Garbage
    /// can pass the 3 check bits and run a few misaligned nodes into the turn; losing more than
    /// 30 of its nodes would take a run of misaligned passes with probability < 4⁻²⁸.)
    #[test]
    fn arbitrary_garbage_is_survived(
        before in prop::collection::vec(any::<u8>(), 0..200),
        between in prop::collection::vec(any::<u8>(), 0..200),
        a in turn(0..40),
        b in turn(40..100),
        chunks in chunks(),
    ) {
        let mut bytes = before;
        bytes.extend(encode(&a, true));
        bytes.extend_from_slice(&between);
        let tb = encode(&b, false);
        bytes.extend_from_slice(&tb);
        let out = run(&bytes, &chunks);
        let want = nodes_of(&tb);
        let keep = want.len() - 30;
        let nodes = out.nodes();
        prop_assert!(nodes.len() >= keep);
        prop_assert_eq!(&nodes[nodes.len() - keep..], &want[want.len() - keep..]);
    }

    /// A stream cut anywhere: the complete nodes before the cut come back, an unfinished node is
    /// reported as truncated, an unfinished descriptor is just skipped.
    #[test]
    fn truncated_streams(beams in any_beams(50), at in any::<prop::sample::Index>(), chunks in chunks()) {
        let bytes = encode(&beams, true);
        let cut = at.index(bytes.len() + 1);
        let out = run(&bytes[..cut], &chunks);
        let whole = cut.saturating_sub(DESCRIPTOR_LEN) / NODE_LEN;
        prop_assert_eq!(out.nodes(), nodes_of(&bytes[DESCRIPTOR_LEN..DESCRIPTOR_LEN + whole * NODE_LEN]));
        let partial = cut > DESCRIPTOR_LEN && (cut - DESCRIPTOR_LEN) % NODE_LEN != 0;
        prop_assert_eq!(out.tail, partial.then_some(RplidarError::Truncated));
        prop_assert_eq!(out.counters.descriptors, u32::from(cut >= DESCRIPTOR_LEN));
        prop_assert!(out.errors().is_empty());
    }

    /// A node with a bad check bit (`C` = 0, or `S` = `!S`) is rejected and counted once; the
    /// stream resynchronises at the next node, and every other node comes back — except that
    /// lock-on needs `LOCK_NODES` nodes, so fewer than that after the bad one are not confirmed.
    #[test]
    fn bad_check_bit_is_rejected_and_resynchronised(
        beams in turn(1..80),
        k in any::<prop::sample::Index>(),
        which in 0usize..3,
        descriptor in any::<bool>(),
        chunks in chunks(),
    ) {
        let mut bytes = encode(&beams, descriptor);
        let base = if descriptor { DESCRIPTOR_LEN } else { 0 };
        let good = nodes_of(&bytes[base..]);
        let k = k.index(good.len());
        let (byte, mask, err) = match which {
            0 => (1, 0x01, RplidarError::CheckBit),
            1 => (0, 0x01, RplidarError::StartFlags),
            _ => (0, 0x02, RplidarError::StartFlags),
        };
        bytes[base + k * NODE_LEN + byte] ^= mask;
        let out = run(&bytes, &chunks);
        let locked_before = descriptor || k >= LOCK_NODES;
        let after = good.len() - k - 1;
        let mut want = if locked_before { good[..k].to_vec() } else { Vec::new() };
        if after >= LOCK_NODES {
            want.extend_from_slice(&good[k + 1..]);
        }
        prop_assert_eq!(out.nodes(), want);
        prop_assert_eq!(out.errors(), if locked_before { vec![err] } else { vec![] });
        prop_assert_eq!(out.counters.bad_nodes, u32::from(locked_before));
        prop_assert_eq!(
            out.counters.skipped_bytes as usize,
            bytes.len() - base - out.nodes().len() * NODE_LEN
        );
    }

    /// Random bit flips anywhere in a stream: never a panic, every byte accounted for and every
    /// rejected node reported (both checked in `run`). A single flip outside a node's check bits
    /// loses nothing: the node count is unchanged.
    #[test]
    fn bit_flips_are_survived_and_counted(
        beams in turn(LOCK_NODES..80),
        flips in prop::collection::vec((any::<prop::sample::Index>(), 0u8..8), 1..6),
        chunks in chunks(),
    ) {
        let clean = encode(&beams, true);
        let mut bytes = clean.clone();
        for (at, bit) in &flips {
            let i = at.index(bytes.len());
            bytes[i] ^= 1 << bit;
        }
        let out = run(&bytes, &chunks);
        prop_assert!(out.counters.nodes as usize <= bytes.len() / NODE_LEN);
        if let [(at, bit)] = flips[..] {
            let i = at.index(bytes.len());
            let in_node = i.checked_sub(DESCRIPTOR_LEN).map(|j| j % NODE_LEN);
            let check_bit = matches!((in_node, bit), (Some(0), 0 | 1) | (Some(1), 0));
            if !check_bit {
                prop_assert_eq!(out.nodes().len(), beams.len(), "flip at byte {} bit {}", i, bit);
                prop_assert_eq!(out.counters.bad_nodes, 0);
            } else {
                prop_assert_eq!(out.counters.bad_nodes, 1);
            }
        }
    }

    /// The reader returns each complete turn (from one start flag to the next) with its beams
    /// within the resolution; the last turn has no end and gives `Eof`; a small buffer drops
    /// and counts the excess.
    #[test]
    fn reader_returns_whole_turns(
        turns in prop::collection::vec(turn(1..60), 1..5),
        lead in turn(0..10),
    ) {
        // Start-up mid-turn: a turn's tail without its start flag comes first.
        let mut bytes = SCAN_DESCRIPTOR.to_vec();
        let lead_bytes = encode(&lead, false);
        bytes.extend_from_slice(lead_bytes.get(NODE_LEN..).unwrap_or(&[]));
        for t in &turns {
            bytes.extend(encode(t, false));
        }
        let mut r = RplidarReader::new(&bytes[..]);
        let mut scan: ScanBuf<64> = ScanBuf::new();
        let mut small: ScanBuf<8> = ScanBuf::new();
        let mut r_small = RplidarReader::new(&bytes[..]);
        for t in &turns[..turns.len() - 1] {
            r.read_scan(&mut scan).unwrap();
            prop_assert_eq!(scan.beams().len(), t.len());
            prop_assert_eq!(scan.overflow(), 0);
            for (got, want) in scan.beams().iter().zip(t) {
                prop_assert!(got.angle.signed_diff(want.angle).abs() <= 1);
                prop_assert_eq!(got.range, expect_range(want.range));
            }
            r_small.read_scan(&mut small).unwrap();
            prop_assert_eq!(small.beams().len(), t.len().min(8));
            prop_assert_eq!(small.overflow() as usize, t.len().saturating_sub(8));
            prop_assert_eq!(small.beams(), &scan.beams()[..t.len().min(8)]);
        }
        prop_assert_eq!(r.read_scan(&mut scan), Err(ReadError::Eof));
        prop_assert_eq!(r.scans() as usize, turns.len() - 1);
        // The lead-in and the unfinished last turn.
        let last = turns.last().map_or(0, Vec::len);
        prop_assert_eq!(r.discarded_nodes() as usize, lead.len().saturating_sub(1) + last);
    }
}

/// `A5 5A` inside a node stream (here: node 1's angle and distance bytes) must not derail a
/// locked parser, and a lock-on window that straddles it must not confirm.
#[test]
fn sync_bytes_inside_nodes_are_data() {
    // angle_q6 with byte1 = 0xA5 and byte2 = 0x5A: 0x5A << 7 | 0xA5 >> 1.
    let tricky = (0x5A << 7) | (0xA5 >> 1);
    let nodes: Vec<Node> = (0..10u16)
        .map(|i| Node {
            start: i == 0,
            quality: 47,
            angle_q6: (tricky + i) % TURN_Q6 as u16,
            distance_q2: u16::from_le_bytes([0xA5, 0x5A]),
        })
        .collect();
    let mut bytes = SCAN_DESCRIPTOR.to_vec();
    for n in &nodes {
        bytes.extend_from_slice(&n.to_bytes());
    }
    assert_eq!(&bytes[8..10], &[0xA5, 0x5A]);
    let out = run(&bytes, &[]);
    assert_eq!(out.nodes(), nodes);
    assert_eq!(out.counters.descriptors, 1);
    // Without the descriptor, locked on from the first node.
    let out = run(&bytes[DESCRIPTOR_LEN..], &[3]);
    assert_eq!(out.nodes(), nodes);
}
