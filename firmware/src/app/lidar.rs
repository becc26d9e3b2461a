//! The lidar on the robot's own UART: the parser the settings name, the turns its packets or
//! nodes are assembled into (placed by the poses from the link), and its counters; and
//! [`App::feed_lidar`], where its bytes come in.

use embedded_io::Write;
use ogm_core::config::{LidarModel, RunConfig};
use ogm_core::lidar::ld06::Ld06Parser;
#[cfg(feature = "rplidar")]
use ogm_core::lidar::rplidar::{self, RplidarParser};
use ogm_core::lidar::turn::{Taken, Turn, Turns};
use ogm_core::session::Storage;
use ogm_core::wire::LidarCounters;
use ogm_core::ScanBuf;

use super::{App, Fed, MAX_BEAMS};
use crate::platform::Platform;

/// The lidar on the robot's own UART.
pub(super) struct Lidar<'a> {
    parser: Parser,
    pub(super) turns: &'a mut Turns,
    pub(super) turn: &'a mut ScanBuf<MAX_BEAMS>,
    bad_packets: u32,
    before_config: u32,
    /// Settings the UART has not been set up for yet ([`App::take_lidar_setup`]).
    pub(super) setup: Option<LidarModel>,
}

/// The parser of the lidar the settings name (an LD06's until they arrive).
#[cfg_attr(not(feature = "rplidar"), allow(dead_code))] // `Rplidar` holds no value then
enum Parser {
    Ld06(Ld06Parser),
    Rplidar(RplidarSlot),
}

/// An RPLIDAR parser in an image built with the `rplidar` feature; without it, a type with no
/// values, so the compiler drops the RPLIDAR code (its settings are refused:
/// [`ogm_core::wire::ConfigFault::Lidar`]).
#[cfg(feature = "rplidar")]
type RplidarSlot = RplidarParser;
#[cfg(not(feature = "rplidar"))]
type RplidarSlot = core::convert::Infallible;

/// Whether this image can read `model`.
pub(super) const fn built_for(model: &LidarModel) -> bool {
    match model {
        LidarModel::Ld06 => true,
        LidarModel::Rplidar { .. } => cfg!(feature = "rplidar"),
    }
}

/// What a lidar parser handed out.
enum Unit {
    Packet(ogm_core::lidar::ld06::Packet),
    #[cfg(feature = "rplidar")]
    Node(rplidar::Node),
}

impl<'a> Lidar<'a> {
    /// An LD06's parser (until the settings name a lidar) over `turns` and `turn`.
    pub(super) fn new(turns: &'a mut Turns, turn: &'a mut ScanBuf<MAX_BEAMS>) -> Self {
        Lidar {
            parser: Parser::Ld06(Ld06Parser::new()),
            turns,
            turn,
            bad_packets: 0,
            before_config: 0,
            setup: None,
        }
    }

    /// Starts over with the settings' lidar, mounting and pose source.
    pub(super) fn configure(&mut self, config: &RunConfig) {
        *self.turns = Turns::configured(config);
        self.turn.clear();
        self.parser = match config.lidar {
            #[cfg(feature = "rplidar")]
            LidarModel::Rplidar { .. } => Parser::Rplidar(RplidarParser::new()),
            // Refused before this (`built_for`) when the image has no RPLIDAR parser.
            _ => Parser::Ld06(Ld06Parser::new()),
        };
        self.setup = Some(config.lidar);
    }

    pub(super) fn counters(&self) -> LidarCounters {
        let t = self.turns.counters();
        LidarCounters {
            packets: t.packets.saturating_add(self.before_config),
            bad_packets: self.bad_packets,
            packets_before_config: self.before_config,
            turns: t.turns,
            packets_without_pose: t.packets_without_pose,
            packets_overflowed: t.packets_overflowed,
            poses: t.poses,
            poses_out_of_order: t.poses_out_of_order,
        }
    }
}

impl<S: Storage> App<'_, S> {
    /// Feeds bytes from the lidar's UART: packets or nodes are placed by the poses from the
    /// link, and each finished turn is mapped, sampled, reported and streamed like a host's
    /// scan. Returns the last turn completed, if any.
    pub fn feed_lidar<W: Write, P: Platform>(
        &mut self,
        bytes: &[u8],
        link: &mut W,
        platform: &mut P,
    ) -> Fed {
        let mut fed = Fed::Nothing;
        let (state, lidar) = (&mut self.state, &mut self.lidar);
        let mut done = None;
        for &b in bytes {
            let Lidar {
                parser,
                turns,
                turn,
                bad_packets,
                before_config,
                ..
            } = &mut *lidar;
            // One copy of the mapping path, whichever parser calls it (flash).
            let unit: &mut dyn FnMut(Result<Unit, ()>) = &mut |u| {
                let u = match u {
                    Ok(u) => u,
                    Err(()) => return *bad_packets = bad_packets.saturating_add(1),
                };
                if state.session.is_none() {
                    return *before_config = before_config.saturating_add(1);
                }
                let mut f = |t: Turn<'_>| {
                    let taken = state.process_turn(link, platform, &t);
                    if taken == Taken::Taken {
                        done = Some(t.seq);
                    }
                    taken
                };
                match u {
                    Unit::Packet(p) => turns.push_packet(&p, turn, &mut f),
                    #[cfg(feature = "rplidar")]
                    Unit::Node(n) => turns.push_node(&n, turn, &mut f),
                }
            };
            match parser {
                Parser::Ld06(p) => match p.push(b) {
                    None => {}
                    Some(r) => unit(r.map(Unit::Packet).map_err(drop)),
                },
                #[cfg(feature = "rplidar")]
                Parser::Rplidar(p) => p.push(b, |e| match e {
                    Ok(rplidar::Event::Node(n)) => unit(Ok(Unit::Node(n))),
                    Ok(_) => {} // descriptors and responses: nothing to map
                    Err(_) => unit(Err(())),
                }),
                #[cfg(not(feature = "rplidar"))]
                Parser::Rplidar(never) => match *never {},
            }
            if let Some(seq) = done.take() {
                let (l, d) = (self.rx.counters(), lidar.counters());
                state.report(link, l, d);
                fed = Fed::Scan(seq);
            }
        }
        fed
    }
}
