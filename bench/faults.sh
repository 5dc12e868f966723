#!/usr/bin/env bash
# Bad networks (issue 39): what a user sees when `pcimg render` reads a dataset
# over plain HTTP (`python3 -m http.server`) through the fault proxy
# (examples/fault_proxy.rs, the tests' tests/common/proxy.rs) that, on the
# parts' requests (`.tif`), adds latency, resets the connection, answers 500 or
# 503 SlowDown, cuts the body short or stalls: twice and then passes
# ("transient", --timeout $TIMEOUT_OK), or on every request ("persistent",
# --timeout $TIMEOUT_FAIL). For each: the outcome (the picture equal to the
# healthy one, or the error's first words), the time of the whole command
# (median and range of REPS runs) and the requests and response body bytes
# through the proxy (extra: beyond a healthy run's, the bytes fetched again).
#
#   bash bench/faults.sh                       # release build, the fixture
#   PROFILE=debug bash bench/faults.sh         # the debug build (no release build)
#   INPUT=scan.las REPS=3 bash bench/faults.sh
set -euo pipefail
cd "$(dirname "$0")/.."
REPS=${REPS:-5}
TIMEOUT_OK=${TIMEOUT_OK:-10s}
TIMEOUT_FAIL=${TIMEOUT_FAIL:-3s}
PROFILE=${PROFILE:-release}
INPUT=${INPUT:-fixtures/autzen_trim.laz}
if [ "$PROFILE" = release ]; then FLAG=--release; else FLAG=; fi
[ "${BUILD:-1}" = 0 ] || { cargo build $FLAG -q && cargo build $FLAG -q --example fault_proxy; }
BIN=$PWD/target/$PROFILE/pcimg
PROXY=$PWD/target/$PROFILE/examples/fault_proxy
# shellcheck source=bench/lib.sh
. bench/lib.sh
scratch_dir pcimg-faults
export NODEVICE_SELECT=1

echo "machine: $(nproc) cores; $(date -u +%FT%TZ); build: $PROFILE; $(python3 --version)"
mkdir -p "$DIR/data"
"$BIN" convert -q --memory 1MiB --compression zstd "$INPUT" -o "$DIR/data/ds.pcimg"
echo "dataset: $INPUT -> $(ls "$DIR/data/ds.pcimg" | grep -c '\.tif$') part(s), $(du -sb "$DIR/data/ds.pcimg" | cut -f1) bytes"

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
wait_port() { # PORT: until it accepts connections (at most 30 s)
  python3 - "$1" <<'EOF'
import socket, sys, time
end = time.time() + 30
while time.time() < end:
    try:
        socket.create_connection(("127.0.0.1", int(sys.argv[1])), 0.2).close(); sys.exit(0)
    except OSError:
        time.sleep(0.02)
sys.exit("nothing listens on port " + sys.argv[1])
EOF
}
SPORT=$(free_port)
python3 -m http.server --bind 127.0.0.1 "$SPORT" --directory "$DIR/data" >/dev/null 2>&1 &
PIDS+=($!)
wait_port "$SPORT"

# One render through a proxy applying FAULT (with extra proxy flags); prints
# "seconds rc requests bytes" and leaves the stderr in $DIR/err.
run_once() { # FAULT TIMEOUT PNG [proxy flags...]
  local fault=$1 timeout=$2 png=$3; shift 3
  rm -f "$DIR/port" "$DIR/stats"
  "$PROXY" "$SPORT" "$fault" --matching .tif --stats "$DIR/stats" "$@" > "$DIR/port" &
  local pp=$!
  until [ -s "$DIR/port" ]; do sleep 0.01; done
  local port; port=$(head -1 "$DIR/port")
  local t0 t1 rc=0
  t0=$(date +%s.%N)
  "$BIN" render "http://127.0.0.1:$port/ds.pcimg" --renderer cpu --width 320 --height 200 \
    --timeout "$timeout" -o "$png" >/dev/null 2>"$DIR/err" || rc=$?
  t1=$(date +%s.%N)
  sleep 0.05 # the proxy's stats file is rewritten within 20 ms of a request
  kill "$pp" 2>/dev/null || true; wait "$pp" 2>/dev/null || true
  local req=0 bytes=0
  if [ -s "$DIR/stats" ]; then
    req=$(sed -n 's/.*requests=\([0-9]*\).*/\1/p' "$DIR/stats")
    bytes=$(sed -n 's/.*bytes=\([0-9]*\).*/\1/p' "$DIR/stats")
  fi
  echo "$(awk "BEGIN {printf \"%.3f\", $t1 - $t0}") $rc $req $bytes"
}

run_once pass "$TIMEOUT_OK" "$DIR/healthy.png" >"$DIR/healthy"
read -r _ _ HREQ HBYTES <"$DIR/healthy"
echo "healthy render: $HREQ requests, $HBYTES body bytes through the proxy"
echo
echo "| fault on the parts' requests | schedule | --timeout | what the user saw | seconds, median (range) | requests | body bytes (extra) |"
echo "|---|---|---|---|---|---|---|"
for fault in pass delay:200 reset 500 503 short:1000 stall; do
  for sched in transient persistent; do
    [ "$fault" = pass ] && [ "$sched" = persistent ] && continue
    if [ "$sched" = transient ]; then timeout=$TIMEOUT_OK; extra=(--times 2); else timeout=$TIMEOUT_FAIL; extra=(); fi
    : >"$DIR/times"
    for _ in $(seq "$REPS"); do
      read -r secs rc req bytes < <(run_once "$fault" "$timeout" "$DIR/out.png" "${extra[@]}")
      echo "$secs" >>"$DIR/times"
    done
    if [ "$rc" = 0 ]; then
      if cmp -s "$DIR/out.png" "$DIR/healthy.png"; then saw="drawn, same picture"; else saw="drawn, DIFFERENT picture"; fi
    else
      # The error's first line without the URL's host and port; the advice cut.
      saw=$(head -1 "$DIR/err" | sed -e 's#http://127.0.0.1:[0-9]*#URL#g' -e 's/; [a-z].*pcimg retried.*//' | cut -c1-160)
      saw="exit $rc: $saw"
    fi
    echo "| $fault | $sched | $timeout | $saw | $(stats <"$DIR/times") | $req | $bytes ($((bytes - HBYTES))) |"
  done
done
