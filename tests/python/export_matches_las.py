#!/usr/bin/env python3
"""A LAS/LAZ that `pcimg export` wrote against its source, through laspy (with
lazrs), which pcimg does not use: the same points as a multiset, every
attribute compared point for point after sorting both by X, Y, Z and time: X Y
Z as the same integers under the same scale and offset, intensity, returns,
classification, colour, user data, point source ID, the flags and the scan
angle exactly, and gps_time bit for bit.

    /usr/bin/python3 tests/python/export_matches_las.py SOURCE EXPORTED \
        [--clip MINX,MINY,MINZ,MAXX,MAXY,MAXZ] [--classes 2,6]

With --clip or --classes the source is filtered the same way first. Prints one
line of counts; on the first difference
prints it and exits 1.
"""
import sys

import laspy
import numpy as np


def fail(msg):
    print(f"MISMATCH: {msg}", file=sys.stderr)
    sys.exit(1)


def main():
    args = sys.argv[1:]
    source, exported = args[0], args[1]
    clip = classes = None
    if "--clip" in args:
        clip = [float(v) for v in args[args.index("--clip") + 1].split(",")]
    if "--classes" in args:
        classes = [int(v) for v in args[args.index("--classes") + 1].split(",")]
    src = laspy.read(source)
    out = laspy.read(exported)
    keep = np.ones(len(src.points), dtype=bool)
    if clip is not None:
        for k, axis in enumerate("xyz"):
            v = np.asarray(getattr(src, axis))
            keep &= (v >= clip[k]) & (v <= clip[k + 3])
    if classes is not None:
        keep &= np.isin(np.asarray(src.classification), classes)
    if not np.array_equal(src.header.scales, out.header.scales):
        fail(f"scales {src.header.scales} against {out.header.scales}")
    if not np.array_equal(src.header.offsets, out.header.offsets):
        fail(f"offsets {src.header.offsets} against {out.header.offsets}")
    n = int(keep.sum())
    if len(out.points) != n:
        fail(f"{len(out.points)} points exported, {n} in the source")
    has_time = "gps_time" in src.point_format.dimension_names

    def order(p, mask=None):
        cols = [p.X, p.Y, p.Z]
        if has_time:
            cols.append(p.gps_time)
        cols = [np.asarray(c) if mask is None else np.asarray(c)[mask] for c in cols]
        return np.lexsort(tuple(reversed(cols)))

    so, oo = order(src, keep), order(out)
    fields = ["X", "Y", "Z", "intensity", "return_number", "number_of_returns", "classification"]
    names = list(src.point_format.dimension_names)
    fields += [f for f in ("red", "green", "blue", "nir") if f in names]
    # The fields every format has, and the flags (overlap and the scanner
    # channel where both formats have them: the extended ones).
    out_names = list(out.point_format.dimension_names)
    fields += [
        f
        for f in ("user_data", "point_source_id", "scan_direction_flag", "edge_of_flight_line",
                  "synthetic", "key_point", "withheld", "overlap", "scanner_channel")
        if f in names and f in out_names
    ]

    def degrees(p, dims):
        if "scan_angle_rank" in dims:
            return np.asarray(p.scan_angle_rank, dtype=np.float64)
        return np.asarray(p.scan_angle, dtype=np.float64) * 0.006

    a = degrees(src, names)[keep][so]
    b = degrees(out, out_names)[oo]
    same = ("scan_angle_rank" in names) == ("scan_angle_rank" in out_names)
    if n and np.abs(a - b).max() > (0.0 if same else 0.003):
        i = int(np.argmax(np.abs(a - b)))
        fail(f"scan angle: point {i} of the sorted points is {a[i]}° in the source, {b[i]}° exported")
    for f in fields:
        a = np.asarray(getattr(src, f))[keep][so]
        b = np.asarray(getattr(out, f))[oo]
        if not np.array_equal(a, b):
            i = int(np.argmax(a != b))
            fail(f"{f}: point {i} of the sorted points is {a[i]} in the source, {b[i]} exported")
    if has_time:
        a = np.asarray(src.gps_time, dtype=np.float64)[keep][so]
        b = np.asarray(out.gps_time, dtype=np.float64)[oo]
        if not np.array_equal(a.view(np.int64), b.view(np.int64)):
            i = int(np.argmax(a.view(np.int64) != b.view(np.int64)))
            fail(f"gps_time: point {i} of the sorted points is {a[i]!r} in the source, {b[i]!r} exported")
        fields.append("gps_time bit for bit")
    wkt = any(v.record_id == 2112 for v in out.header.vlrs)
    print(f"{n} points equal ({', '.join(fields)}); WKT record {wkt}")


if __name__ == "__main__":
    main()
