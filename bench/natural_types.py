#!/usr/bin/env python3
# Natural types against Float32 + floating-point predictor for whole-number bands:
# Zstd level 1 (shortest match 7) on each 256x256 tile with data, as pcimg writes
# (Float32, byte planes per row, differenced) and as the band's own integer type
# with horizontal differencing (TIFF predictor 2). Sizes and Zstd's own time.
# x, y, z and gps_time are left out (they keep Float32 either way). Issue 40;
# figures in bench/history/49-2026-11-29-session-38-zstd-limits.md.
#
#   /usr/bin/python3 bench/natural_types.py DATASET.pcimg/part-00000.tif
#
# (Debian's python3 with python3-gdal, numpy and zstandard.)
import sys, time
import numpy as np, zstandard as zs
from osgeo import gdal
path = sys.argv[1]
ds = gdal.Open(path)
T = 256
params = zs.ZstdCompressionParameters.from_level(1, min_match=7)
cz = zs.ZstdCompressor(compression_params=params)
tot = {"f32": [0, 0.0], "nat": [0, 0.0]}
for b in range(1, ds.RasterCount + 1):
    band = ds.GetRasterBand(b)
    name = band.GetDescription()
    if name in ("x", "y", "z", "gps_time"):
        continue
    a = band.ReadAsArray()
    h, w = a.shape
    valid = ~np.isnan(a)
    # The stored whole numbers carry a bias that GDAL shows as the band's offset.
    off = -band.GetOffset() if band.GetOffset() else 0
    iv = np.where(valid, a.astype(np.float64) - off, 0).astype(np.int64)
    lo, hi = iv[valid].min(), iv[valid].max()
    dt = np.uint8 if (lo >= 0 and hi < 256) else (np.uint16 if (lo >= 0 and hi < 65536) else np.int32)
    res = {}
    for kind in ("f32", "nat"):
        size, secs = 0, 0.0
        for ty in range(0, h, T):
            for tx in range(0, w, T):
                if not valid[ty:ty + T, tx:tx + T].any():
                    continue
                if kind == "f32":
                    t = a[ty:ty + T, tx:tx + T].astype(">f4")
                    planes = t.view(np.uint8).reshape(T, T, 4).transpose(0, 2, 1).reshape(T, 4 * T)
                    d = planes.copy(); d[:, 1:] = planes[:, 1:] - planes[:, :-1]
                    raw = d.tobytes()
                else:
                    t = iv[ty:ty + T, tx:tx + T].astype(dt)
                    d = t.copy(); d[:, 1:] = t[:, 1:] - t[:, :-1]
                    raw = d.astype(dt).tobytes()
                s = time.perf_counter(); out = cz.compress(raw); secs += time.perf_counter() - s
                size += len(out)
        res[kind] = (size, secs)
        tot[kind][0] += size; tot[kind][1] += secs
    print(f"{name:18s} {np.dtype(dt).name:7s} f32 {res['f32'][0]:>11,d} B {res['f32'][1]:6.3f} s | natural {res['nat'][0]:>11,d} B {res['nat'][1]:6.3f} s", flush=True)
print(f"total (these bands, level 0) f32 {tot['f32'][0]:,d} B {tot['f32'][1]:.3f} s | natural {tot['nat'][0]:,d} B {tot['nat'][1]:.3f} s")
