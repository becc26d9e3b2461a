#!/usr/bin/env bash
# Issue 37's robustness table: eval-log on the shared logs with seeded added range noise and
# outliers, benchmark from the unperturbed log, the robot's mode against traditional.
#
#   bash scripts/robustness.sh [OUT]        (default out/robustness)
#
# Environment: SIGMAS (added σ, cells; default "1 1.5 2 3"), OUTLIERS (default "0 0.3 0.6"),
# SEEDS (default "1 2 3"), LOGS (default ../shared/data/logs), METHODS (default
# gibbs_l9_border), EXTRA (more eval-log options), HOST_SIM (default target/release/host-sim).
# Runs one eval-log at a time (≈7-10 s each on the five logs; ≈5 min in all on an idle
# 2-core machine). Writes OUT/<condition>/summary.json per run (a run whose summary.json is
# there already is kept: an interrupted table resumes), then OUT/table.md
# (scripts/robustness-table.py). The runs' pictures (≈25 MB a run) are deleted unless
# KEEP_IMAGES=1.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/robustness}
SIGMAS=${SIGMAS:-"1 1.5 2 3"}
OUTLIERS=${OUTLIERS:-"0 0.3 0.6"}
SEEDS=${SEEDS:-"1 2 3"}
LOGS=${LOGS:-../shared/data/logs}
METHODS=${METHODS:-gibbs_l9_border}
HOST_SIM=${HOST_SIM:-target/release/host-sim}
EXTRA=${EXTRA:-}
if [ ! -d "$LOGS" ]; then
  echo "robustness: $LOGS not found (the shared logs are needed); skipped" >&2
  exit 0
fi
[ -x "$HOST_SIM" ] || CARGO_BUILD_JOBS=${CARGO_BUILD_JOBS:-1} cargo build --release -p host-sim
mkdir -p "$OUT"
run() { # name, options...
  local name=$1; shift
  local dir="$OUT/$name"
  local cmd="$HOST_SIM eval-log --log $LOGS --methods $METHODS --out $dir $EXTRA $*"
  if [ -f "$dir/summary.json" ]; then
    echo "kept $name"
    return
  fi
  mkdir -p "$dir"
  echo "$cmd" > "$dir/command.txt"
  # shellcheck disable=SC2086
  if ! $cmd > "$dir/stdout.txt" 2> "$dir/stderr.txt"; then
    echo "robustness: $name failed (see $dir/stderr.txt)" >&2
    exit 1
  fi
  [ "${KEEP_IMAGES:-0}" = 1 ] || find "$dir" -name '*.png' -delete
  echo "done $name"
}
start=$(date +%s)
run base
for s in $SIGMAS; do
  for p in $OUTLIERS; do
    for seed in $SEEDS; do
      run "s${s}_p${p}_seed${seed}" --add-noise-cells "$s" --add-outliers "$p" --perturb-seed "$seed"
    done
  done
done
echo "robustness: $(( $(date +%s) - start )) s" | tee "$OUT/runtime.txt"
python3 scripts/robustness-table.py "$OUT" | tee "$OUT/table.md"
