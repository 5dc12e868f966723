//! The mutation fuzzer's fast mode, for runs of a million cases per input
//! (issue 39): small seeds of one input kind, mutated, given to the reader or
//! parser alone, in process, with no conversion. Per kind:
//!
//! * `text`, `ply`, `las`, `pcd`, `e57`: the mutated file is streamed through
//!   `pcimg_ingest::open`'s reader in one of the ways `convert` reads it (chunk by
//!   chunk; sampling after the first chunk; chunk extents and the reader's row
//!   source), with drawn read options; every chunk must carry the columns the
//!   reader announced, each as long as `x`;
//! * `part`: the mutated part is opened from memory and every level read;
//! * `index`: a mutated `pcimg-index.json` in a small indexed dataset (four
//!   parts and their overview) is opened as `Dataset::open` does and every level
//!   of every part and node read;
//! * `http`: the same dataset served by `fuzz_http.rs`'s server, whose answers
//!   are cut or corrupted by the case's faults, opened by URL and read.
//!
//! A case is accepted or refused with an error naming its file (or URL); a
//! panic, a panic caught inside the code under test (the panic hook sees it),
//! an error naming nothing, a chunk that breaks the reader's contract or a file
//! left in the case's folder is a failure. Cases are drawn from a seeded
//! [`Rng`] the same way whether or not they run, so case `N` of a seed can be
//! replayed alone.

use super::mutate;
use pcimg::ingest::ReadOptions;
use pcimg::store::dataset::overview::{IndexOptions, build_index};
use pcimg::store::{Dataset, Part, WriteOptions, write_part};
use pcimg::synth::Rng;
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

#[path = "fuzz_http.rs"]
pub mod http;

use super::below;

/// The untrusted inputs, one fuzzer each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Text,
    Ply,
    Las,
    Pcd,
    E57,
    Part,
    Index,
    Http,
}

impl Kind {
    pub const ALL: [Kind; 8] = [
        Kind::Text,
        Kind::Ply,
        Kind::Las,
        Kind::Pcd,
        Kind::E57,
        Kind::Part,
        Kind::Index,
        Kind::Http,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Kind::Text => "text",
            Kind::Ply => "ply",
            Kind::Las => "las",
            Kind::Pcd => "pcd",
            Kind::E57 => "e57",
            Kind::Part => "part",
            Kind::Index => "index",
            Kind::Http => "http",
        }
    }

    pub fn parse(s: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| k.name() == s)
    }
}

/// What became of one case.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Read to the end (or, for a remote dataset, every tile read).
    Accepted,
    /// Refused with an error that names the file (or URL).
    Refused(String),
    /// A panic reached the caller (place and message).
    Panicked(String),
    /// The code under test caught a panic itself and went on (its place and
    /// message, from the panic hook): a bug all the same.
    Contained(String),
    /// An error that does not name the file or URL it is about.
    Unnamed(String),
    /// The reader broke its contract (a chunk without the announced columns).
    Broken(String),
    /// Files left in the case's folder.
    LeftBehind(Vec<String>),
}

impl Verdict {
    /// Whether the case shows a bug.
    pub fn is_failure(&self) -> bool {
        !matches!(self, Verdict::Accepted | Verdict::Refused(_))
    }
}

/// Counts of a run, by verdict.
#[derive(Debug, Clone, Default)]
pub struct Tally {
    pub cases: u64,
    pub accepted: u64,
    pub refused: u64,
    pub panics: u64,
    pub contained: u64,
    pub unnamed: u64,
    pub broken: u64,
    pub left_behind: u64,
}

impl Tally {
    pub fn record(&mut self, v: &Verdict) {
        self.cases += 1;
        match v {
            Verdict::Accepted => self.accepted += 1,
            Verdict::Refused(_) => self.refused += 1,
            Verdict::Panicked(_) => self.panics += 1,
            Verdict::Contained(_) => self.contained += 1,
            Verdict::Unnamed(_) => self.unnamed += 1,
            Verdict::Broken(_) => self.broken += 1,
            Verdict::LeftBehind(_) => self.left_behind += 1,
        }
    }

    pub fn failures(&self) -> u64 {
        self.panics + self.contained + self.unnamed + self.broken + self.left_behind
    }
}

/// Panics seen by the hook, in any thread, and the last one's place and message.
static PANICS: AtomicU64 = AtomicU64::new(0);
static LAST_PANIC: Mutex<String> = Mutex::new(String::new());

thread_local! {
    /// Set while this thread runs a case: its panics are expected to be
    /// reported by the run, not printed.
    static IN_CASE: Cell<bool> = const { Cell::new(false) };
}

/// Installs the panic hook that counts every panic and remembers the last
/// one's place and message; panics outside a case's own thread are printed as
/// before too. Idempotent.
pub fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let place = info
                .location()
                .map(|l| format!("{}:{}", l.file(), l.line()))
                .unwrap_or_default();
            let payload = info.payload();
            let msg = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            *LAST_PANIC.lock().unwrap_or_else(|p| p.into_inner()) = format!("{place}: {msg}");
            PANICS.fetch_add(1, Ordering::SeqCst);
            if !IN_CASE.with(Cell::get) {
                previous(info);
            }
        }));
    });
}

/// One case: which seed, its mutated bytes, how it is read.
#[derive(Debug, Clone)]
pub struct Case {
    pub seed: usize,
    /// The seed's extension (`xyz`, `ply`, `tif`, `json`...).
    pub ext: String,
    pub data: Vec<u8>,
    pub read: ReadOptions,
    /// Readers: 0 chunks, 1 sampling after the first chunk, 2 extents and rows.
    /// Remote: 0 the dataset by its index, 1 one part by its URL.
    pub mode: u8,
    /// Remote: the faults of this case's answers.
    pub faults: Vec<http::Fault>,
}

/// A fuzzer of one input kind: its seeds and the folder its cases run in.
pub struct Fuzzer {
    pub kind: Kind,
    pub seeds: Vec<(Vec<u8>, String)>,
    /// Where a reader case's input is written (nothing else may be left there).
    work: PathBuf,
    /// The indexed dataset (index and remote kinds).
    dataset: PathBuf,
    /// Its files and sizes, to tell what a case left behind.
    dataset_files: Vec<String>,
    server: Option<http::Server>,
}

/// Points in each seed file: enough for several chunks and levels, few enough
/// for thousands of cases a second.
pub const SEED_POINTS: u64 = 200;

impl Fuzzer {
    /// Seeds for `kind`, made under `dir` (kept for the fuzzer's life).
    pub fn new(kind: Kind, dir: &Path) -> anyhow::Result<Fuzzer> {
        let work = dir.join("case");
        std::fs::create_dir_all(&work)?;
        let seeds_dir = dir.join("seeds");
        std::fs::create_dir_all(&seeds_dir)?;
        let dataset = dir.join("ds.pcimg");
        let mut seeds = Vec::new();
        let mut server = None;
        match kind {
            Kind::Index | Kind::Http => {
                indexed_dataset(&dataset)?;
                let index = std::fs::read(dataset.join("pcimg-index.json"))?;
                seeds.push((index, "json".to_string()));
                if kind == Kind::Http {
                    server = Some(http::Server::start(dir)?);
                }
            }
            _ => {
                let want: &[&str] = match kind {
                    Kind::Text => &["xyz", "csv", "pts"],
                    Kind::Ply => &["ply"],
                    Kind::Las => &["las", "laz"],
                    Kind::Pcd => &["pcd"],
                    Kind::E57 => &["e57"],
                    _ => &["tif"],
                };
                seeds = super::seeds(&seeds_dir, SEED_POINTS)?
                    .into_iter()
                    .filter(|(_, ext)| want.contains(&ext.as_str()))
                    .collect();
            }
        }
        let mut fuzzer = Fuzzer {
            kind,
            seeds,
            work,
            dataset,
            dataset_files: Vec::new(),
            server,
        };
        fuzzer.dataset_files = fuzzer.listing(&fuzzer.dataset.clone());
        Ok(fuzzer)
    }

    /// Draws the next case (the same draws whether or not it is then run).
    pub fn case(&self, rng: &mut Rng) -> Case {
        let seed = below(rng, self.seeds.len() as u64) as usize;
        let (orig, ext) = &self.seeds[seed];
        let data = match self.kind {
            // The remote dataset's files are served as they are; its faults
            // are in the answers.
            Kind::Http => Vec::new(),
            // Half of the index cases change the JSON's values (numbers to
            // extremes, names, lists cut or repeated), half its bytes.
            Kind::Index if below(rng, 2) == 0 => mutate_json(orig, rng),
            // Every page of an E57 file ends with its CRC: half of the cases
            // set them right after the mutation, so that the damage reaches
            // the parsers behind the page reader.
            Kind::E57 if below(rng, 2) == 0 => {
                let mut d = mutate(orig, rng);
                fix_e57_checksums(&mut d);
                d
            }
            _ => mutate(orig, rng),
        };
        let text = ext == "xyz" || ext == "csv" || ext == "pts";
        let read = ReadOptions {
            columns: match below(rng, 8) {
                0 => Some("x y z intensity".into()),
                1 => Some("x y z _ r g b".into()),
                2 => Some("_ x y z".into()),
                _ => None,
            }
            .filter(|_| text),
            skip_invalid: below(rng, 2) == 0,
            chunk_points: [1usize, 7, 64, 4096][below(rng, 4) as usize],
            region: None,
        };
        let mode = below(rng, 3) as u8;
        let faults = if self.kind == Kind::Http {
            http::faults(rng)
        } else {
            Vec::new()
        };
        Case {
            seed,
            ext: ext.clone(),
            data,
            read,
            mode,
            faults,
        }
    }

    /// Runs a case in this thread, catching its panics.
    pub fn run(&mut self, case: &Case) -> Verdict {
        install_panic_hook();
        let before = PANICS.load(Ordering::SeqCst);
        IN_CASE.with(|c| c.set(true));
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.run_inner(case)));
        IN_CASE.with(|c| c.set(false));
        let last = || LAST_PANIC.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let v = match r {
            Err(_) => Verdict::Panicked(last()),
            Ok(_) if PANICS.load(Ordering::SeqCst) != before => Verdict::Contained(last()),
            Ok(v) => v,
        };
        if let Some(s) = &self.server {
            s.end_case();
        }
        // Whatever the verdict, the folder is left as it was for the next case.
        let left = self.left_behind();
        if !left.is_empty() && !v.is_failure() {
            return Verdict::LeftBehind(left);
        }
        v
    }

    fn run_inner(&mut self, case: &Case) -> Verdict {
        match self.kind {
            Kind::Part => {
                let name = Path::new("in.tif");
                let r = Part::from_bytes(name, case.data.clone()).and_then(|p| read_all(&p));
                named(r.map_err(|e| e.to_string()), &["in.tif"])
            }
            Kind::Index => {
                let index = self.dataset.join("pcimg-index.json");
                if let Err(e) = std::fs::write(&index, &case.data) {
                    return Verdict::Broken(format!("cannot write {}: {e}", index.display()));
                }
                let r = Dataset::open(&self.dataset).and_then(|ds| read_dataset(&ds));
                named(r.map_err(|e| e.to_string()), &["ds.pcimg"])
            }
            Kind::Http => {
                let server = self.server.as_ref().expect("the http kind has a server");
                server.begin_case(&case.faults);
                let r = server.read(case.mode == 1);
                let here = format!("127.0.0.1:{}", server.port);
                match r {
                    // Healthy answers must give the whole dataset.
                    Err(e) if case.faults.is_empty() => {
                        Verdict::Broken(format!("refused without a fault: {e}"))
                    }
                    r => named(r, &[here.as_str()]),
                }
            }
            _ => {
                let input = self.work.join(format!("in.{}", case.ext));
                // A new file, not one truncated under an old map.
                let _ = std::fs::remove_file(&input);
                if let Err(e) = std::fs::write(&input, &case.data) {
                    return Verdict::Broken(format!("cannot write {}: {e}", input.display()));
                }
                let v = match read_points(&input, &case.read, case.mode) {
                    Ok(Ok(())) => Verdict::Accepted,
                    Ok(Err(broken)) => Verdict::Broken(broken),
                    Err(e) => named(Err(e.to_string()), &["in."]),
                };
                let _ = std::fs::remove_file(&input);
                v
            }
        }
    }

    /// What a case left: files in the reader's folder, or files of the dataset
    /// folder that were not there before (its index is rewritten by each index
    /// case, and put back here).
    fn left_behind(&self) -> Vec<String> {
        let mut left = self.listing(&self.work);
        if matches!(self.kind, Kind::Index | Kind::Http) {
            let now = self.listing(&self.dataset);
            left.extend(now.into_iter().filter(|f| !self.dataset_files.contains(f)));
            if self.kind == Kind::Index {
                let _ = std::fs::write(self.dataset.join("pcimg-index.json"), &self.seeds[0].0);
            }
        }
        left
    }

    /// The names of the files in `dir` and its subfolders.
    fn listing(&self, dir: &Path) -> Vec<String> {
        let mut out = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            let Ok(rd) = std::fs::read_dir(&d) else {
                continue;
            };
            for e in rd.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p.clone());
                }
                out.push(p.strip_prefix(dir).unwrap_or(&p).display().to_string());
            }
        }
        out.sort();
        out
    }
}

/// A refusal that names one of `names`, or [`Verdict::Unnamed`].
fn named(r: Result<(), String>, names: &[&str]) -> Verdict {
    match r {
        Ok(()) => Verdict::Accepted,
        Err(msg) if names.iter().any(|n| msg.contains(n)) => Verdict::Refused(msg),
        Err(msg) => Verdict::Unnamed(msg),
    }
}

/// Parts that declare more points than this are opened but not read (one that
/// declares millions may legitimately need that much memory).
const READ_AT_MOST: u64 = 1 << 20;

/// Every level of a part, every band.
fn read_all(part: &Part) -> pcimg::store::Result<()> {
    if part.meta.point_count <= READ_AT_MOST {
        let bands: Vec<usize> = (0..part.bands.len()).collect();
        for level in 0..part.levels.len() {
            part.read_level(level, &bands)?;
        }
    }
    Ok(())
}

/// Every level of every part and overview node of a dataset.
pub fn read_dataset(ds: &Dataset) -> pcimg::store::Result<()> {
    let nodes = ds.node_count();
    for i in 0..ds.part_count() + nodes {
        if let Some(p) = ds.part(i) {
            read_all(p)?;
        }
    }
    Ok(())
}

/// Streams `input` through its reader as `convert` may (`mode`: 0 chunk by
/// chunk; 1 sampling every few points after the first chunk; 2 chunk extents
/// where the reader gives them, then every point's position and row from its
/// row source). `Ok(Err(_))`: a chunk broke the reader's contract.
fn read_points(
    input: &Path,
    o: &ReadOptions,
    mode: u8,
) -> Result<Result<(), String>, pcimg::ingest::IngestError> {
    let mut r = pcimg::ingest::open(input, o)?;
    let names = r.info().attribute_names.clone();
    if mode == 2 && r.gives_extents()? {
        let mut total = 0usize;
        while let Some(e) = r.next_extent()? {
            total += e.len;
        }
        if let Some(rows) = r.row_source() {
            let n = rows.len().min(total).min(READ_AT_MOST as usize) as u32;
            let idx: Vec<u32> = (0..n).collect();
            let (mut pos, mut vals) = (Vec::new(), Vec::new());
            rows.positions_and_rows(&idx, [0.0; 3], &mut pos, &mut vals);
            if vals.len() != idx.len() * rows.width() {
                return Ok(Err(format!(
                    "{} rows of width {} gave {} values",
                    idx.len(),
                    rows.width(),
                    vals.len()
                )));
            }
        }
        return Ok(Ok(()));
    }
    let mut first = true;
    while let Some(c) = r.next_chunk()? {
        let n = c.x.len();
        if c.y.len() != n || c.z.len() != n {
            return Ok(Err(format!(
                "a chunk of {n} x, {} y, {} z",
                c.y.len(),
                c.z.len()
            )));
        }
        let got: Vec<&str> = c.attributes.iter().map(|a| a.name.as_str()).collect();
        if got != names {
            return Ok(Err(format!(
                "a chunk with attributes {got:?}, announced {names:?}"
            )));
        }
        if let Some(a) = c.attributes.iter().find(|a| a.values.len() != n) {
            return Ok(Err(format!(
                "a chunk of {n} points with {} values of {}",
                a.values.len(),
                a.name
            )));
        }
        if first && mode == 1 {
            r.sample_rest(2 + (n as u64 % 7));
        }
        first = false;
    }
    Ok(Ok(()))
}

/// Four small parts side by side, indexed, with their overview: `dir` (made).
pub fn indexed_dataset(dir: &Path) -> anyhow::Result<()> {
    use pcimg::points::{Attribute, PointColumns};
    use pcimg::store::Compression;
    std::fs::create_dir_all(dir)?;
    let mut r = Rng::new(5);
    for j in 0..2 {
        for i in 0..2 {
            let mut c = PointColumns {
                attributes: vec![Attribute::new("intensity", Vec::new())],
                ..Default::default()
            };
            for _ in 0..SEED_POINTS / 4 {
                let (x, y) = (i as f64 + r.f64(), j as f64 + r.f64());
                c.x.push(500_000.0 + 10.0 * x);
                c.y.push(4_000_000.0 + 10.0 * y);
                c.z.push(100.0 + (x * 0.7).sin());
                c.attributes[0]
                    .values
                    .push((r.f64() * 255.0).round() as f32);
            }
            // A different codec in each part: every tile decoder is fuzzed,
            // and the bytes served per case stay few (an uncompressed part is
            // a 256 × 256 tile per band: a megabyte a case to send).
            let compression = [
                Compression::Zstd,
                Compression::Deflate,
                Compression::LercZstd,
                Compression::Lerc,
            ][2 * j + i];
            write_part(
                &dir.join(format!("tile-{i}-{j}.tif")),
                &c,
                &WriteOptions {
                    compression,
                    // As from a LAS input (half its scale factor): LERC's
                    // bit-stuffed tiles, as most LERC parts hold (a lossless
                    // float tile is 20 times slower to decode).
                    coord_max_error: [0.0005; 3],
                    ..WriteOptions::default()
                },
            )?;
        }
    }
    let report = build_index(dir, &IndexOptions::default(), &|_| {})?;
    anyhow::ensure!(report.nodes >= 1, "no overview: {report:?}");
    Ok(())
}

/// Values a JSON number is set to.
const NUMBERS: [f64; 10] = [
    0.0,
    -1.0,
    1.0,
    0.5,
    2147483648.0,
    4294967296.0,
    9007199254740992.0,
    1.8446744073709552e19,
    1e308,
    -1e308,
];

/// One to three changes to the values of a JSON text (a number set to an
/// extreme, a string to a name or a path, an element removed or repeated, a key
/// removed, a value given another type); the text itself if it is not JSON.
pub fn mutate_json(orig: &[u8], rng: &mut Rng) -> Vec<u8> {
    use serde_json::Value;
    let Ok(mut v) = serde_json::from_slice::<Value>(orig) else {
        return orig.to_vec();
    };
    for _ in 0..1 + below(rng, 3) {
        // A value drawn by descending from the root: at each array or
        // object, stop there one time in four, else go into a random member.
        let mut x = &mut v;
        loop {
            let n = match &*x {
                Value::Array(a) => a.len(),
                Value::Object(o) => o.len(),
                _ => 0,
            };
            if n == 0 || below(rng, 4) == 0 {
                break;
            }
            let i = below(rng, n as u64) as usize;
            x = match x {
                Value::Array(a) => &mut a[i],
                Value::Object(o) => o.values_mut().nth(i).expect("i < len"),
                _ => unreachable!("a container"),
            };
        }
        if below(rng, 4) == 0 {
            *x = match below(rng, 5) {
                0 => Value::Null,
                1 => Value::Bool(true),
                2 => Value::String(String::new()),
                3 => Value::Array(Vec::new()),
                _ => Value::Object(Default::default()),
            };
            continue;
        }
        if x.is_number() {
            let f = NUMBERS[below(rng, NUMBERS.len() as u64) as usize];
            *x = if f.fract() == 0.0 && (0.0..1.8e19).contains(&f) {
                Value::from(f as u64)
            } else if f.fract() == 0.0 && (-1e18..0.0).contains(&f) {
                Value::from(f as i64)
            } else {
                Value::from(f)
            };
            continue;
        }
        match x {
            Value::String(s) => {
                *s = [
                    "",
                    "..",
                    "../tile-0-0.tif",
                    "/etc/passwd",
                    "tile-0-0.tif",
                    "tile-1-1.tif",
                    "pcimg-index.json",
                    "overview",
                    "x",
                ][below(rng, 9) as usize]
                    .to_string()
            }
            Value::Array(a) if !a.is_empty() => {
                let i = below(rng, a.len() as u64) as usize;
                if below(rng, 2) == 0 {
                    a.remove(i);
                } else {
                    let e = a[i].clone();
                    a.insert(below(rng, a.len() as u64 + 1) as usize, e);
                }
            }
            Value::Object(o) if !o.is_empty() => {
                let k = o.keys().nth(below(rng, o.len() as u64) as usize).cloned();
                if let Some(k) = k {
                    o.remove(&k);
                }
            }
            Value::Bool(b) => *b = !*b,
            _ => {}
        }
    }
    serde_json::to_vec(&v).unwrap_or_else(|_| orig.to_vec())
}

/// Page size of an E57 file: 1020 bytes of data, then their CRC-32C.
const E57_PAGE: usize = 1024;

/// Sets the CRC-32C (Castagnoli, stored big-endian as E57 files have it) of
/// every whole page of `d`.
pub fn fix_e57_checksums(d: &mut [u8]) {
    for page in d.chunks_exact_mut(E57_PAGE) {
        let (data, sum) = page.split_at_mut(E57_PAGE - 4);
        sum.copy_from_slice(&crc32c(data).to_be_bytes());
    }
}

/// CRC-32C of `data`, table-driven.
fn crc32c(data: &[u8]) -> u32 {
    static TABLE: std::sync::OnceLock<[u32; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [0u32; 256];
        for (i, e) in t.iter_mut().enumerate() {
            let mut v = i as u32;
            for _ in 0..8 {
                v = if v & 1 == 1 {
                    (v >> 1) ^ 0x82F6_3B78
                } else {
                    v >> 1
                };
            }
            *e = v;
        }
        t
    });
    !data.iter().fold(!0u32, |c, &b| {
        table[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8)
    })
}
