//! COPC 1.0 (<https://copc.io>) read side: a LAS 1.4 file whose LAZ points are
//! stored as one chunk per node of an octree, with the octree's hierarchy in
//! pages of 32-byte entries.
//!
//! Our own reading of the header, VLRs and hierarchy (the specification is two
//! pages) rather than `las::CopcReader`, which reads every hierarchy page up
//! front through one `Read + Seek` (the whole octree before the first point, the
//! complaint of laspy PR #219). Here:
//! - [`Copc::open`] costs at most two reads of the [`ByteSource`]: the first
//!   [`PREFIX`] bytes (header, VLRs), then the root hierarchy page (none where it
//!   lies in the prefix; one more only where the VLRs outgrow the prefix);
//! - further hierarchy pages are read only when a walk reaches them, several at
//!   once in one batch of ranges;
//! - node chunks are read as one batch of ranges, which a remote source merges
//!   when near and fetches concurrently ([`ByteSource::read_ranges`]);
//! - chunks are decompressed by the `laz` crate, only the fields asked for
//!   (`laz::DecompressionSelection`), one chunk per call so that callers
//!   decompress many in parallel.
//!
//! The crate knows no pcimg types: the caller gives the bytes (a local file is
//! [`FileSource`]; object storage and HTTP are implemented by the caller over
//! its ranged reads) and turns raw LAS records into columns.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex};

/// Bytes of a LAS 1.4 header.
pub const HEADER_SIZE: u64 = 375;
/// Bytes of a VLR's header.
pub const VLR_HEADER: u64 = 54;
/// Where the COPC info VLR's body must be (the first VLR, after the header).
pub const INFO_OFFSET: u64 = HEADER_SIZE + VLR_HEADER;
/// Bytes of the COPC info VLR's body.
pub const INFO_SIZE: u64 = 160;
/// Bytes of one hierarchy entry.
pub const ENTRY_SIZE: u64 = 32;
/// Bytes read first on opening: the header and, in every file we have seen,
/// all VLRs (a WKT CRS is a few kilobytes).
pub const PREFIX: u64 = 64 << 10;

/// Where a COPC file's bytes come from.
pub trait ByteSource: Send + Sync {
    /// The path or URL, as errors name it.
    fn name(&self) -> String;
    /// The first `max` bytes, or the whole source where it is shorter.
    fn read_prefix(&self, max: u64) -> std::io::Result<Vec<u8>>;
    /// The whole source (a small file read whole).
    fn read_all(&self) -> std::io::Result<Vec<u8>> {
        self.read_prefix(u64::MAX)
    }
    /// The source's length in bytes (known after [`ByteSource::read_prefix`]).
    fn size(&self) -> std::io::Result<u64>;
    /// The bytes of each range, in order (each must lie inside the source).
    fn read_ranges(&self, ranges: &[Range<u64>]) -> std::io::Result<Vec<Vec<u8>>>;
}

/// A local file read with positioned reads.
#[derive(Debug)]
pub struct FileSource {
    path: std::path::PathBuf,
    file: std::fs::File,
    len: u64,
}

impl FileSource {
    pub fn open(path: &std::path::Path) -> std::io::Result<FileSource> {
        let file = std::fs::File::open(path)?;
        let len = file.metadata()?.len();
        Ok(FileSource {
            path: path.to_path_buf(),
            file,
            len,
        })
    }
}

impl ByteSource for FileSource {
    fn name(&self) -> String {
        self.path.display().to_string()
    }
    fn read_prefix(&self, max: u64) -> std::io::Result<Vec<u8>> {
        let n = max.min(self.len);
        Ok(self.read_ranges(std::slice::from_ref(&(0..n)))?.remove(0))
    }
    fn size(&self) -> std::io::Result<u64> {
        Ok(self.len)
    }
    fn read_ranges(&self, ranges: &[Range<u64>]) -> std::io::Result<Vec<Vec<u8>>> {
        use std::os::unix::fs::FileExt;
        ranges
            .iter()
            .map(|r| {
                let mut b = vec![0u8; r.end.saturating_sub(r.start) as usize];
                self.file.read_exact_at(&mut b, r.start)?;
                Ok(b)
            })
            .collect()
    }
}

/// What kind of failure a [`CopcError`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Not a COPC file (not LAS, not 1.4, no COPC info VLR, not LAZ).
    NotCopc,
    /// A COPC file whose structure is broken (truncated, counts that disagree).
    Corrupt,
    /// The source could not be read.
    Io,
}

/// A failure, with the file or URL and, where known, the byte offset.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{name}{}: {what}", offset.map(|o| format!(": byte {o}")).unwrap_or_default())]
pub struct CopcError {
    pub name: String,
    pub offset: Option<u64>,
    pub what: String,
    pub kind: Kind,
}

pub type Result<T> = std::result::Result<T, CopcError>;

/// The LAS header's fields a reader needs.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub version: (u8, u8),
    /// The point data format (6, 7 or 8), without LAZ's compression bits.
    pub format: u8,
    pub record_len: u16,
    pub points: u64,
    pub scale: [f64; 3],
    pub offset: [f64; 3],
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub point_data_offset: u64,
    pub vlr_count: u32,
}

/// The COPC info VLR.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Info {
    pub center: [f64; 3],
    /// Half the root node's side.
    pub halfsize: f64,
    /// The distance between points at the root.
    pub spacing: f64,
    pub root_hier_offset: u64,
    pub root_hier_size: u64,
    pub gps_time: [f64; 2],
}

/// A node's cube: its smallest and largest corner.
pub type Cube = ([f64; 3], [f64; 3]);

/// A node of the octree: depth and position at that depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Key {
    pub d: i32,
    pub x: i32,
    pub y: i32,
    pub z: i32,
}

impl Key {
    pub const ROOT: Key = Key {
        d: 0,
        x: 0,
        y: 0,
        z: 0,
    };

    /// The eight children.
    pub fn children(&self) -> [Key; 8] {
        std::array::from_fn(|i| Key {
            d: self.d + 1,
            x: 2 * self.x + (i & 1) as i32,
            y: 2 * self.y + ((i >> 1) & 1) as i32,
            z: 2 * self.z + ((i >> 2) & 1) as i32,
        })
    }

    /// The node's cube (min, max).
    pub fn bounds(&self, info: &Info) -> Cube {
        let side = 2.0 * info.halfsize / f64::from(1u32 << self.d.clamp(0, 31) as u32);
        let at = [self.x, self.y, self.z];
        let min: [f64; 3] =
            std::array::from_fn(|a| info.center[a] - info.halfsize + side * f64::from(at[a]));
        (min, std::array::from_fn(|a| min[a] + side))
    }
}

/// A node with points: where its chunk is and how many points it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Entry {
    pub key: Key,
    pub offset: u64,
    pub bytes: u32,
    pub points: u32,
}

#[derive(Debug, Default)]
struct Hierarchy {
    nodes: HashMap<Key, Entry>,
    /// Pages not yet read: their key (the first node they hold) → range.
    pages: HashMap<Key, Range<u64>>,
    pages_read: usize,
}

/// An opened COPC file.
pub struct Copc {
    source: Arc<dyn ByteSource>,
    name: String,
    pub header: Header,
    pub info: Info,
    /// The header and VLRs as stored (bytes 0 to the point data).
    pub head: Vec<u8>,
    pub laz: laz::LazVlr,
    pub len: u64,
    hierarchy: Mutex<Hierarchy>,
}

impl std::fmt::Debug for Copc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Copc")
            .field("name", &self.name)
            .field("header", &self.header)
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap_or_default())
}
fn i32_at(b: &[u8], at: usize) -> i32 {
    u32_at(b, at) as i32
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap_or_default())
}
fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_bits(u64_at(b, at))
}
/// A VLR's user id (16 bytes, NUL-padded).
fn user_id(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

impl Copc {
    fn err(&self, offset: Option<u64>, kind: Kind, what: impl Into<String>) -> CopcError {
        error(&self.name, offset, kind, what)
    }

    /// Opens the COPC file `source` holds: its header, VLRs and root
    /// hierarchy page.
    pub fn open(source: Arc<dyn ByteSource>) -> Result<Copc> {
        let name = source.name();
        let io = |e: std::io::Error| error(&name, None, Kind::Io, e.to_string());
        let mut head = source.read_prefix(PREFIX).map_err(io)?;
        let len = source.size().map_err(io)?;
        let header = parse_header(&name, &head, len)?;
        if header.point_data_offset > head.len() as u64 {
            let more = source
                .read_ranges(std::slice::from_ref(
                    &(head.len() as u64..header.point_data_offset),
                ))
                .map_err(io)?;
            head.extend_from_slice(&more[0]);
        }
        head.truncate(header.point_data_offset as usize);
        let info = parse_info(&name, &head, len)?;
        let laz = find_laz_vlr(&name, &head, &header)?;
        let copc = Copc {
            source,
            name,
            header,
            info,
            head,
            laz,
            len,
            hierarchy: Mutex::new(Hierarchy::default()),
        };
        let root = info.root_hier_offset..info.root_hier_offset + info.root_hier_size;
        let page = copc.read(std::slice::from_ref(&root))?.remove(0);
        copc.add_page(root.start, &page)?;
        if !copc.lock().nodes.contains_key(&Key::ROOT) {
            return Err(copc.err(
                Some(root.start),
                Kind::Corrupt,
                "the root hierarchy page has no entry for the root node 0-0-0-0",
            ));
        }
        Ok(copc)
    }

    /// The path or URL.
    pub fn name(&self) -> &str {
        &self.name
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Hierarchy> {
        self.hierarchy.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn read(&self, ranges: &[Range<u64>]) -> Result<Vec<Vec<u8>>> {
        self.source
            .read_ranges(ranges)
            .map_err(|e| self.err(ranges.first().map(|r| r.start), Kind::Io, e.to_string()))
    }

    /// Adds the entries of the hierarchy page read from byte `at`.
    fn add_page(&self, at: u64, page: &[u8]) -> Result<()> {
        if !(page.len() as u64).is_multiple_of(ENTRY_SIZE) {
            return Err(self.err(
                Some(at),
                Kind::Corrupt,
                format!(
                    "a hierarchy page of {} bytes is not a whole number of {ENTRY_SIZE}-byte \
                     entries (truncated?)",
                    page.len()
                ),
            ));
        }
        let mut h = self.lock();
        h.pages_read += 1;
        for (k, e) in page.chunks_exact(ENTRY_SIZE as usize).enumerate() {
            let here = at + k as u64 * ENTRY_SIZE;
            let key = Key {
                d: i32_at(e, 0),
                x: i32_at(e, 4),
                y: i32_at(e, 8),
                z: i32_at(e, 12),
            };
            let (offset, bytes, points) = (u64_at(e, 16), i32_at(e, 24), i32_at(e, 28));
            let side = 1i64 << key.d.clamp(0, 62);
            let inside = |v: i32| (0..side).contains(&i64::from(v));
            if !(0..=31).contains(&key.d) || ![key.x, key.y, key.z].into_iter().all(inside) {
                return Err(self.err(
                    Some(here),
                    Kind::Corrupt,
                    format!(
                        "hierarchy entry with an impossible key {}-{}-{}-{}",
                        key.d, key.x, key.y, key.z
                    ),
                ));
            }
            let end = offset.checked_add(u64::from(bytes.max(0) as u32));
            if bytes < 0 || points < -1 || end.is_none_or(|e| e > self.len) {
                return Err(self.err(
                    Some(here),
                    Kind::Corrupt,
                    format!(
                        "hierarchy entry of node {}-{}-{}-{}: {bytes} bytes at byte {offset} \
                         with {points} points, outside the file's {} bytes",
                        key.d, key.x, key.y, key.z, self.len
                    ),
                ));
            }
            if points == -1 {
                h.pages
                    .insert(key, offset..offset + u64::from(bytes as u32));
            } else {
                h.nodes.insert(
                    key,
                    Entry {
                        key,
                        offset,
                        bytes: bytes as u32,
                        points: points as u32,
                    },
                );
            }
        }
        Ok(())
    }

    /// Reads the pages named by `keys` not yet read (one batch of ranges).
    fn load_pages(&self, keys: &[Key]) -> Result<()> {
        let want: Vec<(Key, Range<u64>)> = {
            let h = self.lock();
            keys.iter()
                .filter_map(|k| h.pages.get(k).map(|r| (*k, r.clone())))
                .collect()
        };
        if want.is_empty() {
            return Ok(());
        }
        let ranges: Vec<Range<u64>> = want.iter().map(|w| w.1.clone()).collect();
        let pages = self.read(&ranges)?;
        for ((k, r), page) in want.iter().zip(pages) {
            self.lock().pages.remove(k);
            self.add_page(r.start, &page)?;
        }
        Ok(())
    }

    /// The root node's entry.
    pub fn root(&self) -> Entry {
        self.lock().nodes[&Key::ROOT]
    }

    /// The entries of `key`'s children that exist, reading the hierarchy
    /// pages that hold them when not yet read.
    pub fn children(&self, key: &Key) -> Result<Vec<Entry>> {
        let kids = key.children();
        self.load_pages(&kids)?;
        let h = self.lock();
        Ok(kids
            .iter()
            .filter_map(|k| h.nodes.get(k).copied())
            .collect())
    }

    /// Every node whose cube `keep` accepts and whose ancestors' cubes it
    /// accepted, breadth first (a level's pages read as one batch), down to
    /// depth `max_depth`.
    pub fn nodes_where(&self, keep: &dyn Fn(&Cube) -> bool, max_depth: i32) -> Result<Vec<Entry>> {
        let mut out = Vec::new();
        let mut level = vec![self.root()];
        level.retain(|e| keep(&e.key.bounds(&self.info)));
        while !level.is_empty() {
            out.extend(level.iter().copied());
            if level[0].key.d >= max_depth {
                break;
            }
            let kids: Vec<Key> = level.iter().flat_map(|e| e.key.children()).collect();
            self.load_pages(&kids)?;
            let h = self.lock();
            level = kids
                .iter()
                .filter_map(|k| h.nodes.get(k).copied())
                .filter(|e| keep(&e.key.bounds(&self.info)))
                .collect();
        }
        Ok(out)
    }

    /// Every node (reads every hierarchy page).
    pub fn all_nodes(&self) -> Result<Vec<Entry>> {
        self.nodes_where(&|_| true, i32::MAX)
    }

    /// The entry of node `key` if a page read so far holds it.
    pub fn known(&self, key: &Key) -> Option<Entry> {
        self.lock().nodes.get(key).copied()
    }

    /// Every node of the hierarchy pages read so far (the root page's once
    /// opened), in no order: what is known without another read.
    pub fn known_nodes(&self) -> Vec<Entry> {
        self.lock().nodes.values().copied().collect()
    }

    /// Hierarchy pages read so far, and pages known but not read.
    pub fn pages(&self) -> (usize, usize) {
        let h = self.lock();
        (h.pages_read, h.pages.len())
    }

    /// The compressed chunks of `entries`, as one batch of ranges.
    pub fn fetch(&self, entries: &[Entry]) -> Result<Vec<Vec<u8>>> {
        let ranges: Vec<Range<u64>> = entries
            .iter()
            .map(|e| e.offset..e.offset + u64::from(e.bytes))
            .collect();
        self.read(&ranges)
    }

    /// Decompresses node `e`'s chunk into LAS records of
    /// [`Header::record_len`] bytes; fields outside `selection` are left zero.
    pub fn decompress(
        &self,
        e: &Entry,
        chunk: &[u8],
        selection: laz::DecompressionSelection,
    ) -> Result<Vec<u8>> {
        use laz::record::{LayeredPointRecordDecompressor, RecordDecompressor};
        let bad = |what: String| self.err(Some(e.offset), Kind::Corrupt, what);
        let node = format!("node {}-{}-{}-{}", e.key.d, e.key.x, e.key.y, e.key.z);
        if e.points == 0 {
            return Ok(Vec::new());
        }
        // A layered chunk starts with its first point, raw, then its point count.
        let at = self.laz.items_size() as usize;
        if chunk.len() < at + 4 {
            return Err(bad(format!("{node}: a chunk of {} bytes", chunk.len())));
        }
        let held = u32_at(chunk, at);
        if held != e.points {
            return Err(bad(format!(
                "{node}: its chunk holds {held} points, the hierarchy says {}",
                e.points
            )));
        }
        let record = usize::from(self.header.record_len);
        let mut out = vec![0u8; record * e.points as usize];
        let run = || -> std::result::Result<(), String> {
            let mut d = LayeredPointRecordDecompressor::new(std::io::Cursor::new(chunk));
            d.set_fields_from(self.laz.items())
                .map_err(|e| e.to_string())?;
            if d.record_size() != record {
                return Err(format!(
                    "LAZ records of {} bytes, the header says {record}",
                    d.record_size()
                ));
            }
            d.set_selection(selection);
            d.decompress_many(&mut out).map_err(|e| e.to_string())
        };
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(run)) {
            Ok(Ok(())) => Ok(out),
            Ok(Err(why)) => Err(bad(format!("{node}: cannot decompress its chunk: {why}"))),
            Err(_) => Err(bad(format!(
                "{node}: the LAZ decompressor failed on its chunk (corrupt data)"
            ))),
        }
    }
}

fn error(name: &str, offset: Option<u64>, kind: Kind, what: impl Into<String>) -> CopcError {
    CopcError {
        name: name.to_string(),
        offset,
        what: what.into(),
        kind,
    }
}

fn parse_header(name: &str, b: &[u8], len: u64) -> Result<Header> {
    let not = |at: u64, what: String| error(name, Some(at), Kind::NotCopc, what);
    if b.len() < 4 || &b[..4] != b"LASF" {
        return Err(not(
            0,
            "not a LAS file (no \"LASF\" signature): not COPC".into(),
        ));
    }
    if (b.len() as u64) < INFO_OFFSET + INFO_SIZE {
        return Err(error(
            name,
            Some(len),
            Kind::Corrupt,
            format!(
                "truncated: the file ends at byte {len}, before the COPC info VLR ends (byte {})",
                INFO_OFFSET + INFO_SIZE
            ),
        ));
    }
    let version = (b[24], b[25]);
    if version != (1, 4) {
        return Err(not(
            24,
            format!(
                "LAS {}.{}: a COPC file is LAS 1.4 (this is not COPC)",
                version.0, version.1
            ),
        ));
    }
    let f = |a: usize| f64_at(b, a);
    let header = Header {
        version,
        format: b[104] & 0x3f,
        record_len: u16_at(b, 105),
        points: u64_at(b, 247),
        scale: [f(131), f(139), f(147)],
        offset: [f(155), f(163), f(171)],
        max: [f(179), f(195), f(211)],
        min: [f(187), f(203), f(219)],
        point_data_offset: u64::from(u32_at(b, 96)),
        vlr_count: u32_at(b, 100),
    };
    if user_id(&b[377..393]) != "copc" || u16_at(b, 393) != 1 {
        return Err(not(
            HEADER_SIZE,
            "a LAS file without COPC's info VLR as its first VLR (user \"copc\", record 1): \
             not a COPC file (convert it as LAS/LAZ)"
                .into(),
        ));
    }
    if b[104] & 0x80 == 0 {
        return Err(not(
            104,
            "its points are not LAZ-compressed: not COPC".into(),
        ));
    }
    if !(6..=8).contains(&header.format) {
        return Err(not(
            104,
            format!("point format {}: COPC uses 6, 7 or 8", header.format),
        ));
    }
    if !header.scale.iter().all(|s| s.is_finite() && *s != 0.0)
        || !header.offset.iter().all(|o| o.is_finite())
    {
        return Err(error(
            name,
            Some(131),
            Kind::Corrupt,
            "a scale factor of zero or a non-finite scale or offset",
        ));
    }
    if header.point_data_offset > len || header.point_data_offset < INFO_OFFSET + INFO_SIZE {
        return Err(error(
            name,
            Some(96),
            Kind::Corrupt,
            format!(
                "point data at byte {}, outside the file's {len} bytes or inside its VLRs",
                header.point_data_offset
            ),
        ));
    }
    Ok(header)
}

fn parse_info(name: &str, b: &[u8], len: u64) -> Result<Info> {
    let at = INFO_OFFSET as usize;
    let f = |k: usize| f64_at(b, at + 8 * k);
    let info = Info {
        center: [f(0), f(1), f(2)],
        halfsize: f(3),
        spacing: f(4),
        root_hier_offset: u64_at(b, at + 40),
        root_hier_size: u64_at(b, at + 48),
        gps_time: [f(7), f(8)],
    };
    let usable = info.halfsize.is_finite() && info.halfsize > 0.0;
    if !usable || !info.center.iter().all(|c| c.is_finite()) {
        return Err(error(
            name,
            Some(INFO_OFFSET),
            Kind::Corrupt,
            format!(
                "the COPC info VLR's cube (half size {}) is not usable",
                info.halfsize
            ),
        ));
    }
    let end = info.root_hier_offset.checked_add(info.root_hier_size);
    if end.is_none_or(|e| e > len) {
        return Err(error(
            name,
            Some(INFO_OFFSET + 40),
            Kind::Corrupt,
            format!(
                "truncated: the root hierarchy page ({} bytes at byte {}) ends past the file's \
                 end (byte {len})",
                info.root_hier_size, info.root_hier_offset
            ),
        ));
    }
    Ok(info)
}

fn find_laz_vlr(name: &str, head: &[u8], header: &Header) -> Result<laz::LazVlr> {
    let mut at = HEADER_SIZE as usize;
    for _ in 0..header.vlr_count {
        if at + VLR_HEADER as usize > head.len() {
            break;
        }
        let len = usize::from(u16_at(head, at + 20));
        let body = at + VLR_HEADER as usize;
        if user_id(&head[at + 2..at + 18]) == "laszip encoded" && u16_at(head, at + 18) == 22204 {
            let Some(b) = head.get(body..body + len) else {
                break;
            };
            return laz::LazVlr::from_buffer(b).map_err(|e| {
                error(
                    name,
                    Some(body as u64),
                    Kind::Corrupt,
                    format!("the LAZ VLR cannot be read: {e}"),
                )
            });
        }
        at = body + len;
    }
    Err(error(
        name,
        Some(HEADER_SIZE),
        Kind::NotCopc,
        "no LAZ VLR (user \"laszip encoded\", record 22204) among the VLRs",
    ))
}

#[cfg(test)]
mod tests;
