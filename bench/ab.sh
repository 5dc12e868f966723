#!/usr/bin/env bash
# Interleaved A/B of two pcimg binaries on one conversion: on the shared VM the
# same binary's time drifts by 50% within an hour (see bench/RESULTS.md), so only
# runs taken alternately, A then B, at the same time compare.
#
#   bash bench/ab.sh ROUNDS OLD_BINARY NEW_BINARY INPUT [convert options...]
#   e.g. git worktree add /tmp/old e6d669e && (cd /tmp/old && cargo build --release)
#        bash bench/ab.sh 4 /tmp/old/target/release/pcimg target/release/pcimg \
#          /tmp/pcimg-bench/scan-47756566.las
#
# Prints every run (wall, user, system seconds, peak MiB), then each binary's
# median wall time and the ratio NEW / OLD.
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n 2,12p "$0"
  exit 2
fi
ROUNDS=$1 A=$2 B=$3 INPUT=$4
shift 4
source "$(dirname "$0")/lib.sh"
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
LOG="$OUT/runs.txt"
for _ in $(seq "$ROUNDS"); do
  run_convert old "$LOG" "$OUT" "$A" "$INPUT" "$@"
  run_convert new "$LOG" "$OUT" "$B" "$INPUT" "$@"
done
old=$(median_wall old "$LOG")
new=$(median_wall new "$LOG")
awk -v o="$old" -v n="$new" 'BEGIN { printf "median wall: old %.2f s, new %.2f s, new/old %.2f\n", o, n, n / o }'
