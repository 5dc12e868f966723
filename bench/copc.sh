#!/usr/bin/env bash
# COPC with no conversion (issue 42): the first frame (`pcimg render`, CPU
# rasterizer, 1280x720) of a COPC file and of the same points converted to our
# format, local and from SeaweedFS (`weed mini`) behind a proxy that adds 50 ms
# to every request (bench/remote.sh's), with the requests and bytes each took
# (--net-stats); then `info` (opening: header and root page) and a conversion
# of a region (`convert --bounds`) from S3. Runs interleaved, REPS each
# (default 7): median and range.
#
#   bash bench/copc.sh                               # fixtures/autzen_trim.copc.laz
#   COPC=big.copc.laz BOUNDS=x0,y0,x1,y1 bash bench/copc.sh
set -euo pipefail
cd "$(dirname "$0")/.."
COPC=${COPC:-fixtures/autzen_trim.copc.laz}
BOUNDS=${BOUNDS:-636001,848935,636500,849200}
REPS=${REPS:-7}
DELAY_MS=${DELAY_MS:-50}
DIR=${DIR:-/tmp/pcimg-copc-bench}
BIN=$PWD/target/release/pcimg
[ "${BUILD:-1}" = 0 ] || cargo build --release -q
rm -rf "$DIR"
mkdir -p "$DIR"
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); $(weed version 2>&1 | head -1); input $COPC ($(du -h "$COPC" | cut -f1))"
. bench/lib.sh
start_delayed_s3 "$DIR" "$DELAY_MS"

name=$(basename "$COPC")
curl -sf --aws-sigv4 "aws:amz:us-east-1:s3" --user benchkey:benchsecret -T "$COPC" "$direct/bench/$name"
"$BIN" convert "$COPC" -o "$DIR/local.pcimg" -q
AWS_ENDPOINT=$direct "$BIN" convert "$COPC" -o s3://bench/conv.pcimg -q
echo "converted: $(du -sh "$DIR/local.pcimg" | cut -f1)"

: > "$DIR/runs.txt"
for _ in $(seq "$REPS"); do
  net_run copc-local render "$COPC" -o "$DIR/f.png" --renderer cpu
  net_run conv-local render "$DIR/local.pcimg" -o "$DIR/f.png" --renderer cpu
  net_run copc-s3 render "s3://bench/$name" -o "$DIR/f.png" --renderer cpu
  net_run conv-s3 render s3://bench/conv.pcimg -o "$DIR/f.png" --renderer cpu
  net_run copc-s3-info info "s3://bench/$name"
  rm -rf "$DIR/region.pcimg"
  net_run copc-s3-region convert "s3://bench/$name" -o "$DIR/region.pcimg" -q --bounds "$BOUNDS"
done
net_summary copc-local conv-local copc-s3 conv-s3 copc-s3-info copc-s3-region
