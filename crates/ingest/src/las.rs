//! LAS 1.0–1.4 and LAZ input through the `las` crate (with its `laz` feature).
//!
//! * Columns: x y z (scaled and offset to `f64`), `intensity`, `return_number`,
//!   `number_of_returns`, `classification`, `gps_time` (formats with time; its
//!   offset is the median of the first 4,096 points' times (see
//!   `ingest::attribute_offset`), so `f32` keeps steps of 1 ms or finer within
//!   2.3 hours of it),
//!   `red` `green` `blue` (formats with colour; 0–255 by the rule in
//!   [`super::color`]: 16-bit colour is divided by 257 unless every value of the
//!   first chunk is ≤ 255, i.e. 8-bit values stored in 16-bit fields), `nir`.
//! * CRS: the WKT VLR (`LASF_Projection` 2112) when present, otherwise
//!   `EPSG:<code>` from the GeoTIFF keys (ProjectedCSTypeGeoKey 3072, else
//!   GeographicTypeGeoKey 2048), otherwise a note that GeoTIFF keys are present.
//! * Reading: `las::Reader` is not `Send`, so it lives on a decoder thread that
//!   reads chunks with `fill_points` and converts them to columns one chunk ahead
//!   of the consumer (a bounded channel of one chunk). The thread starts with the
//!   first read, so opening a file for its header decodes nothing. LAS records
//!   are decoded in small batches that stay in cache; LAZ uses the `laz-parallel`
//!   decompressor (chunks decompressed with rayon) in large batches, falling back
//!   to the sequential one when the file has no chunk table. Sampling
//!   ([`PointReader::sample_rest`]) seeks through the chunk table, so a file
//!   without one reads every point. A panic in the decoder (the
//!   `laz` crate can panic on corrupt data) is caught and reported as an error;
//!   the default panic hook still prints its message to stderr.
//! * Truncation: an uncompressed file shorter than its header declares is refused
//!   at open; a LAZ file whose chunk table lies past the end of the file is
//!   refused at open; any later read failure is an error naming the byte offset
//!   the decoder had reached.

use crate::bigvec;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use super::color::ColorNormalizer;
use super::contain::contain;
use super::error::IngestError;
use super::{PointReader, ReadOptions, SourceInfo};
use crate::points::{Attribute, PointColumns};

/// A file that publishes its read position (for progress and error offsets).
struct Tracked {
    file: File,
    pos: Arc<AtomicU64>,
}

impl Read for Tracked {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.file.read(buf)?;
        self.pos.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

impl Seek for Tracked {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let p = self.file.seek(to)?;
        self.pos.store(p, Ordering::Relaxed);
        Ok(p)
    }
}

enum Msg {
    /// Decoded points; `true` when they are a sampled piece (see
    /// [`PointReader::sample_rest`]).
    Chunk(PointColumns, bool),
    Err(IngestError),
}

/// Starts a decoder thread and returns its channel.
type Spawn = Box<dyn FnOnce() -> Result<Receiver<Msg>, IngestError> + Send>;

/// Reader for LAS and LAZ files.
pub(crate) struct LasReader {
    info: SourceInfo,
    /// The decoder's channel, once started.
    rx: Option<Receiver<Msg>>,
    /// Starts the decoder (taken by the first read).
    spawn: Option<Spawn>,
    pos: Arc<AtomicU64>,
    finished: bool,
    /// Shared with the decoder: 1 to read every point, `every` > 1 to sample, 0
    /// when the file cannot seek (no chunk table).
    every: Arc<AtomicU64>,
    /// The sampling rate asked for (1: none), to thin a whole chunk the decoder
    /// had decoded before it saw the request.
    thin: u64,
    /// The decoder's count of clamped colour values.
    clamped: Arc<AtomicU64>,
}

/// The band each LAS point field the reader keeps becomes, in the order it
/// gives them (a format without time, colour or near-infrared leaves those
/// out); `pcimg export` writes them back to the same fields.
///
/// `scan_angle` is in degrees (LAS 1.4's formats 6 to 10 count 0.006° steps;
/// the older ones whole degrees). `las_flags` packs the flags as LAS 1.4's
/// formats 6 to 10 lay out their byte 15 (whatever the source's format): bits
/// 0 to 3 synthetic, key-point, withheld, overlap; 4 and 5 the scanner channel;
/// 6 the scan direction; 7 the edge of a flight line ([`LAS_FLAGS`]).
pub const LAS_BANDS: [&str; 13] = [
    "intensity",
    "return_number",
    "number_of_returns",
    "classification",
    "gps_time",
    "red",
    "green",
    "blue",
    "nir",
    "scan_angle",
    "user_data",
    "point_source_id",
    "las_flags",
];

/// The fields packed in the `las_flags` band: name (laspy's), first bit, bits.
pub const LAS_FLAGS: [(&str, u8, u8); 7] = [
    ("synthetic", 0, 1),
    ("key_point", 1, 1),
    ("withheld", 2, 1),
    ("overlap", 3, 1),
    ("scanner_channel", 4, 2),
    ("scan_direction_flag", 6, 1),
    ("edge_of_flight_line", 7, 1),
];

/// The attribute names for a point format.
pub(crate) fn attribute_names(f: &las::point::Format) -> Vec<String> {
    let mut v: Vec<&str> = LAS_BANDS[..4].to_vec();
    if f.has_gps_time {
        v.push(LAS_BANDS[4]);
        v.extend(pcimg_core::time::EXACT_BANDS);
    }
    if f.has_color {
        v.extend(&LAS_BANDS[5..8]);
    }
    if f.has_nir {
        v.push(LAS_BANDS[8]);
    }
    v.extend(&LAS_BANDS[9..]);
    v.into_iter().map(String::from).collect()
}

/// A record's flags as the `las_flags` band packs them ([`LAS_BANDS`]): the
/// extended formats' byte 15 as it is; the older formats' scan direction and
/// edge bits (byte 14, bits 6 and 7) and their synthetic, key-point and
/// withheld bits (byte 15, bits 5 to 7) moved there.
#[inline]
pub(crate) fn las_flags(record: &[u8], extended: bool) -> u8 {
    if extended {
        record[15]
    } else {
        (record[15] >> 5) | (record[14] & 0xC0)
    }
}

/// The header's bounds, when they are finite and not inverted.
pub(crate) fn declared_bounds(header: &las::Header) -> Option<crate::points::Bounds> {
    let b = header.bounds();
    let (min, max) = ([b.min.x, b.min.y, b.min.z], [b.max.x, b.max.y, b.max.z]);
    let ok = (0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] <= max[a]);
    ok.then_some(crate::points::Bounds { min, max })
}

/// The CRS of a LAS header: WKT, else `EPSG:<code>` from GeoTIFF keys.
pub(crate) fn crs_of(h: &las::Header) -> Option<String> {
    if let Some(w) = h.get_wkt_crs_bytes() {
        let s = String::from_utf8_lossy(w);
        let s = s.trim_end_matches('\0').trim();
        if !s.is_empty() {
            return Some(s.to_string());
        }
    }
    match h.get_geotiff_crs() {
        Ok(Some(g)) => {
            // A projected key, user-defined (32767) included, says the CRS is
            // projected: its geographic base's code is not the CRS.
            let code = match g.get_projected_crs_geo_key_value() {
                Some(p) => Some(p).filter(|&c| (1024..=32766).contains(&c)),
                None => g
                    .get_geodetic_crs_geo_key_value()
                    .filter(|&c| (1024..=32766).contains(&c)),
            };
            Some(match code {
                Some(c) => format!("EPSG:{c}"),
                None => user_defined(&g),
            })
        }
        _ => None,
    }
}

/// A user-defined CRS in GeoTIFF keys, named by every key and its value (in key
/// order), so that two files compare equal only when their keys do: without an
/// EPSG code the keys are the definition.
fn user_defined(g: &las::crs::GeoTiffCrs) -> String {
    use las::crs::GeoTiffData;
    let mut keys: Vec<&las::crs::GeoTiffKeyEntry> = g.entries.iter().collect();
    keys.sort_by_key(|k| k.id);
    let values: Vec<String> = keys
        .iter()
        .map(|k| match &k.data {
            GeoTiffData::U16(v) => format!("{}={v}", k.id),
            GeoTiffData::String(t) => format!("{}={t:?}", k.id),
            GeoTiffData::Doubles(d) => {
                let d: Vec<String> = d.iter().map(|v| v.to_string()).collect();
                format!("{}={}", k.id, d.join("/"))
            }
        })
        .collect();
    if values.is_empty() {
        "GeoTIFF keys (user-defined CRS)".to_string()
    } else {
        format!("GeoTIFF keys (user-defined CRS: {})", values.join(", "))
    }
}

fn las_err(path: &Path, offset: u64, what: &str, e: impl std::fmt::Display) -> IngestError {
    IngestError::binary(path, offset, format!("{what}: {}", tidy(&e.to_string())))
}

/// The `las` crate's error text in the words of the rest of pcimg's messages.
fn tidy(msg: &str) -> String {
    let msg = msg.strip_prefix("IoError: ").unwrap_or(msg);
    if msg.contains("failed to fill whole buffer") {
        return "the file ends too early (truncated or cut off)".into();
    }
    msg.replace("format point format", "point format")
}

/// Bytes each LAZ chunk takes at least: its first point is stored raw, and the
/// smallest point record (format 0) is 20 bytes.
const MIN_LAZ_CHUNK_BYTES: u64 = 20;

/// Largest LAZ chunk, in points, accepted beyond the file's own point count
/// (LASzip writes 50,000).
const MAX_SPARE_CHUNK_POINTS: u64 = 1 << 22;

/// Checks the laszip VLR against the header: the `laz` crate decodes as many bytes
/// a point as the VLR's items describe (a point size that differs from the
/// header's made it panic), and reserves a whole chunk's decoded points for the
/// last chunk (a corrupt chunk size aborted the process). A chunk size larger
/// than both the file's points and [`MAX_SPARE_CHUNK_POINTS`] is refused; a VLR
/// that cannot be read is left to the decoder, which reports it.
fn check_laz_vlr(
    path: &Path,
    header: &las::Header,
    points: u64,
    chunks: Option<u64>,
) -> Result<(), IngestError> {
    let Some(Ok(vlr)) = contain(|| header.laz_vlr()) else {
        return Ok(());
    };
    let record = u64::from(header.point_format().len());
    match contain(|| vlr.items_size()) {
        Some(items) if items == record => {}
        items => {
            return Err(IngestError::format(
                path,
                format!(
                    "corrupt laszip VLR: its items describe {} a point, the header's point \
                     format {record} bytes",
                    items.map_or("more than 65,535 bytes".into(), |b| format!("{b} bytes"))
                ),
            ));
        }
    }
    if vlr.uses_variable_size_chunks() {
        return Ok(());
    }
    let size = u64::from(vlr.chunk_size());
    if size > points.max(MAX_SPARE_CHUNK_POINTS) {
        return Err(IngestError::format(
            path,
            format!(
                "corrupt laszip VLR: it gives chunks of {size} points, for a file of {points} \
                 points"
            ),
        ));
    }
    // Fixed-size chunks must hold the points the header declares: the
    // parallel decoder sizes its last chunk's buffer from the difference
    // (fewer made it wrap around and panic).
    if let Some(chunks) = chunks
        && chunks.saturating_mul(size) < points
    {
        return Err(IngestError::format(
            path,
            format!(
                "corrupt LAZ file: its chunk table lists {chunks} chunk(s) of {size} points, \
                 fewer than the {points} points the header declares"
            ),
        ));
    }
    Ok(())
}

/// Checks the number of chunks that the LAZ chunk table declares against what the
/// point data can hold (the `laz` crate reserves memory for all of them first, so
/// a corrupt count would abort the process). `table` is the offset written at the
/// start of the point data (`start`); as in `laz`, one that does not lie past it
/// means the table's offset is in the file's last 8 bytes. A table that cannot be
/// found is left to the decoder, which reads sequentially without one. The
/// number of chunks it lists, where found.
fn check_chunk_table(
    path: &Path,
    file: &mut File,
    start: u64,
    table: i64,
    points: u64,
    file_len: u64,
) -> Result<Option<u64>, IngestError> {
    let mut read_at = |at: u64| -> Option<[u8; 8]> {
        let mut b = [0u8; 8];
        file.seek(SeekFrom::Start(at)).ok()?;
        file.read_exact(&mut b).ok()?;
        Some(b)
    };
    let mut at = table;
    if at <= start as i64 {
        match file_len.checked_sub(8).and_then(&mut read_at) {
            Some(b) => at = i64::from_le_bytes(b),
            None => return Ok(None),
        }
    }
    if at <= start as i64 || at as u64 >= file_len {
        return Ok(None);
    }
    let at = at as u64;
    let Some(b) = read_at(at) else {
        return Err(IngestError::binary(
            path,
            file_len,
            format!("truncated LAZ file: it ends inside the chunk table at byte {at}"),
        ));
    };
    let chunks = u64::from(u32::from_le_bytes([b[4], b[5], b[6], b[7]]));
    // (A table offset inside the 8 bytes that hold it leaves no point data.)
    let data = at.saturating_sub(start + 8);
    let most = (data / MIN_LAZ_CHUNK_BYTES).min(points) + 1;
    if chunks > most {
        return Err(IngestError::binary(
            path,
            at + 4,
            format!(
                "corrupt LAZ chunk table: it lists {chunks} chunks, but {} bytes of point \
                 data for {points} points hold at most {most}",
                data
            ),
        ));
    }
    Ok(Some(chunks))
}

/// A LAS/LAZ file whose header has been read and checked.
pub(crate) struct Opened {
    pub file: File,
    pub header: las::Header,
    /// Byte offset of the first point record.
    pub start: u64,
    /// Bytes per point record (uncompressed files).
    pub record_len: u64,
    pub info: SourceInfo,
}

/// Opens a LAS or LAZ file: uncompressed records are decoded straight from a
/// memory map in parallel ([`super::las_records`]), LAZ through the `las` crate.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    let o = open_header(path)?;
    if o.header.point_format().is_compressed {
        Ok(Box::new(LasReader::start(path, o, opts)?))
    } else {
        Ok(Box::new(super::las_records::RecordReader::new(
            path, o, opts,
        )?))
    }
}

/// Reads and checks the header: the point data must lie inside the file.
pub(crate) fn open_header(path: &Path) -> Result<Opened, IngestError> {
    {
        let mut file = File::open(path).map_err(|e| IngestError::io(path, "cannot open", e))?;
        let file_len = file
            .metadata()
            .map_err(|e| IngestError::io(path, "cannot stat", e))?
            .len();
        if file_len == 0 {
            return Err(IngestError::format(path, "the file is empty"));
        }
        let mut magic = [0u8; 4];
        let got = file
            .read(&mut magic)
            .map_err(|e| IngestError::io(path, "cannot read", e))?;
        if got < 4 && b"LASF".starts_with(&magic[..got]) {
            return Err(IngestError::binary(
                path,
                got as u64,
                "truncated file: it ends inside the LAS signature",
            ));
        }
        if &magic[..got] != b"LASF" {
            return Err(IngestError::binary(
                path,
                0,
                format!(
                    "not a LAS file: it starts with \"{}\", not \"LASF\"",
                    pcimg_core::text::sanitize(&String::from_utf8_lossy(&magic[..got]))
                ),
            ));
        }
        file.seek(SeekFrom::Start(0))
            .map_err(|e| IngestError::io(path, "cannot seek", e))?;
        let raw = las::raw::Header::read_from(&mut BufReader::new(&mut file))
            .map_err(|e| las_err(path, 0, "cannot read the LAS header", e))?;
        file.seek(SeekFrom::Start(0))
            .map_err(|e| IngestError::io(path, "cannot seek", e))?;
        // The header parser runs on corrupt input: contain a panic in it as well.
        let header = contain(|| las::Header::new(&mut BufReader::new(&mut file)))
            .ok_or_else(|| IngestError::binary(path, 0, "the LAS header is corrupt"))?
            .map_err(|e| las_err(path, 0, "cannot read the LAS header and VLRs", e))?;
        // Scale factors and offsets (header bytes 131.. and 155..): a zero or
        // non-finite scale would turn every coordinate into one value or NaN.
        let scales = [raw.x_scale_factor, raw.y_scale_factor, raw.z_scale_factor];
        let offsets = [raw.x_offset, raw.y_offset, raw.z_offset];
        for (a, axis) in ["x", "y", "z"].iter().enumerate() {
            if !scales[a].is_finite() || scales[a] == 0.0 {
                return Err(IngestError::binary(
                    path,
                    131 + 8 * a as u64,
                    format!(
                        "the header's {axis} scale factor is {}; it must be a finite, non-zero \
                         number",
                        scales[a]
                    ),
                ));
            }
            if !offsets[a].is_finite() {
                return Err(IngestError::binary(
                    path,
                    155 + 8 * a as u64,
                    format!("the header's {axis} offset is {}", offsets[a]),
                ));
            }
        }
        let format = *header.point_format();
        let version = header.version();
        let n = header.number_of_points();
        let start = u64::from(raw.offset_to_point_data);
        if start > file_len {
            return Err(IngestError::binary(
                path,
                file_len,
                format!("truncated file: point data should start at byte {start}"),
            ));
        }
        if format.is_compressed {
            // LAZ point data starts with the offset of the chunk table (at the end).
            let mut b = [0u8; 8];
            file.seek(SeekFrom::Start(start))
                .map_err(|e| IngestError::io(path, "cannot seek", e))?;
            // The decoder reads the chunk table whatever the header's point
            // count, so a file that declares no points is checked too (a
            // corrupt table behind a count of 0 aborted the process).
            let read = file.read_exact(&mut b);
            if read.is_err() && n > 0 {
                return Err(IngestError::binary(
                    path,
                    start,
                    "truncated file: no LAZ point data",
                ));
            }
            if read.is_ok() {
                let table = i64::from_le_bytes(b);
                if table > 0 && table as u64 >= file_len {
                    return Err(IngestError::binary(
                        path,
                        file_len,
                        format!(
                            "truncated LAZ file: its chunk table should be at byte {table} \
                             but the file ends at byte {file_len}"
                        ),
                    ));
                }
                let chunks = check_chunk_table(path, &mut file, start, table, n, file_len)?;
                check_laz_vlr(path, &header, n, chunks)?;
            }
        } else {
            let rec = u64::from(format.len());
            let need = n.checked_mul(rec).and_then(|b| b.checked_add(start));
            match need {
                Some(end) if end <= file_len => {}
                _ => {
                    let whole = (file_len - start) / rec.max(1);
                    return Err(IngestError::binary(
                        path,
                        file_len,
                        format!(
                            "truncated file: the header declares {n} points of {rec} bytes from \
                             byte {start}, but the file ends at byte {file_len} after {whole} \
                             complete points"
                        ),
                    ));
                }
            }
        }
        file.seek(SeekFrom::Start(0))
            .map_err(|e| IngestError::io(path, "cannot seek", e))?;
        let record_len = u64::from(raw.point_data_record_length);
        let info = SourceInfo {
            path: path.to_path_buf(),
            format: format!(
                "{} {}.{}",
                if format.is_compressed { "laz" } else { "las" },
                version.major,
                version.minor
            ),
            declared_points: Some(n),
            declared_bounds: declared_bounds(&header),
            crs_wkt: crs_of(&header),
            attribute_names: attribute_names(&format),
            file_bytes: file_len,
            notes: Vec::new(),
            metadata: vec![(
                crate::points::key::LAS_POINT_FORMAT.to_string(),
                format.to_u8().map_or(String::new(), |f| f.to_string()),
            )],
            coordinate_step: Some(scales.map(f64::abs)),
            coordinate_lattice: Some(crate::points::Lattice {
                step: scales,
                origin: offsets,
            }),
        };
        Ok(Opened {
            file,
            header,
            start,
            record_len,
            info,
        })
    }
}

impl LasReader {
    /// Reads `path` through the `las` crate on a decoder thread.
    #[cfg(test)]
    pub(crate) fn open(path: &Path, opts: &ReadOptions) -> Result<LasReader, IngestError> {
        LasReader::start(path, open_header(path)?, opts)
    }

    fn start(path: &Path, o: Opened, opts: &ReadOptions) -> Result<LasReader, IngestError> {
        let Opened {
            file, header, info, ..
        } = o;
        let n = header.number_of_points();
        let pos = Arc::new(AtomicU64::new(0));
        let tracked = Tracked {
            file,
            pos: pos.clone(),
        };
        let chunk = opts.chunk_points as u64;
        let p = path.to_path_buf();
        let pos2 = pos.clone();
        let every = Arc::new(AtomicU64::new(1));
        let every2 = every.clone();
        let colors = ColorNormalizer::new(false);
        let clamped = colors.clamped();
        // The decoder starts with the first read, so a reader opened only for its
        // header decodes nothing.
        let spawn = move || -> Result<Receiver<Msg>, IngestError> {
            let (tx, rx) = sync_channel(1);
            let path = p.clone();
            std::thread::Builder::new()
                .name("pcimg-las".into())
                .spawn(move || {
                    let tx2 = tx.clone();
                    let r = contain(move || decode(p, tracked, chunk, n, tx2, every2, colors));
                    if r.is_none() {
                        let _ = tx.send(Msg::Err(IngestError::binary(
                            &PathBuf::new(),
                            pos2.load(Ordering::Relaxed),
                            "the LAS/LAZ decoder failed on corrupt data",
                        )));
                    }
                })
                .map_err(|e| IngestError::io(&path, "cannot start the decoder thread", e))?;
            Ok(rx)
        };
        Ok(LasReader {
            info,
            rx: None,
            spawn: Some(Box::new(spawn)),
            pos,
            finished: false,
            every,
            thin: 1,
            clamped,
        })
    }
}

/// The decoder thread: reads chunks and sends them as columns. Once `every` > 1,
/// it sends one piece of [`SAMPLE_PIECE`] points (a LAZ chunk's worth, at a
/// jittered place) for every `every` pieces of the file, seeking past the rest.
fn decode(
    path: PathBuf,
    file: Tracked,
    chunk: u64,
    total: u64,
    tx: SyncSender<Msg>,
    every: Arc<AtomicU64>,
    mut colors: ColorNormalizer,
) {
    let pos = file.pos.clone();
    let err_at = |what: &str, e: &dyn std::fmt::Display| {
        Msg::Err(las_err(&path, pos.load(Ordering::Relaxed), what, e))
    };
    let parallel = las::ReaderOptions::default();
    let reader = match las::Reader::with_options(BufReader::with_capacity(1 << 20, file), parallel)
    {
        Ok(r) => Ok(r),
        // The parallel LAZ decompressor needs the chunk table; without one, fall
        // back to the sequential decompressor on a fresh handle.
        Err(first) => match File::open(&path) {
            Ok(f) => {
                // Without a chunk table the decompressor cannot seek: no sampling.
                every.store(0, Ordering::Relaxed);
                let tracked = Tracked {
                    file: f,
                    pos: pos.clone(),
                };
                let seq =
                    las::ReaderOptions::default().with_laz_parallelism(las::LazParallelism::No);
                las::Reader::with_options(BufReader::with_capacity(1 << 20, tracked), seq)
                    .map_err(|_| first)
            }
            Err(_) => Err(first),
        },
    };
    let mut reader = match reader {
        Ok(r) => r,
        Err(e) => {
            let _ = tx.send(err_at("cannot open the LAS reader", &e));
            return;
        }
    };
    let mut pd = las::PointDataBuilder::new()
        .for_header(reader.header())
        .build();
    let names = attribute_names(pd.format());
    // LAZ decompresses in parallel over its chunks (50,000 points each by
    // default), so it gets large batches; LAS uses small ones that stay in cache.
    let batch_points = if pd.format().is_compressed {
        LAZ_BATCH_POINTS
    } else {
        BATCH_POINTS
    };
    let mut done = 0u64;
    let mut gps_offset: Option<f64> = None;
    while done < total {
        let mut want = chunk.min(total - done);
        let mut span = want;
        let e = every.load(Ordering::Relaxed);
        if e > 1 {
            // A slot of `e` pieces; one of them, chosen by a hash, is read.
            span = (SAMPLE_PIECE * e).min(total - done);
            let k = super::mix(done) % e;
            let at = (k * SAMPLE_PIECE).min(span - 1);
            want = SAMPLE_PIECE.min(span - at);
            if let Err(err) = reader.seek(done + at) {
                let _ = tx.send(err_at(&format!("cannot seek to point {}", done + at), &err));
                return;
            }
        }
        let cap = want as usize;
        let mut cols = PointColumns {
            x: bigvec::with_capacity(cap),
            y: bigvec::with_capacity(cap),
            z: bigvec::with_capacity(cap),
            attributes: names
                .iter()
                .map(|n| Attribute::new(n.clone(), bigvec::with_capacity(cap)))
                .collect(),
        };
        // Decode in small batches so the raw records stay in cache and the raw
        // buffer is reused.
        let mut got_total = 0u64;
        while got_total < want {
            let batch = batch_points.min(want - got_total);
            let got = match reader.fill_points(batch, &mut pd) {
                Ok(g) => g,
                Err(e) => {
                    let at = done + got_total;
                    let _ = tx.send(err_at(
                        &format!("cannot read points {}..{}", at, at + batch),
                        &e,
                    ));
                    return;
                }
            };
            if got == 0 {
                let _ = tx.send(err_at(
                    "the file ends early",
                    &format!("{} of {total} declared points read", done + got_total),
                ));
                return;
            }
            append_columns(&pd, &mut cols, &mut gps_offset);
            got_total += got;
        }
        done += span;
        colors.apply(&mut cols);
        if tx.send(Msg::Chunk(cols, e > 1)).is_err() {
            return; // the consumer is gone
        }
    }
}

/// Points of one sampled piece: a LAZ chunk's worth at the default chunk size
/// (seeks land on chunk starts when the file uses it).
const SAMPLE_PIECE: u64 = 50_000;

/// Points decoded per `fill_points` call (LAS).
const BATCH_POINTS: u64 = 32 * 1024;
/// Points decoded per `fill_points` call (LAZ).
const LAZ_BATCH_POINTS: u64 = 1 << 20;

/// Appends decoded LAS records to columns laid out by [`attribute_names`].
fn append_columns(pd: &las::PointData, cols: &mut PointColumns, gps_offset: &mut Option<f64>) {
    cols.x.extend(pd.x());
    cols.y.extend(pd.y());
    cols.z.extend(pd.z());
    let mut it = cols.attributes.iter_mut();
    let mut next = || it.next();
    if let Some(a) = next() {
        a.values.extend(pd.intensity().map(f32::from));
    }
    if let Some(a) = next() {
        a.values.extend(pd.return_number().map(f32::from));
    }
    if let Some(a) = next() {
        a.values.extend(pd.number_of_returns().map(f32::from));
    }
    if let Some(a) = next() {
        a.values.extend(pd.classification().map(f32::from));
    }
    if let Some(t) = pd.gps_time() {
        let off = match gps_offset {
            Some(o) => *o,
            None => {
                let mut first: Vec<f64> = pd
                    .gps_time()
                    .into_iter()
                    .flatten()
                    .take(super::OFFSET_SAMPLE)
                    .collect();
                *gps_offset.insert(super::attribute_offset(&mut first, true))
            }
        };
        if let (Some(a), Some(lo), Some(mid), Some(hi)) = (next(), next(), next(), next()) {
            a.offset = off;
            for x in t {
                let [v, l, m, h] = pcimg_core::time::split(x, off);
                a.values.push(v);
                lo.values.push(l);
                mid.values.push(m);
                hi.values.push(h);
            }
        }
    }
    if let Some(rgb) = pd.rgb()
        && let (Some(r), Some(g), Some(b)) = (next(), next(), next())
    {
        for (cr, cg, cb) in rgb {
            r.values.push(f32::from(cr));
            g.values.push(f32::from(cg));
            b.values.push(f32::from(cb));
        }
    }
    if let Some(nir) = pd.nir()
        && let Some(a) = next()
    {
        a.values.extend(nir.map(f32::from));
    }
    if let Some(a) = next() {
        a.values.extend(pd.scan_angle_degrees());
    }
    if let Some(a) = next() {
        a.values.extend(pd.user_data().map(f32::from));
    }
    if let Some(a) = next() {
        a.values.extend(pd.point_source_id().map(f32::from));
    }
    if let Some(a) = next() {
        let extended = pd.format().is_extended;
        let rec = pd.record_len();
        a.values.extend(
            pd.raw_bytes()
                .chunks_exact(rec)
                .map(|r| f32::from(las_flags(r, extended))),
        );
    }
}

impl PointReader for LasReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        if self.finished {
            return Ok(None);
        }
        if let Some(spawn) = self.spawn.take() {
            self.rx = Some(spawn()?);
        }
        let Some(rx) = &self.rx else {
            return Ok(None);
        };
        match rx.recv() {
            // A whole chunk decoded before sampling began: thinned to the rate.
            Ok(Msg::Chunk(c, false)) if self.thin > 1 => Ok(Some(c.every_nth(self.thin as usize))),
            Ok(Msg::Chunk(c, _)) => Ok(Some(c)),
            Ok(Msg::Err(e)) => {
                self.finished = true;
                Err(match e {
                    // The panic path has no path at hand: put it back.
                    IngestError::Binary { path, offset, msg } if path.as_os_str().is_empty() => {
                        IngestError::binary(&self.info.path, offset, msg)
                    }
                    e => e,
                })
            }
            Err(_) => {
                self.finished = true;
                Ok(None)
            }
        }
    }

    fn bytes_done(&self) -> u64 {
        if self.finished {
            self.info.file_bytes
        } else {
            self.pos.load(Ordering::Relaxed).min(self.info.file_bytes)
        }
    }

    fn skipped(&self) -> u64 {
        0
    }

    fn clamped_colours(&self) -> u64 {
        self.clamped.load(Ordering::Relaxed)
    }

    fn sample_rest(&mut self, every: u64) -> bool {
        let ok = every > 1
            && self
                .every
                .compare_exchange(1, every, Ordering::Relaxed, Ordering::Relaxed)
                .is_ok();
        if ok {
            self.thin = every;
        }
        ok
    }
}

#[cfg(test)]
mod tests {
    use super::super::{ReadOptions, open, read_all};
    use std::path::Path;

    /// Writes `n` points of format 3 (RGB + GPS time); `color16` picks 16-bit
    /// colour values, otherwise 8-bit values in the 16-bit fields.
    fn write_las(path: &Path, n: usize, color16: bool, wkt: bool) {
        let mut b = las::Builder::default();
        b.version = las::Version::new(1, if wkt { 4 } else { 2 });
        b.point_format = las::point::Format::new(3).unwrap();
        let t = |o| las::Transform {
            scale: 0.01,
            offset: o,
        };
        b.transforms = las::Vector {
            x: t(600000.0),
            y: t(800000.0),
            z: t(0.0),
        };
        if wkt {
            b.vlrs.push(las::Vlr {
                user_id: "LASF_Projection".into(),
                record_id: 2112,
                description: String::new(),
                data: b"PROJCS[\"test\"]\0".to_vec(),
            });
            b.has_wkt_crs = true;
        }
        let header = b.into_header().unwrap();
        let mut w = las::Writer::from_path(path, header).unwrap();
        for i in 0..n {
            let c = (i % 200) as u16 + 10;
            let c = if color16 { c * 257 } else { c };
            w.write_point(las::Point {
                x: 600000.0 + i as f64 * 0.01,
                y: 800000.0 + i as f64 * 0.02,
                z: (i % 1000) as f64 * 0.01,
                intensity: (i % 65536) as u16,
                return_number: 1 + (i % 3) as u8,
                number_of_returns: 3,
                classification: las::point::Classification::new((i % 10) as u8).unwrap(),
                gps_time: Some(300_000_000.0 + i as f64 * 1e-5),
                color: Some(las::Color::new(c, c / 2, c / 3)),
                ..Default::default()
            })
            .unwrap();
        }
        w.close().unwrap();
    }

    /// The laszip VLR check ([`super::check_laz_vlr`]) accepts what LASzip writes:
    /// every point format the `laz` crate compresses, with extra bytes, the
    /// items' point size equal to the header's.
    #[test]
    fn laz_of_every_format_with_extra_bytes_reads() {
        let dir = tempfile::tempdir().unwrap();
        for f in [0u8, 1, 2, 3, 6, 7, 8] {
            let mut b = las::Builder::default();
            b.version = las::Version::new(1, if f >= 6 { 4 } else { 2 });
            let mut format = las::point::Format::new(f).unwrap();
            format.extra_bytes = 3;
            format.is_compressed = true;
            b.point_format = format;
            let path = dir.path().join(format!("f{f}.laz"));
            let mut w = las::Writer::from_path(&path, b.into_header().unwrap()).unwrap();
            for i in 0..1000 {
                w.write_point(las::Point {
                    x: i as f64,
                    y: 2.0 * i as f64,
                    z: 1.0,
                    gps_time: format.has_gps_time.then_some(i as f64),
                    color: format.has_color.then(|| las::Color::new(1, 2, 3)),
                    nir: format.has_nir.then_some(7),
                    extra_bytes: vec![1, 2, 3],
                    ..Default::default()
                })
                .unwrap();
            }
            w.close().unwrap();
            let (info, all, _) = read_all(&path, &ReadOptions::default()).unwrap();
            assert!(info.format.starts_with("laz"), "{}", info.format);
            assert_eq!(all.len(), 1000, "format {f}");
        }
    }

    /// GeoTIFF keys: the projected code, else the geographic one; a user-defined
    /// projected CRS is not its geographic base's code, and is named by its keys.
    #[test]
    fn geotiff_keys_give_the_crs() {
        let crs = |keys: &[(u16, u16)]| {
            let mut data: Vec<u16> = vec![1, 1, 0, keys.len() as u16];
            for &(k, v) in keys {
                data.extend([k, 0, 1, v]);
            }
            let mut b = las::Builder::default();
            b.vlrs.push(las::Vlr {
                user_id: "LASF_Projection".into(),
                record_id: 34735,
                description: String::new(),
                data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            });
            super::crs_of(&b.into_header().unwrap())
        };
        const GEOGRAPHIC: u16 = 2048;
        const PROJECTED: u16 = 3072;
        assert_eq!(
            crs(&[(GEOGRAPHIC, 4269), (PROJECTED, 26910)]).as_deref(),
            Some("EPSG:26910")
        );
        assert_eq!(crs(&[(GEOGRAPHIC, 4326)]).as_deref(), Some("EPSG:4326"));
        // User-defined: named by its keys, so two differing definitions differ.
        assert_eq!(
            crs(&[(PROJECTED, 32767), (GEOGRAPHIC, 4269)]).as_deref(),
            Some("GeoTIFF keys (user-defined CRS: 2048=4269, 3072=32767)")
        );
        assert_ne!(
            crs(&[(GEOGRAPHIC, 4269), (PROJECTED, 32767), (3076, 9001)]),
            crs(&[(GEOGRAPHIC, 4269), (PROJECTED, 32767), (3076, 9002)])
        );
        assert_eq!(crs(&[]).as_deref(), Some("GeoTIFF keys (user-defined CRS)"));
    }

    fn values<'a>(c: &'a crate::points::PointColumns, n: &str) -> &'a crate::points::Attribute {
        c.attributes.iter().find(|a| a.name == n).unwrap()
    }

    fn check_file(path: &Path, n: usize, color16: bool) {
        let (info, c, _) = read_all(path, &ReadOptions::default()).unwrap();
        assert_eq!(info.declared_points, Some(n as u64));
        assert_eq!(c.len(), n);
        for i in [0, n / 2, n - 1] {
            assert!((c.x[i] - (600000.0 + i as f64 * 0.01)).abs() < 1e-6);
            assert!((c.y[i] - (800000.0 + i as f64 * 0.02)).abs() < 1e-6);
            assert_eq!(values(&c, "red").values[i], ((i % 200) + 10) as f32);
            assert_eq!(values(&c, "return_number").values[i], (1 + i % 3) as f32);
            assert_eq!(values(&c, "classification").values[i], (i % 10) as f32);
            let t = values(&c, "gps_time");
            let got = t.offset + t.values[i] as f64;
            assert!(
                (got - (300_000_000.0 + i as f64 * 1e-5)).abs() < 1e-7,
                "{got}"
            );
        }
        let _ = color16;
        // Tiny chunks: same points.
        let opts = ReadOptions {
            chunk_points: 999,
            ..Default::default()
        };
        let mut r = open(path, &opts).unwrap();
        let mut all = c.empty_like();
        while let Some(ch) = r.next_chunk().unwrap() {
            assert!(ch.len() <= 999);
            all.append(&ch).unwrap();
        }
        assert_eq!(all, c);
        assert_eq!(r.bytes_done(), info.file_bytes);
    }

    /// Scan angle, user data, point source ID and every flag, in an older and
    /// an extended format, as the `las` crate's own points give them: the flags
    /// packed as `LAS_FLAGS` says.
    #[test]
    fn scan_angle_user_data_source_and_flags_are_kept() {
        let dir = tempfile::tempdir().unwrap();
        for f in [1u8, 6] {
            let format = las::point::Format::new(f).unwrap();
            let mut b = las::Builder::default();
            b.version = las::Version::new(1, 4);
            b.point_format = format;
            let path = dir.path().join(format!("f{f}.las"));
            let mut w = las::Writer::from_path(&path, b.into_header().unwrap()).unwrap();
            for i in 0..500u32 {
                w.write_point(las::Point {
                    x: i as f64,
                    y: 1.0,
                    z: 2.0,
                    gps_time: Some(i as f64),
                    scan_angle: if format.is_extended {
                        (i as f32 - 250.0) * 0.3
                    } else {
                        (i % 181) as f32 - 90.0
                    },
                    user_data: (i % 256) as u8,
                    point_source_id: (i * 131) as u16,
                    scan_direction: if i.is_multiple_of(2) {
                        las::point::ScanDirection::LeftToRight
                    } else {
                        las::point::ScanDirection::RightToLeft
                    },
                    is_edge_of_flight_line: i.is_multiple_of(3),
                    is_synthetic: i.is_multiple_of(5),
                    is_key_point: i.is_multiple_of(7),
                    is_withheld: i.is_multiple_of(11),
                    is_overlap: format.is_extended && i.is_multiple_of(13),
                    scanner_channel: if format.is_extended { (i % 4) as u8 } else { 0 },
                    ..Default::default()
                })
                .unwrap();
            }
            w.close().unwrap();
            let (_, c, _) = read_all(&path, &ReadOptions::default()).unwrap();
            let data = las::Reader::from_path(&path).unwrap().read_all().unwrap();
            for (i, p) in data.points().enumerate() {
                let p = p.unwrap();
                let want = [p.is_synthetic, p.is_key_point, p.is_withheld, p.is_overlap]
                    .iter()
                    .enumerate()
                    .fold(0u8, |m, (k, &on)| m | (u8::from(on) << k))
                    | p.scanner_channel << 4
                    | u8::from(p.scan_direction == las::point::ScanDirection::LeftToRight) << 6
                    | u8::from(p.is_edge_of_flight_line) << 7;
                let got = |n: &str| values(&c, n).values[i];
                assert_eq!(got("las_flags"), f32::from(want), "format {f}, point {i}");
                assert_eq!(got("scan_angle"), p.scan_angle, "format {f}, point {i}");
                assert_eq!(got("user_data"), f32::from(p.user_data));
                assert_eq!(got("point_source_id"), f32::from(p.point_source_id));
            }
        }
    }

    #[test]
    fn las_and_laz_round_trip() {
        let d = tempfile::tempdir().unwrap();
        for (name, color16) in [
            ("a.las", false),
            ("b.las", true),
            ("c.laz", true),
            ("d.laz", false),
        ] {
            let p = d.path().join(name);
            write_las(&p, 10_000, color16, false);
            check_file(&p, 10_000, color16);
            let r = open(&p, &ReadOptions::default()).unwrap();
            let fmt = if name.ends_with("laz") {
                "laz 1.2"
            } else {
                "las 1.2"
            };
            assert_eq!(r.info().format, fmt);
            assert!(r.info().crs_wkt.is_none());
        }
    }

    /// A LAZ reader opened only for its header decodes nothing: its decoder
    /// starts with the first read (a conversion opens the input once for its
    /// header and attribute names before choosing the chunk size).
    #[test]
    fn laz_decoder_starts_with_the_first_read() {
        let p =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/autzen_trim.laz");
        let mut r = open(&p, &ReadOptions::default()).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(300));
        assert_eq!(r.bytes_done(), 0);
        assert!(r.next_chunk().unwrap().is_some());
        assert!(r.bytes_done() > 0);
    }

    #[test]
    fn las_1_4_format_8_with_nir() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pf8.las");
        let mut b = las::Builder::default();
        b.version = las::Version::new(1, 4);
        b.point_format = las::point::Format::new(8).unwrap();
        let header = b.into_header().unwrap();
        let mut w = las::Writer::from_path(&p, header).unwrap();
        for i in 0..100u16 {
            w.write_point(las::Point {
                x: f64::from(i),
                y: 1.0,
                z: 2.0,
                return_number: 2,
                number_of_returns: 5,
                classification: las::point::Classification::new(40).unwrap(),
                gps_time: Some(245379.39843682514 + f64::from(i) * 1.00792386e-5),
                color: Some(las::Color::new(i * 600, 0, 65535)),
                nir: Some(i),
                ..Default::default()
            })
            .unwrap();
        }
        w.close().unwrap();
        let (info, c, _) = read_all(&p, &ReadOptions::default()).unwrap();
        assert_eq!(info.format, "las 1.4");
        assert_eq!(
            info.attribute_names,
            [
                "intensity",
                "return_number",
                "number_of_returns",
                "classification",
                "gps_time",
                "gps_time_lo",
                "gps_time_mid",
                "gps_time_hi",
                "red",
                "green",
                "blue",
                "nir",
                "scan_angle",
                "user_data",
                "point_source_id",
                "las_flags"
            ]
        );
        assert_eq!(c.len(), 100);
        let a = |n: &str| &values(&c, n).values;
        assert_eq!(a("classification")[5], 40.0);
        assert_eq!(a("number_of_returns")[5], 5.0);
        assert_eq!(a("blue")[5], 255.0);
        assert_eq!(a("red")[99], (99.0f32 * 600.0) / 257.0);
        assert_eq!(a("nir")[99], 99.0);
        // The time, exact through its three whole-number bands.
        let off = values(&c, "gps_time").offset;
        for i in 0..100 {
            let t = pcimg_core::time::join(
                off,
                a("gps_time")[i],
                a("gps_time_lo")[i],
                a("gps_time_mid")[i],
                a("gps_time_hi")[i],
            );
            assert_eq!(t, 245379.39843682514 + i as f64 * 1.00792386e-5);
        }
    }

    #[test]
    fn wkt_crs_is_read() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("w.las");
        write_las(&p, 10, false, true);
        let r = open(&p, &ReadOptions::default()).unwrap();
        assert_eq!(r.info().format, "las 1.4");
        assert_eq!(r.info().crs_wkt.as_deref(), Some("PROJCS[\"test\"]"));
    }

    #[test]
    fn truncated_las_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("full.las");
        write_las(&p, 1000, false, false);
        let data = std::fs::read(&p).unwrap();
        for keep in [3usize, 50, 230, 300, data.len() - 1] {
            let q = d.path().join("cut.las");
            std::fs::write(&q, &data[..keep]).unwrap();
            let e = read_all(&q, &ReadOptions::default()).unwrap_err();
            let s = e.to_string();
            assert!(
                s.contains("cut.las") && s.contains("byte offset"),
                "{keep}: {s}"
            );
        }
        let q = d.path().join("empty.las");
        std::fs::write(&q, b"").unwrap();
        assert!(read_all(&q, &ReadOptions::default()).is_err());
        let q = d.path().join("junk.las");
        std::fs::write(&q, b"this is not a las file at all, no sir").unwrap();
        assert!(read_all(&q, &ReadOptions::default()).is_err());
    }

    #[test]
    fn zero_or_nan_scale_factors_are_errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.las");
        write_las(&p, 100, false, false);
        let data = std::fs::read(&p).unwrap();
        for (at, v, want) in [
            (139usize, 0.0f64, "y scale factor is 0"),
            (131, f64::NAN, "x scale factor is NaN"),
        ] {
            let mut bad = data.clone();
            bad[at..at + 8].copy_from_slice(&v.to_le_bytes());
            let q = d.path().join("bad.las");
            std::fs::write(&q, &bad).unwrap();
            let e = read_all(&q, &ReadOptions::default())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("bad.las")
                    && e.contains(&format!("byte offset {at}"))
                    && e.contains(want),
                "{e}"
            );
        }
    }
}
