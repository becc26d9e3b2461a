//! `host-sim`: the std side of the project. Everything that maps calls `ogm-core`; nothing here
//! re-implements it.
//!
//! Three people use it, and its top-level modules are theirs:
//!
//! * the **researcher**: [`eval`] — the evaluations (`demo`, `eval-sim`, `eval-log`,
//!   `exact-1d`, `bench-insert`), the samplers and baselines they compare, metrics, plots and
//!   reports, the range-noise estimate, and the data-driven prior (`train-prior`,
//!   `prior-stats`);
//! * the **firmware developer**: [`firmware`] — `host-sim firmware`: the robot's input and the
//!   robot loop's two serial lines, the firmware in QEMU, the host replay of its application,
//!   the bit-exact comparison and the accuracy of its bounds;
//! * the **robot's user**: the field tools (`listen`, its live view and MCAP recording, the map
//!   stream decoder, `export --stream`) are their own crate, `ogm-field`, which depends on
//!   `ogm-core` and the firmware's library but not on anything here; this crate runs them as
//!   `host-sim listen` and `host-sim export --stream`, and builds on its map type
//!   (`ogm_field::world::World`).
//!
//! Below the first two lies [`sim`], the simulator both use (worlds, the exploring robot, the
//! synthetic lidar, CARMEN logs as recorded scans); [`export`] is the one command that serves
//! the researcher and the user alike. Layers (a module imports only those before it): [`sim`] <
//! [`eval`] < [`firmware`] < [`export`].
//!
//! Why a crate for the field tools rather than a folder: the tools a robot's user runs must not
//! drag in the research code (`listen` used to reach 20 of this crate's 25 modules through the
//! map writer), and five dependencies (serial port, signal handling, MCAP, WebSocket, base64)
//! serve only them; a crate boundary makes both facts checkable with `cargo tree`.
#![warn(missing_docs)]

pub mod eval;
pub mod export;
pub mod firmware;
pub mod sim;
