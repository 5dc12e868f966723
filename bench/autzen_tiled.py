#!/usr/bin/env python3
"""Real airborne LAS at benchmark size: fixtures/autzen_trim.laz tiled with jitter.

    python3 bench/autzen_tiled.py [OUT.las] [POINTS] [SOURCE.laz]

Writes POINTS points (default 47,756,566, the paper's count) as uncompressed
LAS 1.2, point format 3, with autzen_trim's header and CRS: 11 bands as pcimg
reads them (x y z, intensity, return_number, number_of_returns, classification,
gps_time, red, green, blue). The 110,000 real points are copied into a grid of
21 columns of tiles, tile by tile in row-major order (each copy in the source's
own scan order, the last copy cut short); every copy is moved by whole tile
widths, each point by a deterministic jitter of up to ±3 LAS units (±0.03 ft)
in x, y and z, and each copy's gps_time by 7 s more than the one before (the
source spans 6.5 s), so no two points are equal and the time keeps rising as
in one long flight. Deterministic: the same arguments give the same bytes.

Needs `pip install 'laspy[lazrs]' numpy`. Default OUT: /tmp/pcimg-bench/autzen-tiled-POINTS.las.
"""
import os
import sys

import laspy
import numpy as np

COLUMNS = 21
JITTER = 3  # LAS units
TIME_STEP = 7.0  # seconds between copies


def main():
    points = int(sys.argv[2]) if len(sys.argv) > 2 else 47_756_566
    out = sys.argv[1] if len(sys.argv) > 1 else f"/tmp/pcimg-bench/autzen-tiled-{points}.las"
    here = os.path.dirname(os.path.abspath(__file__))
    source = sys.argv[3] if len(sys.argv) > 3 else os.path.join(here, "..", "fixtures", "autzen_trim.laz")
    src = laspy.read(source)
    n = len(src.points)
    sx, sy, _ = src.header.scales
    # tile size in LAS units, rounded up to whole feet plus a margin
    width = int(np.ceil((src.header.maxs[0] - src.header.mins[0]) / sx)) + 100
    height = int(np.ceil((src.header.maxs[1] - src.header.mins[1]) / sy)) + 100
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    header = laspy.LasHeader(point_format=src.header.point_format.id, version=src.header.version)
    header.scales = src.header.scales
    header.offsets = src.header.offsets
    header.vlrs = src.header.vlrs
    rng = np.random.default_rng(38)
    written = 0
    copy = 0
    with laspy.open(out, mode="w", header=header) as writer:
        while written < points:
            take = min(n, points - written)
            col, row = copy % COLUMNS, copy // COLUMNS
            rec = laspy.ScaleAwarePointRecord.zeros(take, header=header)
            for name in src.point_format.dimension_names:
                rec[name] = src.points[name][:take]
            jit = rng.integers(-JITTER, JITTER + 1, size=(3, take), dtype=np.int32)
            rec.X = src.points.X[:take] + col * width + jit[0]
            rec.Y = src.points.Y[:take] + row * height + jit[1]
            rec.Z = src.points.Z[:take] + jit[2]
            rec.gps_time = src.points.gps_time[:take] + copy * TIME_STEP
            writer.write_points(rec)
            written += take
            copy += 1
    print(f"{out}: {written} points, {copy} copies of {source} ({n} points)")


if __name__ == "__main__":
    main()
