#!/usr/bin/env python3
"""A pcimg dataset against its source LAS, through software pcimg does not use:
the source read by laspy, each part's full-resolution image read by GDAL's
Python bindings, each band's value GDAL's `stored * scale + offset` (as
`gdal_translate -unscale` gives it). Every source point must be in exactly one
part, its x y z on the LAS grid (a format-2 part keeps the grid's whole numbers:
its x y z then lie within a millionth of a LAS unit of the source's), and every
attribute the parts store equal to the source's (integers exactly; gps_time to
the float32 precision of the part's band).

    /usr/bin/python3 tests/python/parts_match_las.py SOURCE.las DATASET_DIR

Prints one line of counts; on the first difference prints it and exits 1.
"""
import glob
import os
import sys

import laspy
import numpy as np
from osgeo import gdal

gdal.UseExceptions()


def fail(msg):
    print(f"MISMATCH: {msg}", file=sys.stderr)
    sys.exit(1)


def las_band(src, name):
    """The source's values of pcimg band `name`: a LAS dimension of that name,
    or the scan angle in degrees, or the flags packed as `las_flags` packs them
    (the extended formats' byte 15: synthetic, key-point, withheld, overlap in
    bits 0 to 3, the scanner channel in 4 and 5, scan direction 6, edge 7)."""
    dims = list(src.point_format.dimension_names)
    if name == "scan_angle":
        if "scan_angle_rank" in dims:
            return np.asarray(src.scan_angle_rank, dtype=np.float64)
        return (np.asarray(src.scan_angle, dtype=np.float32) * np.float32(0.006)).astype(np.float64)
    if name == "las_flags":
        bits = [("synthetic", 0), ("key_point", 1), ("withheld", 2), ("overlap", 3),
                ("scanner_channel", 4), ("scan_direction_flag", 6), ("edge_of_flight_line", 7)]
        v = np.zeros(len(src.points), dtype=np.int64)
        for d, shift in bits:
            if d in dims:
                v |= np.asarray(src[d]).astype(np.int64) << shift
        return v.astype(np.float64)
    return np.asarray(src[name], dtype=np.float64)


def main():
    source, dataset = sys.argv[1], sys.argv[2]
    src = laspy.read(source)
    parts = sorted(glob.glob(os.path.join(dataset, "*.tif")))
    if len(parts) < 2:
        fail(f"{dataset}: {len(parts)} part(s); the check wants a conversion in several")
    values, ulps = {}, {}
    lattice = [0]
    for path in parts:
        image = gdal.Open(path)
        bands = {}
        for i in range(1, image.RasterCount + 1):
            band = image.GetRasterBand(i)
            raw = band.ReadAsArray().ravel()
            if raw.dtype != np.float32:
                fail(f"{path}: band {i} is {raw.dtype}, not float32")
            bands[band.GetDescription()] = (raw, band.GetOffset() or 0.0, band.GetScale() or 1.0)
        # Pixels past the last point are nodata (NaN).
        keep = ~np.isnan(bands["x"][0])
        for name, (raw, offset, scale) in bands.items():
            r = raw[keep]
            values.setdefault(name, []).append(r.astype(np.float64) * scale + offset)
            ulps.setdefault(name, []).append(np.spacing(np.abs(r)).astype(np.float64) * abs(scale))
        lattice[0] += int(image.GetMetadataItem("PCIMG_FORMAT") == "2" and "LATTICE" in (image.GetMetadata() or {}))
    values = {k: np.concatenate(v) for k, v in values.items()}
    ulps = {k: np.concatenate(v) for k, v in ulps.items()}
    n = len(values["x"])
    if n != len(src.points):
        fail(f"the parts hold {n} points, the source {len(src.points)}")

    # x y z on the source's grid: within a tenth of a LAS unit, then as integers.
    scales, offsets = src.header.scales, src.header.offsets
    ours, theirs = [], [np.asarray(src.X), np.asarray(src.Y), np.asarray(src.Z)]
    for i, axis in enumerate("xyz"):
        units = (values[axis] - offsets[i]) / scales[i]
        grid = np.rint(units)
        worst = np.max(np.abs(units - grid))
        if worst > 0.1:
            fail(f"{axis} lies {worst:.3f} LAS units off the source's grid")
        if lattice[0] == len(parts) and worst > 1e-6:
            fail(f"{axis} lies {worst:.3g} LAS units off the source's grid in a part on the lattice")
        ours.append(grid.astype(np.int64))
    o = np.lexsort((ours[2], ours[1], ours[0]))
    t = np.lexsort((theirs[2], theirs[1], theirs[0]))
    key = np.stack([ours[0][o], ours[1][o], ours[2][o]])
    if np.any(np.all(key[:, 1:] == key[:, :-1], axis=0)):
        fail("two points share x y z: the check cannot pair them")
    for i, axis in enumerate("xyz"):
        bad = np.nonzero(ours[i][o] != theirs[i][t])[0]
        if len(bad):
            fail(f"{axis}: {len(bad)} points differ, the first {ours[i][o][bad[0]]} vs {theirs[i][t][bad[0]]}")

    names = [k for k in values if k not in ("x", "y", "z")]
    if not names:
        fail("the parts store no attribute")
    for name in names:
        mine = values[name][o]
        source_values = las_band(src, name)[t]
        if name == "gps_time":
            # float32 relative to the band's offset: within one unit in the last place.
            tol = ulps[name][o]
        else:
            tol = np.zeros(n)
        diff = np.abs(mine - source_values)
        bad = np.nonzero(diff > tol)[0]
        if len(bad):
            k = bad[0]
            fail(f"{name}: {len(bad)} points differ, the first {mine[k]!r} vs {source_values[k]!r}")
    print(f"{len(parts)} parts ({lattice[0]} on the LAS lattice), {n} points, x y z and {len(names)} attributes ({' '.join(names)}): all equal")


if __name__ == "__main__":
    main()
