//! Input readers: the public API that turns a point-cloud file into a stream of
//! [`PointColumns`] chunks.
//!
//! * Formats: text (`.xyz .txt .csv .asc .pts`), PLY (ASCII, binary little- and
//!   big-endian; `.ply`), LAS 1.0–1.4 and LAZ (`.las .laz`), PCD 0.5–0.7 (ascii,
//!   binary, binary_compressed; `.pcd`), E57 (`.e57`).
//! * Detection: content first where it is cheap and certain (PLY magic `ply\n`,
//!   LAS signature `LASF`, E57 signature `ASTM-E57`, a PCD header's first line),
//!   then the file extension; anything else is an error.
//! * Chunking: a reader delivers the points in windows of about
//!   [`ReadOptions::chunk_points`] points, so an input larger than memory is never
//!   held whole. Text and PLY are memory-mapped and parsed in parallel with rayon.
//! * Attribute names (used as band names by the store): `intensity`, `red`,
//!   `green`, `blue`, `classification`, `return_number`, `number_of_returns`,
//!   `gps_time`, otherwise the source's own property name in lower case.
//! * Colour is always delivered on a 0–255 scale: see [`color`] for the rule.
//! * GPS time uses the attribute offset: the offset is the first point's time, so
//!   `f32` values keep sub-millisecond precision.
//! * Memory: a reader holds about one chunk of columns (~56 bytes per point with
//!   x y z and eight attributes) plus its parse buffers; the LAS/LAZ reader decodes
//!   one chunk ahead on its own thread. Pages of a memory map already consumed are
//!   released as reading advances.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

#[cfg(test)]
use pcimg_core::rng;
use pcimg_core::{bigvec, points};

pub mod ahead;
pub mod color;
pub(crate) mod contain;
pub mod copc;
pub mod e57;
pub mod ept;
pub mod error;
pub mod las;
pub mod las_records;
pub(crate) mod lines;
pub mod multi;
pub mod pcd;
pub mod ply;
pub mod text;
pub mod value;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use error::IngestError;

use crate::points::{ChunkExtent, PointColumns, RowSource};

/// What a reader knows about its source before reading points.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceInfo {
    pub path: PathBuf,
    /// "text", "ply-ascii", "ply-binary-le", "ply-binary-be", "las 1.2", "laz 1.4"...
    pub format: String,
    /// The point count the file declares (PLY vertex count, LAS header, PTS count
    /// line), if it declares one.
    pub declared_points: Option<u64>,
    /// The bounds the file declares (LAS header), if any: a hint for the
    /// converter's origin, never trusted for anything else.
    pub declared_bounds: Option<crate::points::Bounds>,
    /// The coordinate reference system: WKT when the file has it, otherwise a short
    /// description such as `EPSG:2992` taken from GeoTIFF keys.
    pub crs_wkt: Option<String>,
    /// Names of the attribute columns every chunk carries, in order.
    pub attribute_names: Vec<String>,
    pub file_bytes: u64,
    /// Lines for the conversion's summary on what the reader leaves aside
    /// (embedded images, fields too wide to be bands).
    pub notes: Vec<String>,
    /// Items about the source for the part's metadata, name and value
    /// (`VIEWPOINT`, `SCANS`: see `store::spec::key`).
    pub metadata: Vec<(String, String)>,
    /// The step of the file's coordinate lattice on each axis, where the file
    /// stores coordinates as whole multiples of one (LAS scale factors): a
    /// lossy codec within half of it gives them back on the lattice.
    pub coordinate_step: Option<[f64; 3]>,
    /// The lattice itself (step and origin: LAS scale factors and offsets), where
    /// every coordinate of the input lies on one: the store keeps the whole
    /// numbers, and gives the source's coordinates back exactly.
    pub coordinate_lattice: Option<crate::points::Lattice>,
}

/// How to read an input.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ReadOptions {
    /// Text only: the column layout, names separated by spaces or commas, e.g.
    /// `"x y z intensity r g b"`; `_` skips a column. `None` detects it.
    pub columns: Option<String>,
    /// Text and ASCII PLY: skip (and count) malformed lines instead of failing.
    pub skip_invalid: bool,
    /// Target number of points per chunk.
    pub chunk_points: usize,
    /// Only the points inside this box (COPC: only the octree's nodes that
    /// reach it are read). Other formats refuse it.
    #[serde(default)]
    pub region: Option<crate::points::Bounds>,
}

/// Default target points per chunk. Kept just under 2^22 so that an `f64` column
/// (32,000,000 bytes) stays below glibc's largest dynamic mmap threshold (32 MiB):
/// chunk buffers are then recycled by the allocator instead of being mapped and
/// zeroed afresh by the kernel for every chunk.
pub(crate) const DEFAULT_CHUNK_POINTS: usize = 4_000_000;

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            columns: None,
            skip_invalid: false,
            chunk_points: DEFAULT_CHUNK_POINTS,
            region: None,
        }
    }
}

/// A source of point chunks.
pub trait PointReader: Send {
    fn info(&self) -> &SourceInfo;
    /// Next chunk, `None` at the end. Every chunk has the attributes named in
    /// [`SourceInfo::attribute_names`], in that order.
    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError>;
    /// Progress in bytes consumed so far, for a progress bar (≤ `file_bytes`).
    fn bytes_done(&self) -> u64;
    /// Number of malformed lines skipped so far (with `skip_invalid`).
    fn skipped(&self) -> u64;
    /// Points so far that the file itself marks as holding no measurement and
    /// that were left out: PCD's NaN slots, E57's invalid states.
    fn left_out(&self) -> u64 {
        0
    }
    /// Colour values so far that did not fit the file's colour scale (decided on
    /// its first points, see [`color`]) and were clamped to 0–255.
    fn clamped_colours(&self) -> u64 {
        0
    }
    /// For a pass that only estimates where the points lie: from here on deliver
    /// about one point in `every`, read as pieces spread evenly over the rest of
    /// the input. Malformed records in those pieces may be skipped silently (a
    /// full pass is expected to follow and report them). Returns whether the
    /// reader samples; one that cannot skip cheaply goes on delivering every point.
    fn sample_rest(&mut self, every: u64) -> bool {
        let _ = every;
        false
    }
    /// The attribute rows of every point this reader delivers, given again on
    /// demand from the input itself (see [`RowSource`]): for a caller that would
    /// otherwise hold a copy of them. Asked for after the first chunk (which
    /// settles the colour scale) and before sampling; `None` where the reader
    /// cannot (only uncompressed LAS can).
    fn row_source(&self) -> Option<std::sync::Arc<dyn RowSource>> {
        None
    }
    /// Whether [`PointReader::row_source`] will give the positions and rows of
    /// every point (once the first chunk or extent is read) and
    /// [`PointReader::next_extent`] reads the input faster than `next_chunk`: a
    /// caller that takes the points from the source then needs no columns.
    fn gives_extents(&mut self) -> Result<bool, IngestError> {
        Ok(false)
    }
    /// The next chunk's [`ChunkExtent`] instead of its columns (the same points
    /// `next_chunk` would have delivered, and the reader moves past them the
    /// same way), `None` at the end.
    fn next_extent(&mut self) -> Result<Option<ChunkExtent>, IngestError> {
        Ok(self.next_chunk()?.map(|c| ChunkExtent::of(&c)))
    }
}

/// A well-mixed hash of `v` (splitmix64's finalizer): the jitter that places a
/// sampling reader's pieces, so that a periodic layout (scan lines) cannot alias
/// with evenly spaced pieces. Deterministic, so a conversion repeats exactly.
pub(crate) fn mix(mut v: u64) -> u64 {
    v = v.wrapping_add(0x9e37_79b9_7f4a_7c15);
    v = (v ^ (v >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    v = (v ^ (v >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    v ^ (v >> 31)
}

/// Values of an attribute that decide its offset (the first ones read).
pub(crate) const OFFSET_SAMPLE: usize = 4096;

/// Magnitude from which an attribute is stored relative to an offset: `f32` steps
/// are 1/128 there (GPS times near 3e8 would lose up to 16 s without one).
const OFFSET_FROM: f64 = 65536.0;

/// The offset to store an attribute relative to, from its first values: their
/// median rounded to a whole number (robust to an odd first value, such as a
/// GPS time of 0 before the real ones), or 0 when the values are small (then
/// `f32` keeps them as they are). `always`: use the median whatever its size
/// (GPS time, whose steps matter at any magnitude).
pub(crate) fn attribute_offset(values: &mut Vec<f64>, always: bool) -> f64 {
    values.retain(|v| v.is_finite());
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    let m = m.round();
    if always || m.abs() >= OFFSET_FROM {
        m
    } else {
        0.0
    }
}

/// The input formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputKind {
    Text,
    Ply,
    Las,
    Pcd,
    E57,
}

impl InputKind {
    /// The format's name, as a message says it.
    pub fn name(self) -> &'static str {
        match self {
            InputKind::Text => "text",
            InputKind::Ply => "PLY",
            InputKind::Las => "LAS/LAZ",
            InputKind::Pcd => "PCD",
            InputKind::E57 => "E57",
        }
    }
}

/// Extensions read as text.
pub(crate) const TEXT_EXTENSIONS: &[&str] = &["xyz", "txt", "csv", "asc", "pts"];

/// The format a file's extension names (any case), if it names one.
pub fn kind_by_extension(path: &Path) -> Option<InputKind> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    match ext.as_str() {
        "ply" => Some(InputKind::Ply),
        "las" | "laz" => Some(InputKind::Las),
        "pcd" => Some(InputKind::Pcd),
        "e57" => Some(InputKind::E57),
        e if TEXT_EXTENSIONS.contains(&e) => Some(InputKind::Text),
        _ => None,
    }
}

/// Detects the format of `path` from its first bytes, then its extension.
pub fn detect(path: &Path) -> Result<InputKind, IngestError> {
    let mut magic = [0u8; 8];
    let mut n = 0;
    let mut f = std::fs::File::open(path).map_err(|e| IngestError::io(path, "cannot open", e))?;
    while n < 8 {
        match f.read(&mut magic[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(IngestError::io(path, "cannot read", e)),
        }
    }
    if n >= 4 && (&magic[..4] == b"ply\n" || &magic[..4] == b"ply\r") {
        return Ok(InputKind::Ply);
    }
    if n >= 4 && &magic[..4] == b"LASF" {
        return Ok(InputKind::Las);
    }
    if n == 8 && &magic == b"ASTM-E57" {
        return Ok(InputKind::E57);
    }
    if pcd::header::sniff(&magic[..n]) {
        return Ok(InputKind::Pcd);
    }
    if let Some(kind) = kind_by_extension(path) {
        return Ok(kind);
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "" => Err(IngestError::format(
            path,
            "unknown input format: no file extension and no recognised signature \
             (supported: .xyz .txt .csv .asc .pts .ply .las .laz .pcd .e57)",
        )),
        e => Err(IngestError::format(
            path,
            format!(
                "unknown input format '.{}' (supported: .xyz .txt .csv .asc .pts .ply .las .laz .pcd .e57)",
                pcimg_core::text::sanitize(e)
            ),
        )),
    }
}

/// Opens a URL as a byte source for COPC: set once by a program that has an
/// object-storage client (the binary sets `store::remote::copc::RemoteBytes`);
/// without one a URL input is refused.
pub type UrlOpener =
    dyn Fn(&str) -> Result<std::sync::Arc<dyn pcimg_copc::ByteSource>, String> + Send + Sync;

static URL_OPENER: std::sync::OnceLock<Box<UrlOpener>> = std::sync::OnceLock::new();

/// Sets how URL inputs are opened (once; later calls are ignored).
pub fn set_url_opener(f: Box<UrlOpener>) {
    let _ = URL_OPENER.set(f);
}

/// Whether `path` is a URL input (object storage or HTTP).
pub fn is_url(path: &Path) -> bool {
    const SCHEMES: [&str; 8] = [
        "s3://", "s3a://", "gs://", "az://", "abfs://", "abfss://", "http://", "https://",
    ];
    let s = path.to_string_lossy().to_ascii_lowercase();
    SCHEMES.iter().any(|p| s.starts_with(p))
}

/// Opens the COPC file at URL `path`.
fn open_url(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    Ok(Box::new(copc::from_copc(opened_url(path)?, opts)?))
}

/// The byte source of the URL `path` (through [`set_url_opener`]).
pub(crate) fn url_source(path: &Path) -> Result<Arc<dyn pcimg_copc::ByteSource>, IngestError> {
    let Some(opener) = URL_OPENER.get() else {
        return Err(IngestError::format(
            path,
            "this program reads no URLs (it has no object-storage client)",
        ));
    };
    opener(&path.to_string_lossy()).map_err(|m| IngestError::format(path, m))
}

/// The whole file at `path`, local or a URL (a small file read whole: an EPT
/// dataset's JSON, a survey's index).
pub fn read_whole(path: &Path) -> Result<Vec<u8>, IngestError> {
    if is_url(path) {
        return read_url(path);
    }
    std::fs::read(path).map_err(|e| IngestError::io(path, "cannot read", e))
}

/// The whole object at URL `path` (through [`set_url_opener`]).
pub fn read_url(path: &Path) -> Result<Vec<u8>, IngestError> {
    url_source(path)?
        .read_all()
        .map_err(|e| IngestError::format(path, e.to_string()))
}

/// The COPC file at URL `path`, opened once per process.
pub(crate) fn opened_url(path: &Path) -> Result<Arc<pcimg_copc::Copc>, IngestError> {
    let url = path.to_string_lossy();
    let Some(opener) = URL_OPENER.get() else {
        return Err(IngestError::format(
            path,
            "this program reads no URLs (it has no object-storage client)",
        ));
    };
    // A conversion opens its inputs more than once (to plan, then to read):
    // the header and hierarchy pages read the first time are kept.
    type Opened = std::sync::Mutex<std::collections::HashMap<String, Arc<pcimg_copc::Copc>>>;
    static OPENED: std::sync::OnceLock<Opened> = std::sync::OnceLock::new();
    let opened = OPENED.get_or_init(Default::default);
    let known = opened
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .get(url.as_ref())
        .cloned();
    let copc = match known {
        Some(c) => c,
        None => {
            let source = opener(&url).map_err(|m| IngestError::format(path, m))?;
            let c = Arc::new(copc::open_copc(source).map_err(|mut e| {
                if e.kind == pcimg_copc::Kind::NotCopc {
                    e.what += "; from a URL only COPC files are read: download it first";
                }
                copc::error(e)
            })?);
            opened
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .insert(url.to_string(), c.clone());
            c
        }
    };
    Ok(copc)
}

/// Opens a point-cloud file (or, through [`set_url_opener`], a COPC file at a
/// URL) for chunked reading.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    if opts.chunk_points == 0 {
        return Err(IngestError::format(path, "chunk_points must be at least 1"));
    }
    if ept::is_ept(path) {
        return Ok(Box::new(ept::open(path, opts)?));
    }
    if is_url(path) {
        return open_url(path, opts);
    }
    let kind = detect(path)?;
    if opts.columns.is_some() && kind != InputKind::Text {
        return Err(IngestError::format(
            path,
            format!(
                "a column layout applies only to text inputs, and this is {}",
                kind.name()
            ),
        ));
    }
    if opts.region.is_some() {
        if kind != InputKind::Las || !copc::is_copc(path) {
            return Err(IngestError::format(
                path,
                format!(
                    "a region is read only from COPC and EPT inputs (their octree says which \
                     points lie in it), and this is {}",
                    kind.name()
                ),
            ));
        }
        return Ok(Box::new(copc::open(path, opts)?));
    }
    let reader: Box<dyn PointReader> = match kind {
        InputKind::Text => Box::new(text::TextReader::open(path, opts)?),
        InputKind::Ply => ply::open(path, opts)?,
        InputKind::Las => las::open(path, opts)?,
        InputKind::Pcd => pcd::open(path, opts)?,
        InputKind::E57 => e57::open(path, opts)?,
    };
    let attributes = reader.info().attribute_names.len();
    if attributes > crate::points::MAX_ATTRIBUTES {
        let msg = format!(
            "{attributes} attribute columns besides x y z; a part stores at most {}",
            crate::points::MAX_ATTRIBUTES,
        );
        return Err(if kind == InputKind::Text {
            IngestError::columns(path, None, msg)
        } else {
            IngestError::format(path, msg)
        });
    }
    Ok(reader)
}

/// Reads a whole file into memory: for small inputs and tests.
pub fn read_all(
    path: &Path,
    opts: &ReadOptions,
) -> Result<(SourceInfo, PointColumns, u64), IngestError> {
    let mut r = open(path, opts)?;
    let mut all = PointColumns {
        attributes: r
            .info()
            .attribute_names
            .iter()
            .map(|n| crate::points::Attribute::new(n.clone(), Vec::new()))
            .collect(),
        ..Default::default()
    };
    while let Some(c) = r.next_chunk()? {
        all.append(&c).map_err(|m| IngestError::format(path, m))?;
    }
    Ok((r.info().clone(), all, r.skipped()))
}

/// The canonical attribute (band) name for a source column or property name.
pub fn canonical_name(name: &str) -> String {
    let n = name.trim().to_ascii_lowercase();
    if let Some(c) = color::color_name(&n) {
        return c.to_string();
    }
    match n.as_str() {
        "i" | "intensity" | "scalar_intensity" => "intensity".into(),
        "class" | "classification" | "scalar_classification" => "classification".into(),
        "gps_time" | "gpstime" | "scalar_gpstime" => "gps_time".into(),
        "return_number" | "returnnumber" => "return_number".into(),
        "number_of_returns" | "numberofreturns" => "number_of_returns".into(),
        _ => n,
    }
}

/// [`canonical_name`] of every name of one file's columns or properties, except
/// that the one-letter `r`, `g` and `b` name colour only when all three channels
/// are named (by letter or name; a lone `b` column keeps its name and values).
pub fn canonical_names<S: AsRef<str>>(raw: &[S]) -> Vec<String> {
    let low: Vec<String> = raw
        .iter()
        .map(|s| s.as_ref().trim().to_ascii_lowercase())
        .collect();
    // Every channel named, by its letter or any colour name ("x y z red g blue").
    let triple = ["red", "green", "blue"]
        .iter()
        .all(|c| low.iter().any(|n| color::color_name(n) == Some(*c)));
    low.iter()
        .map(|n| match n.as_str() {
            "r" | "g" | "b" if !triple => n.clone(),
            _ => canonical_name(n),
        })
        .collect()
}

/// Opens and memory-maps a file, refusing empty files.
pub(crate) fn map_file(path: &Path) -> Result<memmap2::Mmap, IngestError> {
    let f = std::fs::File::open(path).map_err(|e| IngestError::io(path, "cannot open", e))?;
    let len = f
        .metadata()
        .map_err(|e| IngestError::io(path, "cannot stat", e))?
        .len();
    if len == 0 {
        return Err(IngestError::format(path, "the file is empty"));
    }
    // SAFETY: the map is read-only; like every reader of memory-mapped input we rely
    // on the file not being truncated by another process while it is read.
    let map = unsafe { memmap2::Mmap::map(&f) }
        .map_err(|e| IngestError::io(path, "cannot memory-map", e))?;
    #[cfg(unix)]
    let _ = map.advise(memmap2::Advice::Sequential);
    Ok(map)
}

/// Drops the page mappings of the consumed bytes `map[*released..upto]`, so that
/// the resident size of a reader stays about one window even on an input larger
/// than memory (the pages stay in the page cache; the kernel reclaims them).
pub(crate) fn release_consumed(map: &memmap2::Mmap, released: &mut usize, upto: usize) {
    const STEP: usize = 16 << 20;
    let upto = upto.min(map.len());
    if upto < *released + STEP && upto < map.len() {
        return;
    }
    #[cfg(unix)]
    {
        // SAFETY: `map` is a read-only shared file mapping. MADV_DONTNEED only drops
        // page-table entries; a later access would fault the same file contents back
        // in, so no reference ever sees different data.
        let _ = unsafe {
            map.unchecked_advise_range(
                memmap2::UncheckedAdvice::DontNeed,
                *released,
                upto - *released,
            )
        };
    }
    *released = upto;
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn unknown_extension_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cloud.e58");
        std::fs::File::create(&p)
            .unwrap()
            .write_all(b"1 2 3\n")
            .unwrap();
        let e = open(&p, &ReadOptions::default()).err().unwrap();
        let s = e.to_string();
        assert!(s.contains("cloud.e58") && s.contains(".e58"), "{s}");
        let p = dir.path().join("noext");
        std::fs::File::create(&p)
            .unwrap()
            .write_all(b"1 2 3\n")
            .unwrap();
        assert!(open(&p, &ReadOptions::default()).is_err());
    }

    #[test]
    fn content_sniffing_beats_extension() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("actually_ply.txt");
        std::fs::write(
            &p,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
        )
        .unwrap();
        assert_eq!(detect(&p).unwrap(), InputKind::Ply);
        let (info, pts, _) = read_all(&p, &ReadOptions::default()).unwrap();
        assert_eq!(info.format, "ply-ascii");
        assert_eq!(pts.x, vec![1.0]);
    }

    #[test]
    fn missing_file_and_zero_chunk() {
        let e = open(Path::new("/nonexistent/x.xyz"), &ReadOptions::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains("/nonexistent/x.xyz"));
        let opts = ReadOptions {
            chunk_points: 0,
            ..Default::default()
        };
        assert!(open(Path::new("/nonexistent/x.xyz"), &opts).is_err());
    }

    #[test]
    fn names() {
        assert_eq!(canonical_name("R"), "red");
        assert_eq!(canonical_name("Intensity"), "intensity");
        assert_eq!(canonical_name("Label"), "label");
        assert_eq!(canonical_names(&["x", "b", "I"]), ["x", "b", "intensity"]);
        assert_eq!(canonical_names(&["R", "g", "b"]), ["red", "green", "blue"]);
        assert_eq!(
            canonical_names(&["red", "g", "Blue"]),
            ["red", "green", "blue"]
        );
    }
}
