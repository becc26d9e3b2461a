//! [`RplidarReader`]: whole turns read from any [`embedded_io::Read`].

use super::parser::{Event, RplidarCounters, RplidarParser, LOCK_NODES};
use crate::lidar::source::ReadError;
use crate::types::angle::Angle;
use crate::types::scan::{Beam, Range, ScanBuf};

/// A blocking RPLIDAR driver over any [`embedded_io::Read`] (a UART on the robot, a byte slice or
/// a pipe on the host): [`RplidarReader::read_scan`] assembles one full 360° turn per scan. The
/// caller starts the stream by writing [`REQ_SCAN`] to the sensor (after [`REQ_STOP`] and a
/// 1 ms pause if it may already be scanning); the reader only reads.
///
/// A scan runs from one node with `S = 1` to the next (exclusive), like the vendor SDK's
/// `grabScanData`: unlike [`crate::lidar::ld06::Ld06Reader`], which returns the partial first turn, nodes
/// before the first start flag are dropped (counted in [`RplidarReader::discarded_nodes`]), as is
/// a turn interrupted by a new descriptor (the sensor restarted) or by an error returned from
/// `read_scan` (the next call starts at the next start flag). Nodes lost to corruption are
/// simply missing from their turn; bad bytes are counted by the parser
/// ([`RplidarReader::counters`]). Beams beyond the [`ScanBuf`]'s capacity are counted in its
/// overflow, never written.
///
/// [`REQ_SCAN`]: super::REQ_SCAN
/// [`REQ_STOP`]: super::REQ_STOP
pub struct RplidarReader<R> {
    rx: R,
    parser: RplidarParser,
    chunk: [u8; 64],
    chunk_len: usize,
    chunk_pos: usize,
    carry: [Beam; CARRY],
    n_carry: usize,
    scans: u32,
    discarded: u32,
}

/// Nodes one byte can complete (a lock-on window): what may spill over into the next scan.
const CARRY: usize = LOCK_NODES + 1;

impl<R: embedded_io::Read> RplidarReader<R> {
    /// A reader on `rx`.
    pub fn new(rx: R) -> Self {
        RplidarReader {
            rx,
            parser: RplidarParser::new(),
            chunk: [0; 64],
            chunk_len: 0,
            chunk_pos: 0,
            carry: [Beam {
                angle: Angle::ZERO,
                range: Range::NoReturn,
            }; CARRY],
            n_carry: 0,
            scans: 0,
            discarded: 0,
        }
    }

    /// Parser counters.
    pub fn counters(&self) -> RplidarCounters {
        self.parser.counters()
    }

    /// Complete turns returned.
    pub fn scans(&self) -> u32 {
        self.scans
    }

    /// Good nodes not returned in any scan: before the first start flag, or in a turn cut short
    /// by a new descriptor, a read error or the end of the stream.
    pub fn discarded_nodes(&self) -> u32 {
        self.discarded
    }

    /// The byte source back.
    pub fn into_inner(self) -> R {
        self.rx
    }

    fn next_byte(&mut self) -> Result<u8, ReadError<R::Error>> {
        if self.chunk_pos >= self.chunk_len {
            let n = self.rx.read(&mut self.chunk).map_err(ReadError::Io)?;
            if n == 0 {
                self.parser.finish();
                return Err(ReadError::Eof);
            }
            (self.chunk_len, self.chunk_pos) = (n.min(self.chunk.len()), 0);
        }
        let b = self.chunk.get(self.chunk_pos).copied().unwrap_or(0);
        self.chunk_pos += 1;
        Ok(b)
    }
}

impl<R: embedded_io::Read> RplidarReader<R> {
    /// Blocks until the next complete scan (one full 360° turn) has been read and writes it into
    /// `scan`, which it clears first; beams beyond `scan`'s capacity are counted as its overflow.
    pub fn read_scan<const N: usize>(
        &mut self,
        scan: &mut ScanBuf<N>,
    ) -> Result<(), ReadError<R::Error>> {
        scan.clear();
        // A carry always starts with the start node that ended the previous scan.
        let mut in_scan = self.n_carry > 0;
        let mut nodes = 0u32; // in this turn, including beams the buffer dropped
        for b in self.carry.iter().take(self.n_carry) {
            scan.push(*b);
            nodes = nodes.saturating_add(1);
        }
        self.n_carry = 0;
        loop {
            let byte = match self.next_byte() {
                Ok(b) => b,
                Err(e) => {
                    // The turn in progress is abandoned; the next call starts at a start flag.
                    self.discarded = self.discarded.saturating_add(nodes);
                    return Err(e);
                }
            };
            let mut done = false;
            let (carry, n_carry, discarded) =
                (&mut self.carry, &mut self.n_carry, &mut self.discarded);
            self.parser.push(byte, |r| match r {
                Ok(Event::Node(n)) => {
                    if done || (n.start && in_scan) {
                        // The next turn has begun: keep its nodes for the next call.
                        done = true;
                        if let Some(slot) = carry.get_mut(*n_carry) {
                            *slot = n.beam();
                            *n_carry += 1;
                        }
                    } else if n.start || in_scan {
                        in_scan = true;
                        scan.push(n.beam());
                        nodes = nodes.saturating_add(1);
                    } else {
                        *discarded = discarded.saturating_add(1);
                    }
                }
                Ok(Event::Descriptor(_)) => {
                    // The sensor (re)started a response: the turn in progress will never be
                    // completed consistently.
                    if done {
                        *discarded = discarded.saturating_add(*n_carry as u32);
                        *n_carry = 0;
                    } else {
                        *discarded = discarded.saturating_add(nodes);
                        nodes = 0;
                        in_scan = false;
                        scan.clear();
                    }
                }
                _ => {}
            });
            if done {
                self.scans = self.scans.saturating_add(1);
                return Ok(());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lidar::rplidar::{beam_angle, encode_scan, scan_len, NODE_LEN};

    #[test]
    fn reader_assembles_full_turns() {
        let beams: Vec<Beam> = (0..36)
            .map(|i| Beam {
                angle: beam_angle((i * 10 * 64) as u16),
                range: if i % 5 == 0 {
                    Range::NoReturn
                } else {
                    Range::Hit(1000 + i)
                },
            })
            .collect();
        let mut bytes = vec![0u8; scan_len(36, true) + 3 * scan_len(36, false)];
        // Start-up mid-turn: the tail of a turn (no start flag) comes first.
        let mut at = encode_scan(&beams, false, &mut bytes).unwrap() - 20 * NODE_LEN;
        bytes.copy_within(20 * NODE_LEN..36 * NODE_LEN, 0);
        at += encode_scan(&beams, false, &mut bytes[at..]).unwrap();
        at += encode_scan(&beams, false, &mut bytes[at..]).unwrap();
        at += encode_scan(&beams[..10], false, &mut bytes[at..]).unwrap();
        bytes.truncate(at);
        let mut r = RplidarReader::new(&bytes[..]);
        let mut scan: ScanBuf<64> = ScanBuf::new();
        for _ in 0..2 {
            r.read_scan(&mut scan).unwrap();
            assert_eq!(scan.beams(), &beams[..]);
            assert_eq!(scan.overflow(), 0);
        }
        assert_eq!(r.read_scan(&mut scan), Err(ReadError::Eof));
        assert_eq!(r.scans(), 2);
        // The leading partial turn (16 nodes: lock-on confirms three of them and delivers
        // all) and the unfinished last one (10) are not returned.
        assert_eq!(r.discarded_nodes(), 16 + 10);
        // A small buffer: beams are dropped and counted, the turn boundary still holds.
        let mut r = RplidarReader::new(&bytes[..]);
        let mut small: ScanBuf<10> = ScanBuf::new();
        r.read_scan(&mut small).unwrap();
        assert_eq!((small.beams().len(), small.overflow()), (10, 26));
        assert_eq!(small.beams(), &beams[..10]);
    }
}
