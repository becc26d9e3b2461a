//! Linker setup for the firmware (runs on the host at build time).
//!
//! * `memory.x` lives at the repository root (shared with other tooling and boards); copy it into
//!   `OUT_DIR` and put that on the linker search path, where cortex-m-rt's `link.x` INCLUDEs it.
//! * `-Tlink.x` (cortex-m-rt) and `-Tdefmt.x` (defmt) are passed here rather than in
//!   `.cargo/config.toml`, so they apply to this package's targets only and an outer
//!   `RUSTFLAGS` cannot drop them.
use std::{env, fs, path::PathBuf};

fn main() {
    // The library also builds for the host (host-sim replays it): no linker scripts there.
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let manifest_dir =
        PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let memory_x = manifest_dir.join("../memory.x");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let text =
        fs::read(&memory_x).unwrap_or_else(|e| panic!("cannot read {}: {e}", memory_x.display()));
    fs::write(out.join("memory.x"), text).expect("write memory.x to OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");

    // Applies to bins, tests and examples of this package (on-target tests link the same way).
    // --nmagic: no page alignment of sections (keeps the ELF small; harmless for lld).
    println!("cargo:rustc-link-arg=--nmagic");
    println!("cargo:rustc-link-arg=-Tlink.x");
    println!("cargo:rustc-link-arg=-Tdefmt.x");
}
