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
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
LOG="$OUT/runs.txt"
for _ in $(seq "$ROUNDS"); do
  for bin in "$A" "$B"; do
    rm -rf "$OUT/out"
    sync
    /usr/bin/time -f "%e %U %S %M" -o "$OUT/t.txt" "$bin" convert "$INPUT" -o "$OUT/out" -q "$@"
    read -r wall user sys kib < "$OUT/t.txt"
    which=$([ "$bin" = "$A" ] && echo old || echo new)
    printf '%s  wall %6.2f s  user %6.2f s  sys %6.2f s  peak %6.0f MiB\n' \
      "$which" "$wall" "$user" "$sys" "$((kib / 1024))" | tee -a "$LOG"
  done
done
median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
old=$(awk '$1 == "old" { print $3 }' "$LOG" | median)
new=$(awk '$1 == "new" { print $3 }' "$LOG" | median)
awk -v o="$old" -v n="$new" 'BEGIN { printf "median wall: old %.2f s, new %.2f s, new/old %.2f\n", o, n, n / o }'
