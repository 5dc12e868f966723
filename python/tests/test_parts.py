"""A dataset of many parts with an overview above them, read as one, against
laspy reading the LAS it was converted from.

Run by `cargo test --test python`, which passes PCIMG_TEST_PARTS_LAS (a
synthetic scan) and PCIMG_TEST_PARTS_DATASET (it converted under a 1 MiB
budget: several parts).
"""

import laspy
import numpy as np

import pcimg
from las_fields import EXACT, given

LAS, DATASET = given("PCIMG_TEST_PARTS_LAS", "PCIMG_TEST_PARTS_DATASET")


def test_every_part_is_read_once_and_the_overview_never():
    las = laspy.read(LAS)
    ds = pcimg.open(DATASET)
    info = ds.info()
    assert info["parts"] > 1, info
    assert info["points"] == len(las.points)
    pts = ds.read()
    assert len(pts) == len(las.points)
    h = las.header
    ours = [np.round((pts[a] - h.offsets[i]) / h.scales[i]).astype(np.int64) for i, a in enumerate("XYZ")]
    theirs = [np.asarray(las.points[a], dtype=np.int64) for a in "XYZ"]
    fields = [f for f in EXACT if f in pts.dtype.names and EXACT[f] in las.point_format.dimension_names]
    assert fields, pts.dtype.names
    ours += [pts[f].astype(np.int64) for f in fields]
    theirs += [np.asarray(las.points[EXACT[f]], dtype=np.int64) for f in fields]
    a = np.lexsort(ours[::-1])
    b = np.lexsort(theirs[::-1])
    for k, (o, t) in enumerate(zip(ours, theirs)):
        np.testing.assert_array_equal(o[a], t[b], err_msg=(["X", "Y", "Z"] + fields)[k])


def test_a_box_across_parts_reads_from_each_part_it_reaches():
    las = laspy.read(LAS)
    ds = pcimg.open(DATASET)
    x0, y0, _, x1, y1, _ = ds.info()["bounds"]
    box = (x0 + (x1 - x0) * 0.3, y0 + (y1 - y0) * 0.3, x0 + (x1 - x0) * 0.7, y0 + (y1 - y0) * 0.7)
    x, y = np.asarray(las.x), np.asarray(las.y)
    inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
    got = ds.read(bounds=box, columns=["X", "Y"])
    assert len(got) == inside.sum() > 0
    # (These parts record no lattice: a Float32 from the part's origin, 200 m
    # away at most, is within 2e-5 m.)
    np.testing.assert_allclose(np.sort(got["X"]), np.sort(x[inside]), rtol=0, atol=2e-5)
