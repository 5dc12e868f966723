#!/usr/bin/env bash
# Several input files against one: the same points converted from one text file
# and from K pieces of it (split at line boundaries, as a survey delivered in
# pieces), runs interleaved. Prints every run (wall, user, system seconds, peak
# MiB) and the median wall time of each, and the ratio pieces / one.
#
#   bash bench/multi.sh ROUNDS K INPUT.xyz [convert options...]
#   e.g. bash bench/multi.sh 3 8 /tmp/pcimg-bench/scan-47756566.xyz --memory 256MiB
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,9p "$0"
  exit 2
fi
ROUNDS=$1 K=$2 INPUT=$3
shift 3
cd "$(dirname "$0")/.."
cargo build --release -q
BIN=$PWD/target/release/pcimg
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
mkdir "$OUT/pieces"
(cd "$OUT/pieces" && split -n "l/$K" -d --additional-suffix=.xyz "$INPUT" piece)
LOG="$OUT/runs.txt"
for _ in $(seq "$ROUNDS"); do
  for which in one pieces; do
    rm -rf "$OUT/out"
    sync
    if [ "$which" = one ]; then in=$INPUT; else in=$OUT/pieces; fi
    /usr/bin/time -f "%e %U %S %M" -o "$OUT/t.txt" "$BIN" convert "$in" -o "$OUT/out" -q "$@"
    read -r wall user sys kib < "$OUT/t.txt"
    printf '%-6s  wall %6.2f s  user %6.2f s  sys %6.2f s  peak %6.0f MiB\n' \
      "$which" "$wall" "$user" "$sys" "$((kib / 1024))" | tee -a "$LOG"
  done
done
median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
one=$(awk '$1 == "one" { print $3 }' "$LOG" | median)
pieces=$(awk '$1 == "pieces" { print $3 }' "$LOG" | median)
awk -v o="$one" -v p="$pieces" -v k="$K" 'BEGIN { printf "median wall: one file %.2f s, %d pieces %.2f s, pieces/one %.2f\n", o, k, p, p / o }'
