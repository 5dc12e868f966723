//! COPC reader crates measured on the same file (issue 42): open, a full read
//! (x, y, z, intensity, classification, GPS time, RGB) and a region read, each
//! reader in turn in every round, with the reads and bytes each asked of its
//! byte source.
//!
//! `cargo run --release -- FILE [REPS]` (see README.md).
//!
//! Every reader decompresses on the calling thread, one node after another:
//! pcimg's `CopcReader` (which decompresses a batch of nodes with rayon) runs
//! inside a one-thread rayon pool; copc-reader is built without its `parallel`
//! feature; copc-streaming (async) runs on `futures_executor::block_on`, a
//! current-thread executor.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

use anyhow::{Context, Result, anyhow};

// ---------------------------------------------------------------- counting

/// What a reader asked of its byte source.
#[derive(Debug, Default)]
struct Counter {
    /// Calls into the source (a `read_ranges` batch is one call; for a
    /// `Read + Seek` source, one `read`).
    calls: AtomicU64,
    /// Ranges asked for (a batch of n ranges is n; for `Read + Seek`, one a `read`).
    ranges: AtomicU64,
    bytes: AtomicU64,
    /// `Read + Seek` only: seeks.
    seeks: AtomicU64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Io {
    calls: u64,
    ranges: u64,
    bytes: u64,
    seeks: u64,
}

impl Counter {
    fn add(&self, calls: u64, ranges: u64, bytes: u64) {
        self.calls.fetch_add(calls, Relaxed);
        self.ranges.fetch_add(ranges, Relaxed);
        self.bytes.fetch_add(bytes, Relaxed);
    }
    fn take(&self) -> Io {
        Io {
            calls: self.calls.swap(0, Relaxed),
            ranges: self.ranges.swap(0, Relaxed),
            bytes: self.bytes.swap(0, Relaxed),
            seeks: self.seeks.swap(0, Relaxed),
        }
    }
}

/// pcimg-copc's `ByteSource`, counted.
struct CountedPcimg {
    inner: pcimg_copc::FileSource,
    n: Arc<Counter>,
}

impl pcimg_copc::ByteSource for CountedPcimg {
    fn name(&self) -> String {
        self.inner.name()
    }
    fn read_prefix(&self, max: u64) -> std::io::Result<Vec<u8>> {
        let b = self.inner.read_prefix(max)?;
        self.n.add(1, 1, b.len() as u64);
        Ok(b)
    }
    fn size(&self) -> std::io::Result<u64> {
        self.inner.size()
    }
    fn read_ranges(&self, ranges: &[std::ops::Range<u64>]) -> std::io::Result<Vec<Vec<u8>>> {
        let b = self.inner.read_ranges(ranges)?;
        let bytes = b.iter().map(|v| v.len() as u64).sum();
        self.n.add(1, ranges.len() as u64, bytes);
        Ok(b)
    }
}

/// copc-streaming's (async) `ByteSource`, counted. `read_ranges` is counted as
/// one call and forwarded range by range, as the crate's default does.
struct CountedStreaming {
    inner: copc_streaming::FileSource,
    n: Arc<Counter>,
}

impl copc_streaming::ByteSource for CountedStreaming {
    async fn read_range(
        &self,
        offset: u64,
        length: u64,
    ) -> Result<Vec<u8>, copc_streaming::CopcError> {
        let b = self.inner.read_range(offset, length).await?;
        self.n.add(1, 1, b.len() as u64);
        Ok(b)
    }
    async fn size(&self) -> Result<Option<u64>, copc_streaming::CopcError> {
        self.inner.size().await
    }
    async fn read_ranges(
        &self,
        ranges: &[(u64, u64)],
    ) -> Result<Vec<Vec<u8>>, copc_streaming::CopcError> {
        let mut out = Vec::with_capacity(ranges.len());
        for &(o, l) in ranges {
            out.push(self.inner.read_range(o, l).await?);
        }
        let bytes = out.iter().map(|v| v.len() as u64).sum();
        self.n.add(1, ranges.len() as u64, bytes);
        Ok(out)
    }
}

/// copc-reader's `RangeRead`, counted.
struct CountedRange {
    inner: std::fs::File,
    n: Arc<Counter>,
}

impl copc_reader::RangeRead for CountedRange {
    fn len(&mut self) -> copc_core::Result<u64> {
        copc_reader::RangeRead::len(&mut self.inner)
    }
    fn read_range(&mut self, offset: u64, buf: &mut [u8]) -> copc_core::Result<()> {
        self.inner.read_range(offset, buf)?;
        self.n.add(1, 1, buf.len() as u64);
        Ok(())
    }
}

/// A `Read + Seek` file, counted (under the `BufReader` the crates are given).
struct CountedFile {
    inner: std::fs::File,
    n: Arc<Counter>,
}

impl Read for CountedFile {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let k = self.inner.read(buf)?;
        self.n.add(1, 1, k as u64);
        Ok(k)
    }
}

impl Seek for CountedFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.n.seeks.fetch_add(1, Relaxed);
        self.inner.seek(pos)
    }
}

fn counted_file(path: &Path, n: &Arc<Counter>) -> Result<BufReader<CountedFile>> {
    Ok(BufReader::new(CountedFile {
        inner: std::fs::File::open(path)?,
        n: n.clone(),
    }))
}

// ---------------------------------------------------------------- sums

/// The file's lattice, to compare coordinates as whole numbers.
#[derive(Debug, Clone, Copy)]
struct Lattice {
    scale: [f64; 3],
    offset: [f64; 3],
}

/// What a read gave: points, the sums of x, y, z as whole multiples of the
/// scale, and sums of the attributes (consumed so that no reader skips them).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Sums {
    points: u64,
    xyz: [i128; 3],
    intensity: u64,
    class: u64,
    /// GPS time in whole microseconds (exact, whatever the order of the points).
    gps: i128,
    rgb: u64,
}

impl Sums {
    fn xyz(&mut self, l: &Lattice, p: [f64; 3]) {
        for (a, v) in p.into_iter().enumerate() {
            self.xyz[a] += ((v - l.offset[a]) / l.scale[a]).round() as i128;
        }
        self.points += 1;
    }
    fn gps(&mut self, t: f64) {
        self.gps += (t * 1e6).round() as i128;
    }
}

/// The box of the region query.
#[derive(Debug, Clone, Copy)]
struct Box3 {
    min: [f64; 3],
    max: [f64; 3],
}

impl Box3 {
    fn holds(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.min[a] && p[a] <= self.max[a])
    }
}

// ---------------------------------------------------------------- readers

/// One measured call: seconds, what it asked of its source, what it gave.
struct Run {
    secs: f64,
    io: Io,
    sums: Sums,
}

trait Reader {
    fn name(&self) -> &'static str;
    /// Whether it gives GPS time and colour as stored (pcimg's columns hold GPS
    /// time as f32 past an offset, and colour scaled to 8 bits where 16-bit).
    fn exact(&self) -> bool {
        true
    }
    /// Open only.
    fn open(&self, path: &Path) -> Result<Run>;
    /// Open and read every point.
    fn read(&self, path: &Path, l: &Lattice) -> Result<Run>;
    /// Open (not timed, not counted), then the points in `b` (timed, counted).
    fn region(&self, path: &Path, l: &Lattice, b: &Box3) -> Result<Run>;
}

/// A reader as measured: how it opens a file over a counted source, and the
/// sums of the points it reads (those in `b`, where given). [`Reader`]'s
/// three measures follow from these.
trait Measured {
    /// The opened file.
    type Handle;
    fn name(&self) -> &'static str;
    fn exact(&self) -> bool {
        true
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle>;
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums>;
}

impl<M: Measured> Reader for M {
    fn name(&self) -> &'static str {
        Measured::name(self)
    }
    fn exact(&self) -> bool {
        Measured::exact(self)
    }
    fn open(&self, path: &Path) -> Result<Run> {
        let n = Arc::new(Counter::default());
        let (secs, _) = timed(|| self.open_counted(path, &n))?;
        Ok(Run {
            secs,
            io: n.take(),
            sums: Sums::default(),
        })
    }
    fn read(&self, path: &Path, l: &Lattice) -> Result<Run> {
        let n = Arc::new(Counter::default());
        let (secs, sums) = timed(|| self.sums(&mut self.open_counted(path, &n)?, l, None))?;
        Ok(Run {
            secs,
            io: n.take(),
            sums,
        })
    }
    fn region(&self, path: &Path, l: &Lattice, b: &Box3) -> Result<Run> {
        let n = Arc::new(Counter::default());
        let mut h = self.open_counted(path, &n)?;
        n.take();
        let (secs, sums) = timed(|| self.sums(&mut h, l, Some(b)))?;
        Ok(Run {
            secs,
            io: n.take(),
            sums,
        })
    }
}

fn timed<T>(f: impl FnOnce() -> Result<T>) -> Result<(f64, T)> {
    let t = Instant::now();
    let v = f()?;
    Ok((t.elapsed().as_secs_f64(), v))
}

// pcimg: pcimg-copc + pcimg-ingest ----------------------------------------

fn pcimg_open(path: &Path, n: &Arc<Counter>) -> Result<pcimg_copc::Copc> {
    let src = CountedPcimg {
        inner: pcimg_copc::FileSource::open(path)?,
        n: n.clone(),
    };
    Ok(pcimg_copc::Copc::open(Arc::new(src))?)
}

/// Adds the columns of `c` (the points in `b` only, where given).
fn add_columns(s: &mut Sums, l: &Lattice, c: &pcimg_core::points::PointColumns, b: Option<&Box3>) {
    let col = |name: &str| c.attributes.iter().find(|a| a.name == name);
    let (int, cls, gps) = (col("intensity"), col("classification"), col("gps_time"));
    let rgb = [col("red"), col("green"), col("blue")];
    for i in 0..c.x.len() {
        let p = [c.x[i], c.y[i], c.z[i]];
        if b.is_some_and(|b| !b.holds(p)) {
            continue;
        }
        s.xyz(l, p);
        s.intensity += int.map_or(0, |a| a.values[i] as u64);
        s.class += cls.map_or(0, |a| a.values[i] as u64);
        if let Some(a) = gps {
            s.gps(a.offset + f64::from(a.values[i]));
        }
        s.rgb += rgb
            .iter()
            .flatten()
            .map(|a| a.values[i] as u64)
            .sum::<u64>();
    }
}

/// `pcimg_ingest::copc::from_copc`: every node that reaches the region
/// (`nodes_where`), fetched in batches of ~4 M points (one `read_ranges` each),
/// decompressed whole (all fields) and decoded by `decode_records`, points
/// outside the region dropped. Its rayon work runs in a one-thread pool.
struct PcimgReader {
    pool: rayon::ThreadPool,
}

impl PcimgReader {
    fn run(&self, copc: Arc<pcimg_copc::Copc>, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        use pcimg_ingest::PointReader;
        let opts = pcimg_ingest::ReadOptions {
            region: b.map(|b| pcimg_core::points::Bounds {
                min: b.min,
                max: b.max,
            }),
            ..Default::default()
        };
        self.pool.install(|| {
            let mut r = pcimg_ingest::copc::from_copc(copc, &opts)?;
            let mut s = Sums::default();
            while let Some(c) = r.next_chunk()? {
                add_columns(&mut s, l, &c, None);
            }
            Ok(s)
        })
    }
}

impl Measured for PcimgReader {
    type Handle = Arc<pcimg_copc::Copc>;
    fn name(&self) -> &'static str {
        "pcimg ingest::copc::CopcReader"
    }
    fn exact(&self) -> bool {
        false
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        Ok(Arc::new(pcimg_open(path, n)?))
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        self.run(h.clone(), l, b)
    }
}

/// `all_nodes` / `nodes_where`, then `NodeDecoder::read` node by node (one
/// fetch each), only the fields of the bands asked for decompressed.
struct PcimgNodes;

const BANDS: [&str; 6] = [
    "intensity",
    "classification",
    "gps_time",
    "red",
    "green",
    "blue",
];

impl PcimgNodes {
    fn run(&self, copc: &pcimg_copc::Copc, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        let dec = pcimg_ingest::copc::NodeDecoder::new(copc)?;
        let bands: Vec<String> = BANDS.iter().map(|s| s.to_string()).collect();
        let nodes = match b {
            None => copc.all_nodes()?,
            Some(b) => copc.nodes_where(
                &|c| (0..3).all(|a| c.0[a] <= b.max[a] && c.1[a] >= b.min[a]),
                i32::MAX,
            )?,
        };
        let mut s = Sums::default();
        for e in nodes.iter().filter(|e| e.points > 0) {
            let c = dec.read(copc, e, &bands)?;
            add_columns(&mut s, l, &c, b);
        }
        Ok(s)
    }
}

impl Measured for PcimgNodes {
    type Handle = pcimg_copc::Copc;
    fn name(&self) -> &'static str {
        "pcimg NodeDecoder (6 bands)"
    }
    fn exact(&self) -> bool {
        false
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        pcimg_open(path, n)
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        self.run(h, l, b)
    }
}

// copc-streaming ----------------------------------------------------------

type Streaming = copc_streaming::CopcStreamingReader<CountedStreaming>;

async fn streaming_open(path: &Path, n: &Arc<Counter>) -> Result<Streaming> {
    let src = CountedStreaming {
        inner: copc_streaming::FileSource::open(path)?,
        n: n.clone(),
    };
    Ok(copc_streaming::CopcStreamingReader::open(src).await?)
}

/// `query_chunks(bounds, fields)`: the hierarchy pages that reach the box, then
/// every chunk that reaches it in one `read_ranges`, decompressed (only
/// `fields`) one after another; columns from the chunk's accessors.
struct StreamingReader {
    fields: copc_streaming::Fields,
    label: &'static str,
}

impl StreamingReader {
    async fn run(&self, r: &mut Streaming, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        let query = match b {
            Some(b) => copc_streaming::Aabb {
                min: b.min,
                max: b.max,
            },
            None => r.copc_info().root_bounds(),
        };
        let chunks = r.query_chunks(&query, self.fields).await?;
        let mut s = Sums::default();
        for c in &chunks {
            let keep: Option<Vec<u32>> = b.map(|_| c.indices_in_bounds(&query).unwrap_or_default());
            let pos: Vec<[f64; 3]> = c.positions().ok_or(anyhow!("no z"))?.collect();
            let int: Vec<u16> = c.intensity().ok_or(anyhow!("no intensity"))?.collect();
            let cls: Vec<u8> = c.classification().ok_or(anyhow!("no class"))?.collect();
            let gps: Vec<f64> = c.gps_time().map(|g| g.collect()).unwrap_or_default();
            let rgb: Vec<(u16, u16, u16)> = c.rgb().map(|g| g.collect()).unwrap_or_default();
            let mut add = |i: usize| {
                s.xyz(l, pos[i]);
                s.intensity += u64::from(int[i]);
                s.class += u64::from(cls[i]);
                if let Some(&t) = gps.get(i) {
                    s.gps(t);
                }
                s.rgb += rgb
                    .get(i)
                    .map_or(0, |c| u64::from(c.0) + u64::from(c.1) + u64::from(c.2));
            };
            match &keep {
                Some(k) => k.iter().for_each(|&i| add(i as usize)),
                None => (0..pos.len()).for_each(&mut add),
            }
        }
        Ok(s)
    }
}

impl Measured for StreamingReader {
    type Handle = Streaming;
    fn name(&self) -> &'static str {
        self.label
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        futures_executor::block_on(streaming_open(path, n))
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        futures_executor::block_on(self.run(h, l, b))
    }
}

// copc-reader -------------------------------------------------------------

fn selection() -> copc_core::ColumnSelection {
    use copc_core::LasDimension as D;
    copc_core::ColumnSelection::from_dimensions([
        D::X,
        D::Y,
        D::Z,
        D::Intensity,
        D::Classification,
        D::GpsTime,
        D::Red,
        D::Green,
        D::Blue,
    ])
}

fn query(b: Option<&Box3>) -> copc_reader::PointQuery {
    copc_reader::PointQuery::new(
        copc_reader::LodSelection::All,
        match b {
            None => copc_reader::BoundsSelection::All,
            Some(b) => copc_reader::BoundsSelection::Within(copc_core::Bounds::new(
                (b.min[0], b.min[1], b.min[2]),
                (b.max[0], b.max[1], b.max[2]),
            )),
        },
    )
}

/// The sums of a copc-reader column batch.
fn batch_sums(l: &Lattice, batch: &copc_core::LasColumnBatch) -> Result<Sums> {
    let mut s = Sums::default();
    add_batch(&mut s, l, batch)?;
    Ok(s)
}

fn add_batch(s: &mut Sums, l: &Lattice, batch: &copc_core::LasColumnBatch) -> Result<()> {
    use copc_core::{ColumnData as C, LasDimension as D};
    let f64s = |d| match batch.column(d) {
        Some(C::F64(v)) => Ok(v.as_slice()),
        other => Err(anyhow!("{d:?}: {:?}", other.map(|_| "not f64"))),
    };
    let u16s = |d| match batch.column(d) {
        Some(C::U16(v)) => Some(v.as_slice()),
        _ => None,
    };
    let (x, y, z) = (f64s(D::X)?, f64s(D::Y)?, f64s(D::Z)?);
    let gps = f64s(D::GpsTime).ok();
    let int = u16s(D::Intensity).ok_or(anyhow!("no intensity"))?;
    let cls = match batch.column(D::Classification) {
        Some(C::U8(v)) => v.as_slice(),
        _ => return Err(anyhow!("no classification")),
    };
    let rgb = [u16s(D::Red), u16s(D::Green), u16s(D::Blue)];
    for i in 0..batch.len() {
        s.xyz(l, [x[i], y[i], z[i]]);
        s.intensity += u64::from(int[i]);
        s.class += u64::from(cls[i]);
        if let Some(g) = gps {
            s.gps(g[i]);
        }
        s.rgb += rgb.iter().flatten().map(|c| u64::from(c[i])).sum::<u64>();
    }
    Ok(())
}

/// `CopcRangeReader` over a `RangeRead`: header and VLRs, root page at open;
/// pages that the query reaches, then chunks in coalesced ranges (gaps under
/// 64 KiB merged), each chunk decompressed whole, columns appended.
struct RangeReader;

fn range_open(path: &Path, n: &Arc<Counter>) -> Result<copc_reader::CopcRangeReader<CountedRange>> {
    let src = CountedRange {
        inner: std::fs::File::open(path)?,
        n: n.clone(),
    };
    Ok(copc_reader::CopcRangeReader::open(src)?)
}

impl Measured for RangeReader {
    type Handle = copc_reader::CopcRangeReader<CountedRange>;
    fn name(&self) -> &'static str {
        "copc-reader CopcRangeReader"
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        range_open(path, n)
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        batch_sums(l, &h.read_columns(query(b), selection())?)
    }
}

/// `copc_reader::CopcReader` over `Read + Seek` (a `BufReader`): the whole
/// hierarchy read at open; chunks read one by one, decompressed whole.
struct SeekReader;

type SeekCopc = copc_reader::CopcReader<BufReader<CountedFile>>;

fn seek_open(path: &Path, n: &Arc<Counter>) -> Result<SeekCopc> {
    Ok(copc_reader::CopcReader::open(counted_file(path, n)?)?)
}

impl Measured for SeekReader {
    type Handle = SeekCopc;
    fn name(&self) -> &'static str {
        "copc-reader CopcReader (Read+Seek)"
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        seek_open(path, n)
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        batch_sums(l, &h.read_columns(query(b), selection())?)
    }
}

// las ---------------------------------------------------------------------

/// `las::CopcReader` over `Read + Seek` (a `BufReader`): header, VLRs and
/// EVLRs (the whole hierarchy EVLR) at open; `query` decompresses the chunks
/// it selects one by one, whole, into one `PointData`.
struct LasReader;

type LasCopc = las::CopcReader<'static, BufReader<CountedFile>>;

fn las_open(path: &Path, n: &Arc<Counter>) -> Result<LasCopc> {
    Ok(las::CopcReader::new(counted_file(path, n)?)?)
}

fn las_sums(r: &mut LasCopc, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
    let bounds = match b {
        None => las::BoundsSelection::All,
        Some(b) => las::BoundsSelection::Within(las::Bounds {
            min: las::Vector {
                x: b.min[0],
                y: b.min[1],
                z: b.min[2],
            },
            max: las::Vector {
                x: b.max[0],
                y: b.max[1],
                z: b.max[2],
            },
        }),
    };
    let d = r.query(las::LodSelection::All, bounds)?;
    let mut s = Sums::default();
    for ((x, y), z) in d.x().zip(d.y()).zip(d.z()) {
        s.xyz(l, [x, y, z]);
    }
    s.intensity = d.intensity().map(u64::from).sum();
    s.class = d.classification().map(u64::from).sum();
    for t in d.gps_time().into_iter().flatten() {
        s.gps(t);
    }
    s.rgb = d.rgb().map_or(0, |c| {
        c.map(|c| u64::from(c.0) + u64::from(c.1) + u64::from(c.2))
            .sum()
    });
    Ok(s)
}

impl Measured for LasReader {
    type Handle = LasCopc;
    fn name(&self) -> &'static str {
        "las CopcReader"
    }
    fn open_counted(&self, path: &Path, n: &Arc<Counter>) -> Result<Self::Handle> {
        las_open(path, n)
    }
    fn sums(&self, h: &mut Self::Handle, l: &Lattice, b: Option<&Box3>) -> Result<Sums> {
        las_sums(h, l, b)
    }
}

// ---------------------------------------------------------------- main

/// Times of one measure over the rounds, and the last round's I/O and sums.
#[derive(Default)]
struct Cell {
    secs: Vec<f64>,
    io: Io,
    sums: Sums,
    error: Option<String>,
}

impl Cell {
    fn push(&mut self, r: Result<Run>) {
        match r {
            Ok(r) => {
                self.secs.push(r.secs);
                self.io = r.io;
                self.sums = r.sums;
            }
            Err(e) => self.error = Some(format!("{e:#}")),
        }
    }
    /// Median, min, max in milliseconds.
    fn ms(&self) -> Option<(f64, f64, f64)> {
        let mut v = self.secs.clone();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let m = v.len() / 2;
        let med = if v.len() % 2 == 1 {
            v[m]
        } else {
            (v[m - 1] + v[m]) / 2.0
        };
        Some((med * 1e3, v[0] * 1e3, v[v.len() - 1] * 1e3))
    }
}

fn time_cols(c: &Cell) -> String {
    match c.ms() {
        Some((m, lo, hi)) => format!("{m:>9.1} {:>19}", format!("[{lo:.1}–{hi:.1}]")),
        None => format!("{:>29}", "—"),
    }
}

fn io_cols(io: &Io) -> String {
    let seeks = if io.seeks > 0 {
        format!(" +{} seeks", io.seeks)
    } else {
        String::new()
    };
    format!("{:>7} {:>7} {:>12}{seeks}", io.calls, io.ranges, io.bytes)
}

/// Catches a reader's panic as an error (a crate that panics on a file).
fn guarded(f: impl FnOnce() -> Result<Run>) -> Result<Run> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|p| {
        let why = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        Err(anyhow!("panicked: {why}"))
    })
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = Path::new(args.get(1).context("usage: copc_crates FILE [REPS]")?);
    let reps: usize = args.get(2).map_or(Ok(5), |s| s.parse())?;
    std::panic::set_hook(Box::new(|_| {}));

    let copc = pcimg_copc::Copc::open(Arc::new(pcimg_copc::FileSource::open(path)?))?;
    let h = &copc.header;
    let lattice = Lattice {
        scale: h.scale,
        offset: h.offset,
    };
    // The lower-left quarter, its upper edges half a scale step short of the
    // midlines: a writer often centres the octree's cube on the bounds, and a
    // box that ends on a midline touches (and makes every reader read) the
    // nodes on its other side, for the points on the line itself.
    let region = Box3 {
        min: [h.min[0], h.min[1], f64::MIN],
        max: [
            h.min[0] + (h.max[0] - h.min[0]) / 2.0 - h.scale[0] / 2.0,
            h.min[1] + (h.max[1] - h.min[1]) / 2.0 - h.scale[1] / 2.0,
            f64::MAX,
        ],
    };
    let nodes = copc.all_nodes()?;
    let (pages, _) = copc.pages();
    println!(
        "{}: {} bytes, {} points, format {}, {} nodes in {} hierarchy pages, scale {:?}",
        path.display(),
        copc.len,
        h.points,
        h.format,
        nodes.iter().filter(|e| e.points > 0).count(),
        pages,
        h.scale
    );
    println!(
        "region: x {:.3}..{:.3}, y {:.3}..{:.3}, all z (the lower-left quarter of the header's xy bounds, less half a scale step)",
        region.min[0], region.max[0], region.min[1], region.max[1]
    );
    println!("{reps} rounds, readers interleaved in each; one thread (see README.md)\n");

    let readers: Vec<Box<dyn Reader>> = vec![
        Box::new(PcimgReader {
            pool: rayon::ThreadPoolBuilder::new().num_threads(1).build()?,
        }),
        Box::new(PcimgNodes),
        Box::new(StreamingReader {
            fields: copc_streaming::Fields::ALL,
            label: "copc-streaming Fields::ALL",
        }),
        Box::new(StreamingReader {
            fields: copc_streaming::Fields::Z
                | copc_streaming::Fields::INTENSITY
                | copc_streaming::Fields::CLASSIFICATION
                | copc_streaming::Fields::GPS_TIME
                | copc_streaming::Fields::RGB,
            label: "copc-streaming 5 fields",
        }),
        Box::new(RangeReader),
        Box::new(SeekReader),
        Box::new(LasReader),
    ];
    let k = readers.len();
    let (mut open, mut read, mut sub): (Vec<Cell>, Vec<Cell>, Vec<Cell>) = (
        (0..k).map(|_| Cell::default()).collect(),
        (0..k).map(|_| Cell::default()).collect(),
        (0..k).map(|_| Cell::default()).collect(),
    );
    // Round 0 warms the page cache and the allocator; not counted.
    for round in 0..=reps {
        for (i, r) in readers.iter().enumerate() {
            let o = guarded(|| r.open(path));
            let a = guarded(|| r.read(path, &lattice));
            let g = guarded(|| r.region(path, &lattice, &region));
            if round > 0 {
                open[i].push(o);
                read[i].push(a);
                sub[i].push(g);
            } else {
                for (cell, res) in [(&mut open[i], o), (&mut read[i], a), (&mut sub[i], g)] {
                    if let Err(e) = res {
                        cell.error = Some(format!("{e:#}"));
                    }
                }
            }
        }
    }

    let w = 36;
    let head = |what: &str| {
        println!(
            "{what:<w$} {:>9} {:>19} {:>7} {:>7} {:>12}",
            "median ms", "[min–max]", "calls", "ranges", "bytes"
        )
    };
    println!("== open (header, VLRs, whatever hierarchy the reader reads up front)");
    head("reader");
    for (r, c) in readers.iter().zip(&open) {
        match &c.error {
            Some(e) => println!("{:<w$} FAILED: {e}", r.name()),
            None => println!("{:<w$} {} {}", r.name(), time_cols(c), io_cols(&c.io)),
        }
    }

    println!("\n== read every point (open included): x y z intensity classification gps_time rgb");
    println!(
        "{:<w$} {:>9} {:>19} {:>7} {:>7} {:>12} {:>10} {:>9}",
        "reader", "median ms", "[min–max]", "calls", "ranges", "bytes", "points", "Mpts/s"
    );
    for (r, c) in readers.iter().zip(&read) {
        match c.ms() {
            None => println!(
                "{:<w$} FAILED: {}",
                r.name(),
                c.error.as_deref().unwrap_or("?")
            ),
            Some((m, _, _)) => {
                println!(
                    "{:<w$} {} {} {:>10} {:>9.2}",
                    r.name(),
                    time_cols(c),
                    io_cols(&c.io),
                    c.sums.points,
                    c.sums.points as f64 / (m / 1e3) / 1e6
                );
            }
        }
    }

    println!("\n== region (after an open that is neither timed nor counted)");
    println!(
        "{:<w$} {:>9} {:>19} {:>7} {:>7} {:>12} {:>10}",
        "reader", "median ms", "[min–max]", "calls", "ranges", "bytes", "points"
    );
    for (r, c) in readers.iter().zip(&sub) {
        match &c.error {
            Some(e) => println!("{:<w$} FAILED: {e}", r.name()),
            None => println!(
                "{:<w$} {} {} {:>10}",
                r.name(),
                time_cols(c),
                io_cols(&c.io),
                c.sums.points
            ),
        }
    }

    println!(
        "\n== checks: x y z as whole multiples of the scale, GPS time in whole µs; \
         pcimg's columns (*) hold GPS time as f32 past an offset and 16-bit colour /257"
    );
    println!(
        "{:<w$} {:<6} {:>10} {:>16} {:>16} {:>14} {:>12} {:>10} {:>24} {:>14}",
        "reader", "", "points", "Σx", "Σy", "Σz", "Σintensity", "Σclass", "Σgps_time µs", "Σrgb"
    );
    let mut mismatches = Vec::new();
    for (what, cells) in [("read", &read), ("region", &sub)] {
        // The reference: the first exact reader that read.
        let first = cells
            .iter()
            .zip(&readers)
            .find(|(c, r)| !c.secs.is_empty() && r.exact());
        for (r, c) in readers.iter().zip(cells) {
            if c.secs.is_empty() {
                continue;
            }
            let s = &c.sums;
            let star = if r.exact() { "" } else { " *" };
            println!(
                "{:<w$} {what:<6} {:>10} {:>16} {:>16} {:>14} {:>12} {:>10} {:>24} {:>14}",
                format!("{}{star}", r.name()),
                s.points,
                s.xyz[0],
                s.xyz[1],
                s.xyz[2],
                s.intensity,
                s.class,
                s.gps,
                s.rgb
            );
            let Some((f, fr)) = first else { continue };
            let t = &f.sums;
            if s.points != t.points || s.xyz != t.xyz {
                mismatches.push(format!(
                    "MISMATCH ({what}): {} gives {} points, Σxyz {:?}; {} gives {} points, Σxyz {:?}",
                    r.name(), s.points, s.xyz, fr.name(), t.points, t.xyz
                ));
            }
            // Exact readers agree to the µs; pcimg's f32 GPS time within 1 ms a point.
            let gps_ok = if r.exact() {
                s.gps == t.gps
            } else {
                (s.gps - t.gps).unsigned_abs() <= 1000 * u128::from(s.points.max(1))
            };
            if s.intensity != t.intensity || s.class != t.class || !gps_ok {
                mismatches.push(format!(
                    "MISMATCH ({what}): {}'s Σintensity/Σclassification/Σgps_time differ from {}'s",
                    r.name(),
                    fr.name()
                ));
            }
            if r.exact() && s.rgb != t.rgb {
                mismatches.push(format!(
                    "MISMATCH ({what}): {}'s Σrgb differs from {}'s",
                    r.name(),
                    fr.name()
                ));
            }
        }
    }
    if mismatches.is_empty() {
        println!(
            "\nall readers agree: points, Σx Σy Σz, Σintensity, Σclassification; Σgps_time and Σrgb \
             exactly among the exact ones (pcimg's GPS time within 1 ms a point)"
        );
    }
    for m in mismatches {
        println!("{m}");
    }
    Ok(())
}
