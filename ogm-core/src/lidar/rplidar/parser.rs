//! The sans-IO parser: [`RplidarParser`] finds descriptors, responses and node boundaries (see
//! the [module docs](super) for the synchronisation rules).

use super::protocol::{
    flags_ok, node_angle, Descriptor, DeviceInfo, Health, HealthStatus, Node, RplidarError,
    SampleRate, DESCRIPTOR_LEN, HEALTH_LEN, INFO_LEN, MODE_MULTIPLE, MODE_SINGLE, NODE_LEN,
    SAMPLERATE_LEN, SYNC1, SYNC2, TURN_Q6, TYPE_HEALTH, TYPE_INFO, TYPE_SAMPLERATE, TYPE_SCAN,
};

/// The sans-IO RPLIDAR parser: feed it bytes as they arrive (any chunking), get events or errors
/// back in stream order. See the module docs for the synchronisation rules.
#[derive(Clone, Debug)]
pub struct RplidarParser {
    buf: [u8; BUF_LEN],
    len: usize,
    mode: Mode,
    counters: RplidarCounters,
}

impl Default for RplidarParser {
    fn default() -> Self {
        Self::new()
    }
}

impl RplidarParser {
    /// A parser looking for a descriptor or a node stream.
    pub const fn new() -> Self {
        RplidarParser {
            buf: [0; BUF_LEN],
            len: 0,
            mode: Mode::Hunting,
            counters: RplidarCounters {
                nodes: 0,
                bad_nodes: 0,
                scans: 0,
                descriptors: 0,
                responses: 0,
                locks: 0,
                skipped_bytes: 0,
                truncated: 0,
            },
        }
    }

    /// Counters so far.
    pub fn counters(&self) -> RplidarCounters {
        self.counters
    }

    /// Bytes held back (an unfinished node, response or lock-on window), always `< 20`.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Whether the parser is at a node boundary (after a scan descriptor or a lock-on).
    pub fn is_locked(&self) -> bool {
        self.mode == Mode::Locked
    }

    /// Feeds `data`, calling `f` for every event or error, in stream order.
    pub fn feed(&mut self, data: &[u8], mut f: impl FnMut(Result<Event, RplidarError>)) {
        for &b in data {
            self.push(b, &mut f);
        }
    }

    /// Feeds one byte, calling `f` for what it completes: usually nothing or one event; a
    /// completed lock-on delivers its [`LOCK_NODES`] nodes at once.
    pub fn push(&mut self, byte: u8, mut f: impl FnMut(Result<Event, RplidarError>)) {
        if self.len >= BUF_LEN {
            // Unreachable (every mode decides before the buffer fills), but a full buffer must
            // not stall the parser: drop the oldest byte.
            self.consume(1);
            self.skip(1);
        }
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
        // Each step consumes bytes or leaves `Locked`, so this ends well within the bound; the
        // bound only guards against a logic error turning into a hang.
        for _ in 0..2 * BUF_LEN + 2 {
            if !self.step(&mut f) {
                break;
            }
        }
    }

    /// End of stream: an unfinished node or response counts as truncated; whatever is held back is
    /// dropped (counted as skipped) and the parser starts hunting again.
    pub fn finish(&mut self) -> Option<RplidarError> {
        let truncated = match self.mode {
            Mode::Locked => self.len > 0,
            Mode::Response(_) => true,
            Mode::Hunting => false,
        };
        self.skip(self.len);
        self.len = 0;
        self.mode = Mode::Hunting;
        if truncated {
            self.counters.truncated = self.counters.truncated.saturating_add(1);
            Some(RplidarError::Truncated)
        } else {
            None
        }
    }

    fn held(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    fn consume(&mut self, n: usize) {
        // `len ≤ BUF_LEN` always; the bound makes `copy_within` provably in range (no panic
        // path, which also kept `core::fmt` in the firmware image).
        let len = self.len.min(self.buf.len());
        let n = n.min(len);
        self.buf.copy_within(n..len, 0);
        self.len = len - n;
    }

    fn skip(&mut self, n: usize) {
        let n = u32::try_from(n).unwrap_or(u32::MAX);
        self.counters.skipped_bytes = self.counters.skipped_bytes.saturating_add(n);
    }

    fn node_at(&self, at: usize) -> Option<Node> {
        let b = self.held().get(at..at + NODE_LEN)?;
        Node::parse(b.try_into().ok()?).ok()
    }

    fn deliver(&mut self, n: Node, f: &mut impl FnMut(Result<Event, RplidarError>)) {
        self.counters.nodes = self.counters.nodes.saturating_add(1);
        if n.start {
            self.counters.scans = self.counters.scans.saturating_add(1);
        }
        f(Ok(Event::Node(n)));
    }

    /// One step of the state machine; `false` when it needs more bytes.
    fn step(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        match self.mode {
            Mode::Locked => self.step_locked(f),
            Mode::Response(kind) => self.step_response(kind, f),
            Mode::Hunting => self.step_hunting(f),
        }
    }

    fn step_locked(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        if let [SYNC1, SYNC2, ..] = *self.held() {
            // Cannot be a node (`C` would be 0): a new descriptor, e.g. after STOP + SCAN.
            self.mode = Mode::Hunting;
            return true;
        }
        let Some(b) = self.held().get(..NODE_LEN) else {
            return false;
        };
        let parsed = <&[u8; NODE_LEN]>::try_from(b)
            .map_err(|_| RplidarError::Truncated)
            .and_then(Node::parse);
        match parsed {
            Ok(n) => {
                self.consume(NODE_LEN);
                self.deliver(n, f);
            }
            Err(e) => {
                // Not consumed: lock-on restarts at this node's first byte, so a valid
                // boundary inside the rejected bytes is still found.
                self.counters.bad_nodes = self.counters.bad_nodes.saturating_add(1);
                self.mode = Mode::Hunting;
                f(Err(e));
            }
        }
        true
    }

    fn step_response(
        &mut self,
        kind: Kind,
        f: &mut impl FnMut(Result<Event, RplidarError>),
    ) -> bool {
        let Some(p) = self.held().get(..kind.len()) else {
            return false;
        };
        let event = match (kind, p) {
            (Kind::Health, &[status, e0, e1]) => Event::Health(Health {
                status: match status {
                    0 => HealthStatus::Good,
                    1 => HealthStatus::Warning,
                    2 => HealthStatus::Error,
                    s => HealthStatus::Unknown(s),
                },
                error_code: u16::from_le_bytes([e0, e1]),
            }),
            (Kind::SampleRate, &[s0, s1, x0, x1]) => Event::SampleRate(SampleRate {
                standard_us: u16::from_le_bytes([s0, s1]),
                express_us: u16::from_le_bytes([x0, x1]),
            }),
            (Kind::Info, &[model, firmware_minor, firmware_major, hardware, ref serial @ ..]) => {
                Event::Info(DeviceInfo {
                    model,
                    firmware_minor,
                    firmware_major,
                    hardware,
                    serial: serial.try_into().unwrap_or_default(),
                })
            }
            // The payload length always matches the kind; never taken.
            _ => {
                self.mode = Mode::Hunting;
                return true;
            }
        };
        self.consume(kind.len());
        self.mode = Mode::Hunting;
        self.counters.responses = self.counters.responses.saturating_add(1);
        f(Ok(event));
        true
    }

    fn step_hunting(&mut self, f: &mut impl FnMut(Result<Event, RplidarError>)) -> bool {
        if let [SYNC1, SYNC2, ..] = *self.held() {
            let Some(Ok(d)) = self
                .held()
                .get(..DESCRIPTOR_LEN)
                .map(<&[u8; DESCRIPTOR_LEN]>::try_from)
            else {
                return false;
            };
            match Descriptor::parse(d) {
                Some(d) if d.mode <= MODE_MULTIPLE => {
                    if follow(&d) == Mode::Hunting {
                        // Nothing beyond `A5 5A` can be checked in a descriptor the parser does
                        // not follow, and `A5 5A` also occurs in node data: a node stream
                        // starting inside it is better evidence than the descriptor, whose 7
                        // bytes would swallow that stream's first node.
                        match lock_inside_descriptor(self.held()) {
                            Candidate::NeedMore => return false,
                            Candidate::Lock => {
                                self.consume(1);
                                self.skip(1);
                                return true;
                            }
                            Candidate::Reject => {}
                        }
                    }
                    self.consume(DESCRIPTOR_LEN);
                    self.counters.descriptors = self.counters.descriptors.saturating_add(1);
                    self.mode = follow(&d);
                    f(Ok(Event::Descriptor(d)));
                }
                _ => {
                    // Reserved send mode: garbage that happens to start with `A5 5A`.
                    self.consume(1);
                    self.skip(1);
                }
            }
            return true;
        }
        match lock_candidate(self.held()) {
            Candidate::NeedMore => false,
            Candidate::Reject => {
                self.consume(1);
                self.skip(1);
                true
            }
            Candidate::Lock => {
                for i in 0..LOCK_NODES {
                    if let Some(n) = self.node_at(i * NODE_LEN) {
                        self.deliver(n, f);
                    }
                }
                self.consume(LOCK_NODES * NODE_LEN);
                self.counters.locks = self.counters.locks.saturating_add(1);
                self.mode = Mode::Locked;
                true
            }
        }
    }
}

/// What the parser delivers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A scan node.
    Node(Node),
    /// A response descriptor (a new response or node stream starts).
    Descriptor(Descriptor),
    /// A `GET_INFO` response.
    Info(DeviceInfo),
    /// A `GET_HEALTH` response.
    Health(Health),
    /// A `GET_SAMPLERATE` response.
    SampleRate(SampleRate),
}

/// What the parser saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RplidarCounters {
    /// Good nodes delivered.
    pub nodes: u32,
    /// Nodes rejected at a locked boundary (check bits wrong).
    pub bad_nodes: u32,
    /// Delivered nodes with `S = 1`: starts of a new 360° scan.
    pub scans: u32,
    /// Response descriptors recognised.
    pub descriptors: u32,
    /// Info, health and sample-rate responses decoded.
    pub responses: u32,
    /// Node boundaries found without a descriptor (start-up mid-stream, resynchronisation).
    pub locks: u32,
    /// Bytes dropped while hunting for a boundary (garbage, bad nodes, unfinished data at the end).
    pub skipped_bytes: u32,
    /// Nodes or responses cut short by the end of the stream.
    pub truncated: u32,
}

/// Consecutive nodes that must look like a scan before the parser locks on without a descriptor.
/// Three: a window of random bytes passes with probability ≈ 10⁻⁶ (first node ≈ 1/6; each
/// further node 1/8 for its flags and check bit times 640/32768 for its angle step).
pub const LOCK_NODES: usize = 3;
/// Largest clockwise step between consecutive nodes accepted while locking on, q6 units (10°).
/// Sensors step ≈ 1° (A1: 2000 samples/s at 5.5 Hz) and at most ≈ 3° (15 Hz).
pub const MAX_LOCK_STEP_Q6: u32 = 10 * 64;

/// Which single response the parser is collecting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Info,
    Health,
    SampleRate,
}

impl Kind {
    const fn len(self) -> usize {
        match self {
            Kind::Info => INFO_LEN,
            Kind::Health => HEALTH_LEN,
            Kind::SampleRate => SAMPLERATE_LEN,
        }
    }
}

/// Parser state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// Looking for a descriptor or a node boundary.
    Hunting,
    /// At a node boundary: every 5 bytes are a node.
    Locked,
    /// Collecting a single response's payload.
    Response(Kind),
}

/// What the parser does after descriptor `d`: the response it decodes, if any.
fn follow(d: &Descriptor) -> Mode {
    match (d.data_type, d.len, d.mode) {
        (TYPE_SCAN, 5, _) => Mode::Locked,
        (TYPE_INFO, 20, MODE_SINGLE) => Mode::Response(Kind::Info),
        (TYPE_HEALTH, 3, MODE_SINGLE) => Mode::Response(Kind::Health),
        (TYPE_SAMPLERATE, 4, MODE_SINGLE) => Mode::Response(Kind::SampleRate),
        _ => Mode::Hunting,
    }
}

/// Verdict on the candidate at the start of the hunting buffer.
enum Candidate {
    NeedMore,
    Reject,
    Lock,
}

/// Buffer size: the largest of a lock-on window (15), a descriptor candidate with the lock-on
/// windows inside it (6 + 13), a descriptor (7) and an info response (20).
const BUF_LEN: usize = INFO_LEN;
/// Bytes of a lock-on window its rules look at: all but the last node's distance.
const LOCK_CHECKED: usize = (LOCK_NODES - 1) * NODE_LEN + 3;
// A descriptor candidate is decided once 6 + 13 = 19 bytes are held, so `pending() < 20` holds
// (the fuzz target checks it).
const _: () =
    assert!(BUF_LEN >= LOCK_NODES * NODE_LEN && BUF_LEN >= DESCRIPTOR_LEN - 1 + LOCK_CHECKED);

/// Judges the lock-on windows starting inside the descriptor candidate at the start of `b`
/// (offsets `1..DESCRIPTOR_LEN`) by [`lock_rules`]: `A5 5A` in node data (node bytes 1–2, 2–3,
/// 3–4, or byte 4 and the next node's byte 0) ends 1…4 bytes before a node boundary, and 6…9
/// before the one after if that node is bad. Locks if any window passes; needs more bytes while
/// one is undecided.
fn lock_inside_descriptor(b: &[u8]) -> Candidate {
    let mut need_more = false;
    for offset in 1..DESCRIPTOR_LEN {
        match lock_rules(b.get(offset..).unwrap_or(&[])) {
            Candidate::Lock => return Candidate::Lock,
            Candidate::NeedMore => need_more = true,
            Candidate::Reject => {}
        }
    }
    if need_more {
        Candidate::NeedMore
    } else {
        Candidate::Reject
    }
}

/// Judges the lock-on window at the start of `b` as far as its bytes go (see the module docs):
/// rejects as soon as a rule fails, locks once [`LOCK_NODES`] whole nodes pass.
fn lock_candidate(b: &[u8]) -> Candidate {
    match lock_rules(b) {
        // The window's nodes are delivered at once: wait for the last distance too.
        Candidate::Lock if b.len() < LOCK_NODES * NODE_LEN => Candidate::NeedMore,
        verdict => verdict,
    }
}

/// The lock-on rules on the window at the start of `b`: rejects as soon as one fails, passes
/// (`Lock`) once its first [`LOCK_CHECKED`] bytes are in (distances are not checked).
fn lock_rules(b: &[u8]) -> Candidate {
    let mut prev: Option<u32> = None;
    for i in 0..LOCK_NODES {
        let byte = |j: usize| b.get(i * NODE_LEN + j).copied();
        let Some(b0) = byte(0) else {
            return Candidate::NeedMore;
        };
        if !flags_ok(b0) || (i > 0 && b0 & 1 == 1) {
            return Candidate::Reject;
        }
        let Some(b1) = byte(1) else {
            return Candidate::NeedMore;
        };
        if b1 & 1 == 0 {
            return Candidate::Reject;
        }
        let Some(b2) = byte(2) else {
            return Candidate::NeedMore;
        };
        let a = u32::from(node_angle(b1, b2));
        if a >= TURN_Q6 {
            return Candidate::Reject;
        }
        if let Some(p) = prev {
            let step = (a + TURN_Q6 - p % TURN_Q6) % TURN_Q6;
            if step == 0 || step > MAX_LOCK_STEP_Q6 {
                return Candidate::Reject;
            }
        }
        prev = Some(a);
    }
    Candidate::Lock
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lidar::rplidar::tests::turn;
    use crate::lidar::rplidar::SCAN_DESCRIPTOR;

    fn run(p: &mut RplidarParser, bytes: &[u8]) -> (Vec<Node>, Vec<Event>, Vec<RplidarError>) {
        let (mut nodes, mut other, mut errors) = (Vec::new(), Vec::new(), Vec::new());
        p.feed(bytes, |r| match r {
            Ok(Event::Node(n)) => nodes.push(n),
            Ok(e) => other.push(e),
            Err(e) => errors.push(e),
        });
        (nodes, other, errors)
    }

    #[test]
    fn descriptor_then_nodes() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(10, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert_eq!(nodes.len(), 10);
        assert!(nodes[0].start && nodes[1..].iter().all(|n| !n.start));
        assert_eq!(
            other,
            vec![Event::Descriptor(
                Descriptor::parse(&SCAN_DESCRIPTOR).unwrap()
            )]
        );
        assert!(errors.is_empty());
        let c = p.counters();
        assert_eq!((c.nodes, c.scans, c.descriptors, c.locks), (10, 1, 1, 0));
        assert_eq!((c.skipped_bytes, c.bad_nodes), (0, 0));
        assert!(p.is_locked());
    }

    #[test]
    fn locks_on_mid_stream_and_skips_the_partial_node() {
        let s = turn(20, 100);
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s[7..]); // starts inside node 1
        assert!(errors.is_empty());
        let want: Vec<Node> = s[10..]
            .chunks(5)
            .map(|c| Node::parse(c.try_into().unwrap()).unwrap())
            .collect();
        assert_eq!(nodes, want);
        let c = p.counters();
        assert_eq!((c.locks, c.skipped_bytes, c.descriptors), (1, 3, 0));
    }

    #[test]
    fn lock_on_needs_a_plausible_angle_sequence() {
        // Noise-free constant distances (q2 0x0102) and quality 15: seen from byte 3 of a node,
        // every window passes the check bits and has S = 0 (`02`, `01`, then `3E …`), and its
        // "angle" (`3E << 7`) never changes. Only the angle rule rejects that boundary.
        let nodes: Vec<Node> = (0..12u16)
            .map(|i| Node {
                start: false,
                quality: 15,
                angle_q6: 1000 + 70 * i,
                distance_q2: 0x0102,
            })
            .collect();
        let bytes: Vec<u8> = nodes.iter().flat_map(|n| n.to_bytes()).collect();
        let window = &bytes[3..3 + LOCK_NODES * NODE_LEN];
        for c in window.chunks(NODE_LEN) {
            let n = Node::parse(c.try_into().unwrap()).unwrap();
            assert!(!n.start && n.angle_q6 == 0x3E << 7);
        }
        assert!(matches!(lock_candidate(window), Candidate::Reject));
        let mut p = RplidarParser::new();
        let (got, _, errors) = run(&mut p, &bytes[3..]);
        assert!(errors.is_empty());
        assert_eq!(got, nodes[1..]);
        assert_eq!(p.counters().skipped_bytes, 2);
    }

    #[test]
    fn bad_check_bit_is_rejected_and_the_stream_resyncs() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(30, 0));
        let at = 7 + 5 * 12;
        s[at + 1] &= !1; // node 12: C = 0
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s);
        assert_eq!(errors, vec![RplidarError::CheckBit]);
        assert_eq!(nodes.len(), 29, "only the corrupted node is lost");
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks, c.skipped_bytes), (1, 1, 5));
        assert!(p.is_locked());
    }

    #[test]
    fn lost_byte_and_garbage_resync() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        let t = turn(40, 0);
        s.extend_from_slice(&t[..5 * 10 + 2]);
        s.extend_from_slice(&t[5 * 10 + 3..5 * 20]); // one byte of node 10 lost
        s.extend_from_slice(&[0x00, 0xFF, 0x33, 0xCC]); // garbage that cannot start a node
        s.extend_from_slice(&t[5 * 20..]);
        let mut p = RplidarParser::new();
        let (nodes, _, errors) = run(&mut p, &s);
        // The garbage is caught at once (its first byte fails `S`/`!S`), the lost byte only
        // when a misaligned node fails a check bit: node 10's remains and two misaligned nodes
        // pass (angles 0 and 26114), nodes 11 and 12 are eaten, and lock-on resumes at node 13.
        assert_eq!(errors, [RplidarError::CheckBit, RplidarError::StartFlags]);
        let angles: Vec<u16> = nodes.iter().map(|n| n.angle_q6).collect();
        let want = |r: core::ops::Range<u16>| r.map(|i| 64 * i).collect::<Vec<u16>>();
        assert_eq!(angles[..10], want(0..10));
        assert_eq!(angles[10..12], [0, 26114]);
        assert_eq!(angles[12..], want(13..40));
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks), (2, 2));
        assert!(p.is_locked());
    }

    /// Nodes with `S = 0` from `(quality, angle_q6, distance_q2)`, and their bytes.
    fn stream(spec: &[(u8, u16, u16)]) -> (Vec<Node>, Vec<u8>) {
        let nodes: Vec<Node> = spec
            .iter()
            .map(|&(quality, angle_q6, distance_q2)| Node {
                start: false,
                quality,
                angle_q6,
                distance_q2,
            })
            .collect();
        let bytes = nodes.iter().flat_map(|n| n.to_bytes()).collect();
        (nodes, bytes)
    }

    #[test]
    fn sync_bytes_in_node_data_do_not_swallow_nodes_while_hunting() {
        // `A5 5A` at each place it can sit in node data. Hunting over it used to read a
        // descriptor of an unknown type, whose 7 bytes ran into (and lost) the next node.
        // a: node 2 bytes 1–2 (angle 11602).
        let a = stream(&[
            (47, 11500, 4000),
            (47, 11550, 4000),
            (47, 11602, 4000),
            (47, 11650, 4000),
            (47, 11700, 4000),
            (47, 11750, 4000),
        ]);
        // b: node 1 bytes 2–3, node 3 bytes 3–4, node 5 byte 4 + node 6 byte 0 (quality 22).
        let b = stream(&[
            (47, 21100, 4000),
            (47, 21150, 0x105A),
            (47, 21200, 4000),
            (47, 21250, 0x5AA5),
            (47, 21300, 4000),
            (47, 21350, 0xA510),
            (22, 21400, 4000),
            (47, 21450, 4000),
            (47, 21500, 4000),
            (47, 21550, 4000),
            (47, 21600, 4000),
        ]);
        assert_eq!(a.1[11..13], [SYNC1, SYNC2]);
        for at in [7, 18, 29] {
            assert_eq!(b.1[at..at + 2], [SYNC1, SYNC2]);
        }
        // Start-up anywhere: every node from the next boundary on comes back.
        for (nodes, bytes) in [&a, &b] {
            for from in 0..bytes.len() {
                let first = from.div_ceil(NODE_LEN);
                if nodes.len() - first < LOCK_NODES {
                    continue; // too few left to lock on
                }
                let mut p = RplidarParser::new();
                let (got, other, errors) = run(&mut p, &bytes[from..]);
                assert_eq!(got, nodes[first..], "start at byte {from}");
                assert!(
                    other.is_empty() && errors.is_empty(),
                    "start at byte {from}"
                );
                assert_eq!(p.counters().skipped_bytes as usize, first * NODE_LEN - from);
            }
        }
        // A bad node holding `A5 5A` (the shape of the proptest regression): only it is lost.
        let (nodes, bytes) = &a;
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend_from_slice(bytes);
        s[DESCRIPTOR_LEN + 2 * NODE_LEN] ^= 1; // node 2: S = !S
        let mut p = RplidarParser::new();
        let (got, other, errors) = run(&mut p, &s);
        assert_eq!(got[..2], nodes[..2]);
        assert_eq!(got[2..], nodes[3..]);
        assert_eq!(other.len(), 1, "only the scan descriptor");
        assert_eq!(errors, [RplidarError::StartFlags]);
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks, c.skipped_bytes), (1, 1, 5));
        // Node 5 (ending in `A5`) and node 6 (starting with `5A`) bad: the candidate covers
        // node 7's first byte, so the lock-on window 6 bytes into it must be judged too.
        let (nodes, bytes) = &b;
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend_from_slice(bytes);
        s[DESCRIPTOR_LEN + 5 * NODE_LEN] ^= 1; // node 5: S = !S
        s[DESCRIPTOR_LEN + 6 * NODE_LEN + 1] ^= 1; // node 6: C = 0
        let mut p = RplidarParser::new();
        let (got, other, errors) = run(&mut p, &s);
        assert_eq!(got[..5], nodes[..5]);
        assert_eq!(got[5..], nodes[7..]);
        assert_eq!(other.len(), 1, "only the scan descriptor");
        assert_eq!(errors, [RplidarError::StartFlags]);
        let c = p.counters();
        assert_eq!((c.bad_nodes, c.locks, c.skipped_bytes), (1, 1, 10));
    }

    #[test]
    fn descriptors_not_followed_are_still_reported() {
        // Express scan (unsupported) and an unknown type: no node stream starts inside them,
        // so both are reported, also right before a node stream or at the very end.
        let express = [SYNC1, SYNC2, 0x54, 0, 0, 0x40, 0x82];
        let unknown = [SYNC1, SYNC2, 0x10, 0, 0, 0, 0x77];
        let mut s = express.to_vec();
        s.extend(turn(5, 0));
        s.extend_from_slice(&unknown);
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert_eq!(nodes.len(), 5);
        assert!(errors.is_empty());
        let want = |b| Event::Descriptor(Descriptor::parse(&b).unwrap());
        assert_eq!(other, [want(express), want(unknown)]);
        assert_eq!((p.pending(), p.counters().skipped_bytes), (0, 0));
    }

    #[test]
    fn info_health_and_samplerate_responses() {
        let mut s = vec![0x13, 0x37]; // garbage first
        s.extend_from_slice(&[0xA5, 0x5A, 0x14, 0, 0, 0, 0x04]);
        s.extend_from_slice(&[0x18, 29, 1, 7]);
        s.extend(1..=16u8);
        s.extend_from_slice(&[0xA5, 0x5A, 0x03, 0, 0, 0, 0x06, 0x02, 0x34, 0x12]);
        s.extend_from_slice(&[0xA5, 0x5A, 0x04, 0, 0, 0, 0x15, 0xF4, 0x01, 0xFA, 0x00]);
        s.extend_from_slice(&SCAN_DESCRIPTOR);
        s.extend(turn(3, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert!(errors.is_empty());
        assert_eq!(nodes.len(), 3);
        let mut serial = [0u8; 16];
        serial.iter_mut().zip(1..).for_each(|(s, i)| *s = i);
        assert_eq!(
            other[1],
            Event::Info(DeviceInfo {
                model: 0x18,
                firmware_minor: 29,
                firmware_major: 1,
                hardware: 7,
                serial
            })
        );
        assert_eq!(
            other[3],
            Event::Health(Health {
                status: HealthStatus::Error,
                error_code: 0x1234
            })
        );
        assert_eq!(
            other[5],
            Event::SampleRate(SampleRate {
                standard_us: 500,
                express_us: 250
            })
        );
        let c = p.counters();
        assert_eq!((c.descriptors, c.responses, c.skipped_bytes), (4, 3, 2));
    }

    #[test]
    fn truncation_is_counted() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend_from_slice(&turn(2, 0)[..7]);
        let mut p = RplidarParser::new();
        let (nodes, _, _) = run(&mut p, &s);
        assert_eq!(nodes.len(), 1);
        assert_eq!(p.pending(), 2);
        assert_eq!(p.finish(), Some(RplidarError::Truncated));
        assert_eq!(p.finish(), None);
        let c = p.counters();
        assert_eq!((c.truncated, c.skipped_bytes), (1, 2));
        // A health descriptor without its payload.
        let mut p = RplidarParser::new();
        p.feed(&[0xA5, 0x5A, 0x03, 0, 0, 0, 0x06, 0x00], |_| {});
        assert_eq!(p.finish(), Some(RplidarError::Truncated));
    }

    #[test]
    fn a_new_descriptor_is_recognised_while_locked() {
        let mut s = SCAN_DESCRIPTOR.to_vec();
        s.extend(turn(5, 0));
        s.extend_from_slice(&SCAN_DESCRIPTOR); // STOP + SCAN
        s.extend(turn(5, 0));
        let mut p = RplidarParser::new();
        let (nodes, other, errors) = run(&mut p, &s);
        assert_eq!((nodes.len(), other.len(), errors.len()), (10, 2, 0));
        assert_eq!(p.counters().skipped_bytes, 0);
    }

    #[test]
    fn parser_never_panics_on_noise_and_accounts_for_every_byte() {
        let mut x = 0x9E37_79B9u32;
        let mut s = Vec::new();
        for k in 0..300 {
            for _ in 0..(k % 23) {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                s.push(if x % 7 == 0 { SYNC1 } else { x as u8 });
            }
            if k % 50 == 0 {
                s.extend_from_slice(&SCAN_DESCRIPTOR);
            }
            s.extend(turn(8, (k * 37 % 360) as u16 * 64));
        }
        let mut p = RplidarParser::new();
        let mut payload = 0usize;
        p.feed(&s, |r| {
            payload += match r {
                Ok(Event::Node(_)) => NODE_LEN,
                Ok(Event::Descriptor(_)) => DESCRIPTOR_LEN,
                Ok(Event::Info(_)) => INFO_LEN,
                Ok(Event::Health(_)) => HEALTH_LEN,
                Ok(Event::SampleRate(_)) => SAMPLERATE_LEN,
                Err(_) => 0,
            }
        });
        let pending = p.pending();
        let c = p.counters();
        assert_eq!(payload + c.skipped_bytes as usize + pending, s.len());
        assert!(c.nodes > 300 * 5, "most nodes recovered: {c:?}");
    }
}
