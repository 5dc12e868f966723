"""Read pcimg point-cloud datasets into numpy arrays.

A dataset is a ``.tif`` part, a directory of parts, or the URL of one
(``s3://bucket/prefix``, ``https://host/path``), as ``pcimg convert`` wrote it::

    import pcimg

    ds = pcimg.open("autzen.pcimg")
    print(ds.info()["points"], ds.info()["fields"])
    pts = ds.read(bounds=(637000, 851000, 637500, 851500), classes=[2])
    print(pts["X"].mean(), pts["Classification"][:10])

    for chunk in ds.chunks(level=2):   # larger than memory: a batch at a time
        ...

Points come back as a numpy structured array whose fields are named as PDAL
and laspy name them (``X``, ``Y``, ``Z`` as float64, ``Intensity``,
``ReturnNumber``, ``NumberOfReturns``, ``Classification``, ``GpsTime``,
``Red``, ``Green``, ``Blue``, ``Infrared``; other bands under their own names
as float64). Reading releases the GIL and runs on all cores; only the tiles the
selection reaches are read, locally or fetched.
"""

import numpy as np

from . import _pcimg

__all__ = ["open", "Dataset", "network_stats"]


def open(location, timeout=30.0):
    """Opens a dataset: a path (str or os.PathLike) or a URL.

    Remote requests are retried for up to ``timeout`` seconds before they
    fail. Raises ``OSError`` naming the file or URL when it cannot be opened.
    """
    return Dataset(_pcimg.open(str(location), float(timeout)))


def network_stats():
    """Requests made to object storage and bytes received so far, by every
    dataset this process opened: ``(requests, bytes)``."""
    return _pcimg.network_stats()


def _dtype(fields):
    return np.dtype([(name, np.dtype(kind)) for name, _band, kind in fields])


def _records(plan, batch=None):
    """The plan's points (or batch `batch`'s) written by the native module
    straight into a structured array."""
    dtype = _dtype(plan.fields())
    offsets = [dtype.fields[name][1] for name in dtype.names]
    return plan.records(dtype, offsets, batch)


class Dataset:
    """An opened dataset (``pcimg.open``)."""

    def __init__(self, native):
        self._native = native

    def __repr__(self):
        return repr(self._native)

    def info(self):
        """The dataset's facts as plain Python values: ``location``,
        ``parts``, ``points``, ``levels`` (points in each level, finest
        first), ``fields`` (name -> (band, numpy type)), ``bounds``
        ``(minx, miny, minz, maxx, maxy, maxz)``, ``crs`` (WKT or
        ``EPSG:n``, or None) and ``classes`` (class code -> points, every
        point's; None when the parts do not record them)."""
        return self._native.info()

    def _plan(self, level, bounds, clip, classes, columns):
        if columns is not None and isinstance(columns, str):
            columns = [columns]
        return self._native.plan(
            int(level),
            None if bounds is None else [float(v) for v in bounds],
            None if clip is None else [float(v) for v in clip],
            None if classes is None else [int(c) for c in classes],
            None if columns is None else [str(c) for c in columns],
        )

    def read(self, level=0, bounds=None, clip=None, classes=None, columns=None):
        """The points of ``level`` (0: every point; each coarser level is an
        even sample of about a quarter as many), in ``bounds``
        ``(minx, miny, maxx, maxy)`` and ``clip``
        ``(minx, miny, minz, maxx, maxy, maxz)`` (both inclusive), of
        ``classes`` (codes), with ``columns`` (field or band names; every
        field when None), as a numpy structured array."""
        return _records(self._plan(level, bounds, clip, classes, columns))

    def chunks(self, level=0, bounds=None, clip=None, classes=None, columns=None):
        """As ``read``, a batch of tiles at a time (at most 4 M points each):
        an iterator of structured arrays, for data larger than memory."""
        plan = self._plan(level, bounds, clip, classes, columns)
        for i in range(plan.batches()):
            yield _records(plan, i)

    def arrow(self, level=0, bounds=None, clip=None, classes=None, columns=None):
        """As ``chunks``, as an Arrow stream: a ``pyarrow.RecordBatchReader``
        where pyarrow is installed, else an object with ``__arrow_c_stream__``
        (the Arrow PyCapsule interface) that polars, DuckDB, pandas and any
        other Arrow consumer take. A record batch per batch of tiles, each
        read when the consumer asks for it; the columns are ``read``'s
        fields in Arrow's types (float64, uint8, uint16)."""
        stream = self._plan(level, bounds, clip, classes, columns).arrow()
        try:
            import pyarrow as pa
        except ImportError:
            return stream
        return pa.RecordBatchReader.from_stream(stream)

    def __arrow_c_stream__(self, requested_schema=None):
        """The Arrow PyCapsule stream of every point (pandas, polars, DuckDB
        take it), made by the native module: no pyarrow needed."""
        stream = self._plan(0, None, None, None, None).arrow()
        return stream.__arrow_c_stream__(requested_schema)
