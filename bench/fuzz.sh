#!/usr/bin/env bash
# The mutation fuzzer's long runs (issue 39): N cases (default 1,000,000) of each
# untrusted input in the fast mode of benches/fuzz_inputs.rs (each reader or
# parser alone, in process: text, PLY, LAS/LAZ, PCD, E57, a part, the dataset
# index, and the remote reader against answers cut or corrupted by the fuzz
# server), then FULL cases (default 0) of the full mode (every format converted
# to a dataset: the mode that checks a failed conversion leaves no file
# behind). Not run in CI (tests/fuzz.rs runs a few hundred cases of each).
# Prints a table: input, cases, accepted, refused, panics, other failures
# (panics the code caught, errors naming no file, broken reader contracts),
# files left behind, cases/s.
#
#   bash bench/fuzz.sh                              # 1 M of each kind, one at a time
#   N=20000 KINDS="text index" bash bench/fuzz.sh   # a quick run of two kinds
#   JOBS=2 NICE=0 bash bench/fuzz.sh                # both cores, when nothing else runs
#   FULL=5000 KINDS= bash bench/fuzz.sh             # the full-conversion mode alone
#
# Each run's log (its distinct failures, its slowest case) is in $OUT/KIND.log,
# the failing cases' inputs in $OUT/saved; replay one with
#   target/release/examples/fuzz_inputs --kind KIND --seed SEED --iterations N --only CASE --save DIR
# An abort (an allocation refused under the MEM_GB address-space limit, a stack
# overflow) ends a kind's run; its .err says in which case.
set -euo pipefail
cd "$(dirname "$0")/.."
N=${N:-1000000}
KINDS=${KINDS-text ply las pcd e57 part index http}
FULL=${FULL:-0}
SEED=${SEED:-1}
JOBS=${JOBS:-1}
NICE=${NICE:-19}
MEM_GB=${MEM_GB:-8}
OUT=${OUT:-/tmp/pcimg-fuzz}
# Cases write their inputs under TMPDIR: memory, where there is some.
if [ -z "${TMPDIR:-}" ] && [ -d /dev/shm ] && [ -w /dev/shm ]; then
  export TMPDIR=/dev/shm
fi
cargo build --release -q --example fuzz_inputs
BIN=$PWD/target/release/examples/fuzz_inputs
mkdir -p "$OUT"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB, $(uname -sr)"
echo "commit $(git rev-parse --short HEAD), $(date -u '+%F %H:%M UTC'), seed $SEED, $N cases per kind, $JOBS at a time, nice $NICE"

run_kind() {
  local k=$1
  (
    ulimit -v $((MEM_GB << 20))
    nice -n "$NICE" "$BIN" --kind "$k" --iterations "$N" --seed "$SEED" --save "$OUT/saved" \
      > "$OUT/$k.log" 2> "$OUT/$k.err"
  ) && echo 0 > "$OUT/$k.rc" || echo $? > "$OUT/$k.rc"
}
export -f run_kind
export BIN N SEED NICE MEM_GB OUT

if [ -n "$KINDS" ]; then
  # shellcheck disable=SC2086
  printf '%s\n' $KINDS | xargs -P "$JOBS" -I{} bash -c 'run_kind {}'
fi
if [ "$FULL" -gt 0 ]; then
  (
    ulimit -v $((MEM_GB << 20))
    nice -n "$NICE" "$BIN" --iterations "$FULL" --seed "$SEED" --save "$OUT/saved" \
      > "$OUT/full.log" 2> "$OUT/full.err"
  ) && echo 0 > "$OUT/full.rc" || echo $? > "$OUT/full.rc"
fi

echo
printf '%-7s %9s %9s %9s %7s %7s %7s %9s  %s\n' \
  input cases accepted refused panics other "left" "cases/s" "exit"
for k in $KINDS; do
  rc=$(cat "$OUT/$k.rc")
  if grep -q '^RESULT ' "$OUT/$k.log"; then
    awk -v rc="$rc" '$1 == "RESULT" {
        printf "%-7s %9d %9d %9d %7d %7d %7d %9.0f  %s\n",
          $2, $3, $4, $5, $6, $7 + $8 + $9, $10, $3 / $11, rc }' "$OUT/$k.log"
  else
    printf '%-7s %s (exit %s): %s\n' "$k" "did not finish" "$rc" "$(tail -n 1 "$OUT/$k.err")"
  fi
done
if [ "$FULL" -gt 0 ]; then
  # "N cases: A accepted, R refused, P panics, L left files behind; ..." then "R cases/s".
  line=$(grep -E '^[0-9]+ cases: ' "$OUT/full.log" || true)
  rate=$(grep -E 'cases/s$' "$OUT/full.log" | awk '{print $1}' || true)
  if [ -n "$line" ]; then
    echo "$line" | awk -v r="$rate" -v rc="$(cat "$OUT/full.rc")" '{
        printf "%-7s %9d %9d %9d %7d %7s %7d %9.1f  %s\n", "full", $1, $3, $5, $7, "-", $9, r, rc }'
  else
    printf '%-7s %s (exit %s): %s\n' full "did not finish" "$(cat "$OUT/full.rc")" "$(tail -n 1 "$OUT/full.err")"
  fi
fi
echo
echo "distinct failures (from $OUT/*.log):"
grep -h '^case ' "$OUT"/*.log 2>/dev/null | head -n 40 || true
