#!/usr/bin/env bash
# `pcimg export` speed (issue 41): a dataset converted from real airborne LAS
# (fixtures/autzen_trim.laz tiled with jitter, bench/autzen_tiled.py), exported
# whole to LAS and LAZ, and a 1 % clip (the middle tenth each way) to LAZ,
# locally (page cache warm) and, where `weed` is installed, from SeaweedFS with
# the bytes fetched (--net-stats). Runs are interleaved, REPS of each; prints
# each run and the median (min-max) M points/s of the points written.
#
#   bash bench/export.sh [PCIMG_BIN] [INPUT.las] [REPS]
#
# INPUT defaults to /tmp/pcimg-bench/autzen-tiled-47756566.las (made when
# missing: 1.6 GB, needs laspy). The dataset and outputs go to
# ${TMPDIR:-/tmp}/pcimg-bench/export (the dataset is kept for later runs).
set -euo pipefail
cd "$(dirname "$0")/.."
. bench/lib.sh
bin=${1:-target/release/pcimg}
input=${2:-/tmp/pcimg-bench/autzen-tiled-47756566.las}
reps=${3:-3}
[ -x "$bin" ] || cargo build --release -q
if [ ! -f "$input" ]; then
  mkdir -p "$(dirname "$input")"
  /usr/bin/python3 bench/autzen_tiled.py "$input" 47756566 fixtures/autzen_trim.laz
fi
dir=${TMPDIR:-/tmp}/pcimg-bench/export
mkdir -p "$dir"
ds=$dir/$(basename "$input" .las).pcimg
[ -d "$ds" ] || "$bin" convert "$input" -o "$ds" -q
bounds=$("$bin" info --json "$ds" | python3 -c '
import json, sys
b = json.load(sys.stdin)["bounds"]
lo = [b["min"][a] + 0.45 * (b["max"][a] - b["min"][a]) for a in (0, 1)]
hi = [b["min"][a] + 0.55 * (b["max"][a] - b["min"][a]) for a in (0, 1)]
print(f"{lo[0]},{lo[1]},{hi[0]},{hi[1]}")')
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); dataset $ds ($(du -sh "$ds" | cut -f1)); clip $bounds"

# one LABEL SRC OUT [options]: one export, its wall time and points.
one() {
  local label=$1 src=$2 out=$3 t0 t1 pts
  shift 3
  t0=$(date +%s%N)
  "$bin" export "$src" -o "$dir/$out" --force "$@" 2> "$dir/said.txt" || { cat "$dir/said.txt"; exit 1; }
  t1=$(date +%s%N)
  pts=$(grep -o 'wrote [0-9,]* points' "$dir/said.txt" | tr -dc 0-9)
  local net
  net=$(grep -o 'network: [0-9]* requests, [0-9]* bytes' "$dir/said.txt" || true)
  printf '%-14s %8.2f s  %10d points  %6.2f M points/s  %s  %s\n' "$label" \
    "$(echo "($t1 - $t0) / 1000000000" | bc -l)" "$pts" "$(echo "$pts / (($t1 - $t0) / 1000)" | bc -l)" \
    "$(du -h "$dir/$out" | cut -f1)" "$net" | tee -a "$dir/runs.txt"
}

rm -f "$dir/runs.txt"
remote=""
if command -v weed >/dev/null; then
  scratch_dir pcimg-export-s3
  start_weed "$DIR" bench benchkey benchsecret
  PIDS+=("$WEED")
  export AWS_ACCESS_KEY_ID=benchkey AWS_SECRET_ACCESS_KEY=benchsecret AWS_REGION=us-east-1 \
    AWS_ALLOW_HTTP=true AWS_ENDPOINT=http://127.0.0.1:$S3
  TMPDIR=$DIR "$bin" convert "$input" -o s3://bench/tiled.pcimg -q
  remote=s3://bench/tiled.pcimg
fi
for r in $(seq "$reps"); do
  one las "$ds" all.las
  one laz "$ds" all.laz
  one clip-laz "$ds" clip.laz --bounds "$bounds"
  if [ -n "$remote" ]; then
    one s3-clip-laz "$remote" s3clip.laz --bounds "$bounds" --net-stats
  fi
done
echo
for l in las laz clip-laz s3-clip-laz; do
  grep -q "^$l " "$dir/runs.txt" || continue
  echo "$l: $(awk -v l="$l" '$1 == l { print $6 }' "$dir/runs.txt" | stats) M points/s, $(awk -v l="$l" '$1 == l { print $2 }' "$dir/runs.txt" | stats) s"
done
rm -f "$dir"/all.las "$dir"/all.laz
