#!/usr/bin/env bash
# Build, run and measure the firmware (see docs/firmware.md).
#
#   scripts/firmware.sh build [CARGO_ARGS...]   release build; prints the ELF's path last
#   scripts/firmware.sh run [RUN_OPTS] [-- QEMU_ARGS...]
#                                              release build, boot it in QEMU mps2-an386,
#                                              decode the defmt log, show what UART1 received
#   scripts/firmware.sh qemu ELF [RUN_OPTS] [-- QEMU_ARGS...]
#                                              run an already built ELF (this is also the cargo
#                                              runner: `cd firmware && cargo run --release`)
#   scripts/firmware.sh size                   release build; section sizes, flash and RAM use
#   scripts/firmware.sh clippy                 clippy -D warnings on the firmware (rustup only)
#   scripts/firmware.sh check-v6m              the firmware type-checks for thumbv6m-none-eabi
#                                              (Cortex-M0/M0+: no compare-and-swap, no FPU)
#   scripts/firmware.sh env                    the toolchain settings in use
#
# FIRMWARE_BOARD=nrf52840 makes build/size/clippy work on the nRF52840-DK binary instead of the
# default mps2-an386 (QEMU) one, in its own target dir (firmware/target/nrf52840), so the QEMU
# ELF is never overwritten. `run`/`qemu` are mps2-an386 only.
# FIRMWARE_FEATURES=rplidar (comma-separated optional features) builds the image with them, in a
# target dir of its own (e.g. firmware/target/features-rplidar), for the same reason.
#
# RUN_OPTS:
#   --timeout SECS   kill QEMU after SECS (default $FIRMWARE_QEMU_TIMEOUT or 60); exit 124 then
#   --uart0 SPEC     QEMU -serial spec for UART0 (lidar in), default `null`
#   --uart1 SPEC     QEMU -serial spec for UART1 (host link), default
#                    file:firmware/target/qemu/uart1.out (the binary map stream; decode it
#                    with `host-sim firmware --decode FILE`)
#                    e.g. `chardev:u1` + `-- -chardev socket,id=u1,path=SOCK` for a binary link
#   --raw FILE       where to keep the raw defmt stream (default firmware/target/qemu/defmt.raw)
#   --no-icount      run at full speed (timer ticks are then host time, not instruction counts)
#
# The exit status of `run`/`qemu` is the firmware's semihosting exit code (0 = success, 101 =
# panic, 3 = HardFault, 4 = unhandled interrupt), or 124 on timeout.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
FW="$ROOT/firmware"
ENV_FILE="$FW/target/toolchain.env"
TARGET=thumbv7em-none-eabihf
BOARD="${FIRMWARE_BOARD:-mps2-an386}"
case "$BOARD" in
mps2-an386) TARGET_DIR="$FW/target" BOARD_ARGS=() ;;
nrf52840) TARGET_DIR="$FW/target/nrf52840" BOARD_ARGS=(--no-default-features --features nrf52840) ;;
*) printf '[firmware] ERROR: unknown FIRMWARE_BOARD %s (mps2-an386 or nrf52840)\n' "$BOARD" >&2; exit 1 ;;
esac
if [ -n "${FIRMWARE_FEATURES:-}" ]; then
    case "$FIRMWARE_FEATURES" in
    *[!a-z0-9,-]*) printf '[firmware] ERROR: bad FIRMWARE_FEATURES %s\n' "$FIRMWARE_FEATURES" >&2; exit 1 ;;
    esac
    TARGET_DIR="$TARGET_DIR/features-${FIRMWARE_FEATURES//,/-}"
    BOARD_ARGS+=(--features "$FIRMWARE_FEATURES")
fi
ELF="$TARGET_DIR/$TARGET/release/ogm-firmware"

say() { printf '[firmware] %s\n' "$*" >&2; }
die() { say "ERROR: $*"; exit 1; }

load_env() {
    [ -f "$ENV_FILE" ] || bash "$ROOT/scripts/firmware-toolchain.sh" >&2
    local key value
    while IFS='=' read -r key value; do
        case "$key" in FW_*) printf -v "$key" '%s' "$value" ;; esac
    done <"$ENV_FILE"
    : "${FW_TOOLCHAIN:?corrupt $ENV_FILE: rerun scripts/firmware-toolchain.sh}"
}

# cargo in firmware/ with the chosen toolchain, shielded from the caller's host-build settings
# (a host `cargo test` that calls this script, coverage RUSTFLAGS, a global CARGO_TARGET_DIR...).
fw_cargo() {
    local envs=(CARGO_TARGET_DIR="$TARGET_DIR" RUSTC="$FW_RUSTC")
    [ -z "$FW_RUSTC_BOOTSTRAP" ] || envs+=(RUSTC_BOOTSTRAP="$FW_RUSTC_BOOTSTRAP")
    [ -z "$FW_PATH_PREFIX" ] || envs+=(PATH="$FW_PATH_PREFIX:$PATH")
    # The stack guard (scripts/firmware-toolchain.sh): flip-link wraps ld.lld.
    if [ -n "${FW_FLIP_LINK:-}" ] && [ -x "$FW_FLIP_LINK" ]; then
        envs+=(CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER="$FW_FLIP_LINK" FLIP_LINK_LINKER="$FW_LLD")
    else
        say "WARNING: no flip-link (rerun scripts/firmware-toolchain.sh): linking without the stack guard"
    fi
    local zargs=()
    [ -z "$FW_CARGO_ARGS" ] || read -r -a zargs <<<"$FW_CARGO_ARGS"
    local sub="$1"
    shift
    (cd "$FW" && env -u RUSTFLAGS -u CARGO_ENCODED_RUSTFLAGS -u CARGO_BUILD_RUSTFLAGS \
        -u CARGO_BUILD_TARGET -u RUSTC_WRAPPER -u RUSTC_WORKSPACE_WRAPPER -u RUSTC_BOOTSTRAP \
        "${envs[@]}" "$FW_CARGO" "$sub" "${zargs[@]}" "$@")
}

build() {
    load_env
    say "building $BOARD (toolchain: $FW_TOOLCHAIN, rustc $FW_RUSTC_VERSION${FW_CARGO_ARGS:+, $FW_CARGO_ARGS})"
    fw_cargo build --release "${BOARD_ARGS[@]}" "$@"
    [ -f "$ELF" ] || die "no ELF at $ELF"
    echo "$ELF"
}

# QEMU's stderr minus the one warning mps2-an386 always prints (its on-board LAN9118 has no
# network backend; -net none does not silence it).
quiet_qemu() { grep -v --line-buffered 'nic lan9118.0 has no peer' >&2 || true; }

run_qemu() {
    local elf="$1"
    shift
    [ -f "$elf" ] || die "no such ELF: $elf"
    load_env
    local out="$FW/target/qemu"
    mkdir -p "$out"
    local timeout_s="${FIRMWARE_QEMU_TIMEOUT:-60}" uart0=null uart1="" raw="$out/defmt.raw"
    local icount=(-icount shift=0,sleep=off) extra=()
    while [ $# -gt 0 ]; do
        case "$1" in
        --timeout) timeout_s="$2"; shift 2 ;;
        --uart0) uart0="$2"; shift 2 ;;
        --uart1) uart1="$2"; shift 2 ;;
        --raw) raw="$2"; shift 2 ;;
        --no-icount) icount=(); shift ;;
        --) shift; extra=("$@"); break ;;
        *) die "unknown run option: $1" ;;
        esac
    done
    # FIRMWARE_QEMU_EXTRA: more QEMU arguments, e.g. "-d in_asm,exec,nochain -D FILE" to count
    # instructions per function and source line (scripts/qemu-profile.py).
    if [ -n "${FIRMWARE_QEMU_EXTRA:-}" ]; then
        local more=()
        read -r -a more <<<"$FIRMWARE_QEMU_EXTRA"
        extra+=("${more[@]}")
    fi
    local uart1_file=""
    if [ -z "$uart1" ]; then
        uart1_file="$out/uart1.out"
        : >"$uart1_file"
        uart1="file:$uart1_file"
    fi
    # -nodefaults -net none: no default devices (and no "nic has no peer" warning);
    # -display none -monitor none: nothing multiplexed onto stdio, so the semihosting stream
    # (QEMU's stdout) is pure defmt binary. Never use -nographic/-serial stdio for binary links.
    local cmd=("$FW_QEMU" -machine mps2-an386 -cpu cortex-m4 -nodefaults -net none
        -display none -monitor none "${icount[@]}"
        -semihosting-config enable=on,target=native
        -serial "$uart0" -serial "$uart1" "${extra[@]}" -kernel "$elf")
    say "qemu (timeout ${timeout_s}s): ${cmd[*]}"
    local rc dec=0
    set +e
    if [ -n "$FW_DEFMT_PRINT" ] && [ -x "$FW_DEFMT_PRINT" ]; then
        timeout -k 5 "$timeout_s" "${cmd[@]}" 2> >(quiet_qemu) | tee "$raw" | "$FW_DEFMT_PRINT" -e "$elf"
        local st=("${PIPESTATUS[@]}")
        rc=${st[0]} dec=${st[2]}
    else
        say "no defmt-print: raw defmt frames only (decode: defmt-print -e $elf < $raw)"
        timeout -k 5 "$timeout_s" "${cmd[@]}" 2> >(quiet_qemu) >"$raw"
        rc=$?
    fi
    set -e
    if [ -n "$uart1_file" ]; then
        # The map stream is binary (COBS frames, docs/wire.md): decode it, do not print it.
        say "UART1 received $(wc -c <"$uart1_file") bytes of map stream (${uart1_file#"$ROOT"/});"
        say "decode: cargo run -p host-sim --release -- firmware --decode ${uart1_file#"$ROOT"/}"
    fi
    case "$rc" in
    0) ;;
    124 | 137) say "TIMEOUT: QEMU killed after ${timeout_s}s (firmware hung or never exited)" ;;
    *) say "firmware exited with status $rc" ;;
    esac
    if [ "$rc" = 0 ] && [ "$dec" != 0 ]; then
        say "defmt-print failed (status $dec)"
        rc=1
    fi
    return "$rc"
}

size_report() {
    build >/dev/null
    [ -n "$FW_SIZE" ] || die "no llvm-size/size found"
    "$FW_SIZE" -A "$ELF" | grep -E '^(section|\.vector_table|\.text|\.rodata|\.data|\.bss|\.uninit|\.gnu\.sgstubs)\b' >&2
    # Flash = what is loaded at 0x0 (vector table, code, constants, .data's initial values);
    # static RAM = .data + .bss + .uninit (the rest of RAM is stack; see docs/firmware.md).
    "$FW_SIZE" -A "$ELF" | awk -v elf="${ELF#"$ROOT"/}" '
        $1 ~ /^\.(vector_table|text|rodata|gnu\.sgstubs)$/ { flash += $2 }
        $1 == ".data" { flash += $2; ram += $2 }
        $1 ~ /^\.(bss|uninit)$/ { ram += $2 }
        END {
            printf "%s\nflash: %d bytes (%.1f KiB, %.2f%% of 1024 KiB)\n", elf, flash, flash/1024, 100*flash/1048576
            printf "static RAM: %d bytes (%.1f KiB, %.2f%% of 256 KiB; stack gets the rest: %d bytes)\n", ram, ram/1024, 100*ram/262144, 262144 - ram
            # The budgets: each image within 256 KiB of the 1 MiB of flash, and at least
            # 16 KiB of the 256 KiB RAM left for the stack (the mapping loop peaks near 6 KiB,
            # building the engine near 9 KiB; flip-link makes an overflow fault).
            if (flash > 262144) { printf "ERROR: flash %d bytes is over the 256 KiB budget\n", flash; exit 1 }
            if (262144 - ram < 16384) { printf "ERROR: only %d bytes left for the stack\n", 262144 - ram; exit 1 }
        }'
}

cmd="${1:-}"
[ $# -eq 0 ] || shift
case "$cmd" in
build) build "$@" ;;
run)
    build >/dev/null
    run_qemu "$ELF" "$@"
    ;;
qemu)
    [ $# -ge 1 ] || die "usage: $0 qemu ELF [RUN_OPTS] [-- QEMU_ARGS]"
    run_qemu "$@"
    ;;
size) size_report ;;
clippy)
    load_env
    if [ "$FW_TOOLCHAIN" != rustup ]; then
        say "clippy skipped: Debian's cargo-web has no clippy (toolchain: $FW_TOOLCHAIN)"
        exit 0
    fi
    fw_cargo clippy --release "${BOARD_ARGS[@]}" -- -D warnings
    ;;
check-v6m)
    load_env
    if [ "$FW_TOOLCHAIN" = rustup ]; then
        if ! rustup target list --installed | grep -qx thumbv6m-none-eabi &&
            ! rustup target add thumbv6m-none-eabi >&2; then
            say "SKIPPED: thumbv6m check (rustup target add thumbv6m-none-eabi failed)"
            exit 0
        fi
    fi
    # On the debian path FW_CARGO_ARGS builds `core` for the target from source.
    fw_cargo check --release --target thumbv6m-none-eabi --bin ogm-firmware
    ;;
env)
    load_env
    cat "$ENV_FILE"
    ;;
*)
    sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
    exit 2
    ;;
esac
