//! A dataset: one part file, or a directory of part files, opened from its index
//! (`index.rs`) when it has one, with the overview nodes above its parts.

pub mod index;
pub mod overview;
pub mod paged;
pub mod source;
pub(crate) mod summary;
pub(crate) mod table;

pub use summary::PartHeader;
pub use table::Node;

use crate::dataset::index::{Child, Index, IndexFile};
use crate::dataset::paged::Totals;
use crate::dataset::table::{PageSource, Table};
use crate::error::{Remedy, Result, StoreError};
use crate::points::Bounds;
use crate::read::part::Part;
use std::path::{Path, PathBuf};

/// An opened dataset (headers only; parts opened from an index not even those).
///
/// Its parts and the overview nodes above them are named by ids: what
/// [`Dataset::part`] takes and a tile reference carries. The ids of a dataset
/// opened from a paged index are spread over its pages; only
/// [`Dataset::part_ids`] and [`Dataset::node_ids`] list them (loading every page).
#[derive(Debug, Default)]
pub struct Dataset {
    pub path: PathBuf,
    pub(crate) table: Table,
    /// Bytes of the index the dataset was opened from (its root, when paged).
    pub index_bytes: Option<u64>,
    /// A directory of several parts opened without an index (one would open it
    /// faster and add an overview of all its parts).
    pub unindexed: bool,
    /// Tiles kept by another format (a COPC file) rather than parts.
    pub(crate) source: Option<std::sync::Arc<dyn source::TileSource>>,
}

/// One overview layer in numbers ([`Dataset::layer_summary`]).
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
pub struct LayerSummary {
    pub nodes: usize,
    /// The points a view of the layer draws (its nodes' coarsest levels).
    pub points: u64,
    pub stored_points: u64,
    pub bytes: u64,
}

impl LayerSummary {
    /// Counts node `n` in.
    pub fn add(&mut self, n: &Part) {
        self.add_node(&n.levels, n.meta.point_count, n.file_bytes);
    }

    /// Counts in a node of these levels, points stored and file bytes.
    pub(crate) fn add_node(
        &mut self,
        levels: &[crate::read::part::Level],
        stored: u64,
        bytes: u64,
    ) {
        self.nodes += 1;
        self.points += levels.last().and_then(|l| l.points).unwrap_or(0);
        self.stored_points += stored;
        self.bytes += bytes;
    }
}

fn is_part_file(p: &Path) -> bool {
    let hidden = p
        .file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.'));
    let ext = p
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    !hidden && matches!(ext.as_deref(), Some("tif" | "tiff"))
}

/// The parts of a directory dataset, sorted by name (an error when it has none).
pub(crate) fn list_parts(dir: &Path) -> Result<Vec<PathBuf>> {
    // The entry's own type where the directory gives it (no stat a file: a
    // thousand parts cost a thousand stats), following links.
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| StoreError::new(dir, format!("cannot list directory: {e}")))?
        .filter_map(|e| e.ok())
        .filter(|e| match e.file_type() {
            Ok(t) if t.is_file() => true,
            Ok(t) if t.is_symlink() => e.path().is_file(),
            _ => false,
        })
        .map(|e| e.path())
        .filter(|p| is_part_file(p))
        .collect();
    files.sort();
    if files.is_empty() {
        // A directory of point clouds (tiles of a survey, COPC files): what
        // to do with them, rather than only what is missing.
        let clouds = std::fs::read_dir(dir)
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .filter(|e| cloud_extension(&e.path()).is_some())
                    .count()
            })
            .unwrap_or(0);
        if clouds > 0 {
            let name = dir.file_name().map(|n| n.to_string_lossy().into_owned());
            return Err(point_clouds(
                dir,
                format!("holds {clouds} point-cloud file(s), not image parts"),
                name.as_deref().unwrap_or("clouds"),
            ));
        }
        return Err(StoreError::new(dir, "directory holds no .tif parts"));
    }
    Ok(files)
}

/// `path` holds point clouds rather than parts: `message`, and the remedy of
/// converting it to `NAME.pcimg`.
fn point_clouds(path: &Path, message: String, name: &str) -> StoreError {
    StoreError::new(path, message).with_remedy(Remedy::Convert {
        input: path.to_path_buf(),
        output: PathBuf::from(format!("{name}.pcimg")),
    })
}

/// `p`'s extension, lower case, when it is that of a point cloud `pcimg
/// convert` reads (named when one is opened as a dataset).
fn cloud_extension(p: &Path) -> Option<String> {
    p.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .filter(|e| POINT_CLOUD_EXTENSIONS.contains(&e.as_str()))
}

const POINT_CLOUD_EXTENSIONS: [&str; 8] = ["las", "laz", "xyz", "txt", "csv", "asc", "pts", "ply"];

/// Whether the file begins as a TIFF does (a part renamed `.txt` is a part).
fn starts_like_tiff(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| matches!(&head, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+"))
}

/// A paged index of at most this many parts is checked against its
/// directory's listing on opening (a few milliseconds); beyond, listing the
/// directory would cost more than the first frame (18 ms at 10,000 parts,
/// `bench/index.sh`): a part removed is named when it is first read, and one
/// added since the index is not seen until `pcimg index`.
pub const LISTING_CHECK_PARTS: usize = 4096;

/// Checks a local paged index against its directory, as a version 1 index is
/// checked ([`index::check_listed`]): with one page, from its entries; with
/// more, from the listing's hash, every page read only when it differs; not
/// at all past [`LISTING_CHECK_PARTS`].
fn check_paged(dir: &Path, root: &paged::IndexRoot) -> Result<()> {
    if root.totals.parts > LISTING_CHECK_PARTS {
        return Ok(());
    }
    if root.pages > 1 {
        let here = index::present_parts(dir);
        if root.listing == Some(index::names_hash(here.iter().map(String::as_str))) {
            return Ok(());
        }
    }
    let all = Index::Paged(Box::new(root.clone())).listing(dir, &index::local_page(dir))?;
    let parts: Vec<&str> = all.parts.iter().map(|e| e.file.as_str()).collect();
    let nodes: Vec<&str> = all.nodes.iter().map(|e| e.file.as_str()).collect();
    index::check_listed(dir, &parts, &nodes)
}

/// Each overview node's layer and children, from the index.
fn tree_of(index: &IndexFile) -> Vec<(u32, Vec<Child>)> {
    index
        .nodes
        .iter()
        .map(|n| (n.layer, n.children.clone()))
        .collect()
}

/// How [`Dataset::open_with`] opens a dataset: for one in object storage, how
/// its requests are retried (a local dataset makes no requests).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenOptions {
    /// How long a failing request is tried again (exponential backoff with
    /// jitter) before it fails; a connection silent for a quarter of this (at
    /// most 10 s) counts as stalled (`remote::Options`).
    pub timeout: std::time::Duration,
}

impl Default for OpenOptions {
    fn default() -> Self {
        OpenOptions {
            timeout: std::time::Duration::from_secs(30),
        }
    }
}

impl Dataset {
    /// A dataset of the tiles `source` keeps (a COPC file), with no parts:
    /// `totals` says its points, bounds, bands and CRS.
    pub fn from_source(
        path: &Path,
        totals: Totals,
        source: std::sync::Arc<dyn source::TileSource>,
    ) -> Dataset {
        let mut table = Table::default();
        table.totals = totals;
        Dataset {
            path: path.to_path_buf(),
            table,
            index_bytes: None,
            unindexed: false,
            source: Some(source),
        }
    }

    /// The tile source of a dataset made by [`Dataset::from_source`].
    pub fn source(&self) -> Option<&std::sync::Arc<dyn source::TileSource>> {
        self.source.as_ref()
    }

    /// Opens a `.tif` part or a directory of them (sorted by name).
    pub fn open(path: &Path) -> Result<Dataset> {
        Self::open_with(path, &OpenOptions::default())
    }

    /// As [`Dataset::open`], with `options` for a dataset in object storage.
    pub fn open_with(path: &Path, options: &OpenOptions) -> Result<Dataset> {
        let text = path.to_string_lossy();
        if let Some(local) = crate::location::file_url_path(&text) {
            return Self::open(&local);
        }
        if crate::location::is_url(&text) {
            #[cfg(feature = "remote")]
            return Self::open_url(
                &text,
                &crate::remote::Options {
                    timeout: options.timeout,
                },
            );
            #[cfg(not(feature = "remote"))]
            let _ = options;
            #[cfg(not(feature = "remote"))]
            return Err(StoreError::new(
                path,
                "a URL, and this build reads local datasets only (the `remote` feature is off)",
            ));
        }
        let meta = std::fs::metadata(path)
            .map_err(|e| StoreError::new(path, format!("cannot open: {e}")))?;
        // An index rewritten meanwhile (`pcimg index`) may have removed files the
        // one read listed: the new one is read again, a few times at most.
        let mut tries = 0;
        while meta.is_dir()
            && let Some(text) = index::read_index(path)?
        {
            let index = Index::parse(&text, path)?;
            let r = match index {
                Index::One(index) => {
                    let tree = tree_of(&index);
                    index
                        .open_parts(path)
                        .map(|(parts, nodes)| Table::from_tree(path, parts, nodes, tree))
                }
                Index::Paged(root) => check_paged(path, &root).map(|()| {
                    let source = PageSource::Local {
                        dir: path.to_path_buf(),
                        pages_dir: root.pages_dir.clone(),
                    };
                    Table::paged(path, *root, source)
                }),
            };
            match r {
                Ok(table) => {
                    return Ok(Dataset {
                        path: path.to_path_buf(),
                        table,
                        index_bytes: Some(text.len() as u64),
                        unindexed: false,
                        source: None,
                    });
                }
                Err(e) => {
                    tries += 1;
                    let now = std::fs::read(path.join(index::INDEX_FILE)).ok();
                    if tries >= 5 || now.is_none_or(|t| t == text) {
                        return Err(e);
                    }
                }
            }
        }
        let parts = if meta.is_dir() {
            list_parts(path)?
                .iter()
                .map(|f| Part::open(f))
                .collect::<Result<Vec<_>>>()?
        } else {
            if let Some(ext) = cloud_extension(path).filter(|_| !starts_like_tiff(path)) {
                let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
                return Err(point_clouds(
                    path,
                    format!("a point cloud (.{ext}), not an image dataset"),
                    stem.as_deref().unwrap_or("cloud"),
                ));
            }
            vec![Part::open(path)?]
        };
        let unindexed = parts.len() > 1;
        Ok(Dataset {
            path: path.to_path_buf(),
            table: Table::loaded(path, parts),
            unindexed,
            index_bytes: None,
            source: None,
        })
    }

    #[cfg(feature = "remote")]
    /// A dataset in object storage: its index in one request (its parts are
    /// fetched from when their tiles are read), or a single `.tif` part.
    pub(crate) fn open_url(url: &str, options: &crate::remote::Options) -> Result<Dataset> {
        let url = url.trim_end_matches('/');
        let remote = std::sync::Arc::new(
            crate::remote::Remote::open_with(url, options).map_err(StoreError::remote)?,
        );
        Self::open_remote(remote)
    }

    /// A dataset in a given object store (an index under its prefix, or a `.tif`).
    /// Whether the dataset was opened from object storage (a URL).
    pub fn is_remote(&self) -> bool {
        crate::location::is_url(&self.path.to_string_lossy())
    }

    #[cfg(feature = "remote")]
    pub fn open_remote(remote: std::sync::Arc<crate::remote::Remote>) -> Result<Dataset> {
        let url = remote.url.as_str();
        let path = Path::new(url);
        let lower = url.to_ascii_lowercase();
        if lower.ends_with(".tif") || lower.ends_with(".tiff") {
            let file = std::sync::Arc::new(remote.file(""));
            return Ok(Dataset {
                path: path.to_path_buf(),
                table: Table::loaded(path, vec![Part::open_remote(file, 0, None)?]),
                ..Default::default()
            });
        }
        let Some((text, size, _)) = remote
            .get(crate::dataset::index::INDEX_FILE)
            .map_err(StoreError::remote)?
        else {
            // What to do (index it, upload the index) is the command line's to say.
            let url = remote.url_of(crate::dataset::index::INDEX_FILE);
            let mut e = StoreError::remote(crate::remote::RemoteError::new(
                &url,
                crate::remote::Problem::NotFound,
            ));
            e.message.push_str(
                ": no dataset index there (a dataset in object storage is opened from its index)",
            );
            return Err(e);
        };
        let table = match Index::parse(&text, path)? {
            Index::One(index) => {
                let tree = tree_of(&index);
                let (parts, nodes) = index.remote_parts(&remote);
                Table::from_tree(path, parts, nodes, tree)
            }
            Index::Paged(root) => {
                // The ETags hold for the store they were recorded in.
                let pinned = root.uploaded_to.as_deref() == Some(remote.url.as_str());
                let source = PageSource::Remote {
                    remote: remote.clone(),
                    pages_dir: root.pages_dir.clone(),
                    pinned,
                };
                Table::paged(path, *root, source)
            }
        };
        Ok(Dataset {
            path: path.to_path_buf(),
            table,
            index_bytes: Some(size),
            unindexed: false,
            source: None,
        })
    }

    /// The dataset's totals (parts, points, bounds...), from its index.
    pub fn totals(&self) -> &Totals {
        &self.table.totals
    }

    /// The number of parts (not counting overview nodes).
    pub fn part_count(&self) -> usize {
        self.table.totals.parts
    }

    /// The number of overview nodes.
    pub fn node_count(&self) -> usize {
        self.table.totals.nodes
    }

    /// The most levels a part has (at least 1).
    pub fn own_levels(&self) -> usize {
        self.table.totals.own_levels.max(1)
    }

    /// The part or overview node `id` names; `None` when there is none, or its
    /// index page cannot be read ([`Dataset::try_part`] says why).
    pub fn part(&self, id: usize) -> Option<&Part> {
        self.table.entry(id).ok().map(|(p, _)| p)
    }

    /// [`Dataset::part`], or why it cannot be had (its index page could not be
    /// read or parsed).
    pub fn try_part(&self, id: usize) -> Result<&Part> {
        self.table.entry(id).map(|(p, _)| p)
    }

    /// The overview node `id` names.
    pub fn node(&self, id: usize) -> Option<&Node> {
        self.table.entry(id).ok().and_then(|(_, n)| n)
    }

    /// Every part's id (the parts of a paged index: every page loaded).
    pub fn part_ids(&self) -> Result<Vec<usize>> {
        self.table.part_ids()
    }

    /// Every overview node's id (every page loaded).
    pub fn node_ids(&self) -> Result<Vec<usize>> {
        self.table.node_ids()
    }

    /// The ids of the parts in the pages loaded so far (every part, but for
    /// a paged index).
    pub fn loaded_part_ids(&self) -> Vec<usize> {
        self.table.loaded_part_ids()
    }

    /// Every part (every page loaded).
    pub fn parts(&self) -> Result<Vec<&Part>> {
        self.part_ids()?
            .into_iter()
            .map(|id| self.try_part(id))
            .collect()
    }

    /// The first part.
    pub fn first_part(&self) -> Option<&Part> {
        self.part(0)
    }

    /// The ids of the parts whose bounds `may_hold` accepts: with an overview,
    /// found from the root down, so that pages of subtrees it refuses are not
    /// read.
    pub fn parts_where(&self, may_hold: &dyn Fn(&Bounds) -> bool) -> Result<Vec<usize>> {
        let Some(root) = self.table.root else {
            let ids = self.part_ids()?;
            return Ok(ids
                .into_iter()
                .filter(|&id| self.part(id).is_some_and(|p| may_hold(&p.meta.bounds)))
                .collect());
        };
        let mut out = Vec::new();
        let mut stack = vec![root];
        while let Some(id) = stack.pop() {
            let kids: Vec<(usize, Bounds)> = self
                .children(id)?
                .into_iter()
                .filter(|(_, b)| may_hold(b))
                .collect();
            self.prefetch(&kids.iter().map(|k| k.0).collect::<Vec<_>>());
            for (c, _) in kids.into_iter().rev() {
                self.child(id, c)?;
                if self.is_overview(c) {
                    stack.push(c);
                } else {
                    out.push(c);
                }
            }
        }
        out.sort_unstable();
        Ok(out)
    }

    /// Whether there is an overview above the parts.
    pub fn has_overview(&self) -> bool {
        self.table.root.is_some()
    }

    /// The overview's root node.
    pub fn root(&self) -> Option<usize> {
        self.table.root
    }

    /// Layers of overview nodes above the parts.
    pub fn layer_count(&self) -> u32 {
        self.table.layers.len() as u32
    }

    /// Layer `layer` (1 just above the parts) in numbers, from the index.
    pub fn layer_summary(&self, layer: u32) -> LayerSummary {
        (layer as usize)
            .checked_sub(1)
            .and_then(|l| self.table.layers.get(l))
            .copied()
            .unwrap_or_default()
    }

    /// The ids of the nodes of `layer` (every page loaded).
    pub fn layer_nodes(&self, layer: u32) -> Result<Vec<usize>> {
        Ok(self
            .node_ids()?
            .into_iter()
            .filter(|&id| self.node(id).is_some_and(|n| n.layer == layer))
            .collect())
    }

    /// The children of node `id` and each one's bounds, from the node's own
    /// entry: nothing else is read (a view culls children by these bounds
    /// before reading their pages). Empty for a part.
    pub fn children(&self, id: usize) -> Result<Vec<(usize, Bounds)>> {
        let (_, node) = self.table.entry(id)?;
        Ok(node.map_or_else(Vec::new, |n| {
            n.children
                .iter()
                .copied()
                .zip(n.child_bounds.iter().copied())
                .collect()
        }))
    }

    /// Reads the index pages that hold `ids` (entries a view is about to
    /// reach) together, rather than one request after another.
    pub fn prefetch(&self, ids: &[usize]) {
        self.table.prefetch(ids);
    }

    /// Child `child` of node `id`, read (its page loaded): a part, or a node of
    /// a lower layer (an index naming any other is refused: no cycles).
    pub fn child(&self, id: usize, child: usize) -> Result<&Part> {
        let (_, Some(n)) = self.table.entry(id)? else {
            return Err(StoreError::new(
                &self.path,
                format!("entry {id} is not a node"),
            ));
        };
        let (part, kid) = self.table.entry(child)?;
        let lower = match kid {
            Some(k) => k.layer < n.layer,
            None => n.layer >= 1,
        };
        if !lower || !n.children.contains(&child) {
            return Err(StoreError::new(
                &self.path.join(index::INDEX_FILE),
                format!("overview node {id} names a child that is not below it"),
            )
            .with_remedy(Remedy::Reindex {
                dataset: self.path.clone(),
            }));
        }
        Ok(part)
    }

    /// What node `id` stands for: the union of its children's bounds.
    pub fn cover(&self, id: usize) -> Option<Bounds> {
        self.node(id).map(|n| n.cover)
    }

    /// Index pages: in all, and loaded now.
    pub fn index_pages(&self) -> (usize, usize) {
        (self.table.page_count(), self.table.pages_loaded())
    }

    /// Index pages read after opening, and their bytes.
    pub fn pages_fetched(&self) -> (u64, u64) {
        use std::sync::atomic::Ordering::Relaxed;
        (
            self.table.fetched.load(Relaxed),
            self.table.fetched_bytes.load(Relaxed),
        )
    }

    /// The overview node above entry `id` (a part or a node).
    pub fn parent(&self, id: usize) -> Option<usize> {
        self.table.parent(id)
    }

    /// The coarsest tiles of the overview's top layers, root first (breadth
    /// first), up to `points` points in all: what a viewer loads before
    /// anything else.
    pub fn overview_first(&self, points: u64) -> Vec<(usize, usize, u32, u64)> {
        let Some(root) = self.table.root else {
            return Vec::new();
        };
        let mut out = Vec::new();
        let mut sum = 0;
        let mut queue = std::collections::VecDeque::from([root]);
        while let Some(id) = queue.pop_front() {
            let Some(n) = self.node(id) else { continue };
            let Some(l) = n.part.levels.last() else {
                continue;
            };
            let pts = l.points.unwrap_or(0);
            if sum + pts > points && !out.is_empty() {
                break;
            }
            sum += pts;
            for t in &l.tiles {
                out.push((id, l.index, t.index, t.points.unwrap_or(0) as u64));
            }
            if let Ok(kids) = self.children(id) {
                queue.extend(
                    kids.into_iter()
                        .map(|(c, _)| c)
                        .filter(|&c| self.table.is_node(c) && self.child(id, c).is_ok()),
                );
            }
        }
        out
    }

    /// Whether `id` names an overview node (nothing is loaded to tell).
    pub fn is_overview(&self, id: usize) -> bool {
        self.table.is_node(id)
    }

    /// Union of the parts' bounds.
    pub fn bounds(&self) -> Bounds {
        self.table.totals.bounds
    }

    /// Total points over all parts.
    pub fn points(&self) -> u64 {
        self.table.totals.points
    }

    /// Total bytes of all part files.
    pub fn bytes(&self) -> u64 {
        self.table.totals.bytes
    }
}
