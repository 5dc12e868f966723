#!/usr/bin/env bash
# The Python package's read speed (issue 41): `pcimg.open(ds).read()` of a
# dataset converted from real airborne LAS (fixtures/autzen_trim.laz tiled with
# jitter, bench/autzen_tiled.py: 47.7 M points) against `laspy.read` of the same
# points as LAZ (lazrs) and as LAS, a 1 % box, and the dataset's Arrow stream
# read whole by pyarrow. Each run is its own process;
# runs are interleaved, REPS of each; prints each run, then the median
# (min-max) seconds and M points/s.
#
#   bash bench/python.sh [INPUT.las] [REPS]
#
# Needs the package built release (`python3 -m pip install ./python`), laspy
# with lazrs. The LAZ and the dataset go to ${TMPDIR:-/tmp}/pcimg-bench/python.
set -euo pipefail
cd "$(dirname "$0")/.."
input=${1:-/tmp/pcimg-bench/autzen-tiled-47756566.las}
reps=${2:-3}
py=/usr/bin/python3
bin=target/release/pcimg
[ -x "$bin" ] || cargo build --release -q
if [ ! -f "$input" ]; then
  mkdir -p "$(dirname "$input")"
  $py bench/autzen_tiled.py "$input" 47756566 fixtures/autzen_trim.laz
fi
dir=${TMPDIR:-/tmp}/pcimg-bench/python
mkdir -p "$dir"
laz=$dir/$(basename "$input" .las).laz
[ -f "$laz" ] || $py -c "import laspy, sys; laspy.read(sys.argv[1]).write(sys.argv[2])" "$input" "$laz"
ds=$dir/$(basename "$input" .las).pcimg
[ -d "$ds" ] || "$bin" convert "$input" -o "$ds" -q
box=$("$bin" info --json "$ds" | $py -c '
import json, sys
b = json.load(sys.stdin)["bounds"]
lo = [b["min"][a] + 0.45 * (b["max"][a] - b["min"][a]) for a in (0, 1)]
hi = [b["min"][a] + 0.55 * (b["max"][a] - b["min"][a]) for a in (0, 1)]
print(f"{lo[0]},{lo[1]},{hi[0]},{hi[1]}")')
echo "machine: $(nproc) cores; $(date -u +%FT%TZ); dataset $ds ($(du -sh "$ds" | cut -f1)); LAZ $(du -h "$laz" | cut -f1); box $box"
echo "pcimg $($py -c 'import pcimg, os; print(os.path.dirname(pcimg.__file__))'); laspy $($py -c 'import laspy; print(laspy.__version__)')"
runs=$dir/runs.txt
rm -f "$runs"
for r in $(seq "$reps"); do
  for what in pcimg laspy-laz laspy-las pcimg-box pcimg-arrow; do
    case $what in
      pcimg) out=$($py bench/python_read.py pcimg "$ds") ;;
      pcimg-arrow) out=$($py bench/python_read.py pcimg-arrow "$ds") ;;
      pcimg-box) out=$($py bench/python_read.py pcimg "$ds" "$box") ;;
      laspy-laz) out=$($py bench/python_read.py laspy "$laz") ;;
      laspy-las) out=$($py bench/python_read.py laspy "$input") ;;
    esac
    echo "$what $out" | tee -a "$runs"
  done
done
$py - "$runs" <<'PY'
import statistics, sys
rows = {}
for line in open(sys.argv[1]):
    what, s, n = line.split()
    rows.setdefault(what, []).append((float(s), int(n)))
for what, v in rows.items():
    s = sorted(x[0] for x in v)
    n = v[0][1]
    print(f"{what:10s} {n:>10,d} points  {statistics.median(s):7.2f} s ({s[0]:.2f}-{s[-1]:.2f})  "
          f"{n / statistics.median(s) / 1e6:7.2f} M points/s")
PY
