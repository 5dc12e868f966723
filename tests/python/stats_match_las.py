#!/usr/bin/env python3
"""`pcimg stats --exact --json` of a dataset converted from a LAS file, against
numpy over the points laspy reads from it (software pcimg does not use): per
band the count, min, max, mean and standard deviation (to 1e-9 relative, the
coordinates to 1e-6 of a LAS unit: pcimg reads them from the part's lattice),
the percentiles of whole-number bands exactly (nearest rank: numpy's
"inverted_cdf"), those of the others within one of 4,096 bins of the range,
and the class counts exactly.

    /usr/bin/python3 tests/python/stats_match_las.py SOURCE.las STATS.json

Prints one line; on the first difference prints it and exits 1.
"""
import json
import sys

import laspy
import numpy as np


def fail(msg):
    print(f"MISMATCH: {msg}", file=sys.stderr)
    sys.exit(1)


def main():
    src = laspy.read(sys.argv[1])
    stats = json.load(open(sys.argv[2]))
    if stats["level"] != 0 or stats["sampled"] != len(src.points):
        fail(f"not every point: level {stats['level']}, {stats['sampled']} of {len(src.points)}")
    checked = []
    dims = list(src.point_format.dimension_names)
    for b in stats["bands"]:
        name = b["name"]
        if name == "scan_angle" and "scan_angle_rank" in dims:
            v = np.asarray(src.scan_angle_rank, dtype=np.float64)
        elif name == "las_flags" and "scan_direction_flag" in dims:
            # LAS_FLAGS: the legacy formats' synthetic, key-point, withheld
            # bits 0 to 2, scan direction 6, edge of flight line 7.
            bits = ["synthetic", "key_point", "withheld"]
            v = sum(np.asarray(src[d], dtype=np.float64) * 2**k for k, d in enumerate(bits))
            v = v + np.asarray(src.scan_direction_flag, dtype=np.float64) * 64
            v = v + np.asarray(src.edge_of_flight_line, dtype=np.float64) * 128
        elif name in ("x", "y", "z") or name in dims:
            v = np.asarray(getattr(src, name), dtype=np.float64)
        else:
            continue
        if b["count"] != len(v):
            fail(f"{name}: count {b['count']} against {len(v)}")
        tol = 1e-6 * float(src.header.scales[0]) if name in "xyz" else 0.0
        for key, want in (("min", v.min()), ("max", v.max())):
            if abs(b[key] - want) > tol + 1e-12 * abs(want):
                fail(f"{name}: {key} {b[key]} against {want}")
        for key, want in (("mean", v.mean()), ("std", v.std(ddof=1))):
            if abs(b[key] - want) > 1e-9 * max(abs(want), 1.0) + tol:
                fail(f"{name}: {key} {b[key]} against {want}")
        whole = bool(np.all(v == np.round(v))) and v.max() - v.min() < 4096
        width = (v.max() - v.min()) / 4096
        for p, got in b["percentiles"]:
            want = np.percentile(v, p, method="inverted_cdf")
            if whole and got != want:
                fail(f"{name}: p{p} {got} against {want} (whole numbers)")
            if not whole and abs(got - want) > width + tol:
                fail(f"{name}: p{p} {got} against {want}, more than a bin ({width})")
        if sum(b["histogram"]) != len(v):
            fail(f"{name}: the histogram holds {sum(b['histogram'])} of {len(v)}")
        checked.append(name)
    codes, counts = np.unique(np.asarray(src.classification), return_counts=True)
    want = {int(c): int(n) for c, n in zip(codes, counts)}
    got = {c["code"]: c["points"] for c in stats["classes"]}
    if got != want:
        fail(f"classes {got} against {want}")
    print(f"{len(checked)} bands and {len(want)} classes equal: {', '.join(checked)}")


if __name__ == "__main__":
    main()
