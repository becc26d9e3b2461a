//! `host-sim firmware`: the firmware in QEMU on a simulated run, checked cell for cell against
//! ogm-core on the host.
//!
//! 1. A world that fits the firmware's 256 × 256 grid (generated, or `--map` cropped), explored
//!    with the simulator's lidar ([`crate::sim::simulate`]).
//! 2. The robot's input ([`input::encode_run`]): settings, then per scan `ScanStart`
//!    (known pose), the scan as LD06 packets, `ScanEnd`; `Finish`. Optionally with garbage.
//! 3. The ELF (`scripts/firmware.sh build`, or `--elf`) boots in QEMU mps2-an386
//!    (`scripts/firmware.sh qemu`, `-icount shift=0`, defmt decoded into the log) with UART1 on a
//!    Unix socket: the input goes in, the map stream comes out.
//! 4. **Replay**: the same input bytes go through the same ogm-core code on the host — link
//!    demultiplexer, mapper, ray store, sampler with the firmware's compile-time sizes, the seed
//!    from the settings and exactly the number of sampler updates the firmware reported per scan
//!    — and every report, every streamed tile (at the time it was sent) and the final map
//!    (log-odds, marginal counts, sample) must be identical.
//! 5. Figures: instructions per cell update / scan / sampled patch (QEMU `-icount shift=0`: one
//!    instruction = 1 ns of the board's timer), stack high-water mark, stream size.
//!
//! `--accuracy` adds the cost of the firmware's bounds: the same replay with unbounded buffers
//! (every ray, every scan, no per-tile list limit, `u32` counts), both scored against ground
//! truth like `eval-sim`.
//!
//! Files: `args` (the options), `setup` (a run's world, simulation and settings), [`input`] (the
//! robot's input), [`robot`] (the robot loop's two serial lines), `qemu` (the firmware in QEMU),
//! [`odometry`] (`--odometry-noise`: drifting odometry sent, the corrected poses' error),
//! `groups` (its stream decoded, by scan), `replay` (the host replay), `report` (what a run
//! reports), `compare` (the stream against the replay), `accuracy` (`--accuracy`), `run` (a run
//! and the command). Each imports only those before it.

mod accuracy;
mod args;
mod compare;
mod groups;
pub mod input;
pub mod log;
mod log_run;
pub mod odometry;
pub mod online;
mod qemu;
mod replay;
mod report;
#[cfg(test)]
mod restore;
pub mod robot;
mod run;
mod setup;

pub use args::{
    parse_data_term, parse_estimator, CorrectionArg, FirmwareArgs, LidarArg, PatternArg,
    SamplerArgs,
};
pub use qemu::{build_elf, build_elf_with, check_elf, repo_root, toolchain_missing};
pub use replay::{marginals, replay_map, sizes_of, HostMemory, ReplaySession, FIRMWARE_SIZES};
pub use report::{
    print_report, Accuracy, AnytimePoint, Figures, FirmwareReport, NoiseReport, RobotReport,
};
pub use run::{cli, run, run_scans, ROBOT_MOUNT_X_MM};
pub use setup::{firmware_world, run_config, sim_config};
