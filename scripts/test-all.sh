#!/usr/bin/env bash
# The full test suite, from a fresh machine of this kind (Debian 12 + rustup stable, as root or
# with passwordless sudo). Installs what it needs — the Cortex-M4 toolchain (rustup target, or
# Debian's rustc-web + rust-web-src + lld with build-std), qemu-system-arm and defmt-print —
# then runs, and stops at the first failure:
#   1. formatting (host workspace and firmware)
#   2. clippy -D warnings (host workspace, all targets; firmware when the rustup toolchain is used)
#   3. ogm-core as a library without default features and with defmt (no_std, no alloc)
#   4. the host workspace tests, including the firmware-in-QEMU integration tests
#      (OGM_REQUIRE_FIRMWARE=1: they fail instead of skipping if QEMU or the toolchain is missing)
#   5. the firmware's on-target self test in QEMU, the nRF52840-DK binary built and sized, and a
#      thumbv6m type-check
#   6. every fuzz target for a few seconds (scripts/fuzz.sh --ci: nightly + cargo-fuzz, installed
#      into ~/.cache/ogm/tools if missing; skipped with a message when there is no nightly)
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }
t0=$SECONDS

step "firmware toolchain and QEMU (installs what is missing)"
bash scripts/firmware-toolchain.sh

step "cargo fmt --check"
cargo fmt --all -- --check
rustfmt --edition 2021 --check firmware/build.rs firmware/src/main.rs firmware/src/lib.rs fuzz/fuzz_targets/*.rs

step "cargo clippy --workspace --all-targets -- -D warnings"
cargo clippy --workspace --all-targets -- -D warnings

step "ogm-core: no default features (no_std, no reference), and with defmt"
cargo build -p ogm-core --no-default-features
cargo build -p ogm-core --no-default-features --features defmt

step "docs: cargo doc with warnings denied (broken links), with and without ogm-core's default features"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps
RUSTDOCFLAGS="-D warnings" cargo doc -p ogm-core --no-deps --no-default-features

step "cargo test --workspace (with the firmware in QEMU)"
OGM_REQUIRE_FIRMWARE=1 cargo test --workspace

step "firmware: clippy (rustup toolchain only), nRF52840-DK build and sizes, thumbv6m check, the on-target run in QEMU"
bash scripts/firmware.sh clippy
FIRMWARE_BOARD=nrf52840 bash scripts/firmware.sh clippy
FIRMWARE_BOARD=nrf52840 bash scripts/firmware.sh size
bash scripts/firmware.sh check-v6m
bash scripts/firmware.sh run

step "fuzz targets, 5 s each (scripts/fuzz.sh --ci)"
bash scripts/fuzz.sh --ci

echo
echo "All tests passed in $((SECONDS - t0)) s."
