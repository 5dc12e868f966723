"""The pcimg Python package against laspy reading the original LAZ.

Run by `cargo test --test python`, which converts fixtures/autzen_trim.laz with
the pcimg binary, serves it with `python3 -m http.server`, and passes:
PCIMG_TEST_LAZ (the source), PCIMG_TEST_DATASET (the converted dataset) and
PCIMG_TEST_URL (the same dataset over HTTP).
"""

import os
import threading

import laspy
import numpy as np
import pytest

import pcimg
from las_fields import EXACT, given

LAZ, DATASET = given("PCIMG_TEST_LAZ", "PCIMG_TEST_DATASET")
URL = os.environ.get("PCIMG_TEST_URL")


@pytest.fixture(scope="module")
def las():
    return laspy.read(LAZ)


@pytest.fixture(scope="module")
def ds():
    return pcimg.open(DATASET)


def lattice(las, pts):
    """pcimg's coordinates as the LAS file's integers (X, Y, Z)."""
    h = las.header
    return [np.round((pts[a] - h.offsets[i]) / h.scales[i]).astype(np.int64) for i, a in enumerate("XYZ")]


def ordered_las(las, mask=None):
    """laspy's points (where `mask`) in a canonical order, as a dict."""
    cols = {a: np.asarray(las.points[a], dtype=np.int64) for a in "XYZ"}
    for ours, theirs in EXACT.items():
        cols[ours] = np.asarray(las.points[theirs]).astype(np.int64)
    cols["GpsTime"] = np.asarray(las.points["gps_time"], dtype=np.float64)
    # PDAL's ClassFlags: synthetic, key-point, withheld (and overlap) as bits.
    cols["ClassFlags"] = sum(
        np.asarray(las.points[d]).astype(np.int64) << k for k, d in enumerate(["synthetic", "key_point", "withheld"])
    )
    if mask is not None:
        cols = {k: v[mask] for k, v in cols.items()}
    order = np.lexsort([cols[k] for k in ["GpsTime", "Intensity", "Z", "Y", "X"]])
    return {k: v[order] for k, v in cols.items()}


def ordered_ours(las, pts):
    cols = dict(zip("XYZ", lattice(las, pts)))
    for k in [*EXACT, "ClassFlags"]:
        cols[k] = pts[k].astype(np.int64)
    cols["GpsTime"] = pts["GpsTime"]
    order = np.lexsort([cols[k] for k in ["GpsTime", "Intensity", "Z", "Y", "X"]])
    return {k: v[order] for k, v in cols.items()}


def assert_same_points(las, pts, mask=None):
    want = ordered_las(las, mask)
    got = ordered_ours(las, pts)
    assert len(got["X"]) == len(want["X"])
    for k in ["X", "Y", "Z", *EXACT, "ClassFlags"]:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    # GPS time bit for bit (a part keeps it exactly: docs/format.md).
    np.testing.assert_array_equal(got["GpsTime"].view(np.int64), want["GpsTime"].view(np.int64))


def test_info_gives_the_facts_as_plain_values(ds, las):
    info = ds.info()
    assert info["points"] == len(las.points)
    assert info["parts"] >= 1
    assert info["levels"][0] == len(las.points)
    assert all(a > b for a, b in zip(info["levels"], info["levels"][1:]))
    codes, counts = np.unique(np.asarray(las.classification), return_counts=True)
    assert info["classes"] == {int(c): int(n) for c, n in zip(codes, counts)}
    h = las.header
    np.testing.assert_allclose(info["bounds"][:3], h.mins, atol=1e-6)
    np.testing.assert_allclose(info["bounds"][3:], h.maxs, atol=1e-6)
    assert info["fields"]["X"] == ("x", "float64")
    assert info["fields"]["Intensity"] == ("intensity", "uint16")
    assert info["fields"]["Classification"] == ("classification", "uint8")
    # GPS time is one field; the bands that make it exact are not fields.
    assert info["fields"]["GpsTime"] == ("gps_time", "float64")
    assert not [b for b, _ in info["fields"].values() if b.startswith("gps_time_")]
    assert info["fields"]["PointSourceId"] == ("point_source_id", "uint16")
    assert info["fields"]["ScanDirectionFlag"] == ("las_flags", "uint8")
    assert info["fields"]["ScanChannel"] == ("las_flags", "uint8")
    assert isinstance(info["crs"], (str, type(None)))


def test_read_gives_every_point_of_the_laz(ds, las):
    pts = ds.read()
    assert pts.dtype["X"] == np.float64
    assert pts.dtype["Intensity"] == np.uint16
    assert pts.dtype["ReturnNumber"] == np.uint8
    assert pts.dtype["Red"] == np.uint16
    assert not [n for n in pts.dtype.names if n.startswith("gps_time_")]
    assert_same_points(las, pts)


def test_a_box_and_classes_give_the_laz_filtered_the_same_way(ds, las):
    x, y, z = (np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))
    # A box around the middle, its faces through points' own coordinates.
    cx, cy = np.median(x), np.median(y)
    inside_2d = (x >= cx - 60.0) & (x <= cx + 60.0) & (y >= cy - 40.0) & (y <= cy + 40.0)
    zlo = np.percentile(z[inside_2d], 10, method="nearest")
    zhi = np.percentile(z[inside_2d], 90, method="nearest")
    box = (cx - 60.0, cy - 40.0, zlo, cx + 60.0, cy + 40.0, zhi)
    inside = inside_2d & (z >= zlo) & (z <= zhi)
    assert 0 < inside.sum() < len(x) // 4
    assert ((z == zlo) & inside_2d).any(), "no point on the box's floor"
    assert_same_points(las, ds.read(clip=box), inside)

    got = ds.read(bounds=(box[0], box[1], box[3], box[4]), classes=[2])
    assert_same_points(las, got, inside_2d & (np.asarray(las.classification) == 2))
    assert 0 < len(got) < inside_2d.sum()

    # Both: their intersection.
    both = ds.read(bounds=(box[0], box[1], box[3], box[4]), clip=(cx, cy, zlo, cx + 500, cy + 500, 1e9))
    want = inside_2d & (x >= cx) & (y >= cy) & (z >= zlo)
    assert_same_points(las, both, want)

    # A box beside the data: nothing, with every field.
    none = ds.read(bounds=(0, 0, 1, 1))
    assert len(none) == 0 and none.dtype.names == ds.read(level=3).dtype.names


def test_columns_are_chosen_by_field_or_band_name_in_the_order_given(ds):
    pts = ds.read(columns=["Classification", "x", "Y", "gps_time"])
    assert pts.dtype.names == ("Classification", "X", "Y", "GpsTime")
    full = ds.read()
    np.testing.assert_array_equal(np.sort(pts["X"]), np.sort(full["X"]))
    with pytest.raises(ValueError, match="no field 'Reflectance'; it has X, Y, Z"):
        ds.read(columns=["X", "Reflectance"])
    with pytest.raises(ValueError, match="asked twice"):
        ds.read(columns=["X", "x"])
    # A band of packed flags gives all of its fields.
    flags = ds.read(columns=["las_flags"])
    assert flags.dtype.names == ("ClassFlags", "ScanChannel", "ScanDirectionFlag", "EdgeOfFlightLine")


def test_chunks_give_the_same_points_as_one_read(ds):
    whole = ds.read(level=1)
    parts = list(ds.chunks(level=1))
    assert len(parts) >= 1
    joined = np.concatenate(parts)
    assert joined.dtype == whole.dtype
    np.testing.assert_array_equal(np.sort(joined, order=["X", "Y", "Z"]), np.sort(whole, order=["X", "Y", "Z"]))


def test_a_coarser_level_is_an_even_sample_of_the_points(ds):
    info = ds.info()
    full = ds.read(columns=["X", "Y", "Z"])
    for level in range(1, len(info["levels"])):
        sample = ds.read(level=level, columns=["X", "Y", "Z"])
        assert len(sample) == info["levels"][level]
        # Every sampled point is a point of the dataset.
        key = lambda a: a.view(np.dtype((np.void, a.dtype.itemsize)))  # noqa: E731
        assert np.isin(key(sample), key(full)).all()
        # Spread like the whole: the sample's centre within 5% of the extent.
        for a in "XY":
            extent = full[a].max() - full[a].min()
            assert abs(sample[a].mean() - full[a].mean()) < 0.05 * extent
    # Past the coarsest level: the coarsest.
    deepest = len(info["levels"]) - 1
    assert len(ds.read(level=deepest + 5)) == info["levels"][deepest]


def test_bad_arguments_and_missing_data_say_what_is_wrong(ds, tmp_path):
    missing = tmp_path / "nowhere.pcimg"
    with pytest.raises(OSError, match="nowhere.pcimg"):
        pcimg.open(missing)
    with pytest.raises(ValueError, match="bounds must be 4 finite numbers"):
        ds.read(bounds=(0, 0, 1))
    with pytest.raises(ValueError, match="minimum .* lies above the maximum"):
        ds.read(clip=(1, 0, 0, 0, 1, 1))
    with pytest.raises(ValueError, match="class 300 is not a class"):
        ds.read(classes=[300])
    with pytest.raises(ValueError, match="timeout"):
        pcimg.open(DATASET, timeout=0)


def test_reading_releases_the_gil(ds):
    # A Python thread keeps counting while the main thread reads: with the GIL
    # held through the read it could not run between the read's start and end.
    ticks = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(1)

    for _ in range(3):
        t = threading.Thread(target=count)
        t.start()
        while not ticks:
            pass
        before = len(ticks)
        ds.read()
        during = len(ticks) - before
        stop.set()
        t.join()
        stop.clear()
        ticks.clear()
        if during > 1000:
            return
    pytest.fail(f"a Python thread ran only {during} steps while the dataset was read")


@pytest.mark.skipif(not URL, reason="no HTTP server (run through cargo test)")
def test_a_dataset_over_http_reads_the_same_and_a_box_fetches_less(ds, las):
    remote = pcimg.open(URL)
    assert remote.info()["points"] == ds.info()["points"]
    r0, b0 = pcimg.network_stats()
    whole = remote.read()
    r1, b1 = pcimg.network_stats()
    assert r1 > r0 and b1 > b0
    assert_same_points(las, whole)

    remote = pcimg.open(URL)  # (a new dataset: nothing read yet)
    info = remote.info()
    x0, y0, _, x1, y1, _ = info["bounds"]
    box = (x0, y0, x0 + (x1 - x0) / 8, y0 + (y1 - y0) / 8)
    r1, b1 = pcimg.network_stats()
    some = remote.read(bounds=box)
    r2, b2 = pcimg.network_stats()
    local = ds.read(bounds=box)
    assert len(some) > 0
    order = ["X", "Y", "Z", "GpsTime"]
    np.testing.assert_array_equal(np.sort(some, order=order), np.sort(local, order=order))
    assert b2 - b1 < b1 - b0, f"a box fetched {b2 - b1} bytes, the whole {b1 - b0}"


def test_arrow_stream_carries_the_same_points(ds):
    pa = pytest.importorskip("pyarrow") if os.environ.get("CI") != "true" else __import__("pyarrow")
    table = pa.RecordBatchReader.from_stream(ds).read_all()
    whole = ds.read()
    assert table.num_rows == len(whole)
    assert table.column_names == list(whole.dtype.names)
    assert table.schema.field("Intensity").type == pa.uint16()
    assert table.schema.field("Classification").type == pa.uint8()
    assert table.schema.field("GpsTime").type == pa.float64()
    # The same points in the same order, field by field, bit for bit.
    for name in whole.dtype.names:
        np.testing.assert_array_equal(table.column(name).to_numpy(), whole[name], err_msg=name)


def test_arrow_reader_follows_the_selection(ds):
    pa = pytest.importorskip("pyarrow") if os.environ.get("CI") != "true" else __import__("pyarrow")
    x0, y0, _, x1, y1, _ = ds.info()["bounds"]
    args = dict(bounds=(x0, y0, (x0 + x1) / 2, (y0 + y1) / 2), classes=[2], columns=["X", "Z", "Intensity"])
    reader = ds.arrow(**args)
    assert isinstance(reader, pa.RecordBatchReader)
    table = reader.read_all()
    want = ds.read(**args)
    assert 0 < table.num_rows == len(want)
    assert table.column_names == ["X", "Z", "Intensity"]
    for name in want.dtype.names:
        np.testing.assert_array_equal(table.column(name).to_numpy(), want[name], err_msg=name)


def test_the_arrow_capsule_needs_no_pyarrow(ds):
    # The stream itself comes from the native module (pyo3-arrow): a PyCapsule
    # named as the Arrow C stream interface says, whoever consumes it.
    capsule = ds.__arrow_c_stream__()
    assert type(capsule).__name__ == "PyCapsule"
    import ctypes

    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype = ctypes.c_char_p
    get_name.argtypes = [ctypes.py_object]
    assert get_name(capsule) == b"arrow_array_stream"
