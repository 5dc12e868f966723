#!/usr/bin/env python3
"""A pcimg dataset against its source LAS, through software pcimg does not use:
the source read by laspy, each part's full-resolution image read by GDAL's
Python bindings, each band's value GDAL's `stored * scale + offset` (as
`gdal_translate -unscale` gives it). Every source point must be in exactly one
part, its x y z on the LAS grid (a format-2 part keeps the grid's whole numbers:
its x y z then lie within a millionth of a LAS unit of the source's), and every
attribute the parts store equal to the source's, exactly: gps_time bit for
bit, joined from its band and the three whole-number bands beside it
(`gps_time_lo`, `_mid`, `_hi`) as docs/format.md describes, written out again
here in numpy.

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


MASK = (1 << 23) - 1
SIGNLESS = np.int64(0x7FFF_FFFF_FFFF_FFFF)


def ordered(bits):
    """A double's bits (int64) as an integer ordered like the doubles, and
    back (the map is its own inverse)."""
    return bits ^ ((bits >> 63) & SIGNLESS)


def ulp(x):
    a = np.abs(x)
    return np.nextafter(a, np.array(np.inf, dtype=a.dtype)) - a


def join_time(offset, v, lo, mid, hi):
    """GPS time, bit for bit, from the gps_time band's offset and Float32 `v`
    and its three whole-number bands (docs/format.md)."""
    with np.errstate(over="ignore", invalid="ignore"):
        t = offset + v.astype(np.float64)
        reach = (0.5 * ulp(v).astype(np.float64) + ulp(np.maximum(abs(offset), np.abs(t)) * 2.0)) / ulp(t) + 2.0
        plain = np.isfinite(t) & np.isfinite(v) & (t != 0.0) & (reach < 2.0**22)
        # ceil(log2(reach)) + 1, rounded up to 8, 16 or 23.
        exponent = np.frexp(np.where(plain, reach, 1.0))[1].astype(np.int64)
        exact_power = np.where(plain, np.frexp(reach)[0] == 0.5, False)
        fewest = exponent - exact_power + 1
        bits = np.where(plain & (fewest <= 8), 8, np.where(plain & (fewest <= 16), 16, 23)).astype(np.int64)
        mask = (np.int64(1) << bits) - 1
        k = ordered(t.view(np.int64))
        k[np.isnan(t)] = 0
        d = lo.astype(np.int64) - (k & mask)
        half = np.int64(1) << (bits - 1)
        d = np.where(d >= half, d - (half << 1), d)
        d = np.where(d < -half, d + (half << 1), d)
        q = (hi.astype(np.int64) << 23) + mid.astype(np.int64)
        return ordered(k + d + (q << bits)).view(np.float64)


def main():
    source, dataset = sys.argv[1], sys.argv[2]
    src = laspy.read(source)
    parts = sorted(glob.glob(os.path.join(dataset, "*.tif")))
    if len(parts) < 2:
        fail(f"{dataset}: {len(parts)} part(s); the check wants a conversion in several")
    values, raw_time, time_offsets = {}, [], []
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
            if name == "gps_time":
                # The Float32s as stored, and the part's offset for each.
                raw_time.append(r)
                time_offsets.append(np.full(len(r), offset))
        lattice[0] += int(image.GetMetadataItem("PCIMG_FORMAT") == "2" and "LATTICE" in (image.GetMetadata() or {}))
    values = {k: np.concatenate(v) for k, v in values.items()}
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

    exact = ("gps_time_lo", "gps_time_mid", "gps_time_hi")
    if "gps_time" in values:
        if not all(e in values for e in exact):
            fail("the parts store gps_time without the bands that make it exact")
        values["gps_time"] = join_time(
            np.concatenate(time_offsets), np.concatenate(raw_time), *(values[e] for e in exact)
        )
    names = [k for k in values if k not in ("x", "y", "z", *exact)]
    if not names:
        fail("the parts store no attribute")
    for name in names:
        mine = values[name][o]
        source_values = las_band(src, name)[t]
        if name == "gps_time":
            bad = np.nonzero(mine.view(np.int64) != source_values.view(np.int64))[0]
        else:
            bad = np.nonzero(mine != source_values)[0]
        if len(bad):
            k = bad[0]
            fail(f"{name}: {len(bad)} points differ, the first {mine[k]!r} vs {source_values[k]!r}")
    print(f"{len(parts)} parts ({lattice[0]} on the LAS lattice), {n} points, x y z and {len(names)} attributes ({' '.join(names)}): all equal")


if __name__ == "__main__":
    main()
