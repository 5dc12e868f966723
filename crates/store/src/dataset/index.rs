//! The dataset index, `pcimg-index.json` in a dataset directory: every part's file,
//! size, modification time and header, and the overview nodes above the parts. It
//! is written last (its presence marks a finished dataset); opening a dataset
//! reads it instead of every part's header.
//!
//! Version 2 (written since issue 44) is paged: the root file holds the totals,
//! the layers' summaries and the first page (the overview's top nodes); every
//! other page, a JSON file in `pages-G/`, holds entries of one subtree, fetched
//! when selection descends into it ([`paginate`]). An entry is named by an id:
//! part ids `page * stride + slot` below `pages * stride`, node ids the same
//! above it. Version 1 (one document, every entry) still opens.

use crate::dataset::paged::{IndexPage, IndexRoot, Slot, locate, page_file};
use crate::dataset::summary::PartHeader;
use crate::error::{Remedy, Result, StoreError};
use crate::read::part::Part;
use std::path::Path;
use std::time::UNIX_EPOCH;

/// The index's file name inside a dataset directory.
pub const INDEX_FILE: &str = "pcimg-index.json";
/// The folder of overview parts inside a dataset directory.
pub const OVERVIEW_DIR: &str = "overview";
/// The folders of a paged index's pages: `pages-0` and `pages-1`, one for each
/// overview generation (`overview.rs`).
pub const PAGES_DIR: &str = "pages";
/// The index format this pcimg writes and reads.
pub(crate) const INDEX_VERSION: u32 = 2;
/// The largest first page, inside the root file: with the rest of the root,
/// opening any dataset reads well under 256 KB.
pub const ROOT_PAGE_BYTES: usize = 160 * 1024;
/// The largest other page (one more unit may carry a page past it only when
/// the unit alone is larger).
pub const PAGE_BYTES: usize = 192 * 1024;
pub(crate) const FORMAT_NAME: &str = "pcimg-index";

/// A file the index lists: its path relative to the dataset, size, modification
/// time and header.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FileEntry {
    /// Relative to the dataset directory, `/`-separated.
    pub file: String,
    pub bytes: u64,
    /// Bytes at the head of the file holding every IFD, tile index and the
    /// metadata (0: unknown, an older part): a reader fetches them in one range.
    #[serde(default)]
    pub head: u64,
    /// Modification time: seconds and nanoseconds since the Unix epoch.
    pub mtime: (i64, u32),
    pub header: PartHeader,
    /// The object's ETag in the store [`IndexFile::uploaded_to`] names, as its
    /// upload returned it (`convert -o URL`); absent in an index written locally.
    /// A reader of that store keys its caches by it and sends every range
    /// request conditional on it, so it needs no HEAD to learn it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub etag: Option<String>,
}

/// What an overview node stands for: a part, or a node of the layer below.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Child {
    Part(usize),
    Node(usize),
}

/// An overview node: an ordinary part (usually one tile) holding an even sample of
/// its children's coarsest levels: a quarter of their points, as the next level of
/// their pyramids would.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct NodeEntry {
    #[serde(flatten)]
    pub entry: FileEntry,
    /// 1 just above the parts, the root's layer highest.
    pub layer: u32,
    pub children: Vec<Child>,
}

/// The whole index file.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct IndexFile {
    pub format: String,
    pub version: u32,
    pub parts: Vec<FileEntry>,
    /// Overview nodes, each after its children; the root last.
    pub nodes: Vec<NodeEntry>,
    /// The URL the dataset was uploaded to when the entries' `etag`s were
    /// recorded: they are used only when the dataset is read from that URL (a
    /// copy elsewhere, made by other tools, may carry other ETags).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uploaded_to: Option<String>,
}

/// Modification time of `meta` as stored in the index.
pub(crate) fn mtime_of(meta: &std::fs::Metadata) -> (i64, u32) {
    match meta.modified().ok().map(|t| t.duration_since(UNIX_EPOCH)) {
        Some(Ok(d)) => (d.as_secs() as i64, d.subsec_nanos()),
        Some(Err(e)) => (
            -(e.duration().as_secs() as i64),
            e.duration().subsec_nanos(),
        ),
        None => (0, 0),
    }
}

/// The index entry of an opened part, `file` relative to the dataset.
pub fn entry_of(part: &Part, file: &str) -> Result<FileEntry> {
    let meta = std::fs::metadata(&part.path)
        .map_err(|e| StoreError::new(&part.path, format!("cannot stat: {e}")))?;
    Ok(FileEntry {
        file: file.to_string(),
        bytes: meta.len(),
        head: head_of_part(part)?,
        mtime: mtime_of(&meta),
        header: part.header(),
        etag: None,
    })
}

/// [`head_of`] for an opened part, from the bytes it holds (a part opened
/// from its file holds them all; one opened from an index, or remote, is
/// read again from its path).
fn head_of_part(part: &Part) -> Result<u64> {
    if part.lazy.is_none() && part.remote.is_none() && !part.map.is_empty() {
        let tiff =
            crate::tiff::ifd::Tiff::parse(&part.map).map_err(|e| StoreError::new(&part.path, e))?;
        return Ok(tiff.head_first_len(&part.map));
    }
    head_of(&part.path)
}

/// The head's length of the part at `path` when it was written head-first
/// (every directory and value before the first tile), else 0.
pub fn head_of(path: &Path) -> Result<u64> {
    let file = std::fs::File::open(path)
        .map_err(|e| StoreError::new(path, format!("cannot open: {e}")))?;
    // SAFETY: a read-only map of a part, read only through the bounds-checked
    // directory parser; a part is replaced by rename, never changed in place.
    let map = unsafe { memmap2::Mmap::map(&file) }
        .map_err(|e| StoreError::new(path, format!("cannot map: {e}")))?;
    let tiff = crate::tiff::ifd::Tiff::parse(&map).map_err(|e| StoreError::new(path, e))?;
    Ok(tiff.head_first_len(&map))
}

/// The text of `dir`'s index, if it has one.
pub(crate) fn read_index(dir: &Path) -> Result<Option<Vec<u8>>> {
    let path = dir.join(INDEX_FILE);
    match std::fs::read(&path) {
        Ok(t) => Ok(Some(t)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(StoreError::new(&path, format!("cannot read: {e}"))),
    }
}

/// Every file `dir`'s index names (its pages included), if it has an index.
pub fn indexed_files(dir: &Path) -> Result<Option<Vec<String>>> {
    let Some(text) = read_index(dir)? else {
        return Ok(None);
    };
    Index::parse(&text, dir)?
        .files(dir, &local_page(dir))
        .map(Some)
}

/// The part files directly in `dir` (names, sorted).
pub(crate) fn present_parts(dir: &Path) -> Vec<String> {
    crate::dataset::list_parts(dir)
        .unwrap_or_default()
        .iter()
        .filter_map(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .collect()
}

/// A hash of sorted part names (FNV-1a, 64 bits): a paged index records its
/// parts' ([`crate::dataset::paged::IndexRoot::listing`]), so that opening
/// compares the directory's listing with it without reading every page.
pub(crate) fn names_hash<'a>(names: impl Iterator<Item = &'a str>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for n in names {
        for b in n.bytes().chain(std::iter::once(b'\n')) {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// Checks that the dataset directory holds every part and node the index
/// lists, and no part it does not list (names the first either way).
pub(crate) fn check_listed(dir: &Path, parts: &[&str], nodes: &[&str]) -> Result<()> {
    let mut here: std::collections::HashSet<String> = present_parts(dir).into_iter().collect();
    let listed: std::collections::HashSet<&str> = parts.iter().copied().collect();
    let mut unlisted: Vec<&String> = here
        .iter()
        .filter(|n| !listed.contains(n.as_str()))
        .collect();
    unlisted.sort();
    if let Some(n) = unlisted.first() {
        return Err(StoreError::new(
            &dir.join(n),
            format!(
                "is not in the dataset's index ({} unlisted part{})",
                unlisted.len(),
                if unlisted.len() == 1 { "" } else { "s" },
            ),
        )
        .with_remedy(reindex(dir)));
    }
    if !nodes.is_empty() {
        let od = dir.join(OVERVIEW_DIR);
        here.extend(
            present_parts(&od)
                .into_iter()
                .map(|n| format!("{OVERVIEW_DIR}/{n}")),
        );
    }
    if let Some(f) = parts.iter().chain(nodes).find(|f| !here.contains(**f)) {
        return Err(StoreError::new(
            &dir.join(f),
            "is listed in the dataset's index but missing (restore the file if it was lost)",
        )
        .with_remedy(reindex(dir)));
    }
    Ok(())
}

/// Reads a page of `dir`'s index (a file relative to it).
pub fn local_page(dir: &Path) -> impl Fn(&str) -> Result<Vec<u8>> + '_ {
    move |name: &str| {
        let p = dir.join(name);
        std::fs::read(&p).map_err(|e| StoreError::new(&p, format!("cannot read: {e}")))
    }
}

/// Writes `text` to `path` atomically (a temporary file beside it, renamed).
pub(crate) fn write_atomic(path: &Path, text: &[u8]) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let r = std::fs::write(&tmp, text).and_then(|()| std::fs::rename(&tmp, path));
    if let Err(e) = r {
        let _ = std::fs::remove_file(&tmp);
        #[cfg(unix)]
        let e = pcimg_core::disk::with_full_note(e, path, Some(text.len() as u64));
        return Err(StoreError::new(path, format!("cannot write: {e}")));
    }
    Ok(())
}

/// An entry names a file inside the dataset, with levels and at least x, y, z.
pub(crate) fn check_entry(e: &FileEntry) -> std::result::Result<(), String> {
    let p = Path::new(&e.file);
    if p.is_absolute()
        || p.components()
            .any(|c| !matches!(c, std::path::Component::Normal(_)))
    {
        return Err(format!(
            "lists '{}', which is not a file inside the dataset",
            crate::text::sanitize(&e.file)
        ));
    }
    if e.header.bands.len() < 3 || e.header.levels.is_empty() {
        return Err(format!(
            "entry '{}' has no levels or fewer than 3 bands",
            crate::text::sanitize(&e.file)
        ));
    }
    Ok(())
}

/// The error for `dir`'s index text that is not the JSON of an index.
fn not_an_index(dir: &Path, e: serde_json::Error) -> StoreError {
    StoreError::new(
        &dir.join(INDEX_FILE),
        format!(
            "not a valid dataset index (line {}, column {}: {e})",
            e.line(),
            e.column(),
        ),
    )
    .with_remedy(reindex(dir))
}

/// The remedy for a dataset whose index is missing, unreadable or stale.
fn reindex(dir: &Path) -> Remedy {
    Remedy::Reindex {
        dataset: dir.to_path_buf(),
    }
}

/// An index as read: version 1 (one document) or the paged version 2.
#[derive(Debug, Clone)]
pub enum Index {
    One(IndexFile),
    Paged(Box<IndexRoot>),
}

/// The two fields every version begins with.
#[derive(serde::Deserialize)]
struct Probe {
    #[serde(default)]
    format: String,
    #[serde(default)]
    version: u32,
}

impl Index {
    /// An index's text, checked; `dir` names the dataset in messages (a
    /// directory, or the URL of one in object storage).
    pub fn parse(text: &[u8], dir: &Path) -> Result<Index> {
        let path = dir.join(INDEX_FILE);
        let not_json = |e| not_an_index(dir, e);
        let probe: Probe = serde_json::from_slice(text).map_err(not_json)?;
        if probe.format != FORMAT_NAME || probe.version > INDEX_VERSION || probe.version == 0 {
            return Err(StoreError::new(
                &path,
                format!(
                    "index format '{}' version {} is not one this version reads ({FORMAT_NAME} 1 to {INDEX_VERSION})",
                    crate::text::sanitize(&probe.format),
                    probe.version,
                ),
            )
            .with_remedy(if probe.format == FORMAT_NAME && probe.version > INDEX_VERSION {
                Remedy::Upgrade
            } else {
                reindex(dir)
            }));
        }
        if probe.version == 1 {
            return Ok(Index::One(IndexFile::parse_v1(text, dir)?));
        }
        let root: IndexRoot = serde_json::from_slice(text).map_err(not_json)?;
        let bad = |m: String| StoreError::new(&path, m).with_remedy(reindex(dir));
        let dir_ok = Path::new(&root.pages_dir)
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        if root.pages == 0
            || root.stride == 0
            || root
                .pages
                .checked_mul(root.stride)
                .and_then(|s| s.checked_mul(2))
                .is_none()
            || !dir_ok
            || root.pages_dir.is_empty()
        {
            return Err(bad("has an impossible page table".into()));
        }
        if root
            .root
            .is_some_and(|id| !matches!(locate(id, root.pages, root.stride), Some(Slot::Node(..))))
        {
            return Err(bad("names a root node that cannot exist".into()));
        }
        root.first.check(&path, dir, root.pages, root.stride)?;
        Ok(Index::Paged(Box::new(root)))
    }

    /// Every entry the index holds, and its pages' files: the pages are read
    /// through `page` (a page's file, relative to the dataset).
    pub fn listing(&self, dir: &Path, page: &dyn Fn(&str) -> Result<Vec<u8>>) -> Result<Listing> {
        let mut out = Listing::default();
        self.visit(dir, page, &mut |v| match v {
            Listed::Part(e) => out.parts.push(e.clone()),
            Listed::Node(e) => out.nodes.push(e.clone()),
            Listed::Page(name) => out.pages.push(name.to_string()),
        })?;
        Ok(out)
    }

    /// Calls `f` with every entry of the index, and the file of every page
    /// after the root, reading one page at a time.
    fn visit(
        &self,
        dir: &Path,
        page: &dyn Fn(&str) -> Result<Vec<u8>>,
        f: &mut dyn FnMut(Listed),
    ) -> Result<()> {
        let each = |p: &IndexPage, f: &mut dyn FnMut(Listed)| {
            p.parts.iter().for_each(|e| f(Listed::Part(&e.entry)));
            p.nodes.iter().for_each(|e| f(Listed::Node(&e.entry)));
        };
        match self {
            Index::One(i) => {
                i.parts.iter().for_each(|e| f(Listed::Part(e)));
                i.nodes.iter().for_each(|n| f(Listed::Node(&n.entry)));
            }
            Index::Paged(r) => {
                each(&r.first, f);
                for k in 1..r.pages {
                    let name = page_file(&r.pages_dir, k);
                    let text = page(&name)?;
                    let p = IndexPage::parse(&text, &dir.join(&name), dir, r.pages, r.stride)?;
                    each(&p, f);
                    f(Listed::Page(&name));
                }
            }
        }
        Ok(())
    }

    /// Every file the index names: parts, nodes and its own pages (read one
    /// page at a time, the names alone kept).
    pub fn files(&self, dir: &Path, page: &dyn Fn(&str) -> Result<Vec<u8>>) -> Result<Vec<String>> {
        let (mut parts, mut nodes, mut pages) = (Vec::new(), Vec::new(), Vec::new());
        self.visit(dir, page, &mut |v| match v {
            Listed::Part(e) => parts.push(e.file.clone()),
            Listed::Node(e) => nodes.push(e.file.clone()),
            Listed::Page(name) => pages.push(name.to_string()),
        })?;
        parts.extend(nodes);
        parts.extend(pages);
        Ok(parts)
    }

    /// The URL the entries' ETags were recorded for.
    pub fn uploaded_to(&self) -> Option<&str> {
        match self {
            Index::One(i) => i.uploaded_to.as_deref(),
            Index::Paged(r) => r.uploaded_to.as_deref(),
        }
    }
}

/// One thing an index lists ([`Index::visit`]).
enum Listed<'a> {
    Part(&'a FileEntry),
    Node(&'a FileEntry),
    /// A page file after the root.
    Page(&'a str),
}

/// What an index lists ([`Index::listing`]).
#[derive(Debug, Clone, Default)]
pub struct Listing {
    pub parts: Vec<FileEntry>,
    /// The overview nodes' entries.
    pub nodes: Vec<FileEntry>,
    /// The index's page files after its root (a paged index's).
    pub pages: Vec<String>,
}

/// Rewrites `dir`'s index with `f` applied to every entry (parts and nodes, in
/// every page) and `uploaded_to` set; returns the page files written (the
/// root's excluded). Pages first, then the root, each atomically.
pub fn rewrite_entries(
    dir: &Path,
    uploaded_to: Option<String>,
    f: &dyn Fn(&mut FileEntry),
) -> Result<Vec<String>> {
    let path = dir.join(INDEX_FILE);
    let text = read_index(dir)?.ok_or_else(|| StoreError::new(&path, "cannot read: no index"))?;
    match Index::parse(&text, dir)? {
        Index::One(mut ix) => {
            ix.parts.iter_mut().for_each(f);
            ix.nodes.iter_mut().for_each(|n| f(&mut n.entry));
            ix.uploaded_to = uploaded_to;
            ix.save(dir)?;
            Ok(Vec::new())
        }
        Index::Paged(mut root) => {
            let mut pages = root.read_pages(dir)?;
            let mut fix = |p: &mut IndexPage| {
                p.parts.iter_mut().for_each(|e| f(&mut e.entry));
                p.nodes.iter_mut().for_each(|n| f(&mut n.entry));
            };
            fix(&mut root.first);
            pages.iter_mut().for_each(&mut fix);
            root.uploaded_to = uploaded_to;
            root.save(dir, &pages)?;
            Ok((1..root.pages)
                .map(|k| page_file(&root.pages_dir, k))
                .collect())
        }
    }
}

impl IndexFile {
    /// A version 1 index (still read; written now only to test that it is).
    pub fn new(parts: Vec<FileEntry>, nodes: Vec<NodeEntry>) -> Self {
        IndexFile {
            format: FORMAT_NAME.into(),
            version: 1,
            parts,
            nodes,
            uploaded_to: None,
        }
    }

    /// A version 1 index's text, checked; `dir` names the dataset in messages
    /// (a directory, or the URL of one in object storage).
    pub fn parse(text: &[u8], dir: &Path) -> Result<IndexFile> {
        match Index::parse(text, dir)? {
            Index::One(i) => Ok(i),
            Index::Paged(_) => Err(StoreError::new(
                &dir.join(INDEX_FILE),
                "a paged index (version 2), where version 1 was expected",
            )),
        }
    }

    fn parse_v1(text: &[u8], dir: &Path) -> Result<IndexFile> {
        let idx: IndexFile = serde_json::from_slice(text).map_err(|e| not_an_index(dir, e))?;
        idx.check_structure(dir)?;
        Ok(idx)
    }

    /// Children that exist and come before their parent; names inside the folder.
    fn check_structure(&self, dir: &Path) -> Result<()> {
        let bad = |m: String| StoreError::new(&dir.join(INDEX_FILE), m).with_remedy(reindex(dir));
        let names = self.parts.iter().chain(self.nodes.iter().map(|n| &n.entry));
        for e in names {
            check_entry(e).map_err(bad)?;
        }
        for (i, n) in self.nodes.iter().enumerate() {
            for c in &n.children {
                let ok = match *c {
                    Child::Part(p) => p < self.parts.len(),
                    Child::Node(k) => k < i,
                };
                if !ok {
                    return Err(bad(format!("node {i} names a child that does not exist")));
                }
            }
        }
        Ok(())
    }

    /// Checks, from the directories' listings alone (no file is opened or
    /// stat'ed: a thousand parts open in milliseconds), that every listed file is
    /// there and that the folder holds no part the index does not list; the parts
    /// and nodes, unopened. Whether a part changed (size or modification time) is
    /// checked when its file is first read.
    pub(crate) fn open_parts(self, dir: &Path) -> Result<(Vec<Part>, Vec<Part>)> {
        let parts: Vec<&str> = self.parts.iter().map(|e| e.file.as_str()).collect();
        let nodes: Vec<&str> = self.nodes.iter().map(|n| n.entry.file.as_str()).collect();
        check_listed(dir, &parts, &nodes)?;
        let open = |e: FileEntry| -> Part {
            let path = dir.join(&e.file);
            Part::from_header(dir, &path, (e.bytes, e.mtime), e.header)
        };
        let parts = self.parts.into_iter().map(open).collect();
        let nodes = self.nodes.into_iter().map(|n| open(n.entry)).collect();
        Ok((parts, nodes))
    }

    #[cfg(feature = "remote")]
    /// The parts and nodes of a dataset in object storage, unopened: nothing is
    /// fetched until a tile is read.
    pub(crate) fn remote_parts(
        self,
        remote: &std::sync::Arc<crate::remote::Remote>,
    ) -> (Vec<Part>, Vec<Part>) {
        let dir = Path::new(&remote.url);
        // The ETags hold for the store they were recorded in.
        let pinned = self.uploaded_to.as_deref() == Some(remote.url.as_str());
        let open = |e: FileEntry| {
            let file = match e.etag.filter(|t| pinned && !t.is_empty()) {
                Some(etag) => remote.file_pinned(&e.file, e.bytes, etag),
                None => remote.file(&e.file),
            };
            Part::from_header_remote(dir, std::sync::Arc::new(file), (e.bytes, e.head), e.header)
        };
        let parts = self.parts.into_iter().map(open).collect();
        let nodes = self.nodes.into_iter().map(|n| open(n.entry)).collect();
        (parts, nodes)
    }

    /// Writes the index into `dir` atomically (a temporary file renamed).
    pub fn save(&self, dir: &Path) -> Result<u64> {
        let path = dir.join(INDEX_FILE);
        let text = serde_json::to_vec(self)
            .map_err(|e| StoreError::new(&path, format!("cannot encode: {e}")))?;
        write_atomic(&path, &text)?;
        Ok(text.len() as u64)
    }
}
