//! COPC inputs read node by node through `pcimg-copc`: the octree's nodes that
//! reach the region asked for (all of them without one), their chunks fetched
//! as one batch of ranges per chunk of points, decompressed and decoded in
//! parallel, each point outside the region dropped. The records' columns are
//! exactly those of a LAS/LAZ input of the same format (`las_records`).
//!
//! Without a region, a local COPC file is read as the LAZ file it also is
//! (`las.rs`, whose chunk-table reader is as fast); this reader is for regions
//! and for sources other than a local file (object storage, HTTP).

use crate::color::ColorNormalizer;
use crate::error::IngestError;
use crate::las_records::{Fields, decode_records, gps_of};
use crate::points::{Bounds, PointColumns};
use crate::{PointReader, ReadOptions, SourceInfo};
use pcimg_copc::{ByteSource, Copc, CopcError, Entry};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Whether the local file at `path` is a COPC file (a LAS 1.4 file whose first
/// VLR is COPC's info), from its first 400 bytes.
pub fn is_copc(path: &Path) -> bool {
    use std::io::Read;
    let mut b = [0u8; 400];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut b))
        .is_ok_and(|()| &b[..4] == b"LASF" && (b[24], b[25]) == (1, 4) && &b[377..382] == b"copc\0")
}

/// The error of the COPC reader as an input error (file or URL, byte offset).
pub fn error(e: CopcError) -> IngestError {
    let path = PathBuf::from(&e.name);
    match e.offset {
        Some(o) => IngestError::binary(&path, o, e.what),
        None => IngestError::format(&path, e.what),
    }
}

/// A COPC file read by nodes.
pub struct CopcReader {
    copc: Arc<Copc>,
    nodes: Vec<Entry>,
    next: usize,
    fields: Fields,
    /// GPS time is kept relative to the median of the first node's first
    /// values (decided with the first chunk).
    gps_offset: Option<f64>,
    info: SourceInfo,
    colors: ColorNormalizer,
    region: Option<Bounds>,
    chunk: u64,
    bytes_done: u64,
    left_out: u64,
    selection: laz::DecompressionSelection,
}

impl std::fmt::Debug for CopcReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CopcReader")
            .field("copc", &self.copc)
            .field("nodes", &self.nodes.len())
            .finish_non_exhaustive()
    }
}

/// The `las` crate's header of `copc` (from its stored header and VLRs).
fn las_header(copc: &Copc, path: &Path) -> Result<las::Header, IngestError> {
    let bad = |e: las::Error| IngestError::binary(path, 0, format!("the LAS header: {e}"));
    let mut cur = std::io::Cursor::new(&copc.head[..]);
    let raw = las::raw::Header::read_from(&mut cur).map_err(bad)?;
    let n = raw.number_of_variable_length_records;
    let mut b = las::Builder::new(raw).map_err(bad)?;
    for _ in 0..n {
        let v = las::raw::Vlr::read_from(&mut cur, false).map_err(bad)?;
        b.vlrs.push(las::Vlr::new(v));
    }
    b.into_header().map_err(bad)
}

/// The CRS (WKT, or a short description from GeoTIFF keys) and the attribute
/// columns of `copc`'s points, from its header and VLRs.
pub fn describe(copc: &Copc) -> Result<(Option<String>, Vec<String>), IngestError> {
    let h = las_header(copc, &PathBuf::from(copc.name()))?;
    Ok((
        super::las::crs_of(&h),
        super::las::attribute_names(h.point_format()),
    ))
}

/// The COPC file at `path` (local) or URL (through [`crate::set_url_opener`]),
/// opened: its header, VLRs and root hierarchy page.
pub fn open_any(path: &Path) -> Result<Arc<Copc>, IngestError> {
    if crate::is_url(path) {
        return crate::opened_url(path);
    }
    let src =
        pcimg_copc::FileSource::open(path).map_err(|e| IngestError::io(path, "cannot open", e))?;
    Ok(Arc::new(open_copc(Arc::new(src)).map_err(error)?))
}

/// [`open_any`], a URL opened afresh rather than kept for the process (a
/// survey of many files opens each twice, and keeps none).
pub fn open_once(path: &Path) -> Result<Arc<Copc>, IngestError> {
    if crate::is_url(path) {
        let source = crate::url_source(path)?;
        return Ok(Arc::new(open_copc(source).map_err(error)?));
    }
    open_any(path)
}

/// Opens the COPC file in `source` for reading the points in `opts.region`
/// (all without one).
pub fn open_source(
    source: Arc<dyn ByteSource>,
    opts: &ReadOptions,
) -> Result<CopcReader, IngestError> {
    from_copc(Arc::new(open_copc(source).map_err(error)?), opts)
}

/// Opens the COPC file in `source` (a panic of the LAZ crate on a corrupt
/// VLR contained).
pub fn open_copc(source: Arc<dyn ByteSource>) -> Result<Copc, CopcError> {
    let name = source.name();
    crate::contain::contain(|| Copc::open(source)).unwrap_or_else(|| {
        Err(CopcError {
            name,
            offset: None,
            what: "the COPC header or its LAZ VLR is corrupt".into(),
            kind: pcimg_copc::Kind::Corrupt,
        })
    })
}

/// Opens the local COPC file `path`.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<CopcReader, IngestError> {
    let src =
        pcimg_copc::FileSource::open(path).map_err(|e| IngestError::io(path, "cannot open", e))?;
    open_source(Arc::new(src), opts)
}

/// Reads `copc`'s points in `opts.region`.
pub fn from_copc(copc: Arc<Copc>, opts: &ReadOptions) -> Result<CopcReader, IngestError> {
    let path = PathBuf::from(copc.name());
    let header = las_header(&copc, &path)?;
    let format = *header.point_format();
    let stride = usize::from(copc.header.record_len);
    let fields = Fields::new(&path, &format, stride, &header)?;
    let region = opts.region;
    let reaches =
        |c: &pcimg_copc::Cube| region.is_none_or(|r| r.intersects(&Bounds { min: c.0, max: c.1 }));
    let nodes = copc.nodes_where(&reaches, i32::MAX).map_err(error)?;
    let nodes: Vec<Entry> = nodes.into_iter().filter(|e| e.points > 0).collect();
    let bytes: u64 = nodes.iter().map(|e| u64::from(e.bytes)).sum();
    let mut declared = super::las::declared_bounds(&header);
    if let (Some(d), Some(r)) = (declared.as_mut(), region) {
        for a in 0..3 {
            d.min[a] = d.min[a].max(r.min[a]);
            d.max[a] = d.max[a].min(r.max[a]);
        }
    }
    let scales = copc.header.scale;
    let info = SourceInfo {
        path: path.clone(),
        format: "copc 1.4".into(),
        declared_points: region.is_none().then_some(copc.header.points),
        declared_bounds: declared,
        crs_wkt: super::las::crs_of(&header),
        attribute_names: super::las::attribute_names(&format),
        file_bytes: bytes,
        notes: region
            .map(|_| {
                format!(
                    "COPC: read the {} octree nodes that reach the region ({} of the file's {}); \
                     points outside it left out",
                    nodes.len(),
                    pcimg_core::text::bytes(bytes),
                    pcimg_core::text::bytes(copc.len)
                )
            })
            .into_iter()
            .collect(),
        metadata: vec![(
            crate::points::key::LAS_POINT_FORMAT.to_string(),
            copc.header.format.to_string(),
        )],
        coordinate_step: Some(scales.map(f64::abs)),
        coordinate_lattice: Some(crate::points::Lattice {
            step: scales,
            origin: copc.header.offset,
        }),
    };
    Ok(CopcReader {
        copc,
        nodes,
        next: 0,
        fields,
        gps_offset: None,
        info,
        colors: ColorNormalizer::new(false),
        region,
        chunk: opts.chunk_points.max(1) as u64,
        bytes_done: 0,
        left_out: 0,
        selection: laz::DecompressionSelection::all(),
    })
}

impl CopcReader {
    /// The nodes this reader reads (those that reach its region).
    pub fn nodes(&self) -> &[Entry] {
        &self.nodes
    }

    /// The opened file.
    pub fn copc(&self) -> &Arc<Copc> {
        &self.copc
    }
}

/// Node `e`'s records from its `chunk`, the fields of `sel` decompressed. The
/// LAZ decoder's panic on a corrupt chunk stays off the terminal: an error
/// naming the chunk's offset instead.
fn decompress(
    copc: &Copc,
    e: &Entry,
    chunk: &[u8],
    sel: laz::DecompressionSelection,
) -> Result<Vec<u8>, IngestError> {
    crate::contain::contain(|| copc.decompress(e, chunk, sel))
        .unwrap_or_else(|| {
            Err(CopcError {
                name: copc.name().to_string(),
                offset: Some(e.offset),
                what: "the LAZ decompressor failed on corrupt data".into(),
                kind: pcimg_copc::Kind::Corrupt,
            })
        })
        .map_err(error)
}

/// Keeps the points of `c` inside `r`; returns how many it dropped.
pub(crate) fn keep_inside(c: &mut PointColumns, r: &Bounds) -> u64 {
    let inside: Vec<bool> = (0..c.len())
        .map(|i| {
            let p = [c.x[i], c.y[i], c.z[i]];
            (0..3).all(|a| p[a] >= r.min[a] && p[a] <= r.max[a])
        })
        .collect();
    let kept = inside.iter().filter(|&&k| k).count();
    if kept == c.len() {
        return 0;
    }
    let dropped = (c.len() - kept) as u64;
    let pick = |v: &mut Vec<f64>| {
        let mut k = inside.iter();
        v.retain(|_| *k.next().unwrap_or(&false));
    };
    pick(&mut c.x);
    pick(&mut c.y);
    pick(&mut c.z);
    for a in c.attributes.iter_mut() {
        let mut k = inside.iter();
        a.values.retain(|_| *k.next().unwrap_or(&false));
    }
    dropped
}

/// The end of the batch of nodes from `next` (of `len`) that holds about
/// `chunk` points (at least one node), and its points; `points(i)`: node `i`'s.
pub(crate) fn batch(
    next: usize,
    len: usize,
    chunk: u64,
    points: impl Fn(usize) -> u64,
) -> (usize, u64) {
    let (mut end, mut sum) = (next, 0u64);
    while end < len && (end == next || sum < chunk) {
        sum += points(end);
        end += 1;
    }
    (end, sum)
}

impl PointReader for CopcReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        if self.next >= self.nodes.len() {
            return Ok(None);
        }
        let (end, points) = batch(self.next, self.nodes.len(), self.chunk, |i| {
            u64::from(self.nodes[i].points)
        });
        let batch = &self.nodes[self.next..end];
        let chunks = self.copc.fetch(batch).map_err(error)?;
        let (copc, sel) = (&self.copc, self.selection);
        let records: Vec<Vec<u8>> = batch
            .par_iter()
            .zip(chunks.par_iter())
            .map(|(e, chunk)| decompress(copc, e, chunk, sel))
            .collect::<Result<_, IngestError>>()?;
        let f = &self.fields;
        let g = *self.gps_offset.get_or_insert_with(|| {
            let mut t: Vec<f64> = records[0]
                .chunks_exact(f.stride)
                .take(crate::OFFSET_SAMPLE)
                .filter_map(|r| gps_of(r, f))
                .collect();
            if t.is_empty() {
                0.0
            } else {
                crate::attribute_offset(&mut t, true)
            }
        });
        let names = &self.info.attribute_names;
        let decoded: Vec<PointColumns> = records
            .par_iter()
            .map(|rec| decode_records(rec, f, g, names))
            .collect();
        let mut parts = decoded.into_iter();
        let mut cols = parts.next().unwrap_or_default();
        cols.x.reserve(points as usize);
        for d in parts {
            cols.append(&d)
                .map_err(|e| IngestError::format(&self.info.path, e))?;
        }
        self.bytes_done += batch.iter().map(|e| u64::from(e.bytes)).sum::<u64>();
        self.next = end;
        if let Some(r) = &self.region {
            self.left_out += keep_inside(&mut cols, r);
        }
        self.colors.apply(&mut cols);
        Ok(Some(cols))
    }

    fn bytes_done(&self) -> u64 {
        self.bytes_done
    }

    fn skipped(&self) -> u64 {
        0
    }

    fn clamped_colours(&self) -> u64 {
        self.colors
            .clamped()
            .load(std::sync::atomic::Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../fixtures")
            .join(name)
    }

    fn all(r: &mut dyn PointReader) -> PointColumns {
        let mut out: Option<PointColumns> = None;
        while let Some(c) = r.next_chunk().unwrap() {
            match out.as_mut() {
                None => out = Some(c),
                Some(o) => o.append(&c).unwrap(),
            }
        }
        out.unwrap()
    }

    /// Rows of the named columns (coordinates first), as integers on the
    /// columns' lattice, sorted: a multiset to compare.
    fn rows(c: &PointColumns, names: &[&str]) -> Vec<Vec<i64>> {
        let mut v: Vec<Vec<i64>> = (0..c.len())
            .map(|i| {
                let mut r = vec![
                    (c.x[i] * 100.0).round() as i64,
                    (c.y[i] * 100.0).round() as i64,
                    (c.z[i] * 100.0).round() as i64,
                ];
                for n in names {
                    let a = c.attributes.iter().find(|a| a.name == *n).unwrap();
                    r.push(((f64::from(a.values[i]) + a.offset) * 1e6).round() as i64);
                }
                r
            })
            .collect();
        v.sort_unstable();
        v
    }

    #[test]
    fn every_point_of_the_copc_is_a_point_of_the_laz_it_was_made_from() {
        let mut laz = crate::open(&fixture("autzen_trim.laz"), &ReadOptions::default()).unwrap();
        let mut copc = open(&fixture("autzen_trim.copc.laz"), &ReadOptions::default()).unwrap();
        assert_eq!(copc.nodes().len(), 9);
        let (a, b) = (all(&mut *laz), all(&mut copc));
        let common: Vec<String> = laz
            .info()
            .attribute_names
            .iter()
            .filter(|n| copc.info().attribute_names.contains(n))
            .cloned()
            .collect();
        // Every attribute the two formats share (format 3 against format 7:
        // the flags' packing differs; GPS time, colour and the rest do not).
        for n in [
            "intensity",
            "return_number",
            "number_of_returns",
            "classification",
            "gps_time",
            "red",
            "green",
            "blue",
            "user_data",
            "point_source_id",
        ] {
            assert!(common.iter().any(|c| c == n), "{n} not in {common:?}");
        }
        // GPS time is compared as stored (f64, below): the columns keep it as
        // f32 relative to an offset each reader picks from its first points,
        // and the whole numbers that make it exact depend on that offset.
        let names: Vec<&str> = common
            .iter()
            .map(String::as_str)
            .filter(|n| !["las_flags", "scan_angle", "gps_time"].contains(n))
            .filter(|n| !pcimg_core::time::is_exact_band(n))
            .collect();
        assert_eq!((a.len(), b.len()), (110_000, 110_000));
        for n in &names {
            let (ra, rb) = (rows(&a, &[n]), rows(&b, &[n]));
            let bad = ra.iter().zip(&rb).position(|(p, q)| p != q);
            assert!(
                bad.is_none(),
                "{n}: {:?} against {:?}",
                bad.map(|i| &ra[i]),
                bad.map(|i| &rb[i])
            );
        }
        assert!(rows(&a, &names) == rows(&b, &names), "the rows differ");
        // Each point's (x, y, z, GPS time) as stored: the LAZ through the `las`
        // crate, the COPC's records as this reader decompresses them.
        let mut want: Vec<(i64, i64, i64, u64)> =
            las::Reader::from_path(fixture("autzen_trim.laz"))
                .unwrap()
                .read_all()
                .unwrap()
                .points()
                .map(|p| {
                    let p = p.unwrap();
                    let c = |v: f64| (v * 100.0).round() as i64;
                    (c(p.x), c(p.y), c(p.z), p.gps_time.unwrap().to_bits())
                })
                .collect();
        let c = copc.copc().clone();
        let stride = usize::from(c.header.record_len);
        let mut got = Vec::new();
        for (e, chunk) in copc.nodes().iter().zip(c.fetch(copc.nodes()).unwrap()) {
            let rec = c
                .decompress(e, &chunk, laz::DecompressionSelection::all())
                .unwrap();
            for r in rec.chunks_exact(stride) {
                let i = |a: usize| i64::from(i32::from_le_bytes(r[a..a + 4].try_into().unwrap()));
                let o = |a: usize, k: usize| {
                    ((c.header.scale[k] * i(a) as f64 + c.header.offset[k]) * 100.0).round() as i64
                };
                let t = u64::from_le_bytes(r[22..30].try_into().unwrap());
                got.push((o(0, 0), o(4, 1), o(8, 2), t));
            }
        }
        want.sort_unstable();
        got.sort_unstable();
        assert!(want == got, "GPS times differ");
    }

    #[test]
    fn a_region_reads_only_the_nodes_that_reach_it_and_only_its_points() {
        let whole = open(&fixture("autzen_trim.copc.laz"), &ReadOptions::default()).unwrap();
        // Inside the cube of the first octant of the root: only the root and
        // that octant are read.
        let octant = pcimg_copc::Key::ROOT.children()[0];
        let (lo, hi) = octant.bounds(&whole.copc().info);
        let m = 0.01 * (hi[0] - lo[0]);
        let region = Bounds {
            min: lo.map(|v| v + m),
            max: hi.map(|v| v - m),
        };
        let opts = ReadOptions {
            region: Some(region),
            ..Default::default()
        };
        let mut r = crate::open(&fixture("autzen_trim.copc.laz"), &opts).unwrap();
        let got = all(&mut *r);
        let mut full = open(&fixture("autzen_trim.copc.laz"), &ReadOptions::default()).unwrap();
        let every = all(&mut full);
        let inside = (0..every.len())
            .filter(|&i| {
                let p = [every.x[i], every.y[i], every.z[i]];
                (0..3).all(|a| p[a] >= region.min[a] && p[a] <= region.max[a])
            })
            .count();
        assert!(inside > 0 && inside < every.len());
        assert_eq!(got.len(), inside, "of {}", every.len());
        let mut sub = open(&fixture("autzen_trim.copc.laz"), &opts).unwrap();
        let keys: Vec<_> = sub.nodes().iter().map(|e| e.key).collect();
        assert_eq!(keys, [pcimg_copc::Key::ROOT, octant]);
        assert!(sub.info().file_bytes < whole.info().file_bytes);
        assert_eq!(all(&mut sub).len(), inside);
        // Other formats refuse a region.
        let e = crate::open(&fixture("autzen_trim.laz"), &opts)
            .err()
            .unwrap();
        assert!(e.to_string().contains("only from COPC"), "{e}");
    }
}

/// The fields of a node to decompress for `bands` (x, y, z, returns always):
/// the `laz` crate skips the layers of the others.
pub fn selection_for(bands: &[String]) -> laz::DecompressionSelection {
    use laz::DecompressionSelection as S;
    let mut bits = S::Z;
    for b in bands {
        bits |= match b.as_str() {
            "intensity" => S::INTENSITY,
            "classification" => S::CLASSIFICATION,
            "red" | "green" | "blue" => S::RGB,
            "nir" => S::NIR,
            "gps_time" => S::GPS_TIME,
            "scan_angle" => S::SCAN_ANGLE,
            "user_data" => S::USER_DATA,
            "point_source_id" => S::POINT_SOURCE_ID,
            "las_flags" => S::FLAGS | S::CLASSIFICATION,
            _ => 0,
        };
    }
    laz::DecompressionSelection(bits)
}

/// Turns one node of a COPC file into columns, as a view loads it: the
/// attribute columns a LAS input of its format has, GPS time relative to the
/// file's first (COPC info), colour scaled as the first node decided.
#[derive(Debug)]
pub struct NodeDecoder {
    fields: Fields,
    names: Vec<String>,
    gps_offset: f64,
    colors: std::sync::Mutex<ColorNormalizer>,
}

impl NodeDecoder {
    pub fn new(copc: &Copc) -> Result<NodeDecoder, IngestError> {
        let path = PathBuf::from(copc.name());
        let header = las_header(copc, &path)?;
        let stride = usize::from(copc.header.record_len);
        let fields = Fields::new(&path, header.point_format(), stride, &header)?;
        let t = copc.info.gps_time[0];
        Ok(NodeDecoder {
            fields,
            names: super::las::attribute_names(header.point_format()),
            gps_offset: if t.is_finite() { t.round() } else { 0.0 },
            colors: std::sync::Mutex::new(ColorNormalizer::new(false)),
        })
    }

    /// The attribute columns (after x, y, z).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Node `e`'s points, the fields of `bands` decompressed (the others 0).
    pub fn read(
        &self,
        copc: &Copc,
        e: &Entry,
        bands: &[String],
    ) -> Result<PointColumns, IngestError> {
        let chunk = copc
            .fetch(std::slice::from_ref(e))
            .map_err(error)?
            .remove(0);
        let rec = decompress(copc, e, &chunk, selection_for(bands))?;
        let mut cols = decode_records(&rec, &self.fields, self.gps_offset, &self.names);
        self.colors
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .apply(&mut cols);
        Ok(cols)
    }
}
