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
ROUNDS=$1 K=$2 INPUT=$(realpath "$3")
shift 3
cd "$(dirname "$0")/.."
source bench/lib.sh
cargo build --release -q
BIN=$PWD/target/release/pcimg
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
mkdir "$OUT/pieces"
(cd "$OUT/pieces" && split -n "l/$K" -d --additional-suffix=.xyz "$INPUT" piece)
LOG="$OUT/runs.txt"
for _ in $(seq "$ROUNDS"); do
  run_convert one "$LOG" "$OUT" "$BIN" "$INPUT" "$@"
  run_convert pieces "$LOG" "$OUT" "$BIN" "$OUT/pieces" "$@"
done
one=$(median_wall one "$LOG")
pieces=$(median_wall pieces "$LOG")
awk -v o="$one" -v p="$pieces" -v k="$K" 'BEGIN { printf "median wall: one file %.2f s, %d pieces %.2f s, pieces/one %.2f\n", o, k, p, p / o }'
