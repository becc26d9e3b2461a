//! `ogm-field`: the tools of the robot's user — watching a robot over its serial link
//! ([`listen`]), the live view for Foxglove Studio ([`live`], its WebSocket protocol), the
//! session recorded as MCAP ([`recording`]), the robot's map stream decoded ([`stream`]) and a
//! captured stream exported as a ROS map_server map ([`export`]), written through the map files
//! every tool shares ([`world`]: the trinary map, its PGM/YAML/PNG writer and reader).
//!
//! It depends on `ogm-core` (the wire format, whose decoder it runs) and on the firmware's
//! library for its compile-time sizes, and on nothing of the simulator or the research
//! evaluation: `host-sim` depends on it, not the other way round, and runs it as
//! `host-sim listen` and `host-sim export --stream`. The serial port, signal handling, MCAP and
//! WebSocket dependencies are this crate's alone.
//!
//! Layers (each imports only those before it): [`world`] < [`stream`] < [`export`] <
//! [`recording`] < [`live`] < [`listen`].
#![warn(missing_docs)]

pub mod export;
pub mod listen;
pub mod live;
pub mod recording;
pub mod stream;
pub mod world;
