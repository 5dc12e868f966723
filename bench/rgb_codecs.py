#!/usr/bin/env python3
"""What other codecs would make of a part's colour (issue 40's colour-only target).

    /usr/bin/python3 bench/rgb_codecs.py PART.tif NPOINTS

Reads the red, green and blue bands of a pcimg part's level 0 through GDAL
(unscaled: the 8-bit values, NaN past the last point as 0), writes them again
with GDAL as one 3-band Byte GeoTIFF of the part's size in 256 x 256 tiles (the
points stay in the tiles and rows pcimg stored them in) as WEBP lossless and as
ZSTD 9 with the horizontal predictor, pixel- and band-interleaved, checks each
reads back exactly, and prints its bytes against the part's own level-0 RGB
tiles (their TIFF byte counts). Needs GDAL's Python bindings and numpy (Debian:
python3-gdal). Writes /tmp/rgb-codecs.tif.
"""
import os, sys, time
import numpy as np
from osgeo import gdal
gdal.UseExceptions()
gdal.PushErrorHandler("CPLQuietErrorHandler")
path, n = sys.argv[1], int(sys.argv[2])
ds = gdal.Open(path)
names = [ds.GetRasterBand(b).GetDescription() for b in range(1, ds.RasterCount + 1)]
idx = [names.index(c) + 1 for c in ("red", "green", "blue")]
ours = 0
for b in idx:
    band = ds.GetRasterBand(b)
    bx, by = band.GetBlockSize()
    for ty in range((ds.RasterYSize + by - 1) // by):
        for tx in range((ds.RasterXSize + bx - 1) // bx):
            v = band.GetMetadataItem(f"BLOCK_SIZE_{tx}_{ty}", "TIFF")
            ours += int(v) if v else 0
arrs = []
for b in idx:
    band = ds.GetRasterBand(b)
    a = band.ReadAsArray().astype(np.float64)
    a = a * (band.GetScale() or 1.0) + (band.GetOffset() or 0.0)
    a[np.isnan(a)] = 0
    arrs.append(a.astype(np.uint8))
mem = gdal.GetDriverByName("MEM").Create("", ds.RasterXSize, ds.RasterYSize, 3, gdal.GDT_Byte)
for k, a in enumerate(arrs):
    mem.GetRasterBand(k + 1).WriteArray(a)
print(f"{os.path.basename(path)}: {n} points; pcimg's RGB tiles (level 0): {ours} bytes, {ours / n:.3f} B/pt")
for name, opts in [
    ("WEBP lossless, pixel-interleaved", ["COMPRESS=WEBP", "WEBP_LOSSLESS=YES"]),
    ("ZSTD 9 + PREDICTOR=2, pixel-interleaved", ["COMPRESS=ZSTD", "ZSTD_LEVEL=9", "PREDICTOR=2"]),
    ("ZSTD 9 + PREDICTOR=2, band-separate", ["COMPRESS=ZSTD", "ZSTD_LEVEL=9", "PREDICTOR=2", "INTERLEAVE=BAND"]),
]:
    out = "/tmp/rgb-codecs.tif"
    t = time.time()
    gdal.GetDriverByName("GTiff").CreateCopy(out, mem, options=["TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=256"] + opts)
    s = time.time() - t
    back = gdal.Open(out)
    assert all((back.GetRasterBand(k + 1).ReadAsArray() == arrs[k]).all() for k in range(3)), name
    size = os.path.getsize(out)
    print(f"  {name}: {size} bytes, {size / n:.3f} B/pt ({size / ours:.2f}x pcimg's), {s:.1f} s, read back exactly")
