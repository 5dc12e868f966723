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
use crate::dataset::paged::{layer_summaries, paginate};
use crate::error::{Result, StoreError};
use crate::points::{Attribute, PointColumns};
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
    path: PathBuf,
    entry: &'a FileEntry,
    top_points: u64,
    center: [f64; 3],
}

/// Groups a layer's members into compact runs whose coarsest levels hold at most
/// [`GROUP_POINTS`] (so a node, a quarter of that, fits one tile), of at most
/// [`MAX_CHILDREN`] members: the members are
/// split in two at the median of their points along the longer side of their
/// centres' box (a k-d split), again and again, never into fewer than two.
fn group(members: &mut [Member]) -> Vec<std::ops::Range<usize>> {
    group_compact(members, GROUP_POINTS, &|m| m.center, &|m| m.top_points)
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
/// columns in source units. (An overview node's points for the layer above:
/// here, and in a survey of COPC files.)
pub fn next_coarser(part: &Part) -> Result<PointColumns> {
    let top = part.levels.len() - 1;
    let bands: Vec<usize> = (0..part.bands.len()).collect();
    let p = part.read_level(top, &bands)?;
    let quarter = |c: Vec<f32>| -> Vec<f32> { c.into_iter().step_by(4).collect() };
    let mut cols = p.columns.into_iter().map(quarter);
    let mut coord = |o: f64| -> Vec<f64> {
        cols.next()
            .unwrap_or_default()
            .into_iter()
            .map(|v| v as f64 + o)
            .collect()
    };
    let (x, y, z) = (
        coord(p.offsets[0]),
        coord(p.offsets[1]),
        coord(p.offsets[2]),
    );
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

/// Why the parts cannot share an overview, if they cannot.
fn incompatible(parts: &[FileEntry], files: &[PathBuf]) -> Option<String> {
    let names = |e: &FileEntry| {
        e.header
            .bands
            .iter()
            .map(|b| b.name.clone())
            .collect::<Vec<_>>()
    };
    let first = names(&parts[0]);
    parts
        .iter()
        .zip(files)
        .find(|(e, _)| names(e) != first)
        .map(|(_, f)| {
            format!(
                "{} has other bands than {}",
                f.display(),
                files[0].display()
            )
        })
}

/// Options of [`build_index`].
#[derive(Debug, Clone, Default)]
pub struct IndexOptions {
    /// Compression of the overview nodes (`None`: as the first part's level 0).
    pub compression: Option<Compression>,
    pub cancel: Option<Arc<AtomicBool>>,
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
    // Each part's entry, the part closed again: a hundred thousand parts held
    // open would pass the kernel's limit on memory maps (65,530 by default).
    let name = |f: &Path| f.file_name().map(|n| n.to_string_lossy().into_owned());
    let entries: Vec<FileEntry> = files
        .par_iter()
        .map(|f| {
            let p = Part::open(f)?;
            if p.meta.point_count == 0 {
                return Err(StoreError::new(
                    &p.path,
                    "holds no points: a dataset's index lists parts with points only; move \
                     it out of the directory",
                ));
            }
            entry_of(&p, &name(f).unwrap_or_default())
        })
        .collect::<Result<_>>()?;
    let mut report = IndexReport {
        parts: entries.len(),
        points: entries.iter().map(|e| e.header.meta.point_count).sum(),
        leftovers,
        ..Default::default()
    };
    report.no_overview = if entries.len() < 2 {
        Some("a single part is its own overview".into())
    } else {
        incompatible(&entries, &files)
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
        let built = build_nodes(&entries, &files, &tmp, generation, o, progress)
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
    let saved = paginate(entries, nodes, layers, &format!("{PAGES_DIR}-{generation}")).and_then(
        |(root, pages)| {
            report.index_pages = root.pages;
            root.save(dir, &pages)
        },
    );
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
/// the final overview folder.
fn build_nodes(
    parts: &[FileEntry],
    files: &[PathBuf],
    tmp: &Path,
    generation: u32,
    o: &IndexOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Vec<NodeEntry>> {
    let compression = o.compression.unwrap_or_else(|| {
        let l = &parts[0].header.levels[0];
        // (LERC nodes keep their coordinates losslessly: they are read
        // back from parts whose values already carry the parts' bound.)
        Compression::from_codes(l.compression, l.lerc_extra).unwrap_or(Compression::None)
    });
    let top = |e: &FileEntry| e.header.levels.last().and_then(|l| l.points).unwrap_or(0);
    let file_name = |f: &Path| f.file_name().map(|n| n.to_string_lossy().into_owned());
    let mut names: Vec<String> = files
        .iter()
        .map(|f| file_name(f).unwrap_or_default())
        .collect();
    let mut nodes: Vec<NodeEntry> = Vec::new();
    let mut members: Vec<Child> = (0..parts.len()).map(Child::Part).collect();
    let done = AtomicUsize::new(0);
    let mut layer = 0;
    while members.len() > 1 {
        layer += 1;
        let member = |&child: &Child| -> Member {
            let (entry, path) = match child {
                Child::Part(i) => (&parts[i], files[i].clone()),
                Child::Node(k) => (&nodes[k].entry, tmp.join(&names[parts.len() + k])),
            };
            Member {
                child,
                path,
                entry,
                top_points: top(entry),
                center: entry.header.meta.bounds.center(),
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
                    append(&mut pts, next_coarser(&Part::open(&kid.path)?)?);
                }
                let child_names: Vec<String> = kids
                    .iter()
                    .map(|kid| match kid.child {
                        Child::Part(i) => names[i].clone(),
                        Child::Node(j) => format!("{OVERVIEW_DIR}/{}", names[parts.len() + j]),
                    })
                    .collect();
                let path = tmp.join(node_name(generation, layer, k));
                let meta = &kids[0].entry.header.meta;
                let opts = WriteOptions {
                    compression,
                    source: Some(format!("pcimg overview of {}", child_names.join(" "))),
                    crs: meta.crs.clone(),
                    cancel: o.cancel.clone(),
                    // Children on one lattice: the node keeps their whole numbers.
                    lattice: meta
                        .lattice
                        .filter(|l| kids.iter().all(|k| k.entry.header.meta.lattice == Some(*l))),
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
            nodes.push(entry);
        }
    }
    Ok(nodes)
}
