#!/usr/bin/env bash
# Colour with no time (issue 40's target "an airborne scan with colour and no time
# band: at most 0.8x its LAZ"), on the stand-ins we have: the scan the issue
# measured (499 k points, LAZ 8.70 B/pt) is not in ../shared or any public
# repository we found.
#
#   bash bench/colour_only.sh [PCIMG_BINARY] [REPS]
#
# 1. autzen_trim as LAS 1.2 point format 2 (its real colour; x y z and attributes
#    as they are; GPS time dropped), written by laspy's `convert(…,
#    point_format_id=2)`;
# 2. cgal b9 (fixtures/cgal_b9_training.ply: an aerial scene whose colours are
#    its four class colours), written as format 2 at 1 mm by laspy.
# Each goes through bench/compact.sh (bytes a point per band and in total, next
# to the LAZ laspy writes and, where `copc_converter` is installed, its COPC).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-target/release/pcimg}
REPS=${2:-3}
source bench/lib.sh
scratch_dir pcimg-colour
/usr/bin/python3 - fixtures/autzen_trim.laz fixtures/cgal_b9_training.ply "$DIR" <<'PY'
import sys
import numpy as np
import laspy
laz, ply, out = sys.argv[1:4]
las = laspy.convert(laspy.read(laz), point_format_id=2)
las.write(out + "/autzen_fmt2.las")
# cgal b9: a binary little-endian PLY of x y z (float) and red green blue (uchar)
# and more; read with numpy from the header's own property list.
with open(ply, "rb") as f:
    head = []
    while True:
        line = f.readline().decode("ascii").strip()
        head.append(line)
        if line == "end_header":
            break
    n = next(int(l.split()[2]) for l in head if l.startswith("element vertex"))
    kinds = {"float": "<f4", "double": "<f8", "uchar": "u1", "int": "<i4",
             "uint": "<u4", "short": "<i2", "ushort": "<u2", "char": "i1"}
    props = [l.split() for l in head if l.startswith("property")]
    dt = np.dtype([(p[2], kinds[p[1]]) for p in props])
    v = np.frombuffer(f.read(n * dt.itemsize), dtype=dt, count=n)
h = laspy.LasHeader(version="1.2", point_format=2)
h.scales = [0.001, 0.001, 0.001]
h.offsets = [float(np.floor(v["x"].min())), float(np.floor(v["y"].min())),
             float(np.floor(v["z"].min()))]
b9 = laspy.LasData(h)
b9.x, b9.y, b9.z = v["x"], v["y"], v["z"]
for c in ("red", "green", "blue"):
    setattr(b9, c, v[c].astype(np.uint16) * 257)
b9.write(out + "/cgal_b9_fmt2.las")
PY
for name in autzen_fmt2 cgal_b9_fmt2; do
  copc=
  if command -v copc_converter >/dev/null; then
    copc_converter "$DIR/$name.las" "$DIR/$name.copc.laz" >/dev/null 2>&1 && copc=$DIR/$name.copc.laz
  fi
  echo "== $name"
  bash bench/compact.sh "$BIN" "$DIR/$name.las" "$REPS" $copc
done
