//! The native half of the `pcimg` Python package (`pcimg._pcimg`): a dataset
//! opened through the store crate alone (no renderer, no terminal), its facts as
//! plain Python values, and its points written straight into a numpy structured
//! array (`pcimg/__init__.py` gives its dtype: one field per [`Field`]).
//!
//! Reading goes through the store's query path (`pcimg_store::query`), the one
//! `pcimg export` uses: only the tiles a selection reaches are read (locally not
//! touched, remotely not fetched), batches of at most 4 M points of one part,
//! read in parallel on rayon's threads with the GIL released. Remote datasets
//! (`s3://`, `http(s)://`) come through the same byte source as the binary's.
//!
//! Fields are named as PDAL and laspy's point records name them (`X`, `Y`, `Z`,
//! `Intensity`, `ReturnNumber`, `Classification`, `GpsTime`, `Red`, ...):
//! coordinates as float64 (on the source's lattice where the parts keep one),
//! LAS's whole-number fields in LAS's own integer types where every part's
//! recorded range fits them, anything else as float64.

use arrow_array::{
    ArrayRef, Float64Array, RecordBatch, RecordBatchReader, UInt8Array, UInt16Array,
};
use arrow_buffer::{ArrowNativeType, ScalarBuffer};
use arrow_schema::{ArrowError, DataType, Field as ArrowField, Schema, SchemaRef};
use pcimg_core::points::Bounds;
use pcimg_core::time;
use pcimg_store::query::{self, Plan, Selection};
use pcimg_store::{Dataset, OpenOptions, StoreError};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use pyo3_arrow::PyRecordBatchReader;
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// A store error as Python's `OSError`, its message naming the file or URL.
fn store_err(e: StoreError) -> PyErr {
    PyOSError::new_err(e.to_string())
}

/// A field's numpy type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    U8,
    U16,
    F64,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::U8 => "uint8",
            Kind::U16 => "uint16",
            Kind::F64 => "float64",
        }
    }

    fn max(self) -> f64 {
        match self {
            Kind::U8 => u8::MAX as f64,
            Kind::U16 => u16::MAX as f64,
            Kind::F64 => f64::INFINITY,
        }
    }
}

/// PDAL's (and laspy's point record's) name of band `band`, and the LAS type
/// of its values; other bands keep their names, as float64.
fn las_field(band: &str) -> (&str, Kind) {
    match band {
        "x" => ("X", Kind::F64),
        "y" => ("Y", Kind::F64),
        "z" => ("Z", Kind::F64),
        "intensity" => ("Intensity", Kind::U16),
        "return_number" => ("ReturnNumber", Kind::U8),
        "number_of_returns" => ("NumberOfReturns", Kind::U8),
        "classification" => ("Classification", Kind::U8),
        "gps_time" => ("GpsTime", Kind::F64),
        "red" => ("Red", Kind::U16),
        "green" => ("Green", Kind::U16),
        "blue" => ("Blue", Kind::U16),
        "nir" => ("Infrared", Kind::U16),
        "scan_angle" => ("ScanAngleRank", Kind::F64),
        "user_data" => ("UserData", Kind::U8),
        "point_source_id" => ("PointSourceId", Kind::U16),
        other => (other, Kind::F64),
    }
}

/// The fields PDAL splits LAS's flags into, from the `las_flags` band (its
/// layout: `pcimg_ingest::las::LAS_FLAGS`): name, first bit, mask.
const FLAG_FIELDS: [(&str, u8, u8); 4] = [
    ("ClassFlags", 0, 0x0f),
    ("ScanChannel", 4, 0x03),
    ("ScanDirectionFlag", 6, 0x01),
    ("EdgeOfFlightLine", 7, 0x01),
];

/// One field of what a read returns.
#[derive(Debug, Clone)]
struct Field {
    /// The name in the array.
    name: String,
    /// The dataset's band (`x`, `y`, `z` for the coordinates).
    band: String,
    kind: Kind,
    /// Bits of the band's whole numbers (shift, mask): flags packed in one.
    bits: Option<(u8, u8)>,
}

/// The fields of `band` in `ds`: one, or the flags packed in `las_flags`.
fn fields_of(ds: &Dataset, band: &str) -> Vec<Field> {
    if band == "las_flags" {
        return FLAG_FIELDS
            .iter()
            .map(|&(name, shift, mask)| Field {
                name: name.to_string(),
                band: band.to_string(),
                kind: Kind::U8,
                bits: Some((shift, mask)),
            })
            .collect();
    }
    vec![field(ds, band)]
}

/// The field for `band` in `ds`: LAS's integer type only where every part that
/// has the band records a range of whole numbers inside it.
fn field(ds: &Dataset, band: &str) -> Field {
    let (name, mut kind) = las_field(band);
    if kind != Kind::F64 {
        // (The index's totals: the band's range over every part that has it.)
        let t = ds.totals();
        let range = t
            .bands
            .iter()
            .position(|b| b == band)
            .and_then(|i| t.ranges[i]);
        let fits = range.is_some_and(|(lo, hi)| {
            lo >= 0.0 && hi <= kind.max() && lo.fract() == 0.0 && hi.fract() == 0.0
        });
        if !fits {
            kind = Kind::F64;
        }
    }
    Field {
        name: name.to_string(),
        band: band.to_string(),
        kind,
        bits: None,
    }
}

/// An opened dataset (`pcimg.open`).
#[pyclass(frozen, module = "pcimg._pcimg", name = "Dataset")]
struct NativeDataset {
    ds: Arc<Dataset>,
    location: String,
}

/// Opens a dataset: a `.tif` part, a directory of parts, or the URL of one
/// (`s3://bucket/prefix`, `http(s)://...`); remote requests are retried for
/// up to `timeout` seconds before they fail.
#[pyfunction]
#[pyo3(signature = (location, timeout = 30.0))]
fn open(py: Python<'_>, location: &str, timeout: f64) -> PyResult<NativeDataset> {
    if !(timeout.is_finite() && timeout > 0.0) {
        return Err(PyValueError::new_err(format!(
            "timeout must be a positive number of seconds, not {timeout}"
        )));
    }
    let options = OpenOptions {
        timeout: Duration::from_secs_f64(timeout),
    };
    let loc = location.to_string();
    let ds = py
        .detach(move || Dataset::open_with(Path::new(&loc), &options))
        .map_err(store_err)?;
    Ok(NativeDataset {
        ds: Arc::new(ds),
        location: location.to_string(),
    })
}

/// The requests made to object storage and the bytes received so far, by
/// every dataset this process opened: `(requests, bytes)`.
#[pyfunction]
fn network_stats() -> (u64, u64) {
    let s = pcimg_store::remote::stats();
    (s.requests, s.bytes)
}

/// Parses a Python box: `(minx, miny, maxx, maxy)` in 2D (any height) or
/// `(minx, miny, minz, maxx, maxy, maxz)`.
fn parse_box(what: &str, v: &[f64], dims: usize) -> PyResult<Bounds> {
    let bad = || {
        PyValueError::new_err(format!(
            "{what} must be {} finite numbers (the minimum corner, then the maximum), got {v:?}",
            dims * 2
        ))
    };
    if v.len() != dims * 2 || v.iter().any(|x| !x.is_finite()) {
        return Err(bad());
    }
    let mut b = Bounds {
        min: [f64::NEG_INFINITY; 3],
        max: [f64::INFINITY; 3],
    };
    for a in 0..dims {
        b.min[a] = v[a];
        b.max[a] = v[a + dims];
        if b.min[a] > b.max[a] {
            return Err(PyValueError::new_err(format!(
                "{what}: the minimum {} lies above the maximum {} on axis {a}",
                b.min[a], b.max[a]
            )));
        }
    }
    Ok(b)
}

/// The intersection of two boxes (`None` when either is absent).
fn both(a: Option<Bounds>, b: Option<Bounds>) -> Option<Bounds> {
    match (a, b) {
        (Some(a), Some(b)) => Some(Bounds {
            min: [0, 1, 2].map(|i| a.min[i].max(b.min[i])),
            max: [0, 1, 2].map(|i| a.max[i].min(b.max[i])),
        }),
        (a, b) => a.or(b),
    }
}

#[pymethods]
impl NativeDataset {
    /// The dataset's facts as plain Python values.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let ds = &self.ds;
        let d = PyDict::new(py);
        d.set_item("location", &self.location)?;
        let t = ds.totals();
        d.set_item("parts", t.parts)?;
        d.set_item("points", ds.points())?;
        let level_points = t.level_points.clone();
        d.set_item("levels", level_points)?;
        let mut bands = vec!["x".to_string(), "y".into(), "z".into()];
        bands.extend(
            t.shown_bands()
                .filter(|b| !["x", "y", "z"].contains(&b.as_str()))
                .cloned(),
        );
        let fields = PyDict::new(py);
        for f in bands.iter().flat_map(|b| fields_of(ds, b)) {
            fields.set_item(&f.name, (f.band.as_str(), f.kind.name()))?;
        }
        d.set_item("fields", fields)?;
        let b = ds.bounds();
        d.set_item(
            "bounds",
            (b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]),
        )?;
        d.set_item("crs", t.crs.clone())?;
        // Class counts, every point's, where every classified part records them.
        let classified = t.bands.iter().any(|b| b == "classification");
        if classified && t.classes_complete && !t.class_counts.is_empty() {
            let counts: std::collections::BTreeMap<u8, u64> =
                t.class_counts.iter().copied().collect();
            d.set_item("classes", counts)?;
        } else {
            d.set_item("classes", py.None())?;
        }
        Ok(d)
    }

    /// What a read of `level` (each part's coarsest where it has fewer) in
    /// `bounds` (2D) and `clip` (3D), of `classes`, with `columns` (field or
    /// band names; every field when `None`) reads.
    #[pyo3(signature = (level = 0, bounds = None, clip = None, classes = None, columns = None))]
    fn plan(
        &self,
        level: usize,
        bounds: Option<Vec<f64>>,
        clip: Option<Vec<f64>>,
        classes: Option<Vec<i64>>,
        columns: Option<Vec<String>>,
    ) -> PyResult<NativePlan> {
        let ds = &self.ds;
        let bounds = bounds.map(|v| parse_box("bounds", &v, 2)).transpose()?;
        let clip = clip.map(|v| parse_box("clip", &v, 3)).transpose()?;
        let classes = classes
            .map(|v| {
                v.into_iter()
                    .map(|c| {
                        u8::try_from(c).map_err(|_| {
                            PyValueError::new_err(format!("class {c} is not a class (0 to 255)"))
                        })
                    })
                    .collect::<PyResult<Vec<u8>>>()
            })
            .transpose()?;
        let selection = Selection {
            clip: both(bounds, clip),
            classes,
        };
        let plan = query::plan(ds, level, |b| selection.may_hold(b)).map_err(store_err)?;
        let mut all = vec![field(ds, "x"), field(ds, "y"), field(ds, "z")];
        // (A plan's bands are every part's, whatever its tiles.)
        all.extend(plan.bands.iter().flat_map(|b| fields_of(ds, b)));
        let fields = match columns {
            None => all,
            Some(names) => names
                .iter()
                .map(|n| {
                    // A field's name, or a band's (all of its fields).
                    let by_name: Vec<Field> = all
                        .iter()
                        .filter(|f| f.name.eq_ignore_ascii_case(n))
                        .cloned()
                        .collect();
                    let found = if by_name.is_empty() {
                        all.iter()
                            .filter(|f| f.band.eq_ignore_ascii_case(n))
                            .cloned()
                            .collect()
                    } else {
                        by_name
                    };
                    Some(found)
                        .filter(|f: &Vec<Field>| !f.is_empty())
                        .ok_or_else(|| {
                            let have: Vec<&str> = all.iter().map(|f| f.name.as_str()).collect();
                            PyValueError::new_err(format!(
                                "{}: no field '{n}'; it has {}",
                                self.location,
                                have.join(", ")
                            ))
                        })
                })
                .collect::<PyResult<Vec<Vec<Field>>>>()?
                .into_iter()
                .flatten()
                .collect(),
        };
        for (i, f) in fields.iter().enumerate() {
            if fields[..i].iter().any(|g| g.name == f.name) {
                return Err(PyValueError::new_err(format!(
                    "field '{}' asked twice",
                    f.name
                )));
            }
        }
        let batches = query::batches(ds, &plan.tiles);
        Ok(NativePlan {
            ds: self.ds.clone(),
            plan,
            selection,
            fields,
            batches,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "pcimg.Dataset('{}': {} points in {} parts)",
            self.location,
            self.ds.points(),
            self.ds.part_count()
        )
    }
}

/// A batch read: its columns, the rows the selection keeps (`None`: all) and
/// its part's lattice.
struct Kept {
    points: pcimg_store::Points,
    rows: Option<Vec<u32>>,
    lattice: Option<pcimg_core::points::Lattice>,
}

/// A band's column in a batch: its offset and values, and for `gps_time` the
/// columns that make it exact (`pcimg_core::time`) where the part has them.
type Column<'a> = (f64, &'a [f32], Option<[&'a [f32]; 3]>);

/// A field's column in a batch and its lattice (origin and step):
/// [`Kept::source`].
type Source<'a> = (Option<Column<'a>>, Option<(f64, f64)>);

impl Kept {
    fn len(&self) -> usize {
        self.rows.as_ref().map_or(self.points.len(), Vec::len)
    }

    /// The batch's row of kept point `i`.
    #[inline(always)]
    fn row(&self, i: usize) -> usize {
        match &self.rows {
            Some(rows) => rows[i] as usize,
            None => i,
        }
    }

    /// Where field `f` comes from: its band's column (offset and values; `None`
    /// where the part lacks the band) and, for a coordinate, the lattice
    /// (origin and step) it goes back onto.
    fn source(&self, f: &Field) -> Source<'_> {
        let p = &self.points;
        let find = |name: &str| p.bands.iter().position(|b| b == name);
        let exact = (f.band == time::TIME_BAND)
            .then(|| time::exact_columns(|b| find(b).map(|i| p.columns[i].as_slice())))
            .flatten();
        let col = find(&f.band).map(|i| (p.offsets[i], p.columns[i].as_slice(), exact));
        let lattice = ["x", "y", "z"]
            .iter()
            .position(|a| *a == f.band)
            .zip(self.lattice)
            .map(|(a, l)| (l.origin[a], l.step[a]));
        (col, lattice)
    }
}

/// Writes `value(r)` at byte `at` of each of the first `n` records of `out`
/// (`record` bytes each).
#[inline(always)]
fn put<const W: usize>(
    out: &mut [u8],
    record: usize,
    at: usize,
    n: usize,
    value: impl Fn(usize) -> [u8; W],
) {
    for (r, rec) in out.chunks_exact_mut(record).take(n).enumerate() {
        rec[at..at + W].copy_from_slice(&value(r));
    }
}

/// `v` as a whole number within `0..=max` (NaN: 0).
#[inline(always)]
fn whole(v: f64, max: f64) -> f64 {
    if v.is_nan() {
        0.0
    } else {
        pcimg_core::points::round_whole(v.clamp(0.0, max))
    }
}

/// Writes field `f` of `n` points into `out` (`record` bytes each, the field
/// at byte `at`), point `r` being row `row(r)` of the band's column `col`
/// (offset and values; `None` where the part lacks the band: NaN, or 0 in an
/// integer type): a coordinate back on its `lattice` (origin and step), a LAS
/// field as its whole number (a flag as its bits), anything else as read.
/// The one place values are made for both `read` and the Arrow stream.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn put_field(
    f: &Field,
    col: Option<Column<'_>>,
    lattice: Option<(f64, f64)>,
    row: impl Fn(usize) -> usize,
    out: &mut [u8],
    record: usize,
    at: usize,
    n: usize,
) {
    let Some((off, col, exact)) = col else {
        let nan = f64::NAN.to_le_bytes();
        match f.kind {
            Kind::F64 if f.bits.is_none() => put(out, record, at, n, |_| nan),
            Kind::U16 if f.bits.is_none() => put(out, record, at, n, |_| [0u8; 2]),
            _ => put(out, record, at, n, |_| [0u8; 1]),
        }
        return;
    };
    if let (Some([lo, mid, hi]), Kind::F64, None) = (exact, f.kind, f.bits) {
        // GPS time, bit for bit (its own loop: a branch a value slowed
        // every field).
        put(out, record, at, n, |r| {
            let i = row(r);
            time::join(off, col[i], lo[i], mid[i], hi[i]).to_le_bytes()
        });
        return;
    }
    let value = |r: usize| off + col[row(r)] as f64;
    match (f.kind, f.bits, lattice) {
        (_, Some((shift, mask)), _) => put(out, record, at, n, |r| {
            [(whole(value(r), 255.0) as u8 >> shift) & mask]
        }),
        (Kind::F64, None, Some((o, step))) => put(out, record, at, n, |r| {
            let v = value(r);
            (o + pcimg_core::points::round_whole((v - o) / step) * step).to_le_bytes()
        }),
        (Kind::F64, None, None) => put(out, record, at, n, |r| value(r).to_le_bytes()),
        (Kind::U16, None, _) => put(out, record, at, n, |r| {
            (whole(value(r), 65535.0) as u16).to_le_bytes()
        }),
        (Kind::U8, None, _) => put(out, record, at, n, |r| [whole(value(r), 255.0) as u8]),
    }
}

impl Kind {
    /// Bytes of one value.
    fn width(self) -> usize {
        match self {
            Kind::U8 => 1,
            Kind::U16 => 2,
            Kind::F64 => 8,
        }
    }
}

/// A column of `n` values of `T` (u8, u16 or f64), its little-endian bytes
/// written by `fill`.
fn column<T: ArrowNativeType>(n: usize, fill: impl FnOnce(&mut [u8])) -> ScalarBuffer<T> {
    let mut v = vec![T::default(); n];
    // SAFETY: T is a plain number type, every bit pattern a value; the byte
    // slice covers exactly `v`'s values (this is a little-endian target, as
    // the records `read` writes assume).
    let bytes = unsafe {
        std::slice::from_raw_parts_mut(v.as_mut_ptr().cast::<u8>(), std::mem::size_of_val(&v[..]))
    };
    fill(bytes);
    ScalarBuffer::from(v)
}

/// A read planned: the tiles it reaches, in batches.
#[pyclass(frozen, module = "pcimg._pcimg", name = "Plan")]
struct NativePlan {
    ds: Arc<Dataset>,
    plan: Plan,
    selection: Selection,
    fields: Vec<Field>,
    batches: Vec<(usize, usize, Vec<u32>)>,
}

impl NativePlan {
    /// The bands a batch is read with besides x y z: the selection's, then the
    /// fields'.
    fn bands(&self) -> Vec<String> {
        let mut bands: Vec<String> = self.selection.bands();
        for f in &self.fields {
            if !["x", "y", "z"].contains(&f.band.as_str()) && !bands.contains(&f.band) {
                bands.push(f.band.clone());
            }
        }
        bands
    }

    /// Batch `i` read, and which of its points the selection keeps.
    fn read_kept(&self, i: usize, bands: &[String]) -> Result<Kept, StoreError> {
        let r = query::read_batch(&self.ds, self.batches[i].clone(), bands)?;
        let lattice = self.ds.part(r.part).and_then(|p| p.meta.lattice);
        let keep = self.selection.keep(&r.points, lattice);
        let rows: Option<Vec<u32>> = keep.map(|k| {
            k.iter()
                .enumerate()
                .filter(|(_, k)| **k)
                .map(|(i, _)| i as u32)
                .collect()
        });
        Ok(Kept {
            points: r.points,
            rows,
            lattice,
        })
    }

    /// Writes the kept points of `k` as records into `out` (`record` bytes
    /// each, field `j` at `offsets[j]`), in parallel.
    fn fill(&self, k: &Kept, out: &mut [u8], record: usize, offsets: &[usize]) {
        let sources: Vec<_> = self.fields.iter().map(|f| k.source(f)).collect();
        const ROWS: usize = 1 << 14;
        out.par_chunks_mut(ROWS * record)
            .enumerate()
            .for_each(|(c, chunk)| {
                let first = c * ROWS;
                let n = chunk.len() / record;
                let row = |r: usize| k.row(first + r);
                // Field by field, each with its own loop (no choice per value).
                for (j, f) in self.fields.iter().enumerate() {
                    let (col, lattice) = sources[j];
                    put_field(f, col, lattice, row, chunk, record, offsets[j], n);
                }
            });
    }

    /// The Arrow schema of the fields: LAS's integer types, float64 else.
    fn arrow_schema(&self) -> SchemaRef {
        let fields: Vec<ArrowField> = self
            .fields
            .iter()
            .map(|f| {
                let t = match f.kind {
                    Kind::U8 => DataType::UInt8,
                    Kind::U16 => DataType::UInt16,
                    Kind::F64 => DataType::Float64,
                };
                ArrowField::new(&f.name, t, false)
            })
            .collect();
        Arc::new(Schema::new(fields))
    }

    /// Batch `i`'s kept points as an Arrow record batch of `schema`, the same
    /// values as [`records`](Self::records) writes.
    fn arrow_batch(
        &self,
        i: usize,
        bands: &[String],
        schema: &SchemaRef,
    ) -> Result<RecordBatch, ArrowError> {
        let k = self
            .read_kept(i, bands)
            .map_err(|e| ArrowError::ExternalError(Box::new(e)))?;
        let n = k.len();
        const ROWS: usize = 1 << 14;
        let columns: Vec<ArrayRef> = self
            .fields
            .iter()
            .map(|f| {
                let (col, lattice) = k.source(f);
                // The field's values written as `read` writes them, into
                // the Arrow type's own buffer.
                let fill = |bytes: &mut [u8]| {
                    let w = f.kind.width();
                    bytes
                        .par_chunks_mut(ROWS * w)
                        .enumerate()
                        .for_each(|(c, chunk)| {
                            let row = |r: usize| k.row(c * ROWS + r);
                            put_field(f, col, lattice, row, chunk, w, 0, chunk.len() / w);
                        })
                };
                let array: ArrayRef = match f.kind {
                    Kind::U8 => Arc::new(UInt8Array::new(column(n, fill), None)),
                    Kind::U16 => Arc::new(UInt16Array::new(column(n, fill), None)),
                    Kind::F64 => Arc::new(Float64Array::new(column(n, fill), None)),
                };
                array
            })
            .collect();
        RecordBatch::try_new(schema.clone(), columns)
    }

    /// The points batch `i`'s tiles record.
    fn batch_points(&self, i: usize) -> usize {
        let (p, l, tiles) = &self.batches[i];
        let Some(level) = self.ds.part(*p).and_then(|p| p.levels.get(*l)) else {
            return 0;
        };
        let count: std::collections::HashMap<u32, u32> = level
            .tiles
            .iter()
            .map(|t| (t.index, t.points.unwrap_or(0)))
            .collect();
        tiles
            .iter()
            .map(|t| count.get(t).copied().unwrap_or(0) as usize)
            .sum()
    }
}

#[pymethods]
impl NativePlan {
    /// The fields read, in order: `[(name, band, numpy type)]`.
    fn fields(&self) -> Vec<(String, String, &'static str)> {
        self.fields
            .iter()
            .map(|f| (f.name.clone(), f.band.clone(), f.kind.name()))
            .collect()
    }

    /// Batches of tiles (each at most 4 M points of one part).
    fn batches(&self) -> usize {
        self.batches.len()
    }

    /// Tiles reached and tiles left unread.
    fn tiles(&self) -> (usize, usize) {
        (self.plan.tiles.len(), self.plan.skipped)
    }

    /// Points in the tiles reached: the most a read returns.
    fn points(&self) -> u64 {
        self.plan.points
    }

    /// Every point as an Arrow stream (pyo3-arrow's `RecordBatchReader`, which
    /// has `__arrow_c_stream__`): a record batch per batch of tiles, each read
    /// when the consumer asks for it.
    fn arrow(slf: Bound<'_, Self>) -> PyRecordBatchReader {
        let plan = slf.get();
        let reader = ArrowBatches {
            schema: plan.arrow_schema(),
            bands: plan.bands(),
            plan: slf.clone().unbind(),
            next: 0,
        };
        PyRecordBatchReader::new(Box::new(reader))
    }

    /// Every point as a numpy structured array of `dtype` (its fields those of
    /// [`fields`](Self::fields), at `offsets`), written straight into it.
    /// Without a selection the batches' sizes are known (the tiles record
    /// them), so each batch is read and written in turn, in parallel; with one,
    /// the batches are read first, then written.
    fn records<'py>(
        &self,
        py: Python<'py>,
        dtype: Bound<'py, PyAny>,
        offsets: Vec<usize>,
        batch: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let record: usize = dtype.getattr("itemsize")?.extract()?;
        if offsets.len() != self.fields.len() {
            return Err(PyValueError::new_err("one offset a field"));
        }
        let which: Vec<usize> = match batch {
            Some(i) if i >= self.batches.len() => {
                return Err(PyValueError::new_err(format!(
                    "batch {i} of {}",
                    self.batches.len()
                )));
            }
            Some(i) => vec![i],
            None => (0..self.batches.len()).collect(),
        };
        let bands = self.bands();
        let plain = self.selection == Selection::default();
        // The batches' points: from the tiles' counts, or read first.
        let (sizes, held): (Vec<usize>, Option<Vec<Kept>>) = if plain {
            let sizes = which.iter().map(|&i| self.batch_points(i)).collect();
            (sizes, None)
        } else {
            let held = py
                .detach(|| {
                    which
                        .par_iter()
                        .map(|&i| self.read_kept(i, &bands))
                        .collect::<Result<Vec<Kept>, _>>()
                })
                .map_err(store_err)?;
            (held.iter().map(Kept::len).collect(), Some(held))
        };
        let total: usize = sizes.iter().sum();
        let np = py.import("numpy")?;
        let out = np.call_method1("empty", (total, &dtype))?;
        let bytes = out.call_method1("view", (np.getattr("uint8")?,))?;
        let mut rw: numpy::PyReadwriteArray1<'py, u8> = bytes.extract()?;
        let slice = rw
            .as_slice_mut()
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        // Each batch's records.
        let mut parts: Vec<&mut [u8]> = Vec::with_capacity(sizes.len());
        let mut rest = slice;
        for &n in &sizes {
            let (a, b) = rest.split_at_mut(n * record);
            parts.push(a);
            rest = b;
        }
        py.detach(|| -> Result<(), StoreError> {
            match held {
                Some(held) => {
                    for (k, part) in held.iter().zip(parts) {
                        self.fill(k, part, record, &offsets);
                    }
                    Ok(())
                }
                None => which.par_iter().zip(parts).try_for_each(|(&i, part)| {
                    let k = self.read_kept(i, &bands)?;
                    if k.len() * record != part.len() {
                        return Err(StoreError::new(
                            &self.ds.path,
                            format!(
                                "batch {i}: {} points read where its tiles record {}",
                                k.len(),
                                part.len() / record
                            ),
                        ));
                    }
                    self.fill(&k, part, record, &offsets);
                    Ok(())
                }),
            }
        })
        .map_err(store_err)?;
        Ok(out)
    }
}

/// A plan's batches as Arrow record batches, read one at a time as the
/// stream's consumer asks (the reads themselves in parallel).
struct ArrowBatches {
    plan: Py<NativePlan>,
    schema: SchemaRef,
    bands: Vec<String>,
    next: usize,
}

impl Iterator for ArrowBatches {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let plan = self.plan.get();
        if self.next >= plan.batches.len() {
            return None;
        }
        self.next += 1;
        Some(plan.arrow_batch(self.next - 1, &self.bands, &self.schema))
    }
}

impl RecordBatchReader for ArrowBatches {
    fn schema(&self) -> SchemaRef {
        self.schema.clone()
    }
}

#[pymodule]
fn _pcimg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(open, m)?)?;
    m.add_function(wrap_pyfunction!(network_stats, m)?)?;
    m.add_class::<NativeDataset>()?;
    m.add_class::<NativePlan>()?;
    Ok(())
}
