//! Conversion on a cluster: a plan fixed once ([`make_plan`]), shards that each
//! convert the points of their own grid cells into deterministically named parts
//! plus a receipt ([`run_shard`]), and the receipts checked against the plan
//! before `pcimg index` builds the overview ([`check_receipts`]).
//!
//! Ownership: the plan's count grid maps every point to one cell (half-open cells;
//! points outside the grid's bounds to the edge cells), each cell to one region
//! (cells of no region to the nearest, ties to the lowest index), and each region
//! to one shard (shard `i` holds regions `regions[0]..regions[1]`). So every point
//! belongs to exactly one shard, whichever machine reads it.

use super::distribute::spill_all;
use super::job::Job;
use super::partition::{CountGrid, Region};
use super::plan::{Cells, Placer, Plan};
use super::sample::Sample;
use super::scan::{self, Scanned};
use super::{Collect, ConvertOptions, Progress, Result, check_cancel, normalize, spill};
use crate::ingest;
use crate::points::{Bounds, PointColumns};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// The plan's name inside the dataset directory (`pcimg index` checks the
/// receipts against it when it is there).
pub const PLAN_NAME: &str = "pcimg-plan.json";
/// The receipts' folder inside the dataset directory.
pub const RECEIPTS: &str = "receipts";
/// The plan file's format tag.
const FORMAT: &str = "pcimg-plan/1";

/// An input file as it was when planned: a shard refuses one that changed since.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InputStamp {
    pub path: PathBuf,
    pub bytes: u64,
    /// Modification time, nanoseconds since the Unix epoch (0 where unknown).
    pub mtime_ns: u64,
}

/// One shard: a contiguous range of the plan's regions, and the inputs it reads.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Shard {
    /// Regions `regions[0]..regions[1]` (half-open) of the plan.
    pub regions: [u32; 2],
    /// Points (estimated from the sample or headers).
    pub points: u64,
    /// Indexes into the plan's inputs: those whose points may fall in the shard's
    /// cells (all of them where an input declares no bounds).
    pub inputs: Vec<u32>,
}

/// Everything the shards and the finalize step share.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ClusterPlan {
    pub format: String,
    /// The dataset directory the shards write into (a shard may be given another).
    pub output: PathBuf,
    pub inputs: Vec<InputStamp>,
    /// The inputs' coordinate reference system (WKT), which every shard checks.
    pub crs: Option<String>,
    /// Memory budget per shard, bytes (it decides the points per part).
    pub memory: u64,
    /// Where points go and how parts are written (inputs as absolute paths).
    pub plan: Plan,
    pub shards: Vec<Shard>,
}

/// A plan as stored: its hash (FNV-1a 64 of the plan's JSON, hex) and the plan.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct PlanFile {
    hash: String,
    plan: ClusterPlan,
}

/// A part a shard wrote.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ReceiptPart {
    pub name: String,
    pub bytes: u64,
    pub points: u64,
    /// FNV-1a 64 of the file's bytes, hex.
    pub fnv1a64: String,
}

/// What a finished shard leaves in `receipts/shard-IIIII.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Receipt {
    pub plan_hash: String,
    pub shard: usize,
    pub shards: usize,
    pub points: u64,
    pub parts: Vec<ReceiptPart>,
}

/// FNV-1a, 64 bits: a checksum with no dependency, the same on every machine.
pub fn fnv1a64(data: &[u8], mut h: u64) -> u64 {
    for &b in data {
        h ^= b as u64;
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}
const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

fn file_checksum(path: &Path) -> Result<String> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).with_context(|| format!("{}", path.display()))?;
    let mut buf = vec![0u8; 1 << 20];
    let mut h = FNV_START;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h = fnv1a64(&buf[..n], h);
    }
    Ok(format!("{h:016x}"))
}

fn stamp(path: &Path) -> Result<InputStamp> {
    let m = std::fs::metadata(path)
        .with_context(|| format!("{}: cannot read the input", path.display()))?;
    let mtime_ns = m
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos() as u64);
    Ok(InputStamp {
        path: path.to_path_buf(),
        bytes: m.len(),
        mtime_ns,
    })
}

/// Writes `bytes` to `path` through a temporary file renamed into place.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension(format!(
        "tmp-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos())
    ));
    std::fs::write(&tmp, bytes).with_context(|| format!("{}: cannot write", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(())
}

impl ClusterPlan {
    /// The plan's hash: FNV-1a 64 of its JSON (hex).
    pub fn hash(&self) -> Result<String> {
        Ok(format!(
            "{:016x}",
            fnv1a64(&serde_json::to_vec(self)?, FNV_START)
        ))
    }

    /// Writes the plan with its hash to `path` (atomically).
    pub fn save(&self, path: &Path) -> Result<String> {
        let hash = self.hash()?;
        let f = PlanFile {
            hash: hash.clone(),
            plan: self.clone(),
        };
        write_atomic(path, &serde_json::to_vec_pretty(&f)?)?;
        Ok(hash)
    }

    /// Reads a plan and checks its hash; returns it and the hash.
    pub fn load(path: &Path) -> Result<(ClusterPlan, String)> {
        let shown = crate::text::sanitize(&path.display().to_string());
        let text = std::fs::read(path).with_context(|| format!("{shown}: cannot read the plan"))?;
        let f: PlanFile =
            serde_json::from_slice(&text).with_context(|| format!("{shown}: not a pcimg plan"))?;
        if f.plan.format != FORMAT {
            bail!(
                "{shown}: plan format {:?}, this pcimg reads {FORMAT:?}",
                crate::text::sanitize(&f.plan.format)
            );
        }
        let hash = f.plan.hash()?;
        if hash != f.hash {
            bail!(
                "{shown}: the plan's hash is {}, its contents hash to {hash}: it was edited \
                 or damaged",
                crate::text::sanitize(&f.hash)
            );
        }
        Ok((f.plan, hash))
    }
}

/// The region owning cell `c`: its own, or the nearest (ties: lowest index).
fn owner(cells: &Cells, regions: &[Region], c: [usize; 3]) -> usize {
    match cells.cell_region[cells.grid.index(c)] {
        u32::MAX => super::distribute::nearest_region(regions, c),
        r => r as usize,
    }
}

/// Splits the regions (in plan order) into `n` contiguous ranges of about
/// equal points: shard `s` takes the regions whose points' midpoint lies in its
/// `s/n .. (s+1)/n` share of the total.
fn balance(regions: &[Region], n: usize) -> Vec<[u32; 2]> {
    let total: u128 = regions.iter().map(|r| r.points.max(1) as u128).sum();
    let len = regions.len();
    let mut acc = 0u128;
    let mut prev = 0usize;
    let mut bounds = vec![0u32; n + 1];
    for (i, r) in regions.iter().enumerate() {
        let w = r.points.max(1) as u128;
        let want = ((acc * 2 + w) * n as u128 / (2 * total.max(1))) as usize;
        acc += w;
        // Non-decreasing by at most one, ending at n - 1: no shard is empty
        // (where regions are at least n).
        let low = prev.max((n + i).saturating_sub(len));
        let high = if i == 0 { 0 } else { prev + 1 };
        let s = want.clamp(low.min(high), high).min(n - 1);
        if i > 0 && s > prev {
            for b in &mut bounds[prev + 1..=s] {
                *b = i as u32;
            }
        }
        prev = s;
    }
    bounds[n] = len as u32;
    (0..n).map(|s| [bounds[s], bounds[s + 1]]).collect()
}

/// Reads the inputs (LAS/LAZ/E57 headers where they declare counts and bounds;
/// else a sampling pass) and fixes every global choice in a plan of `shards`
/// shards (default: one per region).
pub fn make_plan(
    inputs: &[PathBuf],
    o: &ConvertOptions,
    shards: Option<usize>,
    progress: &dyn Progress,
) -> Result<ClusterPlan> {
    if inputs.is_empty() {
        bail!("no input files");
    }
    let inputs: Vec<PathBuf> = inputs
        .iter()
        .map(|p| std::path::absolute(p).with_context(|| format!("{}: cannot resolve", p.display())))
        .collect::<Result<_>>()?;
    let stamps: Vec<InputStamp> = inputs.iter().map(|p| stamp(p)).collect::<Result<_>>()?;
    // Each file's header: declared points and bounds.
    let mut declared = Vec::new();
    for p in &inputs {
        let r = ingest::multi::open_all(std::slice::from_ref(p), &o.read)?;
        let i = r.info();
        declared.push(i.declared_points.zip(i.declared_bounds));
    }
    // Nothing is written: the job's output check and staging go to a scratch
    // path (the dataset directory may already hold this plan); a killed
    // planner's scratch goes first.
    spill::sweep(&std::env::temp_dir(), ".pcimg-plan-", "pcimg-out-", "");
    let o_plan = ConvertOptions {
        output: std::env::temp_dir().join(format!("pcimg-plan-{}", std::process::id())),
        force: true,
        ..o.clone()
    };
    let (mut job, mut reader) = Job::open(&inputs, &o_plan, progress, Collect::Held)?;
    let crs = job.info.crs_wkt.clone();
    let header_only = o.partition == super::Partition::Spatial
        && declared.iter().all(|d| d.is_some())
        && !declared.is_empty();
    let (plan, cells) = if header_only {
        // The sample: each file's points spread evenly over its declared bounds
        // (a deterministic lattice), in proportion to its count.
        let total: u64 = declared.iter().flatten().map(|(n, _)| *n).sum();
        let like = match reader.next_chunk()? {
            Some(c) => c.empty_like(),
            None => bail!("{}: no points in the input", inputs[0].display()),
        };
        let mut sample = Sample::new(1 << 21);
        let budget = (1u64 << 20).min(total.max(1));
        let mut bounds = Bounds::EMPTY;
        for (n, b) in declared.iter().flatten() {
            bounds = bounds.union(b);
            let k = ((*n as u128 * budget as u128) / total.max(1) as u128).max(1) as u64;
            let mut c = like.empty_like();
            let side = (k as f64).cbrt().ceil().max(1.0) as u64;
            let mut made = 0;
            'fill: for iz in 0..side {
                for iy in 0..side {
                    for ix in 0..side {
                        if made == k {
                            break 'fill;
                        }
                        let f = |i: u64, a: usize| {
                            b.min[a] + (b.max[a] - b.min[a]) * (i as f64 + 0.5) / side as f64
                        };
                        c.x.push(f(ix, 0));
                        c.y.push(f(iy, 1));
                        c.z.push(f(iz, 2));
                        made += 1;
                    }
                }
            }
            for a in &mut c.attributes {
                a.values = vec![0.0; c.x.len()];
            }
            sample.add(&c, (*n / k).max(1));
        }
        let over = scan::Overflow {
            sample,
            bounds,
            like,
            weight: 1,
            points: total,
        };
        let placer = Placer::new(&over.sample, job.per_part, job.max_extent);
        Plan::new(&job, &placer, &over)
    } else {
        let t = job.begin();
        match scan::scan(&mut job, &mut *reader, false, t)? {
            Scanned::Many(over) => {
                let placer = Placer::new(&over.sample, job.per_part, job.max_extent);
                Plan::new(&job, &placer, &over)
            }
            Scanned::One(one) => {
                let like = one.held.first().map(|c| c.empty_like()).unwrap_or_default();
                let grid = CountGrid::new(one.bounds);
                let region = Region {
                    lo: [0; 3],
                    hi: grid.dims,
                    points: one.points,
                };
                let plan = Plan {
                    inputs: inputs.clone(),
                    read: job.read.clone(),
                    grid_bounds: one.bounds,
                    regions: vec![region],
                    origins: vec![one.bounds.center()],
                    attributes: like
                        .attributes
                        .iter()
                        .map(|a| (a.name.clone(), a.offset))
                        .collect(),
                    points: one.points,
                    points_per_part: job.per_part,
                    compression: o.compression,
                    max_error: o.max_error,
                    precision: o.precision,
                    layout: o.layout,
                    zstd_level: o.zstd_level,
                };
                let cells = Cells::of(&plan);
                (plan, cells)
            }
        }
    };
    if plan.points == 0 {
        bail!("{}: no points in the input", inputs[0].display());
    }
    let n = shards.unwrap_or(plan.regions.len()).max(1);
    if n > plan.regions.len() {
        bail!(
            "--shards {n}: the plan has only {} spatial region(s) at --memory {}; ask for at \
             most {} shards, or a smaller --memory",
            plan.regions.len(),
            crate::text::bytes(o.memory),
            plan.regions.len()
        );
    }
    let ranges = balance(&plan.regions, n);
    let scale =
        plan.points as f64 / plan.regions.iter().map(|r| r.points).sum::<u64>().max(1) as f64;
    // Which inputs each shard reads: those whose declared bounds reach a cell the
    // shard owns; every input where one declares none.
    let shard_of_region = |r: usize| {
        ranges
            .iter()
            .position(|s| (s[0] as usize..s[1] as usize).contains(&r))
    };
    let mut reads: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (k, d) in declared.iter().enumerate() {
        match d {
            Some((_, b)) if !b.is_empty() => {
                let (lo, hi) = (cells.grid.cell(b.min), cells.grid.cell(b.max));
                let mut hit = vec![false; n];
                for z in lo[2]..=hi[2] {
                    for y in lo[1]..=hi[1] {
                        for x in lo[0]..=hi[0] {
                            if let Some(s) =
                                shard_of_region(owner(&cells, &plan.regions, [x, y, z]))
                            {
                                hit[s] = true;
                            }
                        }
                    }
                }
                for (s, h) in hit.iter().enumerate() {
                    if *h {
                        reads[s].push(k as u32);
                    }
                }
            }
            _ => reads.iter_mut().for_each(|r| r.push(k as u32)),
        }
    }
    let shards = ranges
        .iter()
        .zip(reads)
        .map(|(r, inputs)| Shard {
            regions: *r,
            points: (plan.regions[r[0] as usize..r[1] as usize]
                .iter()
                .map(|x| x.points)
                .sum::<u64>() as f64
                * scale) as u64,
            inputs,
        })
        .collect();
    drop(reader);
    drop(job);
    Ok(ClusterPlan {
        format: FORMAT.into(),
        output: std::path::absolute(&o.output)?,
        inputs: stamps,
        crs,
        memory: o.memory,
        plan,
        shards,
    })
}

/// Which shard to run: `spec` is `I/N` (0-based I), or `N`, or absent; without
/// an index it comes from `SLURM_ARRAY_TASK_ID` (run the array as
/// `--array=0-(N-1)`) or `JOB_COMPLETION_INDEX` (Kubernetes Indexed Job), both
/// 0-based. N defaults to the plan's shard count and must equal it.
pub fn shard_index(
    spec: Option<&str>,
    planned: usize,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<usize> {
    let (i, n) = match spec.map(|s| s.split_once('/')) {
        Some(Some((i, n))) => (Some(i.to_string()), Some(n)),
        Some(None) => (None, spec),
        None => (None, None),
    };
    let n = match n {
        Some(n) => n
            .trim()
            .parse::<usize>()
            .map_err(|_| anyhow::anyhow!("--shard {:?}: N is not a number", spec.unwrap_or("")))?,
        None => planned,
    };
    if n != planned {
        bail!("--shard: N is {n}, the plan has {planned} shards");
    }
    let (i, from) = match i {
        Some(i) => (i, "--shard"),
        None => match env("SLURM_ARRAY_TASK_ID") {
            Some(v) => (v, "SLURM_ARRAY_TASK_ID"),
            None => match env("JOB_COMPLETION_INDEX") {
                Some(v) => (v, "JOB_COMPLETION_INDEX"),
                None => bail!(
                    "which shard? give --shard I/{n} (0-based), or run under a Slurm array \
                     (SLURM_ARRAY_TASK_ID) or a Kubernetes Indexed Job (JOB_COMPLETION_INDEX)"
                ),
            },
        },
    };
    let i: usize = i.trim().parse().map_err(|_| {
        anyhow::anyhow!(
            "{from}: {:?} is not a shard index",
            crate::text::sanitize(&i)
        )
    })?;
    if i >= n {
        bail!(
            "{from}: shard {i} of {n}: shards are numbered 0 to {} (0-based)",
            n - 1
        );
    }
    Ok(i)
}

/// The parts' name prefix of shard `i`.
fn prefix(i: usize) -> String {
    format!("part-s{i:05}-")
}

/// Removes the staging directories of shards that were killed (any shard's:
/// [`spill::stale`]) from the output `dir`, and the conversion's own staging
/// directory (`..shard-I.tmp-*.pcimg-out-PID`) of a shard killed between
/// opening its inputs and taking its locked one. Returns what it removed.
pub fn remove_leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut gone = spill::sweep(dir, ".shard-", ".tmp-", "");
    gone.extend(spill::sweep(dir, "..shard-", "pcimg-out-", ""));
    gone
}

fn receipt_path(dir: &Path, i: usize) -> PathBuf {
    dir.join(RECEIPTS).join(format!("shard-{i:05}.json"))
}

/// Runs shard `i` of the plan at `plan_path`, into `output` (default: the
/// plan's). Returns its receipt. Re-running it, or two copies at once, gives the
/// same files.
pub fn run_shard(
    plan_path: &Path,
    i: usize,
    output: Option<&Path>,
    o: &ConvertOptions,
    progress: &dyn Progress,
) -> Result<Receipt> {
    let (cp, hash) = ClusterPlan::load(plan_path)?;
    let dir = output.map_or(cp.output.clone(), Path::to_path_buf);
    let shard = cp
        .shards
        .get(i)
        .ok_or_else(|| anyhow::anyhow!("shard {i}: the plan has {}", cp.shards.len()))?
        .clone();
    for s in &cp.inputs {
        let now = stamp(&s.path)?;
        if now.bytes != s.bytes || now.mtime_ns != s.mtime_ns {
            bail!(
                "{}: changed since it was planned ({} bytes then, {} now); plan again",
                crate::text::sanitize(&s.path.display().to_string()),
                s.bytes,
                now.bytes
            );
        }
    }
    std::fs::create_dir_all(dir.join(RECEIPTS))
        .with_context(|| format!("{}: cannot create", dir.display()))?;
    for gone in remove_leftovers(&dir) {
        progress.notice(&format!(
            "removed {}, left by a shard that was stopped",
            crate::text::sanitize(&gone.display().to_string())
        ));
    }
    // The plan beside the parts, for `pcimg index`.
    let here = dir.join(PLAN_NAME);
    if ClusterPlan::load(&here).map(|(_, h)| h).ok().as_deref() != Some(hash.as_str()) {
        cp.save(&here)?;
    }
    let inputs: Vec<PathBuf> = shard
        .inputs
        .iter()
        .map(|&k| cp.inputs[k as usize].path.clone())
        .collect();
    let (lo, hi) = (shard.regions[0] as usize, shard.regions[1] as usize);
    let mut parts = Vec::new();
    if !inputs.is_empty() && hi > lo {
        let unique = format!(
            ".shard-{i:05}.tmp-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        );
        let so = ConvertOptions {
            // (The staging directory, not yet made, passes the output check.)
            output: dir.join(&unique),
            force: true,
            memory: cp.memory,
            compression: cp.plan.compression,
            max_error: cp.plan.max_error,
            precision: cp.plan.precision,
            layout: cp.plan.layout,
            zstd_level: cp.plan.zstd_level,
            read: cp.plan.read.clone(),
            ..o.clone()
        };
        let (mut job, mut reader) = Job::open(&inputs, &so, progress, Collect::Held)?;
        if job.info.crs_wkt != cp.crs {
            bail!("shard {i}: the inputs' CRS differs from the plan's");
        }
        // Locked: a shard killed meanwhile, here or on another machine, leaves
        // it unlocked, and the next shard or `pcimg index` removes it.
        let stage = spill::TempDir::locked(dir.join(unique))?;
        job.stage_in(stage, &prefix(i));
        let spill_dir = spill::TempDir::adopt(job.staging().unwrap_or(&dir).join("spill"));
        std::fs::create_dir_all(&spill_dir.path)?;
        let cells = Cells::of(&cp.plan);
        let all = &cp.plan.regions;
        // This shard's regions, and each cell's region among them.
        let mut local = cp.plan.clone();
        local.regions = all[lo..hi].to_vec();
        local.origins = cp.plan.origins[lo..hi].to_vec();
        let map: Vec<u32> = cells
            .cell_region
            .iter()
            .map(|&r| match r as usize {
                r if (lo..hi).contains(&r) => (r - lo) as u32,
                _ => u32::MAX,
            })
            .collect();
        let like = local.like();
        progress.phase("partition", job.info.file_bytes, "bytes");
        let t = job.begin();
        let mut seen = 0u64;
        let files = {
            let job = &job;
            let reader = &mut *reader;
            spill_all(
                &so,
                &cells.grid,
                &local.regions,
                &map,
                &local.origins,
                &spill_dir.path,
                "region",
                |sink| {
                    while let Some(mut chunk) = reader.next_chunk()? {
                        check_cancel(&so)?;
                        seen += chunk.len() as u64;
                        normalize(&mut chunk, &like, progress, &job.rebased);
                        keep_owned(&mut chunk, &cells, all, lo..hi);
                        sink(chunk)?;
                        progress.advance(reader.bytes_done(), seen);
                    }
                    Ok(())
                },
            )?
        };
        job.pass("partition", t);
        let total = files.iter().map(|f| f.points).sum();
        super::write::regions(&mut job, &local, files, total, &spill_dir.path)?;
        drop(spill_dir);
        // Publish: each part renamed into place (same bytes whichever copy
        // renames last), then parts of an earlier run of this shard that this
        // one did not write are removed.
        for p in &job.parts {
            let name = p
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let from = job.staging().unwrap_or(&dir).join(&name);
            let bytes = std::fs::metadata(&from)?.len();
            let sum = file_checksum(&from)?;
            std::fs::rename(&from, dir.join(&name))
                .with_context(|| format!("{}: cannot publish", dir.join(&name).display()))?;
            parts.push(ReceiptPart {
                name,
                bytes,
                points: p.points,
                fnv1a64: sum,
            });
        }
    }
    let mine = prefix(i);
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            if n.starts_with(&mine) && n.ends_with(".tif") && !parts.iter().any(|p| p.name == n) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    let receipt = Receipt {
        plan_hash: hash,
        shard: i,
        shards: cp.shards.len(),
        points: parts.iter().map(|p| p.points).sum(),
        parts,
    };
    write_atomic(
        &receipt_path(&dir, i),
        &serde_json::to_vec_pretty(&receipt)?,
    )?;
    Ok(receipt)
}

/// Keeps the points of `c` whose cell's region lies in `mine`.
fn keep_owned(
    c: &mut PointColumns,
    cells: &Cells,
    regions: &[Region],
    mine: std::ops::Range<usize>,
) {
    use rayon::prelude::*;
    let keep: Vec<bool> = (0..c.len())
        .into_par_iter()
        .with_min_len(1 << 14)
        .map(|i| {
            let cell = cells.grid.cell([c.x[i], c.y[i], c.z[i]]);
            mine.contains(&owner(cells, regions, cell))
        })
        .collect();
    if keep.iter().all(|k| *k) {
        return;
    }
    fn retain<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
        let mut k = keep.iter();
        v.retain(|_| k.next().copied().unwrap_or(false));
    }
    retain(&mut c.x, &keep);
    retain(&mut c.y, &keep);
    retain(&mut c.z, &keep);
    for a in &mut c.attributes {
        retain(&mut a.values, &keep);
    }
}

/// What [`check_receipts`] found.
#[derive(Debug, Clone)]
pub struct Checked {
    pub shards: usize,
    pub parts: usize,
    pub points: u64,
}

/// Where `dir` holds a plan: checks that every shard's receipt is there, made
/// from this plan, and that the parts it lists exist with the recorded sizes,
/// and that no other parts lie there. `None` where there is no plan.
pub fn check_receipts(dir: &Path) -> Result<Option<Checked>> {
    let plan_path = dir.join(PLAN_NAME);
    if !plan_path.exists() {
        return Ok(None);
    }
    let (cp, hash) = ClusterPlan::load(&plan_path)?;
    let shown = |p: &Path| crate::text::sanitize(&p.display().to_string());
    let mut missing = Vec::new();
    let mut listed = std::collections::HashSet::new();
    let (mut parts, mut points) = (0, 0);
    for i in 0..cp.shards.len() {
        let rp = receipt_path(dir, i);
        let Ok(text) = std::fs::read(&rp) else {
            missing.push(i);
            continue;
        };
        let r: Receipt = serde_json::from_slice(&text)
            .with_context(|| format!("{}: not a shard receipt", shown(&rp)))?;
        if r.plan_hash != hash || r.shard != i || r.shards != cp.shards.len() {
            bail!(
                "{}: made for plan {} shard {}/{}, not this plan ({hash}, shard {i}/{}): run \
                 the shard again",
                shown(&rp),
                crate::text::sanitize(&r.plan_hash),
                r.shard,
                r.shards,
                cp.shards.len()
            );
        }
        for p in &r.parts {
            let path = dir.join(&p.name);
            match std::fs::metadata(&path) {
                Ok(m) if m.len() == p.bytes => {}
                Ok(m) => bail!(
                    "{}: {} bytes, shard {i}'s receipt says {}: run shard {i} again",
                    shown(&path),
                    m.len(),
                    p.bytes
                ),
                Err(_) => bail!(
                    "{}: missing, listed by shard {i}'s receipt: run shard {i} again",
                    shown(&path)
                ),
            }
            listed.insert(p.name.clone());
            parts += 1;
            points += p.points;
        }
    }
    if !missing.is_empty() {
        let names: Vec<String> = missing.iter().take(20).map(|i| i.to_string()).collect();
        bail!(
            "{}: {} of {} shards have no receipt (not run or not finished): shard(s) {}{}",
            shown(dir),
            missing.len(),
            cp.shards.len(),
            names.join(", "),
            if missing.len() > 20 { ", …" } else { "" }
        );
    }
    // Parts of no receipt (a shard's leftovers from another plan) would be
    // indexed too.
    for e in std::fs::read_dir(dir)?.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if n.starts_with("part-") && n.ends_with(".tif") && !listed.contains(&n) {
            bail!(
                "{}: a part no receipt lists (left from another plan?): remove it",
                shown(&e.path())
            );
        }
    }
    Ok(Some(Checked {
        shards: cp.shards.len(),
        parts,
        points,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A shard killed after its conversion made its own staging directory but
    /// before it took the locked one leaves `..shard-I.tmp-*.pcimg-out-PID`:
    /// the next shard removes it, and leaves a live process's alone.
    #[test]
    fn leftovers_include_a_shards_unlocked_conversion_staging() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let me = std::process::id();
        let killed = d.join(format!("..shard-00000.tmp-{dead}-7.pcimg-out-{dead}"));
        let live = d.join(format!("..shard-00001.tmp-{me}-7.pcimg-out-{me}"));
        std::fs::create_dir(&killed).unwrap();
        std::fs::create_dir(&live).unwrap();
        assert_eq!(remove_leftovers(d), vec![killed.clone()]);
        assert!(!killed.exists() && live.exists());
    }

    #[test]
    fn balance_gives_contiguous_cover() {
        let r = |p| Region {
            lo: [0; 3],
            hi: [1; 3],
            points: p,
        };
        let regions: Vec<Region> = [10, 10, 10, 10, 40, 5, 5, 10].map(r).to_vec();
        for n in 1..=8 {
            let b = balance(&regions, n);
            assert_eq!(b.len(), n);
            assert_eq!(b[0][0], 0);
            assert_eq!(b[n - 1][1], 8);
            for w in b.windows(2) {
                assert_eq!(w[0][1], w[1][0]);
            }
            assert!(b.iter().all(|s| s[1] > s[0]), "{n}: {b:?}");
        }
        let b = balance(&regions, 2);
        assert_eq!(b, vec![[0, 4], [4, 8]]);
    }

    #[test]
    fn shard_index_from_flag_and_environment() {
        let none = |_: &str| None;
        assert_eq!(shard_index(Some("3/8"), 8, &none).unwrap(), 3);
        assert!(shard_index(Some("8/8"), 8, &none).is_err());
        assert!(shard_index(Some("1/4"), 8, &none).is_err());
        assert!(shard_index(None, 8, &none).is_err());
        let slurm = |k: &str| (k == "SLURM_ARRAY_TASK_ID").then(|| "5".to_string());
        assert_eq!(shard_index(Some("8"), 8, &slurm).unwrap(), 5);
        let k8s = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "0".to_string());
        assert_eq!(shard_index(None, 8, &k8s).unwrap(), 0);
        let bad = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "x".to_string());
        assert!(shard_index(None, 8, &bad).is_err());
    }
}
