#!/usr/bin/env bash
# A survey of many COPC files as one dataset (issue 42): `pcimg index` over a
# directory of COPC tiles (bench/make_survey.sh makes 121), then the first
# frame (`pcimg render`, CPU rasterizer, 1280x720) of the survey, of one of its
# tiles alone, and of the same points converted to our format, local and from
# SeaweedFS (`weed mini`) behind a proxy that adds 50 ms to every request
# (bench/remote.sh's), with the requests and bytes each took (--net-stats);
# `info` of the survey from S3; and `pcimg index` itself, local and over S3.
# Runs interleaved, REPS each (default 5): median and range.
#
#   OUT=/tmp/survey POINTS=400000 bash bench/make_survey.sh
#   TILES=/tmp/survey/copc bash bench/survey.sh
set -euo pipefail
cd "$(dirname "$0")/.."
TILES=${TILES:?set TILES to a directory of COPC tiles (bench/make_survey.sh makes them)}
ONE=${ONE:-$(ls "$TILES"/*.copc.laz | awk '{a[NR]=$0} END {print a[int((NR+1)/2)]}')}
REPS=${REPS:-5}
DELAY_MS=${DELAY_MS:-50}
DIR=${DIR:-/tmp/pcimg-survey-bench}
BIN=$PWD/target/release/pcimg
[ "${BUILD:-1}" = 0 ] || cargo build --release -q
rm -rf "$DIR"
mkdir -p "$DIR"
n=$(ls "$TILES"/*.copc.laz | wc -l)
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); $(weed version 2>&1 | head -1); $n tiles in $TILES ($(du -sh "$TILES" | cut -f1)); one: $(basename "$ONE")"
. bench/lib.sh
start_delayed_s3 "$DIR" "$DELAY_MS"
put() { curl -sf --aws-sigv4 "aws:amz:us-east-1:s3" --user benchkey:benchsecret -T "$1" "$direct/bench/$2"; }

for f in "$TILES"/*.copc.laz; do put "$f" "tiles/$(basename "$f")"; done
for f in "$TILES"/*.copc.laz; do echo "s3://bench/tiles/$(basename "$f")"; done > "$DIR/tiles.txt"
one=$(basename "$ONE")

# The survey, local (of the local tiles) and in S3 (of the S3 tiles, itself
# uploaded beside them).
t0=$(date +%s%N)
"$BIN" index "$TILES" -o "$DIR/local-survey" | tee "$DIR/index.txt"
echo "index (local): $(( ($(date +%s%N) - t0) / 1000000 )) ms"
t0=$(date +%s%N)
AWS_ENDPOINT=$delayed "$BIN" index "$DIR/tiles.txt" -o "$DIR/s3-survey"
echo "index (S3, +${DELAY_MS} ms a request): $(( ($(date +%s%N) - t0) / 1000000 )) ms"
(cd "$DIR/s3-survey" && find . -type f | sed 's|^\./||') | while read -r f; do put "$DIR/s3-survey/$f" "survey/$f"; done
# The same points converted.
t0=$(date +%s%N)
"$BIN" convert "$TILES" -o "$DIR/conv" -q
echo "converted: $(du -sh "$DIR/conv" | cut -f1), $(( ($(date +%s%N) - t0) / 1000000 )) ms"
AWS_ENDPOINT=$direct "$BIN" convert "$TILES" -o s3://bench/conv -q

: > "$DIR/runs.txt"
for _ in $(seq "$REPS"); do
  net_run survey-local render "$DIR/local-survey" -o "$DIR/f.png" --renderer cpu
  net_run tile-local render "$ONE" -o "$DIR/f.png" --renderer cpu
  net_run conv-local render "$DIR/conv" -o "$DIR/f.png" --renderer cpu
  net_run survey-s3 render s3://bench/survey/pcimg-survey.json -o "$DIR/f.png" --renderer cpu
  net_run tile-s3 render "s3://bench/tiles/$one" -o "$DIR/f.png" --renderer cpu
  net_run conv-s3 render s3://bench/conv -o "$DIR/f.png" --renderer cpu
  net_run survey-s3-info info s3://bench/survey/pcimg-survey.json
done
net_summary survey-local tile-local conv-local survey-s3 tile-s3 conv-s3 survey-s3-info
