//! The dataset index, `pcimg-index.json` in a dataset directory: every part's file,
//! size, modification time and header, and the overview nodes above the parts. It
//! is written last (its presence marks a finished dataset); opening a dataset
//! reads it instead of every part's header, after checking that the directory
//! still holds exactly the files it lists.

use crate::dataset::summary::PartHeader;
use crate::error::{Remedy, Result, StoreError};
use crate::read::part::Part;
use std::path::Path;
use std::time::UNIX_EPOCH;

/// The index's file name inside a dataset directory.
pub const INDEX_FILE: &str = "pcimg-index.json";
/// The folder of overview parts inside a dataset directory.
pub const OVERVIEW_DIR: &str = "overview";
/// The index format this pcimg writes and reads.
pub(crate) const INDEX_VERSION: u32 = 1;
const FORMAT_NAME: &str = "pcimg-index";

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
        head: head_of(&part.path)?,
        mtime: mtime_of(&meta),
        header: part.header(),
        etag: None,
    })
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

/// The remedy for a dataset whose index is missing, unreadable or stale.
fn reindex(dir: &Path) -> Remedy {
    Remedy::Reindex {
        dataset: dir.to_path_buf(),
    }
}

impl IndexFile {
    pub fn new(parts: Vec<FileEntry>, nodes: Vec<NodeEntry>) -> Self {
        IndexFile {
            format: FORMAT_NAME.into(),
            version: INDEX_VERSION,
            parts,
            nodes,
            uploaded_to: None,
        }
    }

    /// Reads `dir`'s index, if it has one, and its size in bytes.
    pub fn load(dir: &Path) -> Result<Option<(IndexFile, u64)>> {
        Ok(Self::load_text(dir)?.map(|(i, t)| (i, t.len() as u64)))
    }

    /// [`IndexFile::load`], with the index's text.
    pub(crate) fn load_text(dir: &Path) -> Result<Option<(IndexFile, Vec<u8>)>> {
        let path = dir.join(INDEX_FILE);
        let text = match std::fs::read(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(StoreError::new(&path, format!("cannot read: {e}"))),
        };
        let idx = Self::parse(&text, dir)?;
        Ok(Some((idx, text)))
    }

    /// An index's text, checked; `dir` names the dataset in messages (a
    /// directory, or the URL of one in object storage).
    pub fn parse(text: &[u8], dir: &Path) -> Result<IndexFile> {
        let path = dir.join(INDEX_FILE);
        let idx: IndexFile = serde_json::from_slice(text).map_err(|e| {
            StoreError::new(
                &path,
                format!(
                    "not a valid dataset index (line {}, column {}: {e})",
                    e.line(),
                    e.column(),
                ),
            )
            .with_remedy(reindex(dir))
        })?;
        if idx.format != FORMAT_NAME || idx.version > INDEX_VERSION {
            return Err(StoreError::new(
                &path,
                format!(
                    "index format '{}' version {} is not one this version reads ({FORMAT_NAME} {INDEX_VERSION})",
                    crate::text::sanitize(&idx.format),
                    idx.version,
                ),
            )
            .with_remedy(if idx.format == FORMAT_NAME {
                Remedy::Upgrade
            } else {
                reindex(dir)
            }));
        }
        idx.check_structure(dir)?;
        Ok(idx)
    }

    /// Children that exist and come before their parent; names inside the folder.
    fn check_structure(&self, dir: &Path) -> Result<()> {
        let bad = |m: String| StoreError::new(&dir.join(INDEX_FILE), m).with_remedy(reindex(dir));
        let names = self.parts.iter().chain(self.nodes.iter().map(|n| &n.entry));
        for e in names {
            let p = Path::new(&e.file);
            if p.is_absolute()
                || p.components()
                    .any(|c| !matches!(c, std::path::Component::Normal(_)))
            {
                return Err(bad(format!(
                    "lists '{}', which is not a file inside the dataset",
                    crate::text::sanitize(&e.file)
                )));
            }
            if e.header.bands.len() < 3 || e.header.levels.is_empty() {
                return Err(bad(format!(
                    "entry '{}' has no levels or fewer than 3 bands",
                    crate::text::sanitize(&e.file)
                )));
            }
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
        let present = |d: &Path| -> std::collections::HashSet<String> {
            crate::dataset::list_parts(d)
                .unwrap_or_default()
                .iter()
                .filter_map(|p| p.strip_prefix(dir).ok())
                .map(|p| p.to_string_lossy().replace('\\', "/"))
                .collect()
        };
        let mut here = present(dir);
        if !self.nodes.is_empty() {
            here.extend(present(&dir.join(OVERVIEW_DIR)));
        }
        let listed: std::collections::HashSet<&str> =
            self.parts.iter().map(|e| e.file.as_str()).collect();
        let mut unlisted: Vec<&String> = here
            .iter()
            .filter(|n| !n.contains('/') && !listed.contains(n.as_str()))
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
        let open = |e: FileEntry| -> Result<Part> {
            let path = dir.join(&e.file);
            if !here.contains(&e.file) {
                return Err(StoreError::new(
                    &path,
                    "is listed in the dataset's index but missing (restore the file if it was lost)",
                )
                .with_remedy(reindex(dir)));
            }
            Ok(Part::from_header(dir, &path, (e.bytes, e.mtime), e.header))
        };
        let parts = self
            .parts
            .into_iter()
            .map(open)
            .collect::<Result<Vec<_>>>()?;
        let nodes = self
            .nodes
            .into_iter()
            .map(|n| open(n.entry))
            .collect::<Result<Vec<_>>>()?;
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
        let tmp = dir.join(format!(".{INDEX_FILE}.tmp-{}", std::process::id()));
        let text = serde_json::to_vec(self)
            .map_err(|e| StoreError::new(&path, format!("cannot encode: {e}")))?;
        let r = std::fs::write(&tmp, &text).and_then(|()| std::fs::rename(&tmp, &path));
        if let Err(e) = r {
            let _ = std::fs::remove_file(&tmp);
            #[cfg(unix)]
            let e = pcimg_core::disk::with_full_note(e, &path, Some(text.len() as u64));
            return Err(StoreError::new(&path, format!("cannot write: {e}")));
        }
        Ok(text.len() as u64)
    }
}
