#!/usr/bin/env python3
"""Write an NX x NY grid of synthetic LAS 1.4 tiles (point format 7) for benchmarks.

Each tile is 100 m x 100 m and holds POINTS points drawn uniformly at random in it.
Terrain is one smooth height field over the whole survey (sines + gaussian hills,
a function of world x/y only), so neighbouring tiles join seamlessly.  Per tile:
  - ground (class 2) on the height field,
  - a few flat-roofed box buildings (class 6, roofs only as seen from the air),
  - round tree crowns (class 5): a crown point is vegetation (return 1 of 2) with
    probability 0.7, otherwise the ground below it (return 2 of 2).
RGB (16-bit) follows class and height; intensity follows class; gps_time runs
along the survey.  Scale 0.01 m, offset = survey origin, CRS WGS 84 / UTM 10N (WKT).
Deterministic: tile (i, j) depends only on SEED, i and j (not on NX/NY).

Usage: make_survey.py [--nx N] [--ny N] [--points N] [--out DIR] [--seed N]
       (defaults from env NX, NY, POINTS, OUT, SEED: 11, 11, 100000, ./survey/las, 1)
Writes DIR/tile-XX-YY.las (XX = column from west, YY = row from south).
"""
import argparse, os
import laspy, numpy as np

TILE = 100.0                          # tile edge, metres
X0, Y0 = 500000.0, 5000000.0          # survey origin (south-west corner), UTM metres
WKT = ('PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",'
       '6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM['
       '"Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY['
       '"EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER['
       '"latitude_of_origin",0],PARAMETER["central_meridian",-123],PARAMETER["scale_factor",'
       '0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1,'
       'AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","32610"]]')


def ground(x, y, hills):
    """Smooth height (m) at survey-relative x, y: base + sines + gaussian hills."""
    z = 120.0 + 6.0 * np.sin(x / 170.0) * np.cos(y / 230.0) + 2.5 * np.sin((x + 2 * y) / 61.0)
    for cx, cy, a, s in hills:
        z += a * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return z


def make_tile(i, j, n, seed, hills):
    rng = np.random.default_rng([seed, i, j])
    x = i * TILE + rng.uniform(0, TILE, n)           # survey-relative coordinates
    y = j * TILE + rng.uniform(0, TILE, n)
    z = ground(x, y, hills)
    cls = np.full(n, 2, np.uint8)
    ret = np.ones(n, np.uint8); nret = np.ones(n, np.uint8)

    # trees: round crowns, paraboloid canopy 4-20 m above ground
    for _ in range(rng.integers(5, 25)):
        cx, cy = i * TILE + rng.uniform(0, TILE), j * TILE + rng.uniform(0, TILE)
        r, h = rng.uniform(2, 7), rng.uniform(4, 20)
        d2 = ((x - cx) ** 2 + (y - cy) ** 2) / (r * r)
        inside = d2 < 1
        canopy = inside & (rng.random(n) < 0.7)
        z[canopy] += h * (1 - 0.5 * d2[canopy]) + rng.normal(0, 0.4, canopy.sum()).clip(-1, 1)
        cls[canopy] = 5
        nret[inside] = 2
        ret[inside] = np.where(canopy[inside], 1, 2)

    # buildings: flat-roofed boxes fully inside the tile (override trees)
    for _ in range(rng.integers(0, 4)):
        w, d = rng.uniform(8, 30, 2)
        bx, by = i * TILE + rng.uniform(2, TILE - 2 - w), j * TILE + rng.uniform(2, TILE - 2 - d)
        roof = ground(bx + w / 2, by + d / 2, hills) + rng.uniform(4, 15)
        m = (x >= bx) & (x < bx + w) & (y >= by) & (y < by + d)
        z[m], cls[m], ret[m], nret[m] = roof, 6, 1, 1

    # colours (8-bit, scaled to 16-bit below) and intensity by class
    t = np.clip((z - 100.0) / 50.0, 0, 1)             # height tint
    rgb = np.empty((n, 3))
    g, v, b = cls == 2, cls == 5, cls == 6
    rgb[g] = np.stack([110 + 60 * t[g], 140 - 20 * t[g], 70 + 20 * t[g]], 1)
    rgb[v] = np.stack([40 + 30 * t[v], 100 + 60 * t[v], 40 + 10 * t[v]], 1)
    rgb[b] = np.stack([150 + 40 * t[b], 80 + 40 * t[b], 70 + 40 * t[b]], 1)
    rgb = np.clip(rgb + rng.normal(0, 8, (n, 3)), 0, 255).astype(np.uint16) * 257
    base = np.select([g, v, b], [900, 400, 1600])
    intensity = np.clip(base + rng.normal(0, 150, n), 0, 65535).astype(np.uint16)

    # gps time: one flight line per tile row, sweeping west->east at ~50 m/s
    gps = 3.0e8 + j * 600.0 + x / 50.0 + rng.uniform(0, 0.01, n)

    hdr = laspy.LasHeader(point_format=7, version="1.4")
    hdr.scales = np.array([0.01, 0.01, 0.01])
    hdr.offsets = np.array([X0, Y0, 0.0])
    hdr.global_encoding.wkt = True
    hdr.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    hdr.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(WKT))
    hdr.system_identifier, hdr.generating_software = "SYNTHETIC", "pcimg make_survey.py"
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x + X0, y + Y0, z
    las.intensity, las.classification, las.gps_time = intensity, cls, gps
    las.return_number, las.number_of_returns = ret, nret
    las.red, las.green, las.blue = rgb.T
    return las


def main():
    env = os.environ.get
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--nx", type=int, default=int(env("NX", 11)))
    p.add_argument("--ny", type=int, default=int(env("NY", 11)))
    p.add_argument("--points", type=int, default=int(env("POINTS", 100000)))
    p.add_argument("--out", default=env("OUT", "survey/las"))
    p.add_argument("--seed", type=int, default=int(env("SEED", 1)))
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    # hills in a fixed 1.1 km square, so terrain does not depend on NX/NY
    hr = np.random.default_rng([a.seed, 999])
    hills = [(*hr.uniform(0, 1100, 2), hr.uniform(-15, 30), hr.uniform(80, 250)) for _ in range(8)]
    for j in range(a.ny):
        for i in range(a.nx):
            make_tile(i, j, a.points, a.seed, hills).write(os.path.join(a.out, f"tile-{i:02d}-{j:02d}.las"))
    print(f"wrote {a.nx * a.ny} tiles x {a.points} points to {a.out}")


if __name__ == "__main__":
    main()
