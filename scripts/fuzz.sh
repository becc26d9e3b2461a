#!/usr/bin/env bash
# Runs the fuzz targets in fuzz/ (cargo-fuzz + libFuzzer, nightly, AddressSanitizer), each for a
# bounded time, and fails if any of them finds a crash, a panic, a leak, an out-of-memory or a
# hang (> 20 s for one input).
#
#   bash scripts/fuzz.sh                       every target for $FUZZ_SECONDS (default 600) s
#   bash scripts/fuzz.sh --ci                  every target for 5 s (scripts/test-all.sh runs this)
#   bash scripts/fuzz.sh --time S [TARGET...]  the given targets (default: all) for S s each
#   bash scripts/fuzz.sh --jobs 2 ...          two targets at a time (one core each)
#   bash scripts/fuzz.sh --list                the targets
#
# Targets: ld06 (LD06 parser and reader), rplidar (RPLIDAR A1/A2 parser and reader), wire_frame (postcard/COBS frame decoders, robot
# demultiplexer, host stream decoder), pose_frames (host frames incl. poses and settings → link →
# insert_and_seed → sampler), carmen (CARMEN log reader), map_loader (PNG/PGM/map YAML decoding).
#
# Corpus: fuzz/corpus/TARGET holds the committed seeds and is only read; what libFuzzer finds goes
# to fuzz/target/corpus/TARGET (kept between runs, not committed). Crash inputs land in
# fuzz/artifacts/TARGET/ (reproduce: `cd fuzz && cargo +nightly fuzz run TARGET FILE`). Logs with
# libFuzzer's final statistics: fuzz/target/logs/TARGET.log; the summary line per target gives
# the executions.
#
# Needs a nightly toolchain (`cargo +nightly`; `rustup toolchain install nightly` if it is
# missing) and cargo-fuzz: taken from PATH, else from $OGM_TOOLS_DIR/bin (default
# ~/.cache/ogm/tools), installed there with `cargo install --locked cargo-fuzz` (~3 min, once per
# machine) if missing. Without nightly the script prints SKIPPED and exits 0, unless
# FUZZ_REQUIRE=1.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
FUZZ="$ROOT/fuzz"
ALL=(ld06 rplidar wire_frame pose_frames carmen map_loader matcher)
CARGO_FUZZ_VERSION=0.13.2

say() { printf '[fuzz] %s\n' "$*" >&2; }
die() { say "ERROR: $*"; exit 1; }

seconds="${FUZZ_SECONDS:-600}"
jobs=1
targets=()
while [ $# -gt 0 ]; do
    case "$1" in
    --ci) seconds=5; shift ;;
    --time) seconds="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --list) printf '%s\n' "${ALL[@]}"; exit 0 ;;
    -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    -*) die "unknown option $1" ;;
    *) targets+=("$1"); shift ;;
    esac
done
[ ${#targets[@]} -gt 0 ] || targets=("${ALL[@]}")
for t in "${targets[@]}"; do
    [ -f "$FUZZ/fuzz_targets/$t.rs" ] || die "no fuzz target '$t' (have: ${ALL[*]})"
done

if ! cargo +nightly --version >/dev/null 2>&1; then
    msg="no nightly toolchain (cargo +nightly); install it with 'rustup toolchain install nightly'"
    [ "${FUZZ_REQUIRE:-0}" = 1 ] && die "$msg"
    say "SKIPPED: $msg"
    exit 0
fi

TOOLS="${OGM_TOOLS_DIR:-$HOME/.cache/ogm/tools}"
export PATH="$TOOLS/bin:$PATH"
if ! cargo fuzz --version >/dev/null 2>&1; then
    say "installing cargo-fuzz $CARGO_FUZZ_VERSION into $TOOLS (once per machine, ~3 min)"
    mkdir -p "$TOOLS"
    env -u RUSTFLAGS -u CARGO_ENCODED_RUSTFLAGS -u CARGO_BUILD_TARGET -u CARGO_TARGET_DIR \
        cargo install --locked --quiet "cargo-fuzz@$CARGO_FUZZ_VERSION" --root "$TOOLS" ||
        die "cargo install cargo-fuzz failed"
fi

cd "$FUZZ"
# The host workspace's settings must not leak into the sanitizer build.
unset RUSTFLAGS CARGO_ENCODED_RUSTFLAGS CARGO_BUILD_RUSTFLAGS CARGO_BUILD_TARGET CARGO_TARGET_DIR \
    RUSTC_WRAPPER RUSTC_WORKSPACE_WRAPPER
say "building ${targets[*]} (cargo +nightly fuzz build, release + debug assertions + ASan)"
start=$SECONDS
for t in "${targets[@]}"; do
    cargo +nightly fuzz build "$t" 2>&1 | grep -vE '^\s+(Compiling|Finished|Blocking)' >&2 || true
    [ -x "target/x86_64-unknown-linux-gnu/release/$t" ] || die "building $t failed"
done
say "built in $((SECONDS - start)) s; running each for $seconds s ($jobs at a time)"
mkdir -p target/logs

run_one() {
    local t="$1" log="target/logs/$1.log"
    mkdir -p "target/corpus/$t" "artifacts/$t"
    local rc=0
    cargo +nightly fuzz run "$t" "target/corpus/$t" "corpus/$t" -- \
        -max_total_time="$seconds" -print_final_stats=1 -max_len=4096 -timeout=20 \
        -rss_limit_mb=2048 >"$log" 2>&1 || rc=$?
    local execs
    execs="$(grep -aoE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$' | tail -1)"
    if [ "$rc" = 0 ]; then
        printf '[fuzz] %-12s %s executions in %s s, 0 crashes (corpus %s files; log fuzz/%s)\n' \
            "$t" "${execs:-?}" "$seconds" "$(find "target/corpus/$t" -type f | wc -l)" "$log" >&2
    else
        printf '[fuzz] %-12s FAILED (status %s) after %s executions; log fuzz/%s:\n' \
            "$t" "$rc" "${execs:-?}" "$log" >&2
        grep -aE 'panicked|ERROR: |SUMMARY|Test unit written|artifact_prefix' "$log" | head -8 >&2 || true
        return 1
    fi
}

failed=0
if [ "$jobs" -le 1 ]; then
    for t in "${targets[@]}"; do run_one "$t" || failed=1; done
else
    pids=()
    for t in "${targets[@]}"; do
        run_one "$t" &
        pids+=($!)
        if [ ${#pids[@]} -ge "$jobs" ]; then
            wait "${pids[0]}" || failed=1
            pids=("${pids[@]:1}")
        fi
    done
    for p in "${pids[@]}"; do wait "$p" || failed=1; done
fi
[ "$failed" = 0 ] || die "a fuzz target failed (inputs in fuzz/artifacts/)"
say "all ${#targets[@]} targets ran $seconds s each without a crash"
