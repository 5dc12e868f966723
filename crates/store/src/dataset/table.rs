//! A dataset's parts and overview nodes as a reader reaches them: in pages
//! (`paged.rs`), each loaded on the first question about an entry in it, so that
//! what a dataset holds in memory grows with what its views have visited. A
//! dataset opened from a version 1 index, or from its part files, is one page
//! already loaded.

use crate::dataset::LayerSummary;
use crate::dataset::index::{Child, FileEntry};
use crate::dataset::paged::{
    IndexPage, IndexRoot, PageNode, PagePart, Slot, Totals, locate, page_file,
};
use crate::error::{Result, StoreError};
use crate::points::Bounds;
use crate::read::part::Part;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// An overview node: its part (one tile, usually), layer, children and cover.
#[derive(Debug)]
pub struct Node {
    pub part: Part,
    /// 1 just above the parts.
    pub layer: u32,
    /// Ids of the entries it stands for.
    pub children: Vec<usize>,
    /// Each child's bounds (a part's, a node's cover).
    pub child_bounds: Vec<Bounds>,
    /// The union of its children's bounds (its own points, a sample, may not
    /// reach their edges).
    pub cover: Bounds,
    pub parent: Option<usize>,
}

/// One page in memory.
#[derive(Debug, Default)]
pub(crate) struct Page {
    pub(crate) parts: Vec<(Part, Option<usize>)>,
    pub(crate) nodes: Vec<Node>,
}

/// Where pages not yet loaded come from.
#[derive(Debug)]
pub(crate) enum PageSource {
    /// Every page is loaded.
    Loaded,
    /// A dataset directory: its `pages_dir`.
    Local { dir: PathBuf, pages_dir: String },
    #[cfg(feature = "remote")]
    Remote {
        remote: std::sync::Arc<crate::remote::Remote>,
        pages_dir: String,
        /// Whether the entries' ETags hold for this store.
        pinned: bool,
    },
}

/// The pages of a dataset.
#[derive(Debug)]
pub(crate) struct Table {
    pub(crate) stride: usize,
    pages: Vec<OnceLock<Box<Page>>>,
    /// Held while page `k` loads: two readers of one page fetch it once,
    /// readers of different pages fetch them together.
    loading: Vec<Mutex<()>>,
    source: PageSource,
    pub(crate) totals: Totals,
    pub(crate) layers: Vec<LayerSummary>,
    pub(crate) root: Option<usize>,
    /// The dataset, named in messages.
    dir: PathBuf,
    /// Pages loaded after opening, and their bytes.
    pub(crate) fetched: std::sync::atomic::AtomicU64,
    pub(crate) fetched_bytes: std::sync::atomic::AtomicU64,
}

impl Default for Table {
    fn default() -> Self {
        Table::loaded(Path::new(""), Vec::new())
    }
}

impl Table {
    /// Parts with no overview, all in memory.
    pub(crate) fn loaded(dir: &Path, parts: Vec<Part>) -> Table {
        let totals = totals_of(&parts, 0);
        let stride = parts.len().max(1);
        let page = Page {
            parts: parts.into_iter().map(|p| (p, None)).collect(),
            nodes: Vec::new(),
        };
        Table::one_page(dir, page, stride, totals, Vec::new(), None)
    }

    /// A table of one page, loaded.
    fn one_page(
        dir: &Path,
        page: Page,
        stride: usize,
        totals: Totals,
        layers: Vec<LayerSummary>,
        root: Option<usize>,
    ) -> Table {
        Table {
            stride,
            pages: vec![OnceLock::from(Box::new(page))],
            loading: vec![Mutex::new(())],
            source: PageSource::Loaded,
            totals,
            layers,
            root,
            dir: dir.to_path_buf(),
            fetched: Default::default(),
            fetched_bytes: Default::default(),
        }
    }

    /// A version 1 index's parts and nodes (each node after its children, the
    /// root last), all in memory: part `i` is id `i`, node `k` id
    /// `stride + k`.
    pub(crate) fn from_tree(
        dir: &Path,
        parts: Vec<Part>,
        nodes: Vec<Part>,
        tree: Vec<(u32, Vec<Child>)>,
    ) -> Table {
        let np = parts.len();
        let stride = np.max(nodes.len()).max(1);
        let id = |c: Child| match c {
            Child::Part(i) => i,
            Child::Node(k) => stride + k,
        };
        let mut parents = vec![None; np + nodes.len()];
        for (k, (_, children)) in tree.iter().enumerate() {
            for &c in children {
                let at = match c {
                    Child::Part(i) => i,
                    Child::Node(j) => np + j,
                };
                parents[at] = Some(stride + k);
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
        let nn = nodes.len();
        let part_bounds: Vec<Bounds> = parts.iter().map(|p| p.meta.bounds).collect();
        let bounds_of = |c: Child| match c {
            Child::Part(i) => part_bounds[i],
            Child::Node(j) => covers[j],
        };
        let mut layers: Vec<LayerSummary> = Vec::new();
        for (n, (layer, _)) in nodes.iter().zip(&tree) {
            let l = *layer as usize;
            if layers.len() < l {
                layers.resize(l, LayerSummary::default());
            }
            layers[l - 1].add(n);
        }
        let totals = totals_of(&parts, nn);
        let page = Page {
            parts: parts.into_iter().zip(parents.iter().copied()).collect(),
            nodes: nodes
                .into_iter()
                .zip(tree)
                .enumerate()
                .map(|(k, (part, (layer, children)))| Node {
                    part,
                    layer,
                    child_bounds: children.iter().map(|c| bounds_of(*c)).collect(),
                    children: children.into_iter().map(id).collect(),
                    cover: covers[k],
                    parent: parents[np + k],
                })
                .collect(),
        };
        let root = (nn > 0).then(|| stride + nn - 1);
        Table::one_page(dir, page, stride, totals, layers, root)
    }

    /// A paged index: its first page loaded, the others when reached.
    pub(crate) fn paged(dir: &Path, mut root: IndexRoot, source: PageSource) -> Table {
        let first = std::mem::take(&mut root.first);
        let t = Table {
            stride: root.stride,
            pages: (0..root.pages).map(|_| OnceLock::new()).collect(),
            loading: (0..root.pages).map(|_| Mutex::new(())).collect(),
            source,
            totals: root.totals,
            layers: root.layers,
            root: root.root,
            dir: dir.to_path_buf(),
            fetched: Default::default(),
            fetched_bytes: Default::default(),
        };
        let page = t.page_of(first);
        let _ = t.pages[0].set(Box::new(page));
        t
    }

    /// Pages, loaded or not.
    pub(crate) fn page_count(&self) -> usize {
        self.pages.len()
    }

    /// Pages loaded now.
    pub(crate) fn pages_loaded(&self) -> usize {
        self.pages.iter().filter(|p| p.get().is_some()).count()
    }

    /// The parts of a page read from the index.
    fn page_of(&self, p: IndexPage) -> Page {
        let part = |e: FileEntry| -> Part {
            match &self.source {
                #[cfg(feature = "remote")]
                PageSource::Remote { remote, pinned, .. } => {
                    let file = match e.etag.filter(|t| *pinned && !t.is_empty()) {
                        Some(etag) => remote.file_pinned(&e.file, e.bytes, etag),
                        None => remote.file(&e.file),
                    };
                    Part::from_header_remote(
                        &self.dir,
                        std::sync::Arc::new(file),
                        (e.bytes, e.head),
                        e.header,
                    )
                }
                _ => {
                    let path = self.dir.join(&e.file);
                    Part::from_header(&self.dir, &path, (e.bytes, e.mtime), e.header)
                }
            }
        };
        Page {
            parts: p
                .parts
                .into_iter()
                .map(|PagePart { entry, parent }| (part(entry), parent))
                .collect(),
            nodes: p
                .nodes
                .into_iter()
                .map(|n: PageNode| Node {
                    part: part(n.entry),
                    layer: n.layer,
                    children: n.children,
                    child_bounds: n.bounds,
                    cover: n.cover,
                    parent: n.parent,
                })
                .collect(),
        }
    }

    /// Page `k`, loaded now if it was not.
    pub(crate) fn page(&self, k: usize) -> Result<&Page> {
        let slot = self
            .pages
            .get(k)
            .ok_or_else(|| StoreError::new(&self.dir, format!("index page {k} does not exist")))?;
        if let Some(p) = slot.get() {
            return Ok(p);
        }
        let _one = self.loading[k].lock().unwrap_or_else(|p| p.into_inner());
        if let Some(p) = slot.get() {
            return Ok(p);
        }
        let (text, name) = self.fetch(k)?;
        let file = self.dir.join(&name);
        let page = IndexPage::parse(&text, &file, &self.dir, self.pages.len(), self.stride)?;
        self.fetched
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.fetched_bytes
            .fetch_add(text.len() as u64, std::sync::atomic::Ordering::Relaxed);
        let _ = slot.set(Box::new(self.page_of(page)));
        Ok(slot.get().expect("just set"))
    }

    /// Loads the pages holding `ids` that are not loaded yet, several at once
    /// (a view refining a node needs its children's pages together: fetched
    /// one after the other, each would wait a request's latency). Failures
    /// are left for the reader of the entry to meet.
    pub(crate) fn prefetch(&self, ids: &[usize]) {
        let mut want: Vec<usize> = ids
            .iter()
            .filter_map(|&id| match locate(id, self.pages.len(), self.stride)? {
                Slot::Part(p, _) | Slot::Node(p, _) => Some(p),
            })
            .filter(|&p| self.pages[p].get().is_none())
            .collect();
        want.sort_unstable();
        want.dedup();
        if want.len() < 2 {
            return;
        }
        const THREADS: usize = 8;
        let per = want.len().div_ceil(THREADS);
        std::thread::scope(|s| {
            for chunk in want.chunks(per) {
                s.spawn(move || {
                    for &p in chunk {
                        let _ = self.page(p);
                    }
                });
            }
        });
    }

    /// Page `k`'s text and its file relative to the dataset.
    fn fetch(&self, k: usize) -> Result<(Vec<u8>, String)> {
        match &self.source {
            PageSource::Loaded => Err(StoreError::new(
                &self.dir,
                format!("index page {k} is not loaded and has no source"),
            )),
            PageSource::Local { dir, pages_dir } => {
                let name = page_file(pages_dir, k);
                let path = dir.join(&name);
                let text = std::fs::read(&path).map_err(|e| {
                    StoreError::new(&path, format!("cannot read the dataset's index page: {e}"))
                        .with_remedy(crate::error::Remedy::Reindex {
                            dataset: dir.clone(),
                        })
                })?;
                Ok((text, name))
            }
            #[cfg(feature = "remote")]
            PageSource::Remote {
                remote, pages_dir, ..
            } => {
                let name = page_file(pages_dir, k);
                match remote.get(&name).map_err(StoreError::remote)? {
                    Some((text, _, _)) => Ok((text.to_vec(), name)),
                    None => Err(StoreError::remote(crate::remote::RemoteError::new(
                        &remote.url_of(&name),
                        crate::remote::Problem::NotFound,
                    ))),
                }
            }
        }
    }

    /// The part or node `id` names.
    pub(crate) fn entry(&self, id: usize) -> Result<(&Part, Option<&Node>)> {
        let missing = || StoreError::new(&self.dir, format!("the index has no entry {id}"));
        match locate(id, self.pages.len(), self.stride).ok_or_else(missing)? {
            Slot::Part(p, s) => {
                let page = self.page(p)?;
                page.parts
                    .get(s)
                    .map(|(p, _)| (p, None))
                    .ok_or_else(missing)
            }
            Slot::Node(p, s) => {
                let page = self.page(p)?;
                page.nodes
                    .get(s)
                    .map(|n| (&n.part, Some(n)))
                    .ok_or_else(missing)
            }
        }
    }

    /// Whether `id` is a node's (without loading anything).
    pub(crate) fn is_node(&self, id: usize) -> bool {
        matches!(
            locate(id, self.pages.len(), self.stride),
            Some(Slot::Node(..))
        )
    }

    /// The parent of entry `id`.
    pub(crate) fn parent(&self, id: usize) -> Option<usize> {
        match locate(id, self.pages.len(), self.stride)? {
            Slot::Part(p, s) => self.page(p).ok()?.parts.get(s)?.1,
            Slot::Node(p, s) => self.page(p).ok()?.nodes.get(s)?.parent,
        }
    }

    /// Every part's id, loading every page.
    pub(crate) fn part_ids(&self) -> Result<Vec<usize>> {
        let mut out = Vec::with_capacity(self.totals.parts);
        for k in 0..self.pages.len() {
            let n = self.page(k)?.parts.len();
            out.extend((0..n).map(|s| k * self.stride + s));
        }
        Ok(out)
    }

    /// The ids of the parts in the pages loaded now.
    pub(crate) fn loaded_part_ids(&self) -> Vec<usize> {
        let mut out = Vec::new();
        for (k, p) in self.pages.iter().enumerate() {
            if let Some(p) = p.get() {
                out.extend((0..p.parts.len()).map(|s| k * self.stride + s));
            }
        }
        out
    }

    /// Every node's id, loading every page.
    pub(crate) fn node_ids(&self) -> Result<Vec<usize>> {
        let span = self.pages.len() * self.stride;
        let mut out = Vec::with_capacity(self.totals.nodes);
        for k in 0..self.pages.len() {
            let n = self.page(k)?.nodes.len();
            out.extend((0..n).map(|s| span + k * self.stride + s));
        }
        Ok(out)
    }
}

/// The totals of parts in memory.
fn totals_of(parts: &[Part], nodes: usize) -> Totals {
    Totals::of(
        parts
            .iter()
            .map(|p| (&p.meta, p.bands.as_slice(), p.levels.len(), p.file_bytes)),
        nodes,
    )
}
