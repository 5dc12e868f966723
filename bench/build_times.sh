#!/usr/bin/env bash
# Interleaved build and test times of two checkouts on this machine: a release
# build from clean (`cargo build --release`, each checkout in its own fresh target
# directory), then, once each checkout's tests are built, the test run
# (`cargo test`). Checkouts alternate, old then new, so a drift in the VM's speed
# hits both alike.
#
#   bash bench/build_times.sh ROUNDS OLD_CHECKOUT NEW_CHECKOUT [WORKDIR]
#   e.g. git worktree add /work/base dcb7989
#        bash bench/build_times.sh 2 /work/base . /work/build-times
#
# Prints every run (wall, user, system seconds) and each phase's median wall time
# and ratio new/old. Needs the registry already downloaded (`cargo fetch`).
# Set PHASES=build or PHASES=test to run one phase only; TEST_TARGET_OLD and
# TEST_TARGET_NEW name target directories to build the tests in (an existing
# one saves a build; that build is not timed either way). Tests run with CI=true
# (a missing tool fails rather than skips, so both sides run the same tests).
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,14p "$0"
  exit 2
fi
ROUNDS=$1 OLD=$(realpath "$2") NEW=$(realpath "$3") WORK=${4:-$(mktemp -d)}
PHASES=${PHASES:-build test}
source "$(dirname "$0")/lib.sh"
mkdir -p "$WORK"
LOG="$WORK/runs.txt"
: > "$LOG"

timed() { # LABEL DIR TARGET COMMAND...: one timed cargo command in DIR
  local label=$1 dir=$2 target=$3 wall user sys kib
  shift 3
  (cd "$dir" && CARGO_TARGET_DIR=$target /usr/bin/time -f "%e %U %S %M" -o "$WORK/t.txt" "$@" \
    > "$WORK/$label.log" 2>&1) || { echo "$label failed: see $WORK/$label.log" >&2; exit 1; }
  read -r wall user sys kib < "$WORK/t.txt"
  printf '%-12s  wall %7.1f s  user %7.1f s  sys %6.1f s\n' "$label" "$wall" "$user" "$sys" | tee -a "$LOG"
}

if [[ " $PHASES " == *" build "* ]]; then
  for _ in $(seq "$ROUNDS"); do
    for side in old new; do
      dir=$OLD; [ $side = new ] && dir=$NEW
      rm -rf "$WORK/target-$side-release"
      sync
      timed "build-$side" "$dir" "$WORK/target-$side-release" cargo build --release --locked
    done
  done
fi
if [[ " $PHASES " == *" test "* ]]; then
  test_target() { # SIDE
    if [ "$1" = old ]; then echo "${TEST_TARGET_OLD:-$WORK/target-old-test}"; else echo "${TEST_TARGET_NEW:-$WORK/target-new-test}"; fi
  }
  for side in old new; do
    dir=$OLD; [ $side = new ] && dir=$NEW
    (cd "$dir" && CARGO_TARGET_DIR=$(test_target $side) cargo test --locked --no-run -q > /dev/null 2>&1)
  done
  for _ in $(seq "$ROUNDS"); do
    for side in old new; do
      dir=$OLD; [ $side = new ] && dir=$NEW
      CI=true timed "test-$side" "$dir" "$(test_target $side)" cargo test --locked
    done
  done
fi
for phase in build test; do
  grep -q "^$phase-" "$LOG" || continue
  old=$(median_wall "$phase-old" "$LOG")
  new=$(median_wall "$phase-new" "$LOG")
  awk -v p="$phase" -v o="$old" -v n="$new" \
    'BEGIN { printf "%s median wall: old %.1f s, new %.1f s, new/old %.2f\n", p, o, n, n / o }'
done
