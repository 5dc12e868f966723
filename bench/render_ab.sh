#!/usr/bin/env bash
# Interleaved A/B of `pcimg render` runs: each round runs every labelled
# command once, in turn, so drift on the shared VM hits all of them alike.
# Reports, per label, the median and range of the frame's render time (the
# rasterizer, as `render` prints it), of its load time, of its colour time
# (colouring and filtering the loaded points; binaries before issue 29 print
# none: "-"), and the tiles and points loaded.
#
#   bash bench/render_ab.sh ROUNDS DATASET 'LABEL=BINARY [render options...]' ...
#   e.g. bash bench/render_ab.sh 7 /tmp/big.tif \
#          'old=/tmp/pcimg-before --renderer cpu' \
#          'new=target/release/pcimg --renderer cpu' \
#          'classes=target/release/pcimg --renderer cpu --exclude-classes 6'
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,12p "$0"
  exit 2
fi
ROUNDS=$1 DATASET=$2
shift 2
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
LOG="$OUT/runs.txt"
for _ in $(seq "$ROUNDS"); do
  for spec in "$@"; do
    label=${spec%%=*}
    read -r -a cmd <<< "${spec#*=}"
    line=$("${cmd[0]}" render "$DATASET" -o "$OUT/f.png" "${cmd[@]:1}" 2>&1 | grep ' points from ')
    render=$(sed -E 's/.*render ([0-9.]+) ms.*/\1/' <<< "$line")
    load=$(sed -E 's/.*load ([0-9.]+) ms.*/\1/' <<< "$line")
    colour=$(grep -q 'colour ' <<< "$line" && sed -E 's/.*colour ([0-9.]+) ms.*/\1/' <<< "$line" || echo -)
    tiles=$(sed -E 's/.* points from ([0-9]+) tiles.*/\1/' <<< "$line")
    points=$(sed -E 's/^([0-9,]+) points.*/\1/' <<< "$line")
    echo "$label $render $load $tiles $points $colour" | tee -a "$LOG"
  done
done
stats() { # LABEL COLUMN: median min max
  awk -v l="$1" -v c="$2" '$1 == l && $c != "-" { print $c }' "$LOG" | sort -g |
    awk '{ v[NR] = $1 } END { if (NR == 0) { printf "-"; exit } m = (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2; printf "%g (%g-%g)", m, v[1], v[NR] }'
}
echo "label: render ms median (range) | load ms median (range) | colour ms median (range) | tiles | points"
for spec in "$@"; do
  label=${spec%%=*}
  tp=$(awk -v l="$label" '$1 == l { t = $4; p = $5 } END { print t, p }' "$LOG")
  echo "$label: $(stats "$label" 2) | $(stats "$label" 3) | $(stats "$label" 6) | ${tp% *} | ${tp#* }"
done
