//! The paged index (version 2, issue 44): a small root and pages of entries, each
//! page one piece of the overview's tree, so that opening a dataset of any number
//! of parts reads one file of at most a few hundred KB, and a viewer fetches the
//! pages of the subtrees its view reaches.
//!
//! [`paginate`] cuts the tree into pages breadth-first from the root: an upper
//! node goes alone, a node just above the parts goes with its parts (the unit a
//! view refining that node needs at once); a unit that does not fit the page
//! starts a page of its own. The first page ([`ROOT_PAGE_BYTES`]) lies inside the
//! root file; the others ([`PAGE_BYTES`]) in `pages-G/page-NNNNNN.json`, `G` the
//! overview's generation (`overview.rs`): a rebuild writes the other
//! generation's folder, and a reader holding the old root still finds its pages.
//!
//! JSON, as version 1 was (`bench/index.sh` prints what parsing every page
//! costs: `bench/RESULTS.md`).

use crate::dataset::LayerSummary;
use crate::dataset::index::{Child, FileEntry, NodeEntry, PAGE_BYTES, ROOT_PAGE_BYTES};
use crate::error::{Remedy, Result, StoreError};
use crate::points::Bounds;
use crate::read::part::{BandInfo, PartMeta};
use crate::write::part::full_note;
use std::collections::VecDeque;
use std::path::Path;

/// What the whole dataset holds, kept in the root: answered without a page.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Totals {
    pub parts: usize,
    pub nodes: usize,
    pub points: u64,
    /// Bytes of the parts' files.
    pub bytes: u64,
    pub bounds: Bounds,
    /// The most levels a part has.
    pub own_levels: usize,
    /// The first part's coordinate reference system.
    pub crs: Option<String>,
    /// Points per classification code over all parts, codes ascending.
    #[serde(default)]
    pub class_counts: Vec<(u8, u64)>,
    /// Every band name some part has, x y z first.
    #[serde(default)]
    pub bands: Vec<String>,
    /// Each band's smallest and largest value over the parts that have it
    /// (source units); `None` where one of them records no range.
    #[serde(default)]
    pub ranges: Vec<Option<(f64, f64)>>,
    /// Whether every part with a classification band records its class
    /// counts (then `class_counts` counts every point).
    #[serde(default)]
    pub classes_complete: bool,
    /// Each level's points over the parts, a part with fewer levels giving
    /// its coarsest to the deeper ones (as a read of that level does).
    #[serde(default)]
    pub level_points: Vec<u64>,
}

impl Totals {
    /// The bands a user picks from: every band some part has, less those that
    /// are parts of another's value (`pcimg_core::time::EXACT_BANDS`, read with
    /// `gps_time`).
    pub fn shown_bands(&self) -> impl Iterator<Item = &String> {
        self.bands
            .iter()
            .filter(|b| !pcimg_core::time::is_exact_band(b))
    }

    /// The totals of parts given by their metadata, bands, level count and
    /// file size.
    pub fn of<'a>(
        parts: impl Iterator<Item = (&'a PartMeta, &'a [BandInfo], usize, u64)>,
        nodes: usize,
    ) -> Totals {
        let mut t = TotalsSum::default();
        for (meta, bands, levels, bytes) in parts {
            t.add(meta, bands, levels, bytes);
        }
        t.finish(nodes)
    }

    /// The totals of index entries.
    pub fn of_entries<'a>(parts: impl Iterator<Item = &'a FileEntry>, nodes: usize) -> Totals {
        let mut t = TotalsSum::default();
        parts.for_each(|e| t.add_entry(e));
        t.finish(nodes)
    }
}

/// [`Totals`] summed one part at a time, holding nothing per part: the index
/// of a hundred thousand parts is built without keeping their entries.
#[derive(Debug, Clone)]
pub struct TotalsSum {
    t: Totals,
    counts: Vec<u64>,
    /// Points of each level over the parts that have it (`levels[l]`), and the
    /// coarsest level's points of the parts with `L` levels (`beyond[L]`),
    /// which count at every level from `L` on.
    levels: Vec<u64>,
    beyond: Vec<u64>,
}

impl Default for TotalsSum {
    fn default() -> Self {
        TotalsSum {
            t: Totals {
                parts: 0,
                nodes: 0,
                points: 0,
                bytes: 0,
                bounds: Bounds::EMPTY,
                own_levels: 1,
                crs: None,
                class_counts: Vec::new(),
                bands: Vec::new(),
                ranges: Vec::new(),
                classes_complete: true,
                level_points: Vec::new(),
            },
            counts: vec![0; 256],
            levels: Vec::new(),
            beyond: Vec::new(),
        }
    }
}

impl TotalsSum {
    pub fn add_entry(&mut self, e: &FileEntry) {
        let h = &e.header;
        self.add(&h.meta, &h.bands, h.levels.len(), e.bytes);
    }

    pub fn add(&mut self, meta: &PartMeta, bands: &[BandInfo], levels: usize, bytes: u64) {
        let t = &mut self.t;
        if meta.class_counts.is_empty() && bands.iter().any(|b| b.name == "classification") {
            t.classes_complete = false;
        }
        t.parts += 1;
        t.points += meta.point_count;
        t.bytes += bytes;
        t.bounds = t.bounds.union(&meta.bounds);
        t.own_levels = t.own_levels.max(levels);
        if t.crs.is_none() {
            t.crs = meta.crs.clone();
        }
        for &(c, n) in &meta.class_counts {
            self.counts[c as usize] += n;
        }
        for b in bands {
            match t.bands.iter().position(|n| *n == b.name) {
                None => {
                    t.bands.push(b.name.clone());
                    t.ranges.push(b.range);
                }
                Some(i) => {
                    t.ranges[i] = match (t.ranges[i], b.range) {
                        (Some((a, b)), Some((c, d))) => Some((a.min(c), b.max(d))),
                        _ => None,
                    }
                }
            }
        }
        let lp = &meta.level_points;
        if let Some(&last) = lp.last() {
            if self.levels.len() < lp.len() {
                self.levels.resize(lp.len(), 0);
            }
            if self.beyond.len() <= lp.len() {
                self.beyond.resize(lp.len() + 1, 0);
            }
            for (l, &n) in lp.iter().enumerate() {
                self.levels[l] += n;
            }
            self.beyond[lp.len()] += last;
        }
    }

    /// The totals, with `nodes` overview nodes.
    pub fn finish(self, nodes: usize) -> Totals {
        let mut t = self.t;
        t.nodes = nodes;
        // (A part with fewer levels gives its coarsest to the deeper ones.)
        let mut carried = 0;
        t.level_points = (0..t.own_levels)
            .map(|l| {
                carried += self.beyond.get(l).copied().unwrap_or(0);
                self.levels.get(l).copied().unwrap_or(0) + carried
            })
            .collect();
        t.class_counts = (0..=255u8)
            .filter(|&c| self.counts[c as usize] > 0)
            .map(|c| (c, self.counts[c as usize]))
            .collect();
        t
    }
}

/// A part's entry in a page: its file and header, and the node above it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PagePart {
    pub entry: FileEntry,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<usize>,
}

/// An overview node's entry in a page.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PageNode {
    pub entry: FileEntry,
    /// 1 just above the parts.
    pub layer: u32,
    /// Ids of its children (parts or nodes).
    pub children: Vec<usize>,
    /// Each child's bounds (a part's, a node's cover): a view culls a child
    /// without reading the page that holds it.
    pub bounds: Vec<Bounds>,
    /// The union of its children's bounds.
    pub cover: Bounds,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<usize>,
}

/// One page: entries of parts and of nodes, in slot order.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct IndexPage {
    pub parts: Vec<PagePart>,
    pub nodes: Vec<PageNode>,
}

/// The root of a paged index: `pcimg-index.json`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct IndexRoot {
    pub format: String,
    pub version: u32,
    pub totals: Totals,
    /// Each overview layer's summary, layer 1 first.
    pub layers: Vec<LayerSummary>,
    /// Pages, the first included.
    pub pages: usize,
    /// Slots a page may hold of each kind: ids are `page * stride + slot`.
    pub stride: usize,
    /// The folder of the other pages, relative to the dataset.
    pub pages_dir: String,
    /// The root node's id, when there is an overview.
    pub root: Option<usize>,
    /// Page 0.
    pub first: IndexPage,
    /// The hash of the parts' file names, sorted
    /// ([`super::index::names_hash`]): a local dataset's listing is compared
    /// with it on opening, every page read only when they differ.
    #[serde(default)]
    pub listing: Option<u64>,
    /// As version 1's: the URL the entries' ETags were recorded for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uploaded_to: Option<String>,
}

/// Where entry ids point: a part or a node, its page and slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    Part(usize, usize),
    Node(usize, usize),
}

/// Decodes id `id` in an index of `pages` pages of `stride` slots.
pub fn locate(id: usize, pages: usize, stride: usize) -> Option<Slot> {
    let span = pages.checked_mul(stride)?;
    if stride == 0 {
        return None;
    }
    if id < span {
        Some(Slot::Part(id / stride, id % stride))
    } else if id - span < span {
        let k = id - span;
        Some(Slot::Node(k / stride, k % stride))
    } else {
        None
    }
}

/// A page's file, relative to the dataset.
pub fn page_file(pages_dir: &str, page: usize) -> String {
    format!("{pages_dir}/page-{page:06}.json")
}

/// What cutting the tree into pages needs of a part: its file, bounds and the
/// length of its entry's JSON (the entry itself waits elsewhere: `pcimg index`
/// keeps a hundred thousand of them in a file, not in memory).
#[derive(Debug, Clone)]
pub struct PartBrief {
    pub file: String,
    pub bounds: Bounds,
    pub json_len: usize,
}

/// One page as [`paginate`] planned it: its parts (their number among the
/// briefs, and their parent's id) and its nodes' entries, in slot order.
#[derive(Debug, Default)]
pub struct PagePlan {
    pub parts: Vec<(usize, Option<usize>)>,
    pub nodes: Vec<PageNode>,
}

impl PagePlan {
    /// The page, each part's entry given by `entry`.
    pub fn page(self, entry: &mut dyn FnMut(usize) -> Result<FileEntry>) -> Result<IndexPage> {
        let parts = self
            .parts
            .into_iter()
            .map(|(i, parent)| {
                Ok(PagePart {
                    entry: entry(i)?,
                    parent,
                })
            })
            .collect::<Result<_>>()?;
        Ok(IndexPage {
            parts,
            nodes: self.nodes,
        })
    }
}

/// Cuts the tree of `parts` and `nodes` (version 1's lists: nodes after their
/// children, the root last) into pages; returns the root (its first page
/// still empty) and every page's plan, the first included.
pub fn paginate(
    parts: &[PartBrief],
    nodes: Vec<NodeEntry>,
    layers: Vec<LayerSummary>,
    totals: Totals,
    pages_dir: &str,
) -> Result<(IndexRoot, Vec<PagePlan>)> {
    let mut names: Vec<&str> = parts.iter().map(|e| e.file.as_str()).collect();
    names.sort_unstable();
    let listing = Some(super::index::names_hash(names.into_iter()));
    let size = |e: &FileEntry| serde_json::to_vec(e).map_or(0, |v| v.len()) + 40;
    // Which page and slot each entry gets.
    let mut part_at: Vec<(usize, usize)> = vec![(usize::MAX, 0); parts.len()];
    let mut node_at: Vec<(usize, usize)> = vec![(usize::MAX, 0); nodes.len()];
    let mut counts: Vec<(usize, usize)> = Vec::new();
    if nodes.is_empty() {
        // No overview (one part, or parts that cannot share one): a view starts
        // from every part, so every part is in the first page.
        counts.push((parts.len(), 0));
        for (i, a) in part_at.iter_mut().enumerate() {
            *a = (0, i);
        }
    } else {
        let mut roots = VecDeque::from([nodes.len() - 1]);
        while let Some(top) = roots.pop_front() {
            let page = counts.len();
            let limit = if page == 0 {
                ROOT_PAGE_BYTES
            } else {
                PAGE_BYTES
            };
            let (mut np, mut nn, mut bytes) = (0usize, 0usize, 0usize);
            let mut queue = VecDeque::from([top]);
            while let Some(k) = queue.pop_front() {
                let n = &nodes[k];
                let kids_parts: Vec<usize> = n
                    .children
                    .iter()
                    .filter_map(|c| match *c {
                        Child::Part(i) => Some(i),
                        Child::Node(_) => None,
                    })
                    .collect();
                // (A child's id and bounds take about 120 bytes.)
                let unit = size(&n.entry)
                    + 120 * n.children.len()
                    + kids_parts
                        .iter()
                        .map(|&i| parts[i].json_len + 40)
                        .sum::<usize>();
                if np + nn > 0 && bytes + unit > limit {
                    roots.push_back(k);
                    continue;
                }
                bytes += unit;
                node_at[k] = (page, nn);
                nn += 1;
                for i in kids_parts {
                    part_at[i] = (page, np);
                    np += 1;
                }
                for c in &n.children {
                    if let Child::Node(j) = *c {
                        queue.push_back(j);
                    }
                }
            }
            counts.push((np, nn));
        }
    }
    let pages = counts.len();
    let stride = counts
        .iter()
        .map(|&(a, b)| a.max(b))
        .max()
        .unwrap_or(0)
        .max(1);
    let span = pages * stride;
    let part_id = |i: usize| part_at[i].0 * stride + part_at[i].1;
    let node_id = |k: usize| span + node_at[k].0 * stride + node_at[k].1;
    if let Some(i) = part_at.iter().position(|a| a.0 == usize::MAX) {
        return Err(StoreError::new(
            Path::new(&parts[i].file),
            "is under no overview node (the overview does not reach every part)",
        ));
    }
    let mut parent = vec![None; parts.len() + nodes.len()];
    for (k, n) in nodes.iter().enumerate() {
        for c in &n.children {
            let at = match *c {
                Child::Part(i) => i,
                Child::Node(j) => parts.len() + j,
            };
            parent[at] = Some(node_id(k));
        }
    }
    // Covers, children before parents.
    let mut covers: Vec<Bounds> = Vec::with_capacity(nodes.len());
    for n in &nodes {
        let b = n.children.iter().fold(Bounds::EMPTY, |b, c| match *c {
            Child::Part(i) => b.union(&parts[i].bounds),
            Child::Node(j) => b.union(&covers[j]),
        });
        covers.push(b);
    }
    let mut out: Vec<PagePlan> = counts
        .iter()
        .map(|&(a, b)| PagePlan {
            parts: Vec::with_capacity(a),
            nodes: Vec::with_capacity(b),
        })
        .collect();
    // Entries in slot order: slots were handed out in increasing order per page.
    let mut by_slot: Vec<(usize, usize, usize)> = (0..parts.len())
        .map(|i| (part_at[i].0, part_at[i].1, i))
        .collect();
    by_slot.sort_unstable();
    for (page, _, i) in by_slot {
        out[page].parts.push((i, parent[i]));
    }
    let np = parts.len();
    let mut by_slot: Vec<(usize, usize, usize)> = (0..nodes.len())
        .map(|k| (node_at[k].0, node_at[k].1, k))
        .collect();
    by_slot.sort_unstable();
    let children: Vec<Vec<usize>> = nodes
        .iter()
        .map(|n| {
            n.children
                .iter()
                .map(|c| match *c {
                    Child::Part(i) => part_id(i),
                    Child::Node(j) => node_id(j),
                })
                .collect()
        })
        .collect();
    let mut nodes: Vec<Option<NodeEntry>> = nodes.into_iter().map(Some).collect();
    for (page, _, k) in by_slot {
        let n = nodes[k].take().expect("each node once");
        out[page].nodes.push(PageNode {
            entry: n.entry,
            layer: n.layer,
            children: children[k].clone(),
            bounds: n
                .children
                .iter()
                .map(|c| match *c {
                    Child::Part(i) => parts[i].bounds,
                    Child::Node(j) => covers[j],
                })
                .collect(),
            cover: covers[k],
            parent: parent[np + k],
        });
    }
    let root = IndexRoot {
        format: super::index::FORMAT_NAME.into(),
        version: super::index::INDEX_VERSION,
        totals,
        layers,
        pages,
        stride,
        pages_dir: pages_dir.to_string(),
        root: (!node_at.is_empty()).then(|| node_id(node_at.len() - 1)),
        first: IndexPage::default(),
        listing,
        uploaded_to: None,
    };
    Ok((root, out))
}

impl IndexPage {
    /// A page's text, checked: every entry names a file inside the dataset and
    /// has levels and bands, every id it holds is one the index can have.
    pub fn parse(
        text: &[u8],
        file: &Path,
        dir: &Path,
        pages: usize,
        stride: usize,
    ) -> Result<IndexPage> {
        let page: IndexPage = serde_json::from_slice(text).map_err(|e| {
            StoreError::new(
                file,
                format!(
                    "not a valid index page (line {}, column {}: {e})",
                    e.line(),
                    e.column()
                ),
            )
            .with_remedy(Remedy::Reindex {
                dataset: dir.to_path_buf(),
            })
        })?;
        page.check(file, dir, pages, stride)?;
        Ok(page)
    }

    pub(crate) fn check(&self, file: &Path, dir: &Path, pages: usize, stride: usize) -> Result<()> {
        let bad = |m: String| {
            StoreError::new(file, m).with_remedy(Remedy::Reindex {
                dataset: dir.to_path_buf(),
            })
        };
        if self.parts.len() > stride || self.nodes.len() > stride {
            return Err(bad(format!(
                "holds more entries than the index's stride ({stride})"
            )));
        }
        let entries = self
            .parts
            .iter()
            .map(|p| &p.entry)
            .chain(self.nodes.iter().map(|n| &n.entry));
        for e in entries {
            super::index::check_entry(e).map_err(bad)?;
        }
        let id_ok = |id: usize| locate(id, pages, stride).is_some();
        let node_ok = |id: usize| matches!(locate(id, pages, stride), Some(Slot::Node(..)));
        for p in &self.parts {
            if p.parent.is_some_and(|id| !node_ok(id)) {
                return Err(bad(format!(
                    "'{}' names a parent that cannot exist",
                    p.entry.file
                )));
            }
        }
        for n in &self.nodes {
            if n.children.is_empty()
                || n.children.len() != n.bounds.len()
                || n.children.iter().any(|&c| !id_ok(c))
                || n.parent.is_some_and(|id| !node_ok(id))
            {
                return Err(bad(format!(
                    "node '{}' names a child or parent that cannot exist",
                    crate::text::sanitize(&n.entry.file)
                )));
            }
        }
        Ok(())
    }
}

impl IndexRoot {
    /// Writes the pages into `dir/pages_dir` (a temporary folder renamed into
    /// place, replacing one of that name), then the root, atomically: a
    /// reader finds either the old root or the new one with all its pages.
    pub fn save(&self, dir: &Path, pages: &[IndexPage]) -> Result<u64> {
        self.save_with(dir, pages.len(), &mut |k| Ok(pages[k].clone()))
    }

    /// [`IndexRoot::save`] with the pages after the first made one at a time by
    /// `page(k)` (`k` from 0: the root's page 1): one page in memory at once.
    pub fn save_with(
        &self,
        dir: &Path,
        count: usize,
        page: &mut dyn FnMut(usize) -> Result<IndexPage>,
    ) -> Result<u64> {
        let folder = dir.join(&self.pages_dir);
        if count > 0 {
            let tmp = dir.join(format!(".{}-tmp-{}", self.pages_dir, std::process::id()));
            let _ = std::fs::remove_dir_all(&tmp);
            let written = (|| -> Result<()> {
                std::fs::create_dir(&tmp).map_err(|e| {
                    StoreError::new(&tmp, format!("cannot create: {}", full_note(e, &tmp, None)))
                })?;
                for k in 0..count {
                    let path = tmp.join(format!("page-{:06}.json", k + 1));
                    let text = serde_json::to_vec(&page(k)?)
                        .map_err(|e| StoreError::new(&path, format!("cannot encode: {e}")))?;
                    std::fs::write(&path, &text).map_err(|e| {
                        let n = Some(text.len() as u64);
                        StoreError::new(&path, format!("cannot write: {}", full_note(e, &path, n)))
                    })?;
                }
                let _ = std::fs::remove_dir_all(&folder);
                std::fs::rename(&tmp, &folder)
                    .map_err(|e| StoreError::new(&folder, format!("cannot rename into place: {e}")))
            })();
            if let Err(e) = written {
                let _ = std::fs::remove_dir_all(&tmp);
                return Err(e);
            }
        }
        let path = dir.join(super::index::INDEX_FILE);
        let text = serde_json::to_vec(self)
            .map_err(|e| StoreError::new(&path, format!("cannot encode: {e}")))?;
        super::index::write_atomic(&path, &text)?;
        Ok(text.len() as u64)
    }

    /// The pages after the first, read from `dir`.
    pub fn read_pages(&self, dir: &Path) -> Result<Vec<IndexPage>> {
        (1..self.pages)
            .map(|k| {
                let name = page_file(&self.pages_dir, k);
                let path = dir.join(&name);
                let text = std::fs::read(&path)
                    .map_err(|e| StoreError::new(&path, format!("cannot read: {e}")))?;
                IndexPage::parse(&text, &path, dir, self.pages, self.stride)
            })
            .collect()
    }
}

/// Each overview layer's summary from the nodes' entries, layer 1 first.
pub fn layer_summaries(nodes: &[NodeEntry]) -> Vec<LayerSummary> {
    let mut layers: Vec<LayerSummary> = Vec::new();
    for n in nodes {
        let l = n.layer.max(1) as usize;
        if layers.len() < l {
            layers.resize(l, LayerSummary::default());
        }
        let h = &n.entry.header;
        layers[l - 1].add_node(&h.levels, h.meta.point_count, n.entry.bytes);
    }
    layers
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(level_points: &[u64]) -> PartMeta {
        PartMeta {
            format_version: 2,
            point_count: level_points[0],
            origin: [0.0; 3],
            bounds: Bounds::EMPTY,
            level_points: level_points.to_vec(),
            layout: String::new(),
            source: None,
            crs: None,
            max_quantization_error: None,
            codec_max_error: None,
            class_counts: vec![(2, level_points[0])],
            from_source: Vec::new(),
            lattice: None,
            lattice_rounded: false,
            items: Default::default(),
        }
    }

    /// A part with fewer levels gives its coarsest to the deeper ones, summed
    /// one part at a time as over the whole list.
    #[test]
    fn totals_summed_part_by_part_carry_short_pyramids_down() {
        let parts = [meta(&[1000, 250, 63]), meta(&[40]), meta(&[400, 100])];
        let t = Totals::of(
            parts.iter().map(|m| (m, &[][..], m.level_points.len(), 7)),
            2,
        );
        assert_eq!(t.level_points, vec![1440, 390, 203]);
        assert_eq!((t.parts, t.points, t.bytes, t.nodes), (3, 1440, 21, 2));
        assert_eq!(t.own_levels, 3);
        assert_eq!(t.class_counts, vec![(2, 1440)]);
    }
}
