#!/usr/bin/env bash
# Makes sure the tools to build and run the firmware (thumbv7em-none-eabihf, QEMU mps2-an386)
# exist, picks a Rust toolchain for it, and records the choice in firmware/target/toolchain.env
# (KEY=VALUE lines, no quoting, no spaces in values: `source` it from bash, or parse it from Rust).
# Idempotent; a second run with everything present takes well under a second.
#
# Toolchain choice (first that works):
#   rustup  (a) the active rustup toolchain already has the thumbv7em-none-eabihf target, or
#           (b) `rustup target add thumbv7em-none-eabihf` succeeds (normal online machines);
#   debian  (c) Debian's rustc-web/cargo-web 1.9x + rust-web-src from apt, building `core` for the
#           target itself: /usr/bin/cargo with RUSTC=/usr/bin/rustc RUSTC_BOOTSTRAP=1 and
#           `-Zbuild-std=core` (passed on the command line by scripts/firmware.sh, never in
#           firmware/.cargo/config.toml, which would break (a)/(b)).
# Always: qemu-system-arm and ld.lld (apt), defmt-print (cargo install, into
# firmware/target/tools) to decode the firmware's defmt log, and flip-link (same place), the
# stack guard every firmware image is linked with.
#
# Environment:
#   FIRMWARE_TOOLCHAIN=rustup|debian   force a path (debian is what a machine without the rustup
#                                      target uses; handy to test it where rustup works)
#   FIRMWARE_SKIP_DEFMT_PRINT=1        do not install defmt-print (runs then print raw frames)
#   FIRMWARE_RUSTUP_TIMEOUT=SECONDS    limit for `rustup target add` (default 120)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
FW="$ROOT/firmware"
TARGET=thumbv7em-none-eabihf
ENV_FILE="$FW/target/toolchain.env"
TOOLS="$FW/target/tools"
FLIP_LINK_VERSION=0.1.12
DEFMT_PRINT_VERSION=1.2.0 # defmt-print 1.x decodes defmt 1.x (wire format "4"); keep majors equal

say() { printf '[firmware-toolchain] %s\n' "$*"; }
die() { say "ERROR: $*" >&2; exit 1; }

SUDO=()
if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO=(sudo -n); else SUDO=(false); fi
fi

APT_UPDATED=0
apt_install() {
    # Installs the given Debian packages (only the missing ones; `apt-get update` only if needed).
    local missing=() p
    for p in "$@"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q '^install ok installed$' ||
            missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    command -v apt-get >/dev/null 2>&1 || die "need ${missing[*]} but apt-get is not available"
    say "apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    if [ "$APT_UPDATED" = 0 ]; then
        # Try without an update first (fast when the lists are fresh); update if that fails.
        if "${SUDO[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null 2>&1; then
            return 0
        fi
        "${SUDO[@]}" apt-get update -q >/dev/null
        APT_UPDATED=1
    fi
    "${SUDO[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
}

# --- QEMU and the linker: needed by every path --------------------------------------------------
need_tools=()
command -v qemu-system-arm >/dev/null 2>&1 || need_tools+=(qemu-system-arm)
command -v ld.lld >/dev/null 2>&1 || need_tools+=(lld)
[ ${#need_tools[@]} -eq 0 ] || apt_install "${need_tools[@]}"
QEMU="$(command -v qemu-system-arm)" || die "qemu-system-arm missing after install"
LLD="$(command -v ld.lld)" || die "ld.lld missing after install"

# --- Rust toolchain -----------------------------------------------------------------------------
rustup_has_target() {
    command -v rustup >/dev/null 2>&1 &&
        (cd "$FW" && rustup target list --installed 2>/dev/null) | grep -qx "$TARGET"
}

choice="${FIRMWARE_TOOLCHAIN:-}"
how=""
if [ -z "$choice" ] || [ "$choice" = rustup ]; then
    if rustup_has_target; then
        choice=rustup how="rustup toolchain with the $TARGET target already installed"
    elif [ -z "$choice" ] && [ -f "$ENV_FILE" ] && grep -qx 'FW_TOOLCHAIN=debian' "$ENV_FILE" &&
        [ -x /usr/bin/cargo ] && [ -d /usr/lib/rustlib/src/rust/library ]; then
        # An earlier run found that rustup cannot add the target here: don't wait for it again.
        choice=debian how="Debian rustc + build-std (cached: rustup target add failed before)"
    elif command -v rustup >/dev/null 2>&1 &&
        (cd "$FW" && timeout "${FIRMWARE_RUSTUP_TIMEOUT:-120}" rustup target add "$TARGET") >/dev/null 2>&1 &&
        rustup_has_target; then
        choice=rustup how="rustup toolchain, target added with 'rustup target add $TARGET'"
    elif [ "$choice" = rustup ]; then
        die "FIRMWARE_TOOLCHAIN=rustup but the rustup toolchain has no $TARGET target"
    else
        say "rustup cannot provide $TARGET here; using Debian's rustc with -Zbuild-std=core"
        choice=debian
    fi
fi
case "$choice" in
rustup)
    CARGO_BIN="$(cd "$FW" && command -v cargo)"
    RUSTC_BIN="$(cd "$FW" && command -v rustc)"
    RUSTC_BOOTSTRAP_VAL=""
    CARGO_ARGS=""
    PATH_PREFIX=""
    ;;
debian)
    [ -n "$how" ] || how="Debian rustc-web + rust-web-src, core built with -Zbuild-std=core"
    apt_install rustc-web cargo-web rust-web-src
    CARGO_BIN=/usr/bin/cargo
    RUSTC_BIN=/usr/bin/rustc
    RUSTC_BOOTSTRAP_VAL=1
    CARGO_ARGS="-Zbuild-std=core"
    PATH_PREFIX=/usr/bin
    [ -x "$CARGO_BIN" ] && [ -x "$RUSTC_BIN" ] || die "Debian cargo/rustc missing after install"
    [ -d "$("$RUSTC_BIN" --print sysroot)/lib/rustlib/src/rust/library" ] ||
        die "rust-web-src is not where $RUSTC_BIN looks for the standard library's source"
    ;;
*) die "FIRMWARE_TOOLCHAIN must be rustup or debian (got '$choice')" ;;
esac
RUSTC_VERSION="$(RUSTC_BOOTSTRAP="$RUSTC_BOOTSTRAP_VAL" "$RUSTC_BIN" --version | awk '{print $2}')"

# --- size tool: llvm-size if present, else binutils' size (reads any ELF with -A) ----------------
SIZE_BIN="$(command -v llvm-size || command -v size || true)"

# --- defmt-print --------------------------------------------------------------------------------
DEFMT_PRINT="$TOOLS/bin/defmt-print"
if [ -x "$DEFMT_PRINT" ] && "$DEFMT_PRINT" --version 2>/dev/null | grep -q " $DEFMT_PRINT_VERSION"; then
    :
elif [ "${FIRMWARE_SKIP_DEFMT_PRINT:-0}" = 1 ]; then
    DEFMT_PRINT=""
else
    # A host build: any cargo works; prefer the rustup one (its registry cache is warm).
    host_cargo="$(command -v cargo || echo /usr/bin/cargo)"
    say "installing defmt-print $DEFMT_PRINT_VERSION into ${TOOLS#"$ROOT"/} (one-off, ~2-3 min on 2 cores)"
    mkdir -p "$TOOLS"
    start=$SECONDS
    if env -u RUSTFLAGS -u CARGO_ENCODED_RUSTFLAGS -u CARGO_BUILD_TARGET -u CARGO_TARGET_DIR \
        "$host_cargo" install --locked --quiet "defmt-print@$DEFMT_PRINT_VERSION" --root "$TOOLS" \
        >"$TOOLS/defmt-print-install.log" 2>&1; then
        say "defmt-print installed in $((SECONDS - start)) s"
    else
        say "WARNING: cargo install defmt-print failed (log: ${TOOLS#"$ROOT"/}/defmt-print-install.log);"
        say "         runs will keep the raw defmt frames instead of decoding them"
        DEFMT_PRINT=""
    fi
fi

# --- flip-link ------------------------------------------------------------------------------------
# The stack guard of every board: flip-link relinks the image with the stack at the bottom of RAM,
# below .data/.bss, so an overflow faults (hitting the end of RAM) instead of silently
# overwriting the map. It wraps the real linker (FLIP_LINK_LINKER = ld.lld).
FLIP_LINK="$TOOLS/bin/flip-link"
if [ -x "$FLIP_LINK" ] && "$FLIP_LINK" --version 2>/dev/null | grep -q " $FLIP_LINK_VERSION"; then
    :
else
    host_cargo="$(command -v cargo || echo /usr/bin/cargo)"
    say "installing flip-link $FLIP_LINK_VERSION into ${TOOLS#"$ROOT"/} (one-off, < 1 min)"
    mkdir -p "$TOOLS"
    start=$SECONDS
    env -u RUSTFLAGS -u CARGO_ENCODED_RUSTFLAGS -u CARGO_BUILD_TARGET -u CARGO_TARGET_DIR \
        "$host_cargo" install --locked --quiet "flip-link@$FLIP_LINK_VERSION" --root "$TOOLS" \
        >"$TOOLS/flip-link-install.log" 2>&1 ||
        die "cargo install flip-link failed (log: ${TOOLS#"$ROOT"/}/flip-link-install.log)"
    say "flip-link installed in $((SECONDS - start)) s"
fi

# --- record the choice --------------------------------------------------------------------------
mkdir -p "$FW/target"
tmp="$ENV_FILE.tmp.$$"
cat >"$tmp" <<EOF
# Written by scripts/firmware-toolchain.sh; read by scripts/firmware.sh and host tests.
# KEY=VALUE, no quoting; an empty value means "not used".
FW_TOOLCHAIN=$choice
FW_TARGET=$TARGET
FW_CARGO=$CARGO_BIN
FW_RUSTC=$RUSTC_BIN
FW_RUSTC_VERSION=$RUSTC_VERSION
FW_RUSTC_BOOTSTRAP=$RUSTC_BOOTSTRAP_VAL
FW_CARGO_ARGS=$CARGO_ARGS
FW_PATH_PREFIX=$PATH_PREFIX
FW_QEMU=$QEMU
FW_LLD=$LLD
FW_SIZE=$SIZE_BIN
FW_DEFMT_PRINT=$DEFMT_PRINT
FW_FLIP_LINK=$FLIP_LINK
EOF
mv "$tmp" "$ENV_FILE"
say "toolchain: $choice (rustc $RUSTC_VERSION) — $how"
say "qemu: $("$QEMU" --version | head -1)"
say "defmt-print: ${DEFMT_PRINT:-none (raw frames)}; settings in ${ENV_FILE#"$ROOT"/}"
