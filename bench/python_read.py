"""One timed read for bench/python.sh: `python_read.py WHAT PATH [BOX]`.

WHAT is `pcimg` (pcimg.open(PATH).read(), or with bounds=BOX),
`pcimg-arrow` (the dataset's Arrow stream read whole by pyarrow), `laspy`
(laspy.read(PATH): LAZ through lazrs) or `laspy-las`. Prints seconds and
points on one line.
"""

import sys
import time

what, path = sys.argv[1], sys.argv[2]
box = [float(v) for v in sys.argv[3].split(",")] if len(sys.argv) > 3 else None
t0 = time.perf_counter()
if what == "pcimg":
    import pcimg

    pts = pcimg.open(path).read(bounds=box)
    n = len(pts)
elif what == "pcimg-arrow":
    import pcimg
    import pyarrow as pa

    n = pa.RecordBatchReader.from_stream(pcimg.open(path)).read_all().num_rows
else:
    import laspy

    las = laspy.read(path)
    n = len(las.points)
    # (laspy's record is packed; what users then take are its scaled arrays)
    _ = las.x, las.y, las.z
t1 = time.perf_counter()
print(f"{t1 - t0:.3f} {n}")
