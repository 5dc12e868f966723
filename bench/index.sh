#!/usr/bin/env bash
# The paged index at scale (issue 44): datasets of N small real parts (the
# `many_parts` generator: 1 km tiles of 1,000-2,000 LAS-like points, zstd,
# centimetre lattice), indexed by `pcimg index` (wall time and peak memory);
# the index's root and pages; then opening and the first frame of the whole
# dataset, locally and from object storage at 50 ms a request
# (`--example index_open`: requests, bytes, time; REPS runs each).
#
#   bash bench/index.sh                       # N = 1,000, 10,000 and 100,000
#   SIZES="1000 10000" REPS=5 bash bench/index.sh
#
# The parts are made once under DIR (100,000 take about 2 GB and a few minutes)
# and kept; the index and overview are rebuilt on every run.
set -euo pipefail
cd "$(dirname "$0")/.."
DIR=${DIR:-/tmp/pcimg-index}
SIZES=${SIZES:-"1000 10000 100000"}
REPS=${REPS:-3}
LATENCY=${LATENCY:-50}
POINTS=${POINTS:-1000:2000}
cargo build --release -q --bin pcimg --example many_parts --example index_open
BIN=$PWD/target/release/pcimg
mkdir -p "$DIR"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB, $(uname -sr); $(date -u +%FT%TZ)"
for n in $SIZES; do
  ds=$DIR/n$n.pcimg
  if [ ! -f "$ds/.made" ]; then
    rm -rf "$ds"
    target/release/examples/many_parts "$ds" "$n" --points "$POINTS" --no-index
    touch "$ds/.made"
  fi
  rm -rf "$ds/pcimg-index.json" "$ds/overview" "$ds"/pages-*
  sync
  /usr/bin/time -f "%e %M" -o "$DIR/time.txt" "$BIN" index "$ds" > "$DIR/index.out"
  read -r wall rss < "$DIR/time.txt"
  root=$(stat -c %s "$ds/pcimg-index.json")
  pages=$(find "$ds" -path '*/pages-*/*.json' | wc -l)
  pbytes=$(find "$ds" -path '*/pages-*/*.json' -printf '%s\n' | awk '{s+=$1} END {print s+0}')
  parts=$(du -sb --exclude=overview --exclude='pages-*' "$ds" | cut -f1)
  echo
  echo "N=$n parts ($(( parts / 1000000 )) MB of parts)"
  echo "  pcimg index: ${wall} s, peak RSS $(( rss / 1024 )) MiB: $(cat "$DIR/index.out")"
  echo "  index: root $root bytes + $pages pages, $pbytes bytes ($(( (root + pbytes) / n )) bytes a part)"
  target/release/examples/index_open "$ds" --latency-ms "$LATENCY" --reps "$REPS" | sed 's/^/  /'
done
