#!/usr/bin/env bash
# How long a conversion that fills its disk takes to fail and to clean up (issue
# 39): a synthetic scan converted onto a tmpfs too small for it, mounted in a
# private mount namespace (unshare; as root or where user namespaces are
# allowed), once as one part (`-o small/one.tif`: the part's temporary file
# fills the disk) and once as several (`--memory 1MiB -o small/many.pcimg`: the
# spill files fill it). The run is traced (strace, writes and exits only):
# "to full" is from the start to the first write refused with ENOSPC, "clean up"
# from there to the process's exit (the error reaching the top, the temporary
# files removed). Also checks that nothing was left on the tmpfs.
#
#   bash bench/full_disk.sh BIN [RUNS=5] [POINTS=2000000] [SIZE=32m]
#   e.g. bash bench/full_disk.sh target/release/pcimg 5
#
# Prints every run, then per case the median and range of both times.
set -euo pipefail
if [ $# -lt 1 ]; then
  sed -n 2,15p "$0"
  exit 2
fi
BIN=$(realpath "$1") RUNS=${2:-5} N=${3:-2000000} SIZE=${4:-32m}
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
"$BIN" synth -n "$N" -o "$W/scan.las" >/dev/null
mkdir "$W/small"
LOG="$W/runs.txt"
for i in $(seq "$RUNS"); do
  for case in one many; do
    if [ "$case" = one ]; then args="-o $W/small/one.tif"; else args="--memory 1MiB -o $W/small/many.pcimg"; fi
    unshare --user --map-root-user --mount sh -c "
      mount -t tmpfs -o size=$SIZE tmpfs '$W/small' || exit 97
      strace -f --seccomp-bpf -ttt -s 0 -o '$W/trace' \
        -e trace=write,pwrite64,writev,pwritev,pwritev2,exit_group \
        '$BIN' convert -q $args '$W/scan.las' 2>'$W/err' && exit 96
      ls -A '$W/small' | wc -l > '$W/left'
    " || { echo "run failed ($?)"; cat "$W/err"; exit 1; }
    python3 - "$W/trace" "$case" "$(cat "$W/left")" "$W/err" >> "$LOG" <<'PY'
import sys
lines = open(sys.argv[1]).read().splitlines()
ts = lambda l: float(l.split()[1])
t0 = ts(lines[0])
full = next(ts(l) for l in lines if "ENOSPC" in l)
end = ts(lines[-1])
err = open(sys.argv[4]).read().strip().splitlines()[-1][:160]
print(f"{sys.argv[2]} {full - t0:.3f} {end - full:.4f} {sys.argv[3]} {err}")
PY
    tail -1 "$LOG"
  done
done
python3 - "$LOG" <<'PY'
import statistics, sys
rows = [l.split(maxsplit=4) for l in open(sys.argv[1])]
for case in ("one", "many"):
    r = [x for x in rows if x[0] == case]
    for k, name in ((1, "to full"), (2, "clean up")):
        v = sorted(float(x[k]) for x in r)
        print(f"{case}: {name}: median {statistics.median(v):.4f} s, range {v[0]:.4f}-{v[-1]:.4f} s ({len(v)} runs)")
    print(f"{case}: entries left on the tmpfs: {sorted(set(x[3] for x in r))}")
PY
