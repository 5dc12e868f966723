#!/usr/bin/env bash
# The inspector after an outage (issue 39): a synthetic scan converted into
# several parts with an overview, served by `python3 -m http.server` on
# 127.0.0.1; the server is stopped while level 0 is asked for, and started
# again after OUTAGES seconds (each). Prints, per outage, the time from the
# server's return (its port accepts connections) to the inspector's render
# worker's frame with every tile (median and range over REPS runs), and the
# requests that failed during the outage. See benches/retry_recovery.rs.
#
#   bash bench/retry.sh                       # 200,000 points, outages of 3 and 30 s, 5 runs
#   POINTS=2000000 OUTAGES=5 REPS=3 bash bench/retry.sh
set -euo pipefail
cd "$(dirname "$0")/.."
POINTS=${POINTS:-200000}
REPS=${REPS:-5}
OUTAGES=${OUTAGES:-3,30}
DIR=$(mktemp -d /tmp/pcimg-retry-bench.XXXXXX)
trap 'rm -rf "$DIR"' EXIT
[ "${BUILD:-1}" = 0 ] || cargo build --release -q --example retry_recovery --bin pcimg
BIN=$PWD/target/release/pcimg
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); $(python3 --version)"
"$BIN" synth -n "$POINTS" -o "$DIR/scan.las" >/dev/null
"$BIN" convert -q --memory 1MiB --compression zstd "$DIR/scan.las" -o "$DIR/scan.pcimg"
rm "$DIR/scan.las"
echo "dataset: $POINTS points, $(ls "$DIR/scan.pcimg"/*.tif | wc -l) parts, $(du -sh "$DIR/scan.pcimg" | cut -f1)"
NODEVICE_SELECT=1 ./target/release/examples/retry_recovery "$DIR" scan.pcimg "$REPS" "$OUTAGES"
