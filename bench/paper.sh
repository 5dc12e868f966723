#!/usr/bin/env bash
# The paper's experiments (Du & Li 2009) side by side with ours, for both layouts:
#   Table 1: storage with 3 and 4 bands: original (level 0) and pyramid bytes, time;
#   Table 2: per level: points, loading time, frames per second (CPU and wgpu).
# Input: `pcimg synth --order scan`: x y z intensity text in scan order (flight
# strips, zigzag scan lines), as a scanner writes its file; the paper's Mogao Caves
# scan was such a file.
#
#   bash bench/paper.sh               # 47,756,566 points (about 1.6 GB of text, minutes)
#   bash bench/paper.sh -n 2000000    # a quick run
#   DIR=/somewhere bash bench/paper.sh  # where inputs and outputs go (default /tmp/pcimg-paper)
set -euo pipefail
cd "$(dirname "$0")/.."
N=47756566
while getopts "n:" opt; do
  case $opt in
    n) N=$OPTARG ;;
    *) echo "usage: bash bench/paper.sh [-n POINTS]" >&2; exit 2 ;;
  esac
done
DIR=${DIR:-/tmp/pcimg-paper}
BIN=target/release/pcimg
cargo build --release -q --bin pcimg --example level_table
mkdir -p "$DIR"

# The machine, and the wgpu adapter as the renderer reports it.
[ -f "$DIR/probe.tif" ] || {
  $BIN synth -n 100000 -o "$DIR/probe.xyz" --force 2> /dev/null
  $BIN convert -q "$DIR/probe.xyz" -o "$DIR/probe.tif" --force
}
adapter=$($BIN render "$DIR/probe.tif" --renderer gpu --width 64 --height 64 \
  -o "$DIR/probe.png" 2>&1 | sed -n 's/.* on \(wgpu .*\)$/\1/p' | head -1)
echo "## Machine"
echo
echo "- CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores"
echo "- memory: $(free -g | awk '/Mem:/ {print $2}') GiB; $(uname -sr)"
echo "- wgpu adapter: ${adapter:-none}"
echo "- load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "- points: $N"
echo

input="$DIR/paper-$N-scan.xyz"
[ -f "$input" ] || $BIN synth -n "$N" --order scan -o "$input" 2> /dev/null
echo "input: $(stat -c %s "$input") bytes of text (x y z intensity, scan order)"
echo

# Bytes of level 0 and of levels >= 1, summed over parts, from `pcimg info --json`.
level_bytes() {
  $BIN info --json "$1" | python3 -c '
import json, sys
d = json.load(sys.stdin)
l0 = sum(p["levels"][0]["bytes"] for p in d["parts"])
print(l0, d["bytes"] - l0, len(d["parts"]))'
}

mib() { awk -v b="$1" 'BEGIN { printf "%.1f", b / 1048576 }'; }

echo "## Table 1: storage (paper: Pentium D, 1 GB; ours: default --memory, one pass per part)"
echo
echo "| layout | bands | level 0 MiB | pyramid MiB | total MiB | parts | time s | peak RSS MiB | paper: original / sampled / total MB, time s |"
echo "|---|---|---|---|---|---|---|---|---|"
for layout in hilbert paper; do
  for bands in 3 4; do
    out="$DIR/out-$layout-$bands.pcimg"
    cols=()
    [ "$bands" = 3 ] && cols=(--columns "x y z _")
    rm -rf "$out"
    sync
    /usr/bin/time -f "%e %M" -o "$DIR/time.txt" \
      $BIN convert -q "$input" -o "$out" --layout "$layout" "${cols[@]}"
    read -r secs rss < "$DIR/time.txt"
    read -r l0 pyr parts <<< "$(level_bytes "$out")"
    if [ "$bands" = 3 ]; then ref="561 / 194 / 755, 211"; else ref="760 / 240 / 1000, 337"; fi
    echo "| $layout | $bands | $(mib "$l0") | $(mib "$pyr") | $(mib $((l0 + pyr))) | $parts | $secs | $((rss / 1024)) | $ref |"
  done
done
echo

for layout in hilbert paper; do
  echo "## Table 2: $layout layout, 4 bands (x y z loaded from the page cache, 1280×720, whole cloud in view)"
  echo
  target/release/examples/level_table "$DIR/out-$layout-4.pcimg" --paper | tail -n +3
  echo
done
rm -rf "$DIR"/out-*.pcimg
