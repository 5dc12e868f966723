//! Building a dataset directory's index and overview (`pcimg index`, and `convert`
//! last): overview nodes above the parts, each an ordinary part of one tile made
//! from its children's coarsest levels only (no pass over the points): the level
//! one coarser that each child's pyramid would have made, joined. A node's
//! children are a compact group of the layer below (a k-d split of their
//! centres); layer after layer up to one root; then the index, written last.

use crate::dataset::index::{
    Child, FileEntry, INDEX_FILE, NodeEntry, OVERVIEW_DIR, PAGES_DIR, entry_of, indexed_files,
};
use crate::dataset::list_parts;
use crate::dataset::paged::{PartBrief, TotalsSum, layer_summaries, paginate};
use crate::error::{Result, StoreError};
use crate::points::{Attribute, Lattice, PointColumns};
use crate::read::part::Part;
use crate::spec::TILE_PIXELS;
use crate::tiff::codec::Compression;
use crate::write::part::{WriteOptions, full_note, write_part};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

/// A node's children's coarsest levels hold at most this many points: four tiles.
/// The node keeps a quarter of them (one tile), so that it refines into four
/// times its points, as a level of a part's own pyramid does.
pub const GROUP_POINTS: u64 = 4 * TILE_PIXELS as u64;

/// The most children a node has: many small parts would otherwise make one
/// node of hundreds (a view refining it then loads them all at once), and its
/// index entries one page of megabytes (`paged.rs`: a node's parts share its
/// page).
pub const MAX_CHILDREN: usize = 64;

/// What building the index did.
#[derive(Debug, Clone, Default)]
pub struct IndexReport {
    pub parts: usize,
    pub points: u64,
    pub nodes: usize,
    pub layers: u32,
    /// Points stored in the overview nodes (all levels).
    pub node_points: u64,
    pub node_bytes: u64,
    /// Bytes of the index's root file.
    pub index_bytes: u64,
    /// Pages of the index, the root's included.
    pub index_pages: usize,
    pub seconds: f64,
    /// Why there is no overview, when there is none.
    pub no_overview: Option<String>,
    /// What a killed run had left in the directory, removed first
    /// ([`remove_leftovers`]).
    pub leftovers: Vec<PathBuf>,
}

/// One member of a layer: a part or a node, with what grouping and writing
/// its node need (its file is opened only to read its coarsest level).
struct Member<'a> {
    child: Child,
    brief: &'a Brief,
    center: [f64; 3],
}

/// What building the overview needs of a part or node, kept for every part
/// while the index is built (a part's whole entry waits in the [`Spill`]).
#[derive(Debug, Clone)]
struct Brief {
    /// Its coarsest level's points.
    top_points: u64,
    /// Its lattice and CRS: numbers in the build's lists of distinct ones
    /// ([`Shared`]).
    lattice: Option<u32>,
    crs: Option<u32>,
    /// Where its entry's JSON lies in the spill file, and its length.
    at: u64,
    json_len: usize,
}

/// The lattices and CRSs of the parts, each once: a hundred thousand parts
/// of one survey share one of each, and parts of separate tiles (each its own
/// LAS offset) as many lattices as tiles, found by hash either way.
#[derive(Debug, Clone, Default)]
struct Shared {
    crss: Vec<String>,
    lattices: Vec<Lattice>,
    crs_at: std::collections::HashMap<String, u32>,
    /// A lattice's number by the bits of its steps and origin.
    lattice_at: std::collections::HashMap<[u64; 6], u32>,
}

impl Shared {
    fn crs(&mut self, c: &str) -> u32 {
        if let Some(&i) = self.crs_at.get(c) {
            return i;
        }
        self.crss.push(c.to_string());
        let i = self.crss.len() as u32 - 1;
        self.crs_at.insert(c.to_string(), i);
        i
    }

    fn lattice(&mut self, l: Lattice) -> u32 {
        let (s, o) = (l.step.map(f64::to_bits), l.origin.map(f64::to_bits));
        let key = [s[0], s[1], s[2], o[0], o[1], o[2]];
        *self.lattice_at.entry(key).or_insert_with(|| {
            self.lattices.push(l);
            self.lattices.len() as u32 - 1
        })
    }
}

/// The points of `e`'s coarsest level.
fn top_points(e: &FileEntry) -> u64 {
    e.header.levels.last().and_then(|l| l.points).unwrap_or(0)
}

impl Brief {
    /// The brief of entry `e` (and what the pages need of it), its JSON
    /// `json_len` bytes at `at` in the spill.
    fn of(e: &FileEntry, json_len: usize, at: u64, shared: &mut Shared) -> (Brief, PartBrief) {
        let m = &e.header.meta;
        let brief = Brief {
            top_points: top_points(e),
            lattice: m.lattice.map(|l| shared.lattice(l)),
            crs: m.crs.as_deref().map(|c| shared.crs(c)),
            at,
            json_len,
        };
        let page = PartBrief {
            file: e.file.clone(),
            bounds: m.bounds,
            json_len,
        };
        (brief, page)
    }
}

/// The parts' entries while the index is built, as JSON in a file beside them
/// (`.pcimg-index-entries-tmp-PID`, removed when done or by the next run): a
/// hundred thousand entries take 200 MB, which `pcimg index` would otherwise
/// hold until the pages are written. Each is read back once, by its page.
struct Spill {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    len: u64,
}

/// The spill file's name before the process id ([`remove_leftovers`]).
const SPILL_TAG: &str = ".pcimg-index-entries-tmp-";

impl Spill {
    fn create(dir: &Path) -> Result<Spill> {
        let path = dir.join(format!("{SPILL_TAG}{}", std::process::id()));
        let file = std::fs::File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(|e| {
                StoreError::new(
                    &path,
                    format!("cannot create: {}", full_note(e, &path, None)),
                )
            })?;
        Ok(Spill {
            path,
            out: std::io::BufWriter::with_capacity(1 << 20, file),
            len: 0,
        })
    }

    /// Appends `json`; returns where it starts.
    fn push(&mut self, json: &[u8]) -> Result<u64> {
        use std::io::Write;
        let at = self.len;
        self.out.write_all(json).map_err(|e| {
            StoreError::new(
                &self.path,
                format!("cannot write: {}", full_note(e, &self.path, None)),
            )
        })?;
        self.len += json.len() as u64;
        Ok(at)
    }

    /// The entry of `b`.
    fn entry(&mut self, b: &Brief) -> Result<FileEntry> {
        use std::io::{Read, Seek, SeekFrom, Write};
        let bad = |e: String| StoreError::new(&self.path, e);
        self.out
            .flush()
            .map_err(|e| bad(format!("cannot write: {e}")))?;
        let mut text = vec![0; b.json_len];
        let f = self.out.get_mut();
        f.seek(SeekFrom::Start(b.at))
            .and_then(|_| f.read_exact(&mut text))
            .map_err(|e| bad(format!("cannot read back: {e}")))?;
        serde_json::from_slice(&text).map_err(|e| bad(format!("cannot read back: {e}")))
    }
}

impl Drop for Spill {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Parts whose entries are made at once (in parallel) before they go to the
/// spill file.
const ENTRY_BATCH: usize = 256;

/// Groups a layer's members into compact runs whose coarsest levels hold at most
/// [`GROUP_POINTS`] (so a node, a quarter of that, fits one tile), of at most
/// [`MAX_CHILDREN`] members: the members are
/// split in two at the median of their points along the longer side of their
/// centres' box (a k-d split), again and again, never into fewer than two.
fn group(members: &mut [Member]) -> Vec<std::ops::Range<usize>> {
    group_compact(members, GROUP_POINTS, &|m| m.center, &|m| {
        m.brief.top_points
    })
}

/// Orders `m` and cuts it into runs of members near each other, each holding
/// at most `limit` points (`points`) and [`MAX_CHILDREN`] members: split in
/// two at the median of their points along the longer side of their centres'
/// (`center`) box, again and again, never into fewer than two. The overview's
/// grouping, and a COPC survey's (`pcimg index` over COPC files).
pub fn group_compact<T>(
    m: &mut [T],
    limit: u64,
    center: &dyn Fn(&T) -> [f64; 3],
    points: &dyn Fn(&T) -> u64,
) -> Vec<std::ops::Range<usize>> {
    let mut runs = Vec::new();
    split(m, 0, limit, center, points, &mut runs);
    runs
}

fn split<T>(
    m: &mut [T],
    at: usize,
    limit: u64,
    center: &dyn Fn(&T) -> [f64; 3],
    points: &dyn Fn(&T) -> u64,
    runs: &mut Vec<std::ops::Range<usize>>,
) {
    let sum: u64 = m.iter().map(points).sum();
    if (sum <= limit && m.len() <= MAX_CHILDREN) || m.len() < 4 {
        runs.push(at..at + m.len());
        return;
    }
    let extent = |a: usize| {
        let (lo, hi) = m
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(center(x)[a]), hi.max(center(x)[a]))
            });
        hi - lo
    };
    let axis = if extent(0) >= extent(1) { 0 } else { 1 };
    m.sort_by(|a, b| center(a)[axis].total_cmp(&center(b)[axis]));
    let mut half = 0;
    let mut mid = m.len() / 2;
    for (i, x) in m.iter().enumerate() {
        half += points(x);
        if 2 * half >= sum {
            mid = i + 1;
            break;
        }
    }
    let mid = mid.clamp(2, m.len() - 2);
    let (left, right) = m.split_at_mut(mid);
    split(left, at, limit, center, points, runs);
    split(right, at + mid, limit, center, points, runs);
}

/// The level one coarser than a part's coarsest, as its pyramid would make it:
/// every fourth point of the coarsest level in its Z order (the first of each 2×2
/// block, which the layout made the block's representative), every band, as
/// columns in source units, less the whole numbers that make GPS time exact
/// (a node is for viewing; exports read the parts). (An overview node's
/// points for the layer above: here, and in a survey of COPC files.)
pub fn next_coarser(part: &Part) -> Result<PointColumns> {
    let top = part.levels.len() - 1;
    let bands: Vec<usize> = (0..part.bands.len())
        .filter(|&b| !pcimg_core::time::is_exact_band(&part.bands[b].name))
        .collect();
    let p = part.read_level(top, &bands)?;
    let quarter = |c: Vec<f32>| -> Vec<f32> { c.into_iter().step_by(4).collect() };
    let mut cols = p.columns.into_iter().map(quarter);
    // On a lattice, each coordinate is the lattice point it was stored as (as
    // `query::Batch` gives it), so the node can keep the lattice too: the f32
    // offset plus the part's origin is only within f32's rounding of it.
    let lattice = part.meta.lattice;
    let mut coord = |a: usize| -> Vec<f64> {
        let o = p.offsets[a];
        let snap = |v: f64| lattice.map_or(v, |l| l.nearest(a, v));
        cols.next()
            .unwrap_or_default()
            .into_iter()
            .map(|v| snap(v as f64 + o))
            .collect()
    };
    let (x, y, z) = (coord(0), coord(1), coord(2));
    let attributes = p.bands[3..]
        .iter()
        .zip(&p.offsets[3..])
        .zip(cols)
        .map(|((name, &offset), values)| Attribute {
            name: name.clone(),
            offset,
            values,
        })
        .collect();
    Ok(PointColumns {
        x,
        y,
        z,
        attributes,
    })
}

/// Appends `b` to `a`, bringing `b`'s attributes to `a`'s offsets.
pub fn append(a: &mut PointColumns, b: PointColumns) {
    if a.x.is_empty() && a.attributes.is_empty() {
        *a = b;
        return;
    }
    a.x.extend(b.x);
    a.y.extend(b.y);
    a.z.extend(b.z);
    for (ta, tb) in a.attributes.iter_mut().zip(b.attributes) {
        let shift = (tb.offset - ta.offset) as f32;
        ta.values.extend(tb.values.into_iter().map(|v| v + shift));
    }
}

/// A node's file name: its layer and its number in the layer; a rebuilt
/// overview whose predecessor is still in use takes the other generation's
/// names (`node-g1-…`), so that both lie side by side until the new index
/// replaces the old.
fn node_name(generation: u32, layer: u32, k: usize) -> String {
    match generation {
        0 => format!("node-{layer}-{k:05}.tif"),
        g => format!("node-g{g}-{layer}-{k:05}.tif"),
    }
}

/// The generation of a node file's name (see [`node_name`]), `None` for a name
/// that is not a node's.
fn node_generation(name: &str) -> Option<u32> {
    let rest = name.strip_prefix("node-")?.strip_suffix(".tif")?;
    let (g, rest) = match rest.strip_prefix('g') {
        Some(r) => {
            let (g, r) = r.split_once('-')?;
            (g.parse().ok()?, r)
        }
        None => (0, rest),
    };
    let (layer, k) = rest.split_once('-')?;
    (layer.parse::<u32>().is_ok() && k.parse::<usize>().is_ok()).then_some(g)
}

/// Why the part at `file` cannot share an overview with the first (`first`:
/// its band names and file), if it cannot.
fn incompatible(e: &FileEntry, file: &Path, first: &(Vec<String>, PathBuf)) -> Option<String> {
    let same = e.header.bands.len() == first.0.len()
        && e.header
            .bands
            .iter()
            .zip(&first.0)
            .all(|(b, n)| b.name == *n);
    (!same).then(|| {
        format!(
            "{} has other bands than {}",
            file.display(),
            first.1.display()
        )
    })
}

/// Options of [`build_index`].
#[derive(Debug, Clone, Default)]
pub struct IndexOptions {
    /// Compression of the overview nodes (`None`: as the first part's level 0).
    pub compression: Option<Compression>,
    pub cancel: Option<Arc<AtomicBool>>,
    /// The memory budget in bytes (`None`: no limit but the threads'): what
    /// the parts' briefs leave of it decides how many nodes are built at once
    /// ([`index_memory`]).
    pub memory: Option<u64>,
    /// Whether a budget too small for the parts' count is an error (`pcimg
    /// index`) rather than building one node at a time over it (a
    /// conversion's index, which must not throw its parts away).
    pub refuse_over_memory: bool,
}

/// What building the index holds for each part until its pages are written:
/// its brief, its place in the tree and in the pages (measured: 0.38 KiB a
/// part between 10,000 and 100,000 parts); its entry waits in a file.
pub const INDEX_PART_BYTES: u64 = 512;

/// What building one overview node holds, per point it keeps and band: its
/// children's coarsest levels read one at a time, its points, and what
/// writing them takes (measured: 24 MiB for nodes of 65,536 points of 12
/// bands, one thread).
pub const INDEX_NODE_BYTES_PER_VALUE: u64 = 32;

/// Memory for indexing `parts` parts of `bands` bands whose coarsest levels
/// hold `tops` points: the least it needs (one node at a time), and the nodes
/// a `budget` lets it build at once (at most `threads`); `Err(least)` when
/// the budget is below the least. (The program's own few MiB are not counted,
/// as a conversion's budget does not count them.)
pub fn index_memory(
    parts: usize,
    bands: usize,
    tops: u64,
    budget: Option<u64>,
    threads: usize,
) -> std::result::Result<usize, u64> {
    // (A node keeps a quarter of its children's coarsest levels, which hold
    // at most GROUP_POINTS: fewer when the parts' together hold fewer.)
    let node = tops.min(GROUP_POINTS).div_ceil(4) * bands as u64 * INDEX_NODE_BYTES_PER_VALUE;
    let least = parts as u64 * INDEX_PART_BYTES + node;
    match budget {
        None => Ok(threads.max(1)),
        Some(b) if b < least => Err(least),
        Some(b) => Ok((1 + ((b - least) / node.max(1)) as usize).clamp(1, threads.max(1))),
    }
}

/// The error of a budget below the `needed` bytes of indexing `parts` parts.
fn over_memory(dir: &Path, parts: usize, needed: u64, o: &IndexOptions) -> StoreError {
    StoreError::new(
        dir,
        format!(
            "indexing {} parts needs about {} of memory, more than the budget of {}",
            pcimg_core::text::count(parts as u64),
            pcimg_core::text::bytes(needed),
            pcimg_core::text::bytes(o.memory.unwrap_or(0))
        ),
    )
    .with_remedy(crate::error::Remedy::MoreMemory { needed })
}

/// Builds the overview of the parts in `dir` and writes its index, replacing any
/// earlier overview and index. `progress(done)` counts nodes written.
pub fn build_index(
    dir: &Path,
    o: &IndexOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<IndexReport> {
    let t0 = Instant::now();
    let leftovers = remove_leftovers(dir);
    let files = list_parts(dir)?;
    // (The parts' briefs alone, checked before any is read.)
    if let (Err(needed), true) = (
        index_memory(files.len(), 0, 0, o.memory, 1),
        o.refuse_over_memory,
    ) {
        return Err(over_memory(dir, files.len(), needed, o));
    }
    // Each part's entry, the part closed again (a hundred thousand parts held
    // open would pass the kernel's limit on memory maps, 65,530 by default),
    // a batch at a time; the entries go to the spill file, and what the
    // overview and the pages need stays here.
    let name = |f: &Path| f.file_name().map(|n| n.to_string_lossy().into_owned());
    let mut spill = Spill::create(dir)?;
    let mut sum = TotalsSum::default();
    let mut briefs: Vec<Brief> = Vec::with_capacity(files.len());
    let mut page_briefs: Vec<PartBrief> = Vec::with_capacity(files.len());
    let mut shared = Shared::default();
    let mut first: Option<(Vec<String>, PathBuf)> = None;
    let mut codec = Compression::None;
    let mut no_overview = None;
    for batch in files.chunks(ENTRY_BATCH) {
        if o.cancel.as_ref().is_some_and(|c| c.load(Ordering::Relaxed)) {
            return Err(StoreError::new(dir, crate::write::part::INTERRUPTED));
        }
        let made: Vec<(FileEntry, Vec<u8>)> = batch
            .par_iter()
            .map(|f| {
                let p = Part::open(f)?;
                if p.meta.point_count == 0 {
                    return Err(StoreError::new(
                        &p.path,
                        "holds no points: a dataset's index lists parts with points only; \
                         move it out of the directory",
                    ));
                }
                let e = entry_of(&p, &name(f).unwrap_or_default())?;
                let json = serde_json::to_vec(&e)
                    .map_err(|err| StoreError::new(f, format!("cannot encode: {err}")))?;
                Ok((e, json))
            })
            .collect::<Result<_>>()?;
        for ((e, json), f) in made.into_iter().zip(batch) {
            match &first {
                None => {
                    let names = e.header.bands.iter().map(|b| b.name.clone()).collect();
                    first = Some((names, f.clone()));
                    let l = &e.header.levels[0];
                    // (LERC nodes keep their coordinates losslessly: they are
                    // read back from parts whose values already carry the
                    // parts' bound.)
                    codec = Compression::from_codes(l.compression, l.lerc_extra)
                        .unwrap_or(Compression::None);
                }
                Some(fst) => {
                    if no_overview.is_none() {
                        no_overview = incompatible(&e, f, fst);
                    }
                }
            }
            sum.add_entry(&e);
            let at = spill.push(&json)?;
            let (brief, page) = Brief::of(&e, json.len(), at, &mut shared);
            briefs.push(brief);
            page_briefs.push(page);
        }
    }
    // (The parts' paths are their names in `dir` from here on.)
    drop(files);
    let bands = first.as_ref().map_or(0, |f| f.0.len());
    let tops: u64 = briefs.iter().map(|b| b.top_points).sum();
    let threads = rayon::current_num_threads();
    let at_once = match index_memory(briefs.len(), bands, tops, o.memory, threads) {
        Ok(n) => n,
        Err(needed) if o.refuse_over_memory => {
            return Err(over_memory(dir, briefs.len(), needed, o));
        }
        Err(_) => 1,
    };
    let mut report = IndexReport {
        parts: briefs.len(),
        leftovers,
        ..Default::default()
    };
    report.no_overview = if briefs.len() < 2 {
        Some("a single part is its own overview".into())
    } else {
        no_overview
    };
    // The earlier index and overview stay in use until the new index replaces
    // the old in one rename: a reader sees the one or the other, and one that
    // opened the old index reads its nodes until the rebuild after this one. The new nodes
    // take names the old index does not use, so both sets lie side by side in
    // the overview folder until then.
    let old = dir.join(OVERVIEW_DIR);
    check_overview(&old)?;
    let in_use: Vec<String> = indexed_files(dir)
        .ok()
        .flatten()
        .unwrap_or_default()
        .into_iter()
        .filter(|f| f.starts_with(&format!("{OVERVIEW_DIR}/")))
        .collect();
    let generation = u32::from(in_use.iter().any(|f| {
        f.strip_prefix(&format!("{OVERVIEW_DIR}/"))
            .is_some_and(|n| node_generation(n) == Some(0))
    }));
    // The nodes of the index before the one in use (kept by the last
    // rebuild for readers that had opened it) go now: the new nodes take
    // their names, and a reader still holding that index must find them gone
    // rather than find other nodes under their names.
    remove_unlisted(&old, &in_use)?;
    let nodes = if report.no_overview.is_none() {
        let tmp = dir.join(format!(".{OVERVIEW_DIR}-tmp-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir(&tmp).map_err(|e| {
            StoreError::new(&tmp, format!("cannot create: {}", full_note(e, &tmp, None)))
        })?;
        let compression = o.compression.unwrap_or(codec);
        let built = {
            let build = || {
                build_nodes(
                    &briefs,
                    &page_briefs,
                    shared,
                    dir,
                    &tmp,
                    generation,
                    compression,
                    o,
                    progress,
                )
            };
            if at_once < rayon::current_num_threads() {
                // (Fewer nodes at once than threads: the memory budget.)
                match rayon::ThreadPoolBuilder::new().num_threads(at_once).build() {
                    Ok(pool) => pool.install(build),
                    Err(_) => build(),
                }
            } else {
                build()
            }
        }
        .and_then(|nodes| move_nodes(&tmp, &old, &nodes).map(|()| nodes));
        let _ = std::fs::remove_dir_all(&tmp);
        match built {
            Ok(n) => n,
            Err(e) => {
                // (Nodes already moved bear names the old index does not use.)
                let _ = remove_unlisted(&old, &in_use);
                return Err(e);
            }
        }
    } else {
        Vec::new()
    };
    report.nodes = nodes.len();
    report.layers = nodes.iter().map(|n| n.layer).max().unwrap_or(0);
    report.node_points = nodes.iter().map(|n| n.entry.header.meta.point_count).sum();
    report.node_bytes = nodes.iter().map(|n| n.entry.bytes).sum();
    let listed: Vec<String> = nodes.iter().map(|n| n.entry.file.clone()).collect();
    let layers = layer_summaries(&nodes);
    let totals = sum.finish(nodes.len());
    report.points = totals.points;
    let pages_dir = format!("{PAGES_DIR}-{generation}");
    let saved =
        paginate(&page_briefs, nodes, layers, totals, &pages_dir).and_then(|(mut root, plans)| {
            report.index_pages = root.pages;
            let mut plans = plans.into_iter();
            let mut entry = |i: usize| spill.entry(&briefs[i]);
            root.first = plans.next().unwrap_or_default().page(&mut entry)?;
            let count = plans.len();
            root.save_with(dir, count, &mut |_| {
                plans.next().unwrap_or_default().page(&mut entry)
            })
        });
    report.index_bytes = match saved {
        Ok(b) => b,
        Err(e) => {
            // The old index stands: the new nodes go.
            let _ = remove_unlisted(&old, &in_use);
            return Err(e);
        }
    };
    // The nodes of the index just replaced stay until the next rebuild: a
    // reader that opened it before the swap still reads them (its index
    // names them). The overview thus takes up to twice its size on disk.
    if listed.is_empty() && in_use.is_empty() {
        remove_unlisted(&old, &listed)?;
    }
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// Removes what a killed `pcimg index` or `convert` left inside the dataset
/// `dir`: the temporary overview folders and index files of processes no longer
/// running (their names carry the process id). Returns what it removed.
pub fn remove_leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut gone = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return gone;
    };
    let tags = [
        format!(".{OVERVIEW_DIR}-tmp-"),
        format!(".{INDEX_FILE}.tmp-"),
        format!(".{PAGES_DIR}-0-tmp-"),
        format!(".{PAGES_DIR}-1-tmp-"),
        SPILL_TAG.to_string(),
    ];
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = tags
            .iter()
            .find(|t| name.starts_with(t.as_str()))
            .and_then(|t| name[t.len()..].parse::<u32>().ok())
        else {
            continue;
        };
        if pid_alive(pid) {
            continue;
        }
        let path = e.path();
        let r = if e.file_type().is_ok_and(|t| t.is_dir()) {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if r.is_ok() {
            gone.push(path);
        }
    }
    gone
}

#[cfg(unix)]
fn pid_alive(pid: u32) -> bool {
    pcimg_core::disk::pid_alive(pid)
}

/// (Elsewhere no process is known to be dead: nothing is removed.)
#[cfg(not(unix))]
fn pid_alive(_pid: u32) -> bool {
    true
}

/// The overview folder, if present, must hold only node files: pcimg replaces
/// and removes them, never anything else.
fn check_overview(old: &Path) -> Result<()> {
    if !old.exists() {
        return Ok(());
    }
    let foreign = std::fs::read_dir(old)
        .map_err(|e| StoreError::new(old, format!("cannot list: {e}")))?
        .filter_map(|e| e.ok())
        .find(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            node_generation(&n).is_none()
        });
    if let Some(f) = foreign {
        return Err(StoreError::new(
            &f.path(),
            "is not an overview node: pcimg replaces the overview folder only when it \
             holds nothing else",
        ));
    }
    Ok(())
}

/// Moves the nodes written in `tmp` into the overview folder `old` (made if
/// absent), beside the nodes in use.
fn move_nodes(tmp: &Path, old: &Path, nodes: &[NodeEntry]) -> Result<()> {
    std::fs::create_dir_all(old)
        .map_err(|e| StoreError::new(old, format!("cannot create: {}", full_note(e, old, None))))?;
    for n in nodes {
        let name = n
            .entry
            .file
            .strip_prefix(&format!("{OVERVIEW_DIR}/"))
            .unwrap_or(&n.entry.file);
        std::fs::rename(tmp.join(name), old.join(name)).map_err(|e| {
            StoreError::new(&old.join(name), format!("cannot rename into place: {e}"))
        })?;
    }
    Ok(())
}

/// Removes the node files in the overview folder `old` that `listed` (paths
/// relative to the dataset) does not name, and the folder once empty.
fn remove_unlisted(old: &Path, listed: &[String]) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(old) else {
        return Ok(());
    };
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let rel = format!("{OVERVIEW_DIR}/{n}");
        if node_generation(&n).is_some() && !listed.contains(&rel) {
            std::fs::remove_file(e.path())
                .map_err(|err| StoreError::new(&e.path(), format!("cannot remove: {err}")))?;
        }
    }
    if listed.is_empty() {
        let _ = std::fs::remove_dir(old);
    }
    Ok(())
}

/// Writes the nodes layer by layer into `tmp`; their entries name them inside
/// the final overview folder. `parts` and `pages` brief the parts of `dir`
/// (`shared` their lattices and CRSs).
#[allow(clippy::too_many_arguments)]
fn build_nodes(
    parts: &[Brief],
    pages: &[PartBrief],
    mut shared: Shared,
    dir: &Path,
    tmp: &Path,
    generation: u32,
    compression: Compression,
    o: &IndexOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Vec<NodeEntry>> {
    // The nodes' file names.
    let mut names: Vec<String> = Vec::new();
    let mut nodes: Vec<NodeEntry> = Vec::new();
    // The nodes' briefs (their lattices and CRSs in `shared` too).
    let mut node_briefs: Vec<Brief> = Vec::new();
    let mut members: Vec<Child> = (0..parts.len()).map(Child::Part).collect();
    let done = AtomicUsize::new(0);
    let mut layer = 0;
    while members.len() > 1 {
        layer += 1;
        let member = |&child: &Child| -> Member {
            let (brief, center) = match child {
                Child::Part(i) => (&parts[i], pages[i].bounds.center()),
                Child::Node(k) => (&node_briefs[k], nodes[k].entry.header.meta.bounds.center()),
            };
            Member {
                child,
                brief,
                center,
            }
        };
        let mut m: Vec<Member> = members.iter().map(member).collect();
        let runs = group(&mut m);
        let written: Vec<NodeEntry> = runs
            .par_iter()
            .enumerate()
            .map(|(k, run)| {
                if o.cancel.as_ref().is_some_and(|c| c.load(Ordering::Relaxed)) {
                    return Err(StoreError::new(tmp, crate::write::part::INTERRUPTED));
                }
                let kids = &m[run.clone()];
                let mut pts = PointColumns::default();
                for kid in kids {
                    let path = match kid.child {
                        Child::Part(i) => dir.join(&pages[i].file),
                        Child::Node(j) => tmp.join(&names[j]),
                    };
                    append(&mut pts, next_coarser(&Part::open(&path)?)?);
                }
                let child_names: Vec<String> = kids
                    .iter()
                    .map(|kid| match kid.child {
                        Child::Part(i) => pages[i].file.clone(),
                        Child::Node(j) => format!("{OVERVIEW_DIR}/{}", names[j]),
                    })
                    .collect();
                let path = tmp.join(node_name(generation, layer, k));
                let first = kids[0].brief;
                let opts = WriteOptions {
                    compression,
                    source: Some(format!("pcimg overview of {}", child_names.join(" "))),
                    crs: first.crs.map(|c| shared.crss[c as usize].clone()),
                    cancel: o.cancel.clone(),
                    // Children on one lattice (tiles converted one by one, each
                    // its own LAS offset, share one): the node keeps their whole
                    // numbers.
                    lattice: kids
                        .iter()
                        .map(|k| k.brief.lattice.map(|l| shared.lattices[l as usize]))
                        .collect::<Option<Vec<Lattice>>>()
                        .and_then(|l| Lattice::common(&l)),
                    ..Default::default()
                };
                write_part(&path, &pts, &opts)?;
                let entry = entry_of(
                    &Part::open(&path)?,
                    &format!("{OVERVIEW_DIR}/{}", node_name(generation, layer, k)),
                )?;
                progress(done.fetch_add(1, Ordering::Relaxed) + 1);
                Ok(NodeEntry {
                    entry,
                    layer,
                    children: kids.iter().map(|kid| kid.child).collect(),
                })
            })
            .collect::<Result<_>>()?;
        drop(m);
        members.clear();
        for entry in written {
            members.push(Child::Node(nodes.len()));
            names.push(node_name(generation, layer, members.len() - 1));
            node_briefs.push(Brief::of(&entry.entry, 0, 0, &mut shared).0);
            nodes.push(entry);
        }
    }
    Ok(nodes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A node's points from a part on a lattice are the part's lattice points
    /// exactly (the f32 offsets plus the origin are only near them), so the
    /// node keeps the lattice: 1 cm steps at UTM-sized coordinates over 20 km.
    #[test]
    fn a_nodes_points_from_a_part_on_a_lattice_are_its_lattice_points() {
        let dir = tempfile::tempdir().unwrap();
        let l = Lattice {
            step: [0.01; 3],
            origin: [500_000.0, 4_000_000.0, 0.0],
        };
        let mut r = crate::rng::Rng::new(3);
        let mut c = PointColumns::default();
        for _ in 0..300_000 {
            let k = |n: f64, r: &mut crate::rng::Rng| (r.f64() * n).floor();
            c.x.push(l.origin[0] + k(2_000_000.0, &mut r) * l.step[0]);
            c.y.push(l.origin[1] + k(2_000_000.0, &mut r) * l.step[1]);
            c.z.push(l.origin[2] + k(10_000.0, &mut r) * l.step[2]);
        }
        let path = dir.path().join("p.tif");
        let opts = WriteOptions {
            compression: Compression::Zstd,
            lattice: Some(l),
            ..Default::default()
        };
        assert!(write_part(&path, &c, &opts).unwrap().lattice.is_some());
        let p = next_coarser(&Part::open(&path).unwrap()).unwrap();
        assert!(p.len() > 1000, "{}", p.len());
        for (a, col) in [&p.x, &p.y, &p.z].into_iter().enumerate() {
            for &v in col {
                let k = ((v - l.origin[a]) / l.step[a]).round();
                assert_eq!(v, l.origin[a] + k * l.step[a], "axis {a}");
            }
        }
    }

    #[test]
    fn the_budget_decides_how_many_nodes_are_built_at_once() {
        // 1,000 parts of 12 bands with full coarsest tiles: nodes of 65,536
        // points, 24 MiB each.
        let node = 65_536 * 12 * INDEX_NODE_BYTES_PER_VALUE;
        let least = 1000 * INDEX_PART_BYTES + node;
        let tops = 1000 * TILE_PIXELS as u64;
        assert_eq!(index_memory(1000, 12, tops, None, 8), Ok(8));
        assert_eq!(index_memory(1000, 12, tops, Some(least - 1), 8), Err(least));
        assert_eq!(index_memory(1000, 12, tops, Some(least), 8), Ok(1));
        assert_eq!(
            index_memory(1000, 12, tops, Some(least + 2 * node), 8),
            Ok(3)
        );
        assert_eq!(index_memory(1000, 12, tops, Some(1 << 40), 2), Ok(2));
        // Few points: a node holds a quarter of them all.
        let small = 1000u64.div_ceil(4) * 4 * INDEX_NODE_BYTES_PER_VALUE;
        assert_eq!(
            index_memory(3, 4, 1000, Some(0), 2),
            Err(3 * INDEX_PART_BYTES + small)
        );
    }
}
