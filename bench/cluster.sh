#!/usr/bin/env bash
# Conversion on a cluster, measured on this machine (docs/cluster.md):
# plan time against input size; one shard's throughput against a single
# `convert`; `pcimg index` time against the part count; 2 shards at once on
# the cores against one after the other. Usage: bench/cluster.sh [RUNS] (3).
# Needs a release build (cargo build --release). Results: bench/RESULTS.md.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${PCIMG:-target/release/pcimg}
runs=${1:-3}
w=$(mktemp -d "${TMPDIR:-/tmp}/pcimg-cluster.XXXX")
trap 'rm -rf "$w"' EXIT
t() { /usr/bin/time -f %e -o "$w/t" "$@" >/dev/null; cat "$w/t"; }
mem=256MiB
for n in 2000000 8000000; do
  "$bin" synth -n $n -o "$w/in$n.xyz" >/dev/null
done
in=$w/in8000000.xyz
echo "input: $(du -h "$in" | cut -f1), 8 M points; memory $mem per shard"
for r in $(seq "$runs"); do
  for n in 2000000 8000000; do
    rm -rf "$w/o$n"
    k=1; [ $n = 8000000 ] && k=4
    echo "plan $n: $(t "$bin" convert --plan "$w/p$n.json" --shards $k --memory $mem -o "$w/o$n" "$w/in$n.xyz") s"
  done
  rm -rf "$w/single"
  echo "single convert 8M: $(t "$bin" convert -q --memory $mem -o "$w/single" "$in") s"
  rm -rf "$w/o8000000"
  # 4 shards one after the other, then 4 shards 2 at a time.
  s=$(date +%s.%N)
  for i in 0 1 2 3; do
    echo "  shard $i/4 alone: $(t "$bin" convert -q --plan "$w/p8000000.json" --shard $i/4) s"
  done
  echo "4 shards serial: $(echo "$(date +%s.%N) - $s" | bc) s"
  echo "index (4 parts... as planned): $(t "$bin" index -q "$w/o8000000") s, $(ls "$w/o8000000"/*.tif | wc -l) parts"
  rm -rf "$w/o8000000"
  s=$(date +%s.%N)
  printf '%s\n' 0/4 1/4 2/4 3/4 | xargs -P 2 -I{} "$bin" convert -q --plan "$w/p8000000.json" --shard {}
  echo "4 shards 2 at once: $(echo "$(date +%s.%N) - $s" | bc) s"
done
# Index time against part count: the same points in more, smaller parts.
for m in 512MiB 128MiB 64MiB; do
  rm -rf "$w/ix"
  "$bin" convert -q --memory $m -o "$w/ix" "$in"
  echo "index of $(ls "$w/ix"/*.tif | wc -l) parts: $(t "$bin" index -q "$w/ix") s"
done
