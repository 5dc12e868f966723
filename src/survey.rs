//! A survey: many COPC files (a tiled survey; local files or URLs) seen as one
//! dataset, with no conversion.
//!
//! `pcimg index` over them (a directory of `.copc.laz` files, or a text file
//! listing paths and URLs) writes `pcimg-survey.json` and overview nodes above
//! the files, built from each file's root node only: no pass over the points.
//! A view's first frame reads the survey file and its top node, what one COPC
//! file's first frame costs, whatever the number of files. The view refines the
//! overview (a node replaced by its children, as a part's pyramid is) down to
//! the files' root nodes, then into each file's octree (additive, as one COPC
//! file's is), opening a file only when the view reaches it.
//!
//! The overview is the one `pcimg index` builds above parts: the store's
//! grouping (`group_compact`, a k-d split of the members' centres, a node's
//! children holding at most four tiles of points), each node an ordinary
//! one-tile part keeping a quarter of its children's coarsest points (here a
//! file's root node). The survey file is JSON, about 300 bytes a file: 30 MB
//! at 10⁵ files, where a paged index (issue 44's) would be the next step.
//!
//! Here, in the binary, because this is where a reader (COPC) meets the store.

use crate::copc_tiles::CopcTiles;
use crate::points::{Bounds, PointColumns};
use crate::store::{
    Compression, Dataset, GROUP_POINTS, Part, Points, SourceStats, SourceTile, StoreError,
    TileSource, Totals, WriteOptions, append_columns, group_compact, next_coarser, write_part,
};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// The survey file's name inside its directory.
pub const SURVEY_FILE: &str = "pcimg-survey.json";
const FORMAT: &str = "pcimg-survey";
const VERSION: u32 = 1;
/// The overview folders' names start so (`survey-overview-<stamp>`).
const OVERVIEW_PREFIX: &str = "survey-overview-";
/// Files opened at once over the network (opening is two requests each).
const OPEN_THREADS: usize = 16;

/// A COPC file of the survey.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SurveyFile {
    /// A URL, an absolute path, or a path relative to the survey's directory.
    pub file: String,
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub points: u64,
    pub bytes: u64,
    /// Points of its root node.
    pub root_points: u64,
}

/// What an overview node stands for: a file's root node, or a node below.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Member {
    File(usize),
    Node(usize),
}

/// An overview node: a one-tile part (path relative to the survey's
/// directory) holding a quarter of its children's coarsest points.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SurveyNode {
    pub file: String,
    /// 1 just above the files, the root's the highest.
    pub layer: u32,
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub points: u64,
    pub bytes: u64,
    pub children: Vec<Member>,
}

/// The survey file.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Survey {
    pub format: String,
    pub version: u32,
    /// The attribute columns every file has (after x, y, z).
    pub bands: Vec<String>,
    pub crs: Option<String>,
    pub files: Vec<SurveyFile>,
    /// Each after its children; the root last.
    pub nodes: Vec<SurveyNode>,
}

impl Survey {
    pub fn points(&self) -> u64 {
        self.files.iter().map(|f| f.points).sum()
    }

    pub fn bounds(&self) -> Bounds {
        let mut b = Bounds {
            min: [f64::INFINITY; 3],
            max: [f64::NEG_INFINITY; 3],
        };
        for f in &self.files {
            for a in 0..3 {
                b.min[a] = b.min[a].min(f.min[a]);
                b.max[a] = b.max[a].max(f.max[a]);
            }
        }
        b
    }

    /// Overview layers (0: none, a single file).
    pub fn layers(&self) -> u32 {
        self.nodes.iter().map(|n| n.layer).max().unwrap_or(0)
    }
}

/// Whether `path` names a survey: its `pcimg-survey.json` (local or a URL), or
/// a directory holding one.
pub fn is_survey(path: &Path) -> bool {
    let s = path.to_string_lossy();
    s.ends_with(SURVEY_FILE) || (!crate::ingest::is_url(path) && path.join(SURVEY_FILE).is_file())
}

/// The survey file's location for `path` (the file, or its directory).
fn survey_file(path: &Path) -> PathBuf {
    if path.to_string_lossy().ends_with(SURVEY_FILE) {
        path.to_path_buf()
    } else {
        path.join(SURVEY_FILE)
    }
}

/// `rel` (a survey's entry) resolved against the survey file `at`.
fn resolve(at: &Path, rel: &str) -> PathBuf {
    if crate::ingest::is_url(Path::new(rel)) || Path::new(rel).is_absolute() {
        return PathBuf::from(rel);
    }
    let s = at.to_string_lossy();
    if crate::ingest::is_url(at) {
        let base = s.rsplit_once('/').map(|(b, _)| b).unwrap_or(&s);
        return PathBuf::from(format!("{base}/{rel}"));
    }
    at.parent().unwrap_or(Path::new(".")).join(rel)
}

/// The whole file at `path`, local or a URL.
fn read_bytes(path: &Path) -> anyhow::Result<Vec<u8>> {
    Ok(crate::ingest::read_whole(path)?)
}

/// Reads the survey at `path` (its file or directory, local or a URL).
pub fn read(path: &Path) -> anyhow::Result<(PathBuf, Survey)> {
    let at = survey_file(path);
    let text = read_bytes(&at)?;
    let s: Survey = serde_json::from_slice(&text)
        .map_err(|e| anyhow::anyhow!("{}: not a pcimg survey: {e}", at.display()))?;
    if s.format != FORMAT || s.version != VERSION {
        anyhow::bail!(
            "{}: a survey file of format {:?} version {}; this pcimg reads {FORMAT:?} version {VERSION}",
            at.display(),
            s.format,
            s.version
        );
    }
    let bad = |what: String| anyhow::anyhow!("{}: {what}", at.display());
    if s.files.is_empty() {
        return Err(bad("lists no files".into()));
    }
    for (k, n) in s.nodes.iter().enumerate() {
        for c in &n.children {
            let ok = match *c {
                Member::File(i) => i < s.files.len(),
                Member::Node(j) => j < k,
            };
            if !ok {
                return Err(bad(format!(
                    "node {k} names a child ({c:?}) it cannot have"
                )));
            }
        }
    }
    Ok((at, s))
}

/// The survey at `path`'s files (paths or URLs) whose recorded bounds reach
/// `region` (all without one), in the survey's order.
pub fn files_in(path: &Path, region: Option<&Bounds>) -> anyhow::Result<Vec<PathBuf>> {
    let (at, s) = read(path)?;
    Ok(s.files
        .iter()
        .filter(|f| {
            region.is_none_or(|r| {
                r.intersects(&Bounds {
                    min: f.min,
                    max: f.max,
                })
            })
        })
        .map(|f| resolve(&at, &f.file))
        .collect())
}

// ---------------------------------------------------------------- building

/// What `pcimg index` over COPC files did.
#[derive(Debug, Default)]
pub struct BuildReport {
    pub files: usize,
    pub points: u64,
    pub nodes: usize,
    pub layers: u32,
    pub node_points: u64,
    pub node_bytes: u64,
    pub survey_bytes: u64,
    pub seconds: f64,
    /// Overview folders of earlier surveys, and of killed runs, removed.
    pub removed: Vec<PathBuf>,
}

/// The COPC files `arg` names: the `.copc.laz` files of a directory (sorted),
/// or the lines of a text file (paths relative to it, or URLs; blank lines
/// and `#` comments skipped).
pub fn inputs_of(arg: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if arg.is_dir() {
        let mut out: Vec<PathBuf> = std::fs::read_dir(arg)
            .map_err(|e| anyhow::anyhow!("{}: cannot list: {e}", arg.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.is_file()
                    && p.file_name()
                        .is_some_and(|n| n.to_string_lossy().to_lowercase().ends_with(".copc.laz"))
            })
            .collect();
        out.sort();
        return Ok(out);
    }
    if crate::ingest::copc::is_copc(arg) {
        anyhow::bail!(
            "{}: one COPC file needs no survey: `pcimg render|inspect|info` open it as it is",
            arg.display()
        );
    }
    let text = std::fs::read_to_string(arg)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the list of files: {e}", arg.display()))?;
    let base = arg.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let p = Path::new(l);
        if crate::ingest::is_url(p) || p.is_absolute() {
            out.push(p.to_path_buf());
        } else if l.contains("://") {
            anyhow::bail!(
                "{}:{}: {l:?} is a URL of a scheme pcimg does not read (s3://, gs://, az://, http://, https://)",
                arg.display(),
                n + 1
            );
        } else {
            out.push(base.join(p));
        }
    }
    if out.is_empty() {
        anyhow::bail!("{}: lists no files", arg.display());
    }
    Ok(out)
}

/// What opening a file tells the survey (its header and root page): its
/// record, fields, CRS and lattice. Its points are read again, a group at a
/// time, when its overview node is written: nothing of a file is held
/// between.
struct Opened {
    rec: SurveyFile,
    names: Vec<String>,
    crs: Option<String>,
    lattice: crate::points::Lattice,
}

/// Every `step`-th point of `c`, less the whole numbers that make GPS time
/// exact (a node is for viewing).
fn every(c: PointColumns, step: usize) -> PointColumns {
    let pick = |v: Vec<f64>| v.into_iter().step_by(step).collect::<Vec<_>>();
    PointColumns {
        x: pick(c.x),
        y: pick(c.y),
        z: pick(c.z),
        attributes: c
            .attributes
            .into_iter()
            .filter(|a| !crate::time::is_exact_band(&a.name))
            .map(|mut a| {
                a.values = a.values.into_iter().step_by(step).collect();
                a
            })
            .collect(),
    }
}

/// How `file` is written in a survey in `out`: relative when it lies in
/// `out`, else absolute (a URL as it is).
fn entry_name(file: &Path, out: &Path) -> String {
    if crate::ingest::is_url(file) {
        return file.to_string_lossy().into_owned();
    }
    let real = file.canonicalize().unwrap_or_else(|_| file.to_path_buf());
    match out
        .canonicalize()
        .ok()
        .and_then(|o| real.strip_prefix(o).ok().map(Path::to_path_buf))
    {
        Some(rel) => rel.to_string_lossy().replace('\\', "/"),
        None => real.to_string_lossy().into_owned(),
    }
}

fn open_one(file: &Path, out: &Path) -> anyhow::Result<Opened> {
    let copc = crate::ingest::copc::open_once(file)?;
    let decoder = crate::ingest::copc::NodeDecoder::new(&copc)?;
    let (crs, _) = crate::ingest::copc::describe(&copc)?;
    let h = &copc.header;
    if h.points == 0 {
        anyhow::bail!(
            "{}: holds no points; leave it out of the survey",
            file.display()
        );
    }
    Ok(Opened {
        rec: SurveyFile {
            file: entry_name(file, out),
            min: h.min,
            max: h.max,
            points: h.points,
            bytes: copc.len,
            root_points: u64::from(copc.root().points),
        },
        names: decoder.names().to_vec(),
        crs,
        lattice: crate::points::Lattice {
            step: h.scale,
            origin: h.offset,
        },
    })
}

/// A quarter of the points of `file`'s root node, every field.
fn root_sample(file: &Path) -> anyhow::Result<PointColumns> {
    let copc = crate::ingest::copc::open_once(file)?;
    let decoder = crate::ingest::copc::NodeDecoder::new(&copc)?;
    let mut bands = decoder.names().to_vec();
    bands.extend(["x", "y", "z"].map(String::from));
    let pts = decoder.read(&copc, &copc.root(), &bands)?;
    Ok(every(pts, 4))
}

/// Removes the overview folders in `out` that `keep` does not name (an
/// older survey's) and what killed runs left (`.survey-tmp-PID` and
/// `.pcimg-survey.json.tmp-PID`, that process gone).
fn remove_others(out: &Path, keep: &[&str]) -> Vec<PathBuf> {
    let mut gone = Vec::new();
    let Ok(entries) = std::fs::read_dir(out) else {
        return gone;
    };
    let json_tmp = format!(".{SURVEY_FILE}.tmp-");
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let dead = |pid: &str| pid.parse::<u32>().is_ok_and(|p| !crate::disk::pid_alive(p));
        let stale = if let Some(pid) = name.strip_prefix(".survey-tmp-") {
            dead(pid)
        } else if let Some(pid) = name.strip_prefix(&json_tmp) {
            dead(pid)
        } else {
            name.starts_with(OVERVIEW_PREFIX) && !keep.contains(&name.as_str())
        };
        if !stale {
            continue;
        }
        let removed = if e.path().is_dir() {
            std::fs::remove_dir_all(e.path())
        } else {
            std::fs::remove_file(e.path())
        };
        if removed.is_ok() {
            gone.push(e.path());
        }
    }
    gone
}

/// Builds the survey of `inputs` in directory `out`: opens every file (its
/// header and root node), writes the overview nodes, then the survey file
/// (last, in one rename: a reader sees the old survey or the new).
/// `progress(what, done, of)` reports the files opened and nodes written.
pub fn build(
    inputs: &[PathBuf],
    out: &Path,
    cancel: &AtomicBool,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> anyhow::Result<BuildReport> {
    let t0 = std::time::Instant::now();
    if inputs.is_empty() {
        anyhow::bail!("{}: no COPC files (.copc.laz) to index", out.display());
    }
    std::fs::create_dir_all(out)
        .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", out.display()))?;
    // The overview the survey in use names stays until the rebuild after
    // this one: a reader that opened it still finds its nodes.
    let current = current_overview(out);
    let mut report = BuildReport {
        removed: remove_others(out, &current.iter().map(String::as_str).collect::<Vec<_>>()),
        ..Default::default()
    };
    let done = AtomicUsize::new(0);
    let interrupted = || anyhow::anyhow!("{}: interrupted; nothing was written", out.display());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(OPEN_THREADS)
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start threads: {e}"))?;
    let opened: Vec<Opened> = pool.install(|| {
        inputs
            .par_iter()
            .map(|f| {
                if cancel.load(Ordering::Relaxed) {
                    return Err(interrupted());
                }
                let o = open_one(f, out);
                progress(
                    "files opened",
                    done.fetch_add(1, Ordering::Relaxed) + 1,
                    inputs.len(),
                );
                o
            })
            .collect::<anyhow::Result<_>>()
    })?;
    let first = &opened[0];
    if let Some((o, f)) = opened
        .iter()
        .zip(inputs)
        .find(|(o, _)| o.names != first.names)
    {
        anyhow::bail!(
            "{} has other fields ({}) than {} ({}): a survey's files share one point format",
            f.display(),
            o.names.join(" "),
            inputs[0].display(),
            first.names.join(" ")
        );
    }
    // Tiles of one survey: one scale, offsets whole steps apart.
    let lattice =
        crate::points::Lattice::common(&opened.iter().map(|o| o.lattice).collect::<Vec<_>>());
    let mut survey = Survey {
        format: FORMAT.into(),
        version: VERSION,
        bands: first
            .names
            .iter()
            .filter(|n| !crate::time::is_exact_band(n))
            .cloned()
            .collect(),
        crs: first.crs.clone(),
        files: opened.iter().map(|o| o.rec.clone()).collect(),
        nodes: Vec::new(),
    };
    report.files = survey.files.len();
    report.points = survey.points();
    let stamp = format!(
        "{OVERVIEW_PREFIX}{}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0)
    );
    let tmp = out.join(format!(".survey-tmp-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let built = (|| -> anyhow::Result<()> {
        if opened.len() > 1 {
            std::fs::create_dir(&tmp)
                .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", tmp.display()))?;
            let opts = WriteOptions {
                compression: Compression::Zstd,
                crs: first.crs.clone(),
                lattice,
                ..Default::default()
            };
            survey.nodes = build_nodes(&opened, inputs, &tmp, &stamp, &opts, cancel, progress)?;
            std::fs::rename(&tmp, out.join(&stamp))
                .map_err(|e| anyhow::anyhow!("{}: cannot rename: {e}", tmp.display()))?;
        }
        let text = serde_json::to_vec(&survey)?;
        report.survey_bytes = text.len() as u64;
        let part = out.join(format!(".{SURVEY_FILE}.tmp-{}", std::process::id()));
        std::fs::write(&part, &text)
            .and_then(|()| std::fs::rename(&part, out.join(SURVEY_FILE)))
            .map_err(|e| {
                let _ = std::fs::remove_file(&part);
                anyhow::anyhow!("{}: cannot write: {e}", out.join(SURVEY_FILE).display())
            })
    })();
    let _ = std::fs::remove_dir_all(&tmp);
    if let Err(e) = built {
        let _ = std::fs::remove_dir_all(out.join(&stamp));
        return Err(e);
    }
    let mut keep = vec![stamp.as_str()];
    keep.extend(current.as_deref());
    report.removed.extend(remove_others(out, &keep));
    report.nodes = survey.nodes.len();
    report.layers = survey.layers();
    report.node_points = survey.nodes.iter().map(|n| n.points).sum();
    report.node_bytes = survey.nodes.iter().map(|n| n.bytes).sum();
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// The overview folder the survey in `out` names now, if any.
fn current_overview(out: &Path) -> Option<String> {
    let (_, s) = read(out).ok()?;
    let f = &s.nodes.last()?.file;
    Some(f.split('/').next()?.to_string())
}

/// Writes the overview's nodes into `tmp` (named as they will be in folder
/// `stamp`), layer after layer up to one root. A node's points are read when
/// it is written: its files' root nodes (layer 1), or its children nodes from
/// `tmp`; memory holds the groups being written, not the survey.
fn build_nodes(
    opened: &[Opened],
    inputs: &[PathBuf],
    tmp: &Path,
    stamp: &str,
    opts: &WriteOptions,
    cancel: &AtomicBool,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> anyhow::Result<Vec<SurveyNode>> {
    struct M {
        member: Member,
        center: [f64; 3],
        points: u64,
    }
    let center = |min: [f64; 3], max: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|a| 0.5 * (min[a] + max[a]))
    };
    let mut nodes: Vec<SurveyNode> = Vec::new();
    let mut members: Vec<M> = opened
        .iter()
        .enumerate()
        .map(|(i, o)| M {
            member: Member::File(i),
            center: center(o.rec.min, o.rec.max),
            points: o.rec.root_points,
        })
        .collect();
    let written = AtomicUsize::new(0);
    // Layer 1 waits on the network where the files are remote.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(if inputs.iter().any(|f| crate::ingest::is_url(f)) {
            OPEN_THREADS
        } else {
            rayon::current_num_threads()
        })
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start threads: {e}"))?;
    let mut layer = 0;
    while members.len() > 1 {
        layer += 1;
        let runs = group_compact(&mut members, GROUP_POINTS, &|m| m.center, &|m| m.points);
        let write = |(k, run): (usize, &std::ops::Range<usize>)| {
            if cancel.load(Ordering::Relaxed) {
                anyhow::bail!("{}: interrupted; nothing was written", tmp.display());
            }
            let kids = &members[run.clone()];
            let mut pts = PointColumns::default();
            for m in kids {
                let sample = match m.member {
                    Member::File(i) => root_sample(&inputs[i])?,
                    Member::Node(j) => {
                        next_coarser(&Part::open(&tmp.join(node_file(&nodes[j].file)))?)?
                    }
                };
                append_columns(&mut pts, sample);
            }
            let name = format!("node-{layer}-{k:05}.tif");
            let path = tmp.join(&name);
            let o = WriteOptions {
                source: Some(format!("pcimg survey overview of {} member(s)", kids.len())),
                ..opts.clone()
            };
            write_part(&path, &pts, &o)?;
            let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for m in kids {
                let (lo, hi) = match m.member {
                    Member::File(i) => (opened[i].rec.min, opened[i].rec.max),
                    Member::Node(j) => (nodes[j].min, nodes[j].max),
                };
                for a in 0..3 {
                    min[a] = min[a].min(lo[a]);
                    max[a] = max[a].max(hi[a]);
                }
            }
            progress(
                "nodes written",
                written.fetch_add(1, Ordering::Relaxed) + 1,
                0,
            );
            Ok(SurveyNode {
                file: format!("{stamp}/{name}"),
                layer,
                min,
                max,
                points: pts.x.len() as u64,
                bytes,
                children: kids.iter().map(|m| m.member).collect(),
            })
        };
        let made: Vec<SurveyNode> = if layer == 1 {
            pool.install(|| {
                runs.par_iter()
                    .enumerate()
                    .map(write)
                    .collect::<anyhow::Result<_>>()
            })?
        } else {
            runs.par_iter()
                .enumerate()
                .map(write)
                .collect::<anyhow::Result<_>>()?
        };
        members.clear();
        for n in made {
            members.push(M {
                member: Member::Node(nodes.len()),
                center: center(n.min, n.max),
                points: n.points,
            });
            nodes.push(n);
        }
    }
    Ok(nodes)
}

/// A node's file name inside its folder (`stamp/name` in the survey).
fn node_file(entry: &str) -> &str {
    entry.rsplit('/').next().unwrap_or(entry)
}

// ---------------------------------------------------------------- viewing

/// A tile of a file's octree: the file, and the tile's id in its source.
type Inner = (u32, u32);

#[derive(Debug, Default)]
struct Registry {
    tiles: Vec<Inner>,
    ids: HashMap<Inner, u32>,
}

/// The survey as the viewer's tile source: overview nodes (ids `0..nodes`),
/// then the files' octree nodes (ids above, handed out as views reach them).
#[derive(Debug)]
pub struct SurveyTiles {
    at: PathBuf,
    survey: Survey,
    /// Each file, opened when a view first reaches it.
    files: Vec<OnceLock<Result<Arc<CopcTiles>, String>>>,
    reg: Mutex<Registry>,
    top: usize,
}

impl SurveyTiles {
    fn err(&self, what: impl std::fmt::Display) -> StoreError {
        StoreError::new(&self.at, what.to_string())
    }

    fn nodes(&self) -> u32 {
        self.survey.nodes.len() as u32
    }

    /// File `i`, opened (once); its root is its tile 0.
    fn file(&self, i: usize) -> Result<&Arc<CopcTiles>, StoreError> {
        let rec = &self.survey.files[i];
        let path = resolve(&self.at, &rec.file);
        self.files[i]
            .get_or_init(|| {
                let (t, totals) = CopcTiles::open(&path).map_err(|e| format!("{e:#}"))?;
                if totals.points != rec.points {
                    return Err(format!(
                        "{} has {} points where the survey recorded {}: it changed; run `pcimg index` again",
                        path.display(),
                        totals.points,
                        rec.points
                    ));
                }
                let _ = t.roots();
                Ok(Arc::new(t))
            })
            .as_ref()
            .map_err(|m| StoreError::new(&path, m.clone()))
    }

    fn id_of(&self, inner: Inner) -> u32 {
        let mut r = self.reg.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(&id) = r.ids.get(&inner) {
            return id;
        }
        let id = self.nodes() + r.tiles.len() as u32;
        r.tiles.push(inner);
        r.ids.insert(inner, id);
        id
    }

    fn inner(&self, id: u32) -> Result<Inner, StoreError> {
        let r = self.reg.lock().unwrap_or_else(|p| p.into_inner());
        r.tiles
            .get((id - self.nodes()) as usize)
            .copied()
            .ok_or_else(|| self.err(format!("has no tile {id}")))
    }

    fn node_tile(&self, k: usize) -> SourceTile {
        let n = &self.survey.nodes[k];
        SourceTile {
            id: k as u32,
            depth: self.top - n.layer as usize,
            bounds: Bounds {
                min: n.min,
                max: n.max,
            },
            points: n.points,
        }
    }

    /// File `i`'s root, from the survey alone (the file is not opened).
    fn file_root(&self, i: usize) -> SourceTile {
        let f = &self.survey.files[i];
        SourceTile {
            id: self.id_of((i as u32, 0)),
            depth: self.top,
            bounds: Bounds {
                min: f.min,
                max: f.max,
            },
            points: f.root_points,
        }
    }

    fn member_tile(&self, m: Member) -> SourceTile {
        match m {
            Member::File(i) => self.file_root(i),
            Member::Node(k) => self.node_tile(k),
        }
    }

    /// Overview node `k`'s points: `bands` it has.
    fn load_node(&self, k: usize, bands: &[String]) -> crate::store::Result<Points> {
        let path = resolve(&self.at, &self.survey.nodes[k].file);
        let part = if crate::ingest::is_url(&path) {
            let bytes = read_bytes(&path).map_err(|e| StoreError::new(&path, format!("{e:#}")))?;
            Part::from_bytes(&path, bytes)?
        } else {
            Part::open(&path)?
        };
        let mut idx = vec![0usize, 1, 2];
        idx.extend(bands.iter().filter_map(|b| part.band_index(b)));
        part.read_level(0, &idx)
    }
}

impl TileSource for SurveyTiles {
    fn roots(&self) -> Vec<SourceTile> {
        match self.survey.nodes.len() {
            0 => vec![self.file_root(0)],
            n => vec![self.node_tile(n - 1)],
        }
    }

    fn children(&self, id: u32) -> crate::store::Result<Vec<SourceTile>> {
        if id < self.nodes() {
            let n = &self.survey.nodes[id as usize];
            return Ok(n.children.iter().map(|&m| self.member_tile(m)).collect());
        }
        let (f, inner) = self.inner(id)?;
        let kids = self.file(f as usize)?.children(inner)?;
        Ok(kids
            .into_iter()
            .map(|t| SourceTile {
                id: self.id_of((f, t.id)),
                depth: self.top + t.depth,
                ..t
            })
            .collect())
    }

    fn additive(&self, id: u32) -> bool {
        id >= self.nodes()
    }

    fn load(&self, id: u32, bands: &[String]) -> crate::store::Result<Points> {
        if id < self.nodes() {
            return self.load_node(id as usize, bands);
        }
        let (f, inner) = self.inner(id)?;
        self.file(f as usize)?.load(inner, bands)
    }

    fn prefetch(&self, ids: &[u32]) {
        let mut by_file: HashMap<u32, Vec<u32>> = HashMap::new();
        for &id in ids.iter().filter(|&&id| id >= self.nodes()) {
            if let Ok((f, inner)) = self.inner(id) {
                by_file.entry(f).or_default().push(inner);
            }
        }
        // Files opened and read ahead side by side (each a batch of ranges).
        let jobs: Vec<(u32, Vec<u32>)> = by_file.into_iter().collect();
        std::thread::scope(|s| {
            for chunk in jobs.chunks(jobs.len().div_ceil(OPEN_THREADS).max(1)) {
                s.spawn(move || {
                    for (f, inner) in chunk {
                        if let Ok(t) = self.file(*f as usize) {
                            t.prefetch(inner);
                        }
                    }
                });
            }
        });
    }

    fn file_of(&self, id: u32) -> Option<String> {
        let rel = if id < self.nodes() {
            &self.survey.nodes[id as usize].file
        } else {
            &self.survey.files[self.inner(id).ok()?.0 as usize].file
        };
        Some(resolve(&self.at, rel).display().to_string())
    }

    fn stats(&self) -> SourceStats {
        let mut depths: Vec<(usize, u64)> = vec![(0, 0); self.top];
        for n in &self.survey.nodes {
            let d = self.top - n.layer as usize;
            depths[d].0 += 1;
            depths[d].1 += n.points;
        }
        let mut pages = (0, 0);
        let mut opened = 0;
        for t in self.files.iter().filter_map(|f| f.get()?.as_ref().ok()) {
            opened += 1;
            let s = t.stats();
            pages.0 += s.pages.0;
            pages.1 += s.pages.1;
            for (d, v) in s.depths.into_iter().enumerate() {
                let d = d + self.top;
                if depths.len() <= d {
                    depths.resize(d + 1, (0, 0));
                }
                depths[d].0 += v.0;
                depths[d].1 += v.1;
            }
        }
        SourceStats {
            format: format!(
                "COPC survey · {} of {} files opened",
                opened,
                self.files.len()
            ),
            depths,
            pages,
        }
    }
}

/// The survey at `path` (its file or directory, local or a URL) as a dataset.
pub fn open(path: &Path) -> anyhow::Result<Dataset> {
    let (at, survey) = read(path)?;
    let mut bands: Vec<String> = ["x", "y", "z"].map(String::from).to_vec();
    bands.extend(survey.bands.iter().cloned());
    let top = survey.layers() as usize;
    let totals = Totals {
        parts: 0,
        nodes: survey.nodes.len(),
        points: survey.points(),
        bytes: survey.files.iter().map(|f| f.bytes).sum::<u64>()
            + survey.nodes.iter().map(|n| n.bytes).sum::<u64>(),
        bounds: survey.bounds(),
        own_levels: top + 1,
        crs: survey.crs.clone(),
        class_counts: Vec::new(),
        ranges: vec![None; bands.len()],
        bands,
        classes_complete: false,
        level_points: Vec::new(),
    };
    let tiles = SurveyTiles {
        files: (0..survey.files.len()).map(|_| OnceLock::new()).collect(),
        at,
        survey,
        reg: Mutex::new(Registry::default()),
        top,
    };
    Ok(Dataset::from_source(path, totals, Arc::new(tiles)))
}
