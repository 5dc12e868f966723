#!/usr/bin/env bash
# PCD and E57 inputs against LAS of the same points (issue 28): binary and
# binary_compressed PCD, E57 with float and with scaled-integer coordinates, and
# LAS, N points each (default 20 M, made by benches/make_e57_pcd.rs), each
# converted REPS times (default 3, interleaved so the VM's drift hits every
# format alike) at --memory 256MiB. Prints per format the median wall time
# (fastest-slowest), M points/s and the largest peak resident memory.
#
#   bash bench/e57_pcd.sh                  # 20 M points, in /tmp/pcimg-e57pcd
#   N=2000000 REPS=1 bash bench/e57_pcd.sh # a quick run
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/lib.sh
N=${N:-20000000}
DIR=${DIR:-/tmp/pcimg-e57pcd}/$N
REPS=${REPS:-3}
MEM=${MEM:-256MiB}
BIN=target/release/pcimg
cargo build --release -q --bin pcimg --example make_e57_pcd
mkdir -p "$DIR"
[ -f "$DIR/scene.las" ] || target/release/examples/make_e57_pcd --points "$N" --dir "$DIR"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB, $(uname -sr)"
echo "points: $N, --memory $MEM, $REPS runs each, commit $(git rev-parse --short HEAD), $(date -u +%F)"
LOG=$DIR/log.txt
: > "$LOG"
FILES="scene.las scene.pcd scene_z.pcd scene_f.e57 scene_i.e57"
for _ in $(seq "$REPS"); do
  for f in $FILES; do
    run_convert "$f" "$LOG" "$DIR" "$BIN" "$DIR/$f" --memory "$MEM" > /dev/null
  done
done
echo
printf '%-12s %10s  %-15s %12s  %10s  %s\n' input MB "median s" "(range)" "M points/s" "peak MiB"
for f in $FILES; do
  awk -v l="$f" -v n="$N" -v mb="$(($(stat -c %s "$DIR/$f") / 1000000))" '$1 == l {
      w[++k] = $3; if ($12 > p) p = $12 }
    END {
      for (i = 1; i <= k; i++) for (j = i + 1; j <= k; j++) if (w[j] < w[i]) { t = w[i]; w[i] = w[j]; w[j] = t }
      m = (k % 2) ? w[(k + 1) / 2] : (w[k / 2] + w[k / 2 + 1]) / 2
      printf "%-12s %10d  %6.2f (%5.2f-%5.2f)  %10.2f  %10d\n", l, mb, m, w[1], w[k], n / m / 1e6, p }' "$LOG"
done
