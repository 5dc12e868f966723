//! A dataset: one part file, or a directory of part files, opened from its index
//! (`index.rs`) when it has one, with the overview nodes above its parts.

pub mod index;
pub mod overview;
pub(crate) mod summary;

pub use summary::PartHeader;

use crate::dataset::index::{Child, IndexFile};
use crate::error::{Remedy, Result, StoreError};
use crate::points::Bounds;
use crate::read::part::Part;
use std::path::{Path, PathBuf};

/// An opened dataset (headers only; parts opened from an index not even those).
#[derive(Debug, Default)]
pub struct Dataset {
    pub path: PathBuf,
    pub parts: Vec<Part>,
    /// The overview above the parts, from the index.
    pub overview: Option<Overview>,
    /// Bytes of the index the dataset was opened from.
    pub index_bytes: Option<u64>,
    /// A directory of several parts opened without an index (one would open it
    /// faster and add an overview of all its parts).
    pub unindexed: bool,
}

/// Overview nodes above the parts: ordinary parts whose coarsest level is an even
/// sample of their children's coarsest levels. In a [`crate::lod::TileRef`], node
/// `k` is part number `parts.len() + k` (see [`Dataset::part`]).
#[derive(Debug)]
pub struct Overview {
    pub nodes: Vec<Part>,
    pub children: Vec<Vec<Child>>,
    /// Layer of each node: 1 just above the parts.
    pub layers: Vec<u32>,
    /// The node above each part number (parts, then nodes), `None` for the root.
    pub parents: Vec<Option<usize>>,
    /// What each node stands for: the union of its children's bounds (its own
    /// points, a sample, may not reach the edges of its children's).
    pub covers: Vec<Bounds>,
}

impl Overview {
    /// The root node (the last).
    pub fn root(&self) -> usize {
        self.nodes.len() - 1
    }

    /// Number of layers above the parts.
    pub fn layer_count(&self) -> u32 {
        self.layers.iter().copied().max().unwrap_or(0)
    }

    /// The nodes (numbers into `nodes`) of `layer`.
    pub fn layer(&self, layer: u32) -> impl Iterator<Item = usize> + '_ {
        (0..self.nodes.len()).filter(move |&k| self.layers[k] == layer)
    }

    /// What `layer` holds: its nodes, the points a view of it draws (their
    /// coarsest levels), the points and bytes stored.
    pub fn layer_summary(&self, layer: u32) -> LayerSummary {
        let mut s = LayerSummary::default();
        for n in self.layer(layer).map(|k| &self.nodes[k]) {
            s.nodes += 1;
            s.points += n.levels.last().and_then(|l| l.points).unwrap_or(0);
            s.stored_points += n.meta.point_count;
            s.bytes += n.file_bytes;
        }
        s
    }
}

/// One overview layer in numbers ([`Overview::layer_summary`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct LayerSummary {
    pub nodes: usize,
    pub points: u64,
    pub stored_points: u64,
    pub bytes: u64,
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
/// The part number of overview child `c` in a dataset of `parts` parts (nodes
/// come after the parts).
fn child_number(parts: usize, c: Child) -> usize {
    match c {
        Child::Part(i) => i,
        Child::Node(k) => parts + k,
    }
}

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
        return Err(StoreError::new(dir, "directory holds no .tif parts"));
    }
    Ok(files)
}

/// Extensions of the point clouds `pcimg convert` reads (named when one is
/// opened as a dataset).
const POINT_CLOUD_EXTENSIONS: [&str; 8] = ["las", "laz", "xyz", "txt", "csv", "asc", "pts", "ply"];

/// Whether the file begins as a TIFF does (a part renamed `.txt` is a part).
fn starts_like_tiff(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| matches!(&head, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+"))
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
            && let Some((index, text)) = IndexFile::load_text(path)?
        {
            let tree = tree_of(&index);
            match index.open_parts(path) {
                Ok((parts, nodes)) => {
                    return Ok(Self::assemble(path, tree, parts, nodes, text.len() as u64));
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
            let cloud = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
                .filter(|e| POINT_CLOUD_EXTENSIONS.contains(&e.as_str()));
            if let Some(ext) = cloud.filter(|_| !starts_like_tiff(path)) {
                let stem = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "cloud".into());
                return Err(StoreError::new(
                    path,
                    format!("a point cloud (.{ext}), not an image dataset"),
                )
                .with_remedy(Remedy::Convert {
                    input: path.to_path_buf(),
                    output: PathBuf::from(format!("{stem}.pcimg")),
                }));
            }
            vec![Part::open(path)?]
        };
        let unindexed = parts.len() > 1;
        Ok(Dataset {
            path: path.to_path_buf(),
            parts,
            unindexed,
            ..Default::default()
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
                parts: vec![Part::open_remote(file, 0, None)?],
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
        let index = IndexFile::parse(&text, path)?;
        let tree = tree_of(&index);
        let (parts, nodes) = index.remote_parts(&remote);
        Ok(Self::assemble(path, tree, parts, nodes, size))
    }

    /// A dataset opened from its index: parts, overview nodes and their tree.
    fn assemble(
        path: &Path,
        tree: Vec<(u32, Vec<Child>)>,
        parts: Vec<Part>,
        nodes: Vec<Part>,
        index_bytes: u64,
    ) -> Dataset {
        let np = parts.len();
        let overview = (!nodes.is_empty()).then(|| {
            let mut parents = vec![None; np + nodes.len()];
            for (k, (_, children)) in tree.iter().enumerate() {
                for &c in children {
                    parents[child_number(np, c)] = Some(np + k);
                }
            }
            let mut covers: Vec<Bounds> = Vec::with_capacity(nodes.len());
            for (_, children) in &tree {
                let b = children.iter().fold(Bounds::EMPTY, |b, c| match *c {
                    Child::Part(i) => b.union(&parts[i].meta.bounds),
                    Child::Node(j) => b.union(&covers[j]),
                });
                covers.push(b);
            }
            Overview {
                nodes,
                layers: tree.iter().map(|t| t.0).collect(),
                children: tree.into_iter().map(|t| t.1).collect(),
                parents,
                covers,
            }
        });
        Dataset {
            path: path.to_path_buf(),
            parts,
            overview,
            index_bytes: Some(index_bytes),
            unindexed: false,
        }
    }

    /// The most levels a part has (at least 1).
    pub fn own_levels(&self) -> usize {
        self.parts.iter().map(|p| p.levels.len()).max().unwrap_or(1)
    }

    /// Part `i` of a [`crate::lod::TileRef`]: a part, or past the parts an
    /// overview node.
    pub fn part(&self, i: usize) -> Option<&Part> {
        match i.checked_sub(self.parts.len()) {
            None => self.parts.get(i),
            Some(k) => self.overview.as_ref().and_then(|o| o.nodes.get(k)),
        }
    }

    /// The part number of an overview child.
    pub fn child_part(&self, c: Child) -> usize {
        child_number(self.parts.len(), c)
    }

    /// The overview node above part number `i` (a part or a node).
    pub fn parent(&self, i: usize) -> Option<usize> {
        self.overview.as_ref()?.parents.get(i).copied().flatten()
    }

    /// The coarsest tiles of the overview's top layers, root first, up to `points`
    /// points in all: what a viewer loads before anything else.
    pub fn overview_first(&self, points: u64) -> Vec<(usize, usize, u32, u64)> {
        let Some(o) = &self.overview else {
            return Vec::new();
        };
        let mut order: Vec<usize> = (0..o.nodes.len()).collect();
        order.sort_by_key(|&k| (std::cmp::Reverse(o.layers[k]), k));
        let mut out = Vec::new();
        let mut sum = 0;
        for k in order {
            let n = &o.nodes[k];
            let Some(l) = n.levels.last() else { continue };
            let pts = l.points.unwrap_or(0);
            if sum + pts > points && !out.is_empty() {
                break;
            }
            sum += pts;
            for t in &l.tiles {
                out.push((
                    self.parts.len() + k,
                    l.index,
                    t.index,
                    t.points.unwrap_or(0) as u64,
                ));
            }
        }
        out
    }

    /// Whether part number `i` is an overview node.
    pub fn is_overview(&self, i: usize) -> bool {
        i >= self.parts.len()
    }

    /// Union of the parts' bounds.
    pub fn bounds(&self) -> Bounds {
        self.parts
            .iter()
            .fold(Bounds::EMPTY, |b, p| b.union(&p.meta.bounds))
    }

    /// Total points over all parts.
    pub fn points(&self) -> u64 {
        self.parts.iter().map(|p| p.meta.point_count).sum()
    }

    /// Total bytes of all part files.
    pub fn bytes(&self) -> u64 {
        self.parts.iter().map(|p| p.file_bytes).sum()
    }
}
