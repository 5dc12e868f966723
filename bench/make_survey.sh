#!/usr/bin/env bash
# Make a synthetic benchmark survey: an NX x NY grid of 100 m x 100 m COPC tiles
# (LAS 1.4 point format 7: ground/buildings/vegetation, RGB, gps_time; seeded, so
# every run gives the same points; see make_survey.py for the terrain model).
#
#   NX=11 NY=11 POINTS=100000 OUT=/tmp/survey bash bench/make_survey.sh
#
# Result: $OUT/copc/tile-XX-YY.copc.laz (XX = column from west, YY = row from south).
# Defaults: NX=11 NY=11 (121 tiles), POINTS=100000 per tile, OUT=./survey, SEED=1,
# JOBS=2 conversions at a time, COPC_ARGS="--threads 1 --progress plain".
# Steps: make_survey.py writes $OUT/las/*.las, copc_converter turns each tile into
# COPC, then $OUT/las is deleted.  Needs copc_converter and Python with laspy:
#   cargo install copc_converter --locked
#   pip install "laspy[lazrs]"        (or set PYTHON=/path/to/python)
set -euo pipefail

NX=${NX:-11} NY=${NY:-11} POINTS=${POINTS:-100000} OUT=${OUT:-survey} SEED=${SEED:-1}
JOBS=${JOBS:-2} COPC_ARGS=${COPC_ARGS:---threads 1 --progress plain}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
die() { echo "make_survey.sh: $*" >&2; exit 1; }

# --- prerequisites -----------------------------------------------------------
CONV=$(command -v copc_converter || true)
[[ -z $CONV && -x $HOME/.cargo/bin/copc_converter ]] && CONV=$HOME/.cargo/bin/copc_converter
[[ -n $CONV ]] || die "copc_converter not found; install it with: cargo install copc_converter --locked"
PY=""
for p in ${PYTHON:-} python3 /usr/bin/python3; do   # first Python that has laspy + numpy
  if command -v "$p" >/dev/null && "$p" -c 'import laspy, numpy' 2>/dev/null; then PY=$p; break; fi
done
[[ -n $PY ]] || die "no Python with laspy found; install it with: pip install \"laspy[lazrs]\" (or set PYTHON=...)"
echo "using $CONV ($("$CONV" --version)), $PY (laspy $("$PY" -c 'import laspy; print(laspy.__version__)'))"

# --- 1. synthetic LAS tiles ----------------------------------------------------
start=$SECONDS
rm -rf "$OUT/las"; mkdir -p "$OUT/las" "$OUT/copc"
rm -f "$OUT"/copc/tile-*.copc.laz                    # no stale tiles from a bigger run
NX=$NX NY=$NY POINTS=$POINTS SEED=$SEED "$PY" "$HERE/make_survey.py" --out "$OUT/las"
echo "LAS written in $((SECONDS - start)) s"

# --- 2. COPC, JOBS tiles at a time; show a tile's log only if it fails ----------
export CONV COPC_ARGS OUT
find "$OUT/las" -name 'tile-*.las' -print0 | sort -z | xargs -0 -P "$JOBS" -n 1 bash -c '
  t=$(basename "$1" .las)
  log=$("$CONV" $COPC_ARGS "$1" "$OUT/copc/$t.copc.laz" 2>&1) || { echo "$log" >&2; echo "FAILED: $t" >&2; exit 255; }' _

# --- 3. clean up and summarise ---------------------------------------------------
rm -rf "$OUT/las"
n=$(find "$OUT/copc" -name 'tile-*.copc.laz' | wc -l)
[[ $n -eq $((NX * NY)) ]] || die "expected $((NX * NY)) COPC tiles, found $n"
echo "done: $n tiles ($((NX * NY * POINTS)) points), $(du -sh "$OUT/copc" | cut -f1) in $OUT/copc, $((SECONDS - start)) s"
