//! Points back out of a dataset: a level (every point, or an even sample), the
//! points in a box, of some classes or within band ranges, written as LAS or LAZ
//! (through the `las` crate, LAZ compressed in parallel chunks), binary PLY, or
//! CSV / XYZ text.
//!
//! Only the tiles the selection can reach are read (a tile whose bounds miss the
//! box is not touched, locally, nor fetched, remotely), a batch of tiles at a
//! time, so the export streams in bounded memory whatever the dataset's size.
//! The output is written under a temporary name beside it and renamed into place
//! when complete; a failure or an interruption removes it.
//!
//! Coordinates come back on the source's lattice where the parts keep one (LAS
//! scale and offset, a text file's decimals: `LATTICE`): each point's whole
//! number is recovered exactly and written with the same scale and offset, so a
//! LAS file converted and exported gives the same integers. Whole-number bands
//! (intensity, returns, classification, colour) come back exactly; `gps_time`
//! bit for bit where the part keeps the bands that make it exact (level 0 of a
//! LAS, COPC or EPT source: `pcimg_core::time`), else its offset plus a Float32.

// The LAS point fields pcimg bands fill, by band name (the reader's names).
use crate::ingest::las::LAS_BANDS;
use crate::points::{Bounds, round_whole as round};
use crate::render::filter::Filter;
use crate::render::lod::LoadedTile;
use crate::store::Dataset;
use crate::store::query::{self, Batch, Plan, read_batches};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// What the output is written as, from its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutFormat {
    Las,
    Laz,
    /// Binary little-endian PLY.
    Ply,
    /// Comma-separated, a header line of column names.
    Csv,
    /// Space-separated, no header: x y z, then the other columns.
    Xyz,
}

impl OutFormat {
    /// The format an output path's extension names.
    pub fn of(path: &Path) -> Option<OutFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "las" => OutFormat::Las,
            "laz" => OutFormat::Laz,
            "ply" => OutFormat::Ply,
            "csv" => OutFormat::Csv,
            "xyz" | "txt" => OutFormat::Xyz,
            _ => return None,
        })
    }
}

/// Why an export stopped. The binary words the advice.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: LAS: {message}", path.display())]
    Las { path: PathBuf, message: String },
    #[error("interrupted: nothing was left at {}", path.display())]
    Interrupted { path: PathBuf },
}

/// The tiles of level `level` (each part's coarsest where it has fewer) that
/// `filter` may keep points of, in the parts only (overview nodes hold copies).
pub fn plan(ds: &Dataset, level: usize, filter: &Filter) -> Result<Plan, ExportError> {
    Ok(query::plan(ds, level, |b| filter.may_show(b))?)
}

/// What an export wrote.
#[derive(Debug, Clone)]
pub struct Summary {
    pub points: u64,
    pub bytes: u64,
    pub tiles_read: usize,
    /// LAS: the point format, the version, the scale and offset.
    pub las: Option<LasLayout>,
    /// LAS: the bands written as extra bytes (a double each), not being
    /// fields of the point format.
    pub extra_bytes: Vec<String>,
    /// Where the coordinates come from: the parts' lattice, or a chosen step.
    pub exact_lattice: bool,
}

/// Writes the points `plan` selects (and `filter` keeps) to `out` as `format`,
/// under a temporary name renamed into place at the end. `progress` is told
/// the points read so far and written so far after each batch; `stop` ends
/// the export early (an interruption), leaving nothing behind.
pub fn export(
    ds: &Dataset,
    plan: &Plan,
    filter: &Filter,
    out: &Path,
    format: OutFormat,
    stop: &AtomicBool,
    progress: &dyn Fn(u64, u64),
) -> Result<Summary, ExportError> {
    let tmp = temporary_name(out);
    let guard = Remove(Some(tmp.clone()));
    let file = std::fs::File::create(&tmp).map_err(|source| ExportError::Write {
        path: out.to_path_buf(),
        source,
    })?;
    // An extended LAS format where a source was in one (its overlap flag,
    // scanner channel and finer scan angle have no place in the older ones),
    // or where a part records classes above 31 (the older formats have 5 bits).
    let mut reached: Vec<usize> = plan.tiles.iter().map(|t| t.0).collect();
    reached.dedup();
    let extended = reached.iter().filter_map(|&i| ds.part(i)).any(|p| {
        let from_extended = p.meta.from_source.iter().any(|(k, v)| {
            k == crate::store::spec::key::LAS_POINT_FORMAT && v.parse::<u8>().is_ok_and(|f| f >= 6)
        });
        let high_classes = p
            .bands
            .iter()
            .find(|b| b.name == "classification")
            .and_then(|b| b.range)
            .is_some_and(|(_, hi)| hi > 31.0);
        from_extended || high_classes
    });
    let mut sink = open_sink(file, out, format, plan, extended)?;
    let (mut read, mut written) = (0u64, 0u64);
    let tiles_read = read_batches(ds, &plan.tiles, &plan.bands, |r| {
        if stop.load(Ordering::SeqCst) {
            return Err(ExportError::Interrupted {
                path: out.to_path_buf(),
            });
        }
        let t = LoadedTile::of_read(r);
        read += t.len() as u64;
        let keep = filter.shown(&t);
        let points = t.batch(keep.as_deref(), &plan.bands, plan.lattice);
        written += points.len() as u64;
        sink.write(&points)?;
        progress(read, written);
        Ok(())
    })?;
    let (las, extra_bytes) = sink.finish()?;
    let bytes = std::fs::metadata(&tmp).map(|m| m.len()).unwrap_or(0);
    std::fs::rename(&tmp, out).map_err(|source| ExportError::Write {
        path: out.to_path_buf(),
        source,
    })?;
    guard.keep();
    Ok(Summary {
        points: written,
        bytes,
        tiles_read,
        las,
        extra_bytes,
        exact_lattice: plan.lattice.is_some(),
    })
}

/// `.NAME.pcimg-export-PID` beside `out`.
fn temporary_name(out: &Path) -> PathBuf {
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    out.with_file_name(format!(".{name}.pcimg-export-{}", std::process::id()))
}

/// Removes the temporary file unless the export completed.
struct Remove(Option<PathBuf>);

impl Remove {
    fn keep(mut self) {
        self.0 = None;
    }
}

impl Drop for Remove {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Where points go.
trait Sink {
    fn write(&mut self, b: &Batch) -> Result<(), ExportError>;
    /// Completes the file: LAS's layout, and the bands in its extra bytes.
    fn finish(self: Box<Self>) -> Result<(Option<LasLayout>, Vec<String>), ExportError>;
}

fn open_sink(
    file: std::fs::File,
    out: &Path,
    format: OutFormat,
    plan: &Plan,
    extended: bool,
) -> Result<Box<dyn Sink>, ExportError> {
    let werr = |source| ExportError::Write {
        path: out.to_path_buf(),
        source,
    };
    Ok(match format {
        OutFormat::Las | OutFormat::Laz => Box::new(LasSink::new(
            file,
            out,
            plan,
            format == OutFormat::Laz,
            extended,
        )?),
        OutFormat::Ply => Box::new(PlySink::new(file, out, plan).map_err(werr)?),
        OutFormat::Csv | OutFormat::Xyz => {
            Box::new(TextSink::new(file, out, plan, format == OutFormat::Csv).map_err(werr)?)
        }
    })
}

/// The LAS file's layout.
#[derive(Debug, Clone)]
pub struct LasLayout {
    pub point_format: u8,
    pub version: (u8, u8),
    pub scale: [f64; 3],
    pub offset: [f64; 3],
    /// The CRS went in as a WKT record.
    pub wkt: bool,
}

/// Whether a CRS string is WKT (which a LAS 1.4 WKT record holds), not an
/// authority code.
fn is_wkt(crs: &str) -> bool {
    let head = crs.trim_start().to_ascii_uppercase();
    [
        "PROJCS",
        "GEOGCS",
        "GEOCCS",
        "COMPD_CS",
        "VERT_CS",
        "PROJCRS",
        "GEOGCRS",
        "GEODCRS",
        "COMPOUNDCRS",
        "VERTCRS",
        "BOUNDCRS",
    ]
    .iter()
    .any(|k| head.starts_with(k))
}

/// Scale and offset for coordinates not on a lattice: a millimetre, coarser
/// where the extent would not fit LAS's 32-bit integers.
fn chosen_transform(bounds: &Bounds) -> ([f64; 3], [f64; 3]) {
    let mut scale = [0.001; 3];
    let mut offset = [0.0; 3];
    for a in 0..3 {
        let (lo, hi) = if bounds.is_empty() {
            (0.0, 0.0)
        } else {
            (bounds.min[a], bounds.max[a])
        };
        offset[a] = lo.floor();
        while (hi - offset[a]) / scale[a] > i32::MAX as f64 * 0.99 {
            scale[a] *= 10.0;
        }
    }
    (scale, offset)
}

/// LAS and LAZ: records laid out here, a batch at a time, and handed to the
/// `las` writer on a thread of its own (header statistics, LAZ compression and
/// the file's writes overlap the next batch's reading).
struct LasSink {
    /// Batches to the writer thread (at most one waiting).
    tx: Option<std::sync::mpsc::SyncSender<las::PointData>>,
    thread: Option<std::thread::JoinHandle<Result<(), las::Error>>>,
    /// The format and transforms records are laid out for.
    header: las::Header,
    out: PathBuf,
    /// The column of each LAS field in a batch's bands.
    cols: [Option<usize>; LAS_BANDS.len()],
    /// The columns written as extra bytes (a double each), in order, and
    /// their names.
    extra: Vec<usize>,
    extra_names: Vec<String>,
    layout: LasLayout,
}

impl LasSink {
    fn new(
        file: std::fs::File,
        out: &Path,
        plan: &Plan,
        compressed: bool,
        extended: bool,
    ) -> Result<LasSink, ExportError> {
        let lerr = |e: las::Error| ExportError::Las {
            path: out.to_path_buf(),
            message: e.to_string(),
        };
        let col = |n: &str| plan.bands.iter().position(|b| b == n);
        let cols = LAS_BANDS.map(col);
        let has = |n: &str| col(n).is_some();
        let colour = has("red") || has("green") || has("blue");
        // Formats 6 to 8 where the points need them: near-infrared, more than
        // 2^32 points, classes above 31 or an extended source (`extended`).
        let big_classes = plan.points > u32::MAX as u64 || has("nir") || extended;
        let format_number: u8 = match (big_classes, has("gps_time"), colour) {
            (true, _, _) if has("nir") => 8,
            (true, _, true) => 7,
            (true, _, false) => 6,
            (false, false, false) => 0,
            (false, true, false) => 1,
            (false, false, true) => 2,
            (false, true, true) => 3,
        };
        let mut format = las::point::Format::new(format_number).map_err(lerr)?;
        format.is_compressed = compressed;
        // Bands LAS has no field for go in as extra bytes, a double each
        // (`offset + Float32`, as stored), described by the Extra Bytes record.
        let extra: Vec<usize> = (0..plan.bands.len())
            .filter(|&c| !LAS_BANDS.contains(&plan.bands[c].as_str()))
            .collect();
        format.extra_bytes = (8 * extra.len()) as u16;
        let (scale, offset) = match plan.lattice {
            Some(l) => (l.step, l.origin),
            None => chosen_transform(&plan.bounds),
        };
        let mut builder = las::Builder::from((1, 4));
        builder.point_format = format;
        builder.generating_software = format!("pcimg {}", env!("CARGO_PKG_VERSION"));
        builder.transforms = las::Vector {
            x: las::Transform {
                scale: scale[0],
                offset: offset[0],
            },
            y: las::Transform {
                scale: scale[1],
                offset: offset[1],
            },
            z: las::Transform {
                scale: scale[2],
                offset: offset[2],
            },
        };
        let wkt = plan.crs.as_deref().filter(|c| is_wkt(c));
        if let Some(w) = wkt {
            let mut data = w.as_bytes().to_vec();
            data.push(0);
            builder.vlrs.push(las::Vlr {
                user_id: "LASF_Projection".into(),
                record_id: 2112,
                description: "OGC WKT".into(),
                data,
            });
            builder.has_wkt_crs = true;
        }
        if !extra.is_empty() {
            builder.vlrs.push(las::Vlr {
                user_id: "LASF_Spec".into(),
                record_id: 4,
                description: "Extra Bytes".into(),
                data: extra
                    .iter()
                    .flat_map(|&c| extra_bytes_descriptor(&plan.bands[c]))
                    .collect(),
            });
        }
        let header = builder.into_header().map_err(lerr)?;
        let writer =
            las::Writer::new(BufWriter::with_capacity(1 << 20, file), header).map_err(lerr)?;
        let header = writer.header().clone();
        let (tx, rx) = std::sync::mpsc::sync_channel::<las::PointData>(1);
        let thread = std::thread::Builder::new()
            .name("pcimg-export-write".into())
            .spawn(move || {
                let mut writer = writer;
                for data in rx {
                    writer.write_points(&data)?;
                }
                writer.close()
            })
            .map_err(|source| ExportError::Write {
                path: out.to_path_buf(),
                source,
            })?;
        Ok(LasSink {
            tx: Some(tx),
            thread: Some(thread),
            header,
            out: out.to_path_buf(),
            cols,
            extra_names: extra.iter().map(|&c| plan.bands[c].clone()).collect(),
            extra,
            layout: LasLayout {
                point_format: format_number,
                version: (1, 4),
                scale,
                offset,
                wkt: wkt.is_some(),
            },
        })
    }
}

/// An Extra Bytes record's descriptor (LAS 1.4 R15, table 24) of a double
/// named `name` (at most 31 bytes of it) with no scale, offset or no-data.
fn extra_bytes_descriptor(name: &str) -> [u8; 192] {
    let mut d = [0u8; 192];
    d[2] = 10; // data type: double
    let n = name.as_bytes();
    let len = n.len().min(31);
    d[4..4 + len].copy_from_slice(&n[..len]);
    let what = b"a pcimg band";
    d[160..160 + what.len()].copy_from_slice(what);
    d
}

impl LasSink {
    /// The writer thread's error once it has stopped.
    fn stop(&mut self) -> ExportError {
        self.tx = None;
        let message = match self.thread.take().map(|t| t.join()) {
            Some(Ok(Err(e))) => e.to_string(),
            _ => "the writer thread stopped".into(),
        };
        ExportError::Las {
            path: self.out.clone(),
            message,
        }
    }
}

impl Drop for LasSink {
    /// An export that failed part-way: the writer thread ends with the channel.
    fn drop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Sink for LasSink {
    fn write(&mut self, b: &Batch) -> Result<(), ExportError> {
        use rayon::prelude::*;
        let header = &self.header;
        let fmt = self.layout.point_format;
        let rec = header.point_format().len() as usize;
        let t = header.transforms();
        let (tx, ty, tz) = (t.x, t.y, t.z);
        let cols = self.cols;
        let extra = &self.extra;
        let get = |k: usize, i: usize| -> Option<f64> {
            cols[k].map(|c| b.bands[c][i]).filter(|v| v.is_finite())
        };
        let whole =
            |k: usize, i: usize, max: f64| get(k, i).map_or(0.0, |v| round(v).clamp(0.0, max));
        let int = |v: f64, t: las::Transform| round((v - t.offset) / t.scale) as i32;
        let mut bytes = vec![0u8; b.len() * rec];
        // Records laid out by hand (LAS 1.4 R15, tables 7 to 16), in parallel:
        // the crate's per-point path (`Point` → raw → bytes, and the header's
        // per-point statistics) took two thirds of an export's time.
        bytes.par_chunks_mut(rec).enumerate().for_each(|(i, r)| {
            r[0..4].copy_from_slice(&int(b.x[i], tx).to_le_bytes());
            r[4..8].copy_from_slice(&int(b.y[i], ty).to_le_bytes());
            r[8..12].copy_from_slice(&int(b.z[i], tz).to_le_bytes());
            r[12..14].copy_from_slice(&(whole(0, i, 65535.0) as u16).to_le_bytes());
            let colour = |r: &mut [u8], at: usize| {
                for (k, band) in [5, 6, 7].into_iter().enumerate() {
                    let v = whole(band, i, 65535.0) as u16;
                    r[at + 2 * k..at + 2 * k + 2].copy_from_slice(&v.to_le_bytes());
                }
            };
            let time = get(4, i).unwrap_or(0.0).to_le_bytes();
            let angle = get(9, i).unwrap_or(0.0);
            let flags = whole(12, i, 255.0) as u8;
            let source = (whole(11, i, 65535.0) as u16).to_le_bytes();
            r[17] = whole(10, i, 255.0) as u8;
            if fmt < 6 {
                let (ret, n) = (whole(1, i, 7.0) as u8, whole(2, i, 7.0) as u8);
                // Scan direction and edge (bits 6, 7 of both), then synthetic,
                // key-point and withheld (the flags' bits 0 to 2, byte 15's
                // bits 5 to 7): `LAS_FLAGS`.
                r[14] = ret | n << 3 | (flags & 0xC0);
                r[15] = whole(3, i, 31.0) as u8 | (flags & 7) << 5;
                r[16] = round(angle).clamp(-90.0, 90.0) as i8 as u8;
                r[18..20].copy_from_slice(&source);
                if matches!(fmt, 1 | 3) {
                    r[20..28].copy_from_slice(&time);
                }
                match fmt {
                    2 => colour(r, 20),
                    3 => colour(r, 28),
                    _ => {}
                }
            } else {
                let (ret, n) = (whole(1, i, 15.0) as u8, whole(2, i, 15.0) as u8);
                r[14] = ret | n << 4;
                r[15] = flags;
                r[16] = whole(3, i, 255.0) as u8;
                let steps = round(angle / 0.006).clamp(-30_000.0, 30_000.0) as i16;
                r[18..20].copy_from_slice(&steps.to_le_bytes());
                r[20..22].copy_from_slice(&source);
                r[22..30].copy_from_slice(&time);
                if fmt >= 7 {
                    colour(r, 30);
                }
                if fmt == 8 {
                    r[36..38].copy_from_slice(&(whole(8, i, 65535.0) as u16).to_le_bytes());
                }
            }
            let at = rec - 8 * extra.len();
            for (k, &c) in extra.iter().enumerate() {
                r[at + 8 * k..at + 8 * k + 8].copy_from_slice(&b.bands[c][i].to_le_bytes());
            }
        });
        let lerr = |e: las::Error| ExportError::Las {
            path: self.out.clone(),
            message: e.to_string(),
        };
        let data = las::PointDataBuilder::new()
            .for_header(header)
            .build_from_bytes(bytes)
            .map_err(lerr)?;
        let sent = self.tx.as_ref().is_some_and(|tx| tx.send(data).is_ok());
        if !sent {
            // The writer stopped: its error says why.
            return Err(self.stop());
        }
        Ok(())
    }

    fn finish(mut self: Box<Self>) -> Result<(Option<LasLayout>, Vec<String>), ExportError> {
        self.tx = None;
        let r = self.thread.take().map(|t| t.join());
        match r {
            Some(Ok(Ok(()))) => {}
            Some(Ok(Err(e))) => {
                return Err(ExportError::Las {
                    path: self.out.clone(),
                    message: e.to_string(),
                });
            }
            _ => {
                return Err(ExportError::Las {
                    path: self.out.clone(),
                    message: "the writer thread stopped".into(),
                });
            }
        }
        Ok((
            Some(self.layout.clone()),
            std::mem::take(&mut self.extra_names),
        ))
    }
}

/// How a band is written in PLY and text: its PLY type, and whether its
/// values are whole numbers.
fn band_kind(name: &str) -> (&'static str, bool) {
    match name {
        "classification" | "return_number" | "number_of_returns" | "user_data" | "las_flags" => {
            ("uchar", true)
        }
        "intensity" | "red" | "green" | "blue" | "nir" | "point_source_id" => ("ushort", true),
        _ => ("double", false),
    }
}

/// Binary little-endian PLY: `double` coordinates, bands in their kinds. The
/// vertex count, unknown until the end, is written in a fixed-width field
/// (leading zeros) and filled in last.
struct PlySink {
    w: BufWriter<std::fs::File>,
    out: PathBuf,
    kinds: Vec<&'static str>,
    count: u64,
    /// Where the count's digits start.
    count_at: u64,
}

const COUNT_DIGITS: usize = 20;

impl PlySink {
    fn new(file: std::fs::File, out: &Path, plan: &Plan) -> std::io::Result<PlySink> {
        let mut w = BufWriter::with_capacity(1 << 20, file);
        let mut head =
            String::from("ply\nformat binary_little_endian 1.0\ncomment written by pcimg export\n");
        if let Some(crs) = &plan.crs {
            // A comment is one line.
            head.push_str(&format!("comment crs {}\n", crs.replace(['\n', '\r'], " ")));
        }
        head.push_str("element vertex ");
        let count_at = head.len() as u64;
        head.push_str(&format!("{:0w$}\n", 0, w = COUNT_DIGITS));
        head.push_str("property double x\nproperty double y\nproperty double z\n");
        let kinds: Vec<&'static str> = plan.bands.iter().map(|b| band_kind(b).0).collect();
        for (b, k) in plan.bands.iter().zip(&kinds) {
            head.push_str(&format!("property {k} {}\n", ply_name(b)));
        }
        head.push_str("end_header\n");
        w.write_all(head.as_bytes())?;
        Ok(PlySink {
            w,
            out: out.to_path_buf(),
            kinds,
            count: 0,
            count_at,
        })
    }
}

/// A band name as a PLY property name (no spaces).
fn ply_name(b: &str) -> String {
    b.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

impl Sink for PlySink {
    fn write(&mut self, b: &Batch) -> Result<(), ExportError> {
        let mut buf = Vec::with_capacity(b.len() * (24 + 8 * b.bands.len()));
        for i in 0..b.len() {
            for v in [b.x[i], b.y[i], b.z[i]] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            for (c, k) in b.bands.iter().zip(&self.kinds) {
                let v = c[i];
                match *k {
                    "uchar" => buf.push(if v.is_finite() {
                        v.round().clamp(0.0, 255.0) as u8
                    } else {
                        0
                    }),
                    "ushort" => buf.extend_from_slice(
                        &(if v.is_finite() {
                            v.round().clamp(0.0, 65535.0) as u16
                        } else {
                            0
                        })
                        .to_le_bytes(),
                    ),
                    _ => buf.extend_from_slice(&v.to_le_bytes()),
                }
            }
        }
        self.count += b.len() as u64;
        self.w.write_all(&buf).map_err(|source| ExportError::Write {
            path: self.out.clone(),
            source,
        })
    }

    fn finish(self: Box<Self>) -> Result<(Option<LasLayout>, Vec<String>), ExportError> {
        use std::io::{Seek, SeekFrom};
        let werr = |source| ExportError::Write {
            path: self.out.clone(),
            source,
        };
        let mut f = self.w.into_inner().map_err(|e| werr(e.into_error()))?;
        f.seek(SeekFrom::Start(self.count_at)).map_err(werr)?;
        f.write_all(format!("{:0w$}", self.count, w = COUNT_DIGITS).as_bytes())
            .map_err(werr)?;
        f.sync_all().map_err(werr)?;
        Ok((None, Vec::new()))
    }
}

/// CSV (a header of column names, commas) or XYZ (spaces, no header).
/// Coordinates on a lattice are printed with its decimals; whole-number bands
/// as integers; the rest as the shortest text that reads back the same.
struct TextSink {
    w: BufWriter<std::fs::File>,
    out: PathBuf,
    sep: char,
    decimals: Option<[usize; 3]>,
    whole: Vec<bool>,
}

impl TextSink {
    fn new(file: std::fs::File, out: &Path, plan: &Plan, csv: bool) -> std::io::Result<TextSink> {
        let mut w = BufWriter::with_capacity(1 << 20, file);
        let sep = if csv { ',' } else { ' ' };
        if csv {
            let mut head = vec!["x".to_string(), "y".into(), "z".into()];
            head.extend(plan.bands.iter().cloned());
            writeln!(w, "{}", head.join(","))?;
        }
        // The decimals the lattice's points need (0.01 from 0: 2; from
        // 636000.005: 3); none where a step needs more than 9.
        let decimals = plan
            .lattice
            .and_then(|l| Some([l.decimals(0)?, l.decimals(1)?, l.decimals(2)?]));
        Ok(TextSink {
            w,
            out: out.to_path_buf(),
            sep,
            decimals,
            whole: plan.bands.iter().map(|b| band_kind(b).1).collect(),
        })
    }
}

impl Sink for TextSink {
    fn write(&mut self, b: &Batch) -> Result<(), ExportError> {
        use std::fmt::Write as _;
        let mut s = String::with_capacity(b.len() * 48);
        for i in 0..b.len() {
            for (a, v) in [b.x[i], b.y[i], b.z[i]].into_iter().enumerate() {
                if a > 0 {
                    s.push(self.sep);
                }
                let _ = match self.decimals {
                    Some(d) => write!(s, "{v:.*}", d[a]),
                    None => write!(s, "{v}"),
                };
            }
            for (c, &whole) in b.bands.iter().zip(&self.whole) {
                s.push(self.sep);
                let v = c[i];
                let _ = if !v.is_finite() {
                    write!(s, "nan")
                } else if whole || v.fract() == 0.0 {
                    write!(s, "{}", v as i64)
                } else {
                    write!(s, "{v}")
                };
            }
            s.push('\n');
        }
        self.w
            .write_all(s.as_bytes())
            .map_err(|source| ExportError::Write {
                path: self.out.clone(),
                source,
            })
    }

    fn finish(self: Box<Self>) -> Result<(Option<LasLayout>, Vec<String>), ExportError> {
        let out = self.out.clone();
        let f = self.w.into_inner().map_err(|e| ExportError::Write {
            path: out.clone(),
            source: e.into_error(),
        })?;
        f.sync_all()
            .map_err(|source| ExportError::Write { path: out, source })?;
        Ok((None, Vec::new()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_come_from_the_extension() {
        assert_eq!(OutFormat::of(Path::new("a/b.LAZ")), Some(OutFormat::Laz));
        assert_eq!(OutFormat::of(Path::new("b.las")), Some(OutFormat::Las));
        assert_eq!(OutFormat::of(Path::new("b.ply")), Some(OutFormat::Ply));
        assert_eq!(OutFormat::of(Path::new("b.csv")), Some(OutFormat::Csv));
        assert_eq!(OutFormat::of(Path::new("b.xyz")), Some(OutFormat::Xyz));
        assert_eq!(OutFormat::of(Path::new("b.tif")), None);
        assert_eq!(OutFormat::of(Path::new("b")), None);
    }

    #[test]
    fn a_chosen_transform_keeps_millimetres_where_they_fit() {
        let b = Bounds {
            min: [637_000.4, 6_010_000.0, -5.0],
            max: [638_000.0, 6_011_000.0, 100.0],
        };
        let (s, o) = chosen_transform(&b);
        assert_eq!(s, [0.001; 3]);
        assert_eq!(o, [637_000.0, 6_010_000.0, -5.0]);
        // 10,000 km across does not fit in 2^31 mm: centimetres... or coarser.
        let wide = Bounds {
            min: [0.0; 3],
            max: [1e7, 1.0, 1.0],
        };
        let (s, _) = chosen_transform(&wide);
        assert!(s[0] >= 0.01 && 1e7 / s[0] < i32::MAX as f64, "{s:?}");
    }

    #[test]
    fn wkt_is_told_from_authority_codes() {
        assert!(is_wkt(
            "PROJCS[\"NAD83 / Oregon GIC Lambert (ft)\",GEOGCS[...]]"
        ));
        assert!(is_wkt("  COMPOUNDCRS[\"x\"]"));
        assert!(!is_wkt("EPSG:2992"));
    }
}
