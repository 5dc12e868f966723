//! The conversion pipeline (the paper's storage phase, out of core): input readers
//! deliver windows of points; the memory budget decides how many points make one
//! image; spatial partitioning (default) or the paper's single stream pass groups
//! them into parts, each written through the image store.

pub mod budget;
mod distribute;
mod output;
pub mod partition;
mod sample;
pub mod spill;

use distribute::{Spilled, distribute, spill_all};
pub use sample::DEFAULT_SAMPLE_POINTS;
use sample::{MIN_SAMPLE, Sample};

use crate::clock::{Span, Stamp};
use crate::ingest::{self, ReadOptions};
use crate::points::{Bounds, PointColumns};
use crate::store::{self, Compression, Layout, PartSummary, WriteOptions};
use partition::CountGrid;
use rayon::prelude::*;
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How points are grouped into parts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Partition {
    /// Bounds and a count grid first, then non-overlapping spatial regions.
    #[default]
    Spatial,
    /// The paper's single pass: parts in file order.
    Stream,
}

/// Everything a conversion needs to know.
#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub output: PathBuf,
    pub force: bool,
    /// Resident memory budget in bytes.
    pub memory: u64,
    pub partition: Partition,
    pub compression: Compression,
    pub layout: Layout,
    pub read: ReadOptions,
    /// Accept parts where f32 cannot keep 1 mm.
    pub allow_lossy: bool,
    /// Set to stop the conversion (Ctrl-C); it then cleans up and fails.
    pub cancel: Arc<AtomicBool>,
    /// Spatial partitioning: once the input proves larger than one part, the rest
    /// of the first pass (which only places the regions) reads a sample of about
    /// this many points instead of every point ([`DEFAULT_SAMPLE_POINTS`]).
    pub sample_points: u64,
    /// How the parts' uncompressed tile data is written.
    pub io: store::TileIo,
}

/// Receives progress; the command line draws bars from it.
pub trait Progress: Sync {
    /// A new phase over `total` units (`bytes` or `points`).
    fn phase(&self, name: &str, total: u64, unit: &'static str);
    /// Units done so far in the phase, and points seen.
    fn advance(&self, done: u64, points: u64);
    /// A line of information.
    fn note(&self, msg: &str);
}

/// A sink that shows nothing.
pub struct Quiet;
impl Progress for Quiet {
    fn phase(&self, _: &str, _: u64, _: &'static str) {}
    fn advance(&self, _: u64, _: u64) {}
    fn note(&self, _: &str) {}
}

/// What a conversion did.
#[derive(Debug, Clone)]
pub struct ConvertSummary {
    /// The input files, in the order read.
    pub inputs: Vec<PathBuf>,
    pub output: PathBuf,
    pub format: String,
    pub input_bytes: u64,
    pub points: u64,
    pub skipped: u64,
    /// Colour values beyond the colour scale decided on the input's first points,
    /// clamped to 0–255.
    pub clamped_colours: u64,
    pub parts: Vec<PartSummary>,
    pub points_per_part: u64,
    pub elapsed: Duration,
    pub max_quantization_error: f64,
    /// Wall and CPU time per phase, in first-seen order: the passes over the
    /// input, then the store's phases summed over parts.
    pub phases: Vec<(String, Span)>,
    /// The index and overview of a directory output.
    pub index: Option<store::overview::IndexReport>,
}

/// Wall and CPU time per named phase, summed, in first-seen order.
#[derive(Default)]
struct Timings(Vec<(String, Span)>);

impl Timings {
    fn add(&mut self, name: &str, d: Span) {
        match self.0.iter_mut().find(|(n, _)| n == name) {
            Some((_, t)) => *t = *t + d,
            None => self.0.push((name.to_string(), d)),
        }
    }
}

impl ConvertSummary {
    pub fn bytes(&self) -> u64 {
        self.parts.iter().map(|p| p.bytes).sum()
    }
}

/// Errors say which file and what went wrong.
pub type Result<T> = anyhow::Result<T>;

/// f32 keeps 1 mm (coordinates in metres) below this distance from a part's
/// origin: under 2^15 an f32's spacing is at most 2^-9, so rounding moves a value
/// by at most 2^-10 ≈ 0.98 mm; from 2^15 on, by up to 1.95 mm.
pub const F32_MM_RADIUS: f64 = (1u64 << 15) as f64;

/// The widest a spatial part may spread on any axis: its points then lie within
/// [`F32_MM_RADIUS`] of their centre.
const MAX_EXTENT: f64 = 2.0 * F32_MM_RADIUS;

/// Whether points within `b` spread too wide for one part (see [`MAX_EXTENT`]).
fn too_wide(b: &Bounds) -> bool {
    !b.is_empty() && b.extent().iter().any(|&e| e >= MAX_EXTENT)
}

/// The largest rounding error of an f32 holding a value of magnitude `reach`
/// (half its spacing there).
fn f32_rounding(reach: f64) -> f64 {
    if reach < f32::MIN_POSITIVE as f64 {
        return 0.0;
    }
    2f64.powi(reach.log2().floor() as i32 - 24)
}

/// The error of a conversion stopped by [`ConvertOptions::cancel`].
const INTERRUPTED: &str = "interrupted: nothing was written";

fn check_cancel(o: &ConvertOptions) -> Result<()> {
    if o.cancel.load(Ordering::Relaxed) {
        anyhow::bail!(INTERRUPTED);
    }
    Ok(())
}

/// Where the dataset goes: one `.tif` file, or a directory of parts.
fn output_is_file(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "tif" | "tiff"))
}

/// Brings a chunk's attribute offsets to those of `like` (each input file decides
/// its own: see `ingest::attribute_offset`). Where the values then lie so far
/// from the common offset that f32 keeps only steps of a millisecond (GPS
/// seconds) or coarser, says so once through `progress` (`noted`).
fn normalize(
    chunk: &mut PointColumns,
    like: &PointColumns,
    progress: &dyn Progress,
    noted: &Cell<bool>,
) {
    for (a, r) in chunk.attributes.iter_mut().zip(&like.attributes) {
        if a.offset != r.offset {
            let shift = a.offset - r.offset;
            let far = a
                .values
                .par_iter_mut()
                .map(|v| {
                    *v = (*v as f64 + shift) as f32;
                    v.abs()
                })
                .reduce(|| 0.0, f32::max);
            a.offset = r.offset;
            let step = 2.0 * f32_rounding(far as f64);
            if step >= 1e-3 && !noted.replace(true) {
                progress.note(&format!(
                    "{}: the input files' values lie up to {} apart; stored as f32 around one \
                     offset they keep steps of {} (convert the files separately for finer)",
                    crate::text::sanitize(&a.name),
                    crate::text::count(far as u64),
                    step
                ));
            }
        }
    }
}

/// The part collected while reading, around the centre of the input's declared
/// bounds or of its first window, reaches farther from it than f32 keeps 1 mm,
/// though not from its own centre; or loses 0.1 mm or more there, over 4 times
/// what its own centre would (a wrong header): the conversion starts over, holding
/// the points as read until their bounds are known.
#[derive(Debug)]
struct OriginTooFar;

impl std::fmt::Display for OriginTooFar {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the points reach too far from the origin chosen while reading")
    }
}

impl std::error::Error for OriginTooFar {}

/// Converts one input file into a dataset.
pub fn convert(
    input: &Path,
    o: &ConvertOptions,
    progress: &dyn Progress,
) -> Result<ConvertSummary> {
    convert_files(&[input.to_path_buf()], o, progress)
}

/// Converts input files, read one after the other as one point cloud, into one
/// dataset (`ingest::multi`: they must carry the same attributes and CRS).
pub fn convert_files(
    inputs: &[PathBuf],
    o: &ConvertOptions,
    progress: &dyn Progress,
) -> Result<ConvertSummary> {
    if inputs.is_empty() {
        anyhow::bail!("no input files");
    }
    let o = &ConvertOptions {
        output: output::resolve(&o.output)?,
        ..o.clone()
    };
    let r = match convert_with(inputs, o, progress, Collect::Extents) {
        Err(e) if e.downcast_ref::<NeedColumns>().is_some() => {
            progress.note(
                "the points spread wider than f32 keeps 1 mm across: reading the input \
                 again to partition them",
            );
            convert_with(inputs, o, progress, Collect::Early)
        }
        r => r,
    };
    let r = match r {
        Err(e) if e.downcast_ref::<OriginTooFar>().is_some() => {
            progress.note(
                "the points lie too far from the centre of the header's bounds or of the \
                 first window for f32 to keep their precision: reading the input again \
                 around their own centre",
            );
            convert_with(inputs, o, progress, Collect::Held)
        }
        r => r,
    };
    // Whatever stopped a conversion that was asked to stop, it was the request.
    match r {
        Err(_) if o.cancel.load(Ordering::Relaxed) => anyhow::bail!(INTERRUPTED),
        r => r,
    }
}

/// The `SOURCE` of parts made from `inputs`: the file name, or the first and last
/// names and the count.
fn source_name(inputs: &[PathBuf]) -> Option<String> {
    let name = |p: &PathBuf| p.file_name().map(|n| n.to_string_lossy().into_owned());
    match inputs {
        [one] => name(one),
        [first, .., last] => Some(format!(
            "{} … {} ({} files)",
            name(first)?,
            name(last)?,
            inputs.len()
        )),
        [] => None,
    }
}

/// How the first pass collects a single part's points (each mode falls back to
/// the next when it cannot finish: [`NeedColumns`], [`OriginTooFar`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Collect {
    /// Where the reader gives every point's position and rows again (an
    /// uncompressed LAS file that fits one part): only each chunk's extent is
    /// read ([`ingest::PointReader::next_extent`]), no columns.
    Extents,
    /// The points are converted for the store as they arrive.
    Early,
    /// The chunks are held as read until their bounds are known.
    Held,
}

/// The first pass read only the points' extents ([`Collect::Extents`]) but the
/// points must be read whole: they spread wider than f32 keeps 1 mm across, so
/// they are partitioned from a sample of them. The conversion starts over.
#[derive(Debug)]
struct NeedColumns;

impl std::fmt::Display for NeedColumns {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the points must be read whole to be partitioned")
    }
}

impl std::error::Error for NeedColumns {}

/// [`convert`], the first pass collecting a single part as `collect` says.
fn convert_with(
    inputs: &[PathBuf],
    o: &ConvertOptions,
    progress: &dyn Progress,
    collect: Collect,
) -> Result<ConvertSummary> {
    let early = collect != Collect::Held;
    let start = Instant::now();
    let as_file = output_is_file(&o.output);
    for input in inputs {
        output::check(input, &o.output, as_file, o.force)?;
    }
    let mut read = o.read.clone();
    let opened = ingest::multi::open_all(inputs, &read)?;
    let info = opened.info().clone();
    let per_part = budget::points_per_part(o.memory, info.attribute_names.len());
    if o.memory < budget::MIN_KEPT && collect == Collect::Extents {
        progress.note(&format!(
            "--memory {} is below {}, the smallest budget a conversion keeps to: parts \
             still hold {} points, and the converter's fixed needs (about 90 MiB) exceed \
             the budget",
            crate::text::bytes(o.memory),
            crate::text::bytes(budget::MIN_KEPT),
            crate::text::count(per_part),
        ));
    }
    // Freed large buffers are kept for the next ones (a part's sort keys reuse the
    // input columns' pages, the next part reuses this one's), within a share of
    // the budget.
    crate::alloc::set_pool_limit((o.memory / 4).min(usize::MAX as u64) as usize);
    // Reader windows are a small share of the budget.
    read.chunk_points = read.chunk_points.min((per_part / 8).max(1 << 16) as usize);
    drop(opened);
    let mut reader = ingest::multi::open_all(inputs, &read)?;
    // What errors about the points as a whole name: the input.
    let about = match inputs {
        [one] => one.display().to_string(),
        _ => source_name(inputs).unwrap_or_default(),
    };
    let write_opts = WriteOptions {
        compression: o.compression,
        layout: o.layout,
        source: source_name(inputs),
        crs: info.crs_wkt.clone(),
        force_bigtiff: false,
        cancel: Some(o.cancel.clone()),
        io: o.io,
        release_pool: false,
    };
    // The single part of a conversion gives the allocator's pool back before its
    // tiles: nothing after it would reuse that memory.
    let last_part = Cell::new(false);
    let opts_now = || WriteOptions {
        release_pool: last_part.get(),
        ..write_opts.clone()
    };
    progress.phase("read", info.file_bytes, "bytes");

    // Parts go into a temporary directory renamed into place at the end (for a
    // single-file output the store's own temporary file does this).
    let staging = if as_file {
        None
    } else {
        Some(spill::TempDir::beside(&o.output, "pcimg-out")?)
    };
    let part_path = |k: usize| match &staging {
        Some(d) => d.path.join(format!("part-{k:05}.tif")),
        None => o.output.clone(),
    };
    // A store error names the part where the user will look for it: the staging
    // directory is gone by the time the message is read.
    let public = |mut e: store::StoreError| -> anyhow::Error {
        if let Some(rel) = staging
            .as_ref()
            .and_then(|d| e.path.strip_prefix(&d.path).ok())
        {
            e.path = o.output.join(rel);
        }
        e.into()
    };
    let mut parts: Vec<PartSummary> = Vec::new();
    let timings = std::cell::RefCell::new(Timings::default());
    // Time spent writing parts so far (passes report their time less this).
    let written = std::cell::Cell::new(Span::default());
    // Notes a written part: its timings and a progress line.
    let record = |s: PartSummary, parts: &mut Vec<PartSummary>| {
        for (name, d) in &s.phases {
            timings.borrow_mut().add(&format!("write: {name}"), *d);
            written.set(written.get() + *d);
        }
        progress.note(&format!(
            "part {} written: {} points, {}",
            parts.len() + 1,
            crate::text::count(s.points),
            crate::text::bytes(s.bytes)
        ));
        parts.push(s);
    };
    // A part from consecutive chunks of points, whose bounds the caller has.
    // It takes the chunks, so their coordinates are freed as soon as the store has
    // read them.
    let write_chunks = |chunks: Vec<PointColumns>,
                        bounds: &Bounds,
                        parts: &mut Vec<PartSummary>|
     -> Result<()> {
        check_cancel(o)?;
        check_precision(&about, bounds, bounds.center(), parts.len(), o, as_file)?;
        let s =
            store::write_part_owned(&part_path(parts.len()), chunks, Some(*bounds), &opts_now())
                .map_err(public)?;
        record(s, parts);
        Ok(())
    };
    // A part collected by a store builder (its own origin and bounds).
    // `while_reading`: the origin was chosen before the points' bounds were known
    // (a single part collected as it is read), so a better one can be had by
    // reading again ([`OriginTooFar`]); a spatial region's origin is already
    // placed from its own points, and reading again would place it the same way.
    let write_built = |b: store::PartBuilder,
                       while_reading: bool,
                       parts: &mut Vec<PartSummary>|
     -> Result<()> {
        check_cancel(o)?;
        let (bounds, origin) = (b.bounds(), b.origin());
        let (here, best) = (reach(&bounds, origin), reach(&bounds, bounds.center()));
        let costly = f32_rounding(here) >= 1e-4 && f32_rounding(here) > 4.0 * f32_rounding(best);
        if while_reading && ((here >= F32_MM_RADIUS && best < F32_MM_RADIUS) || costly) {
            return Err(OriginTooFar.into());
        }
        check_precision(&about, &bounds, origin, parts.len(), o, as_file)?;
        let s = store::write_part_built(&part_path(parts.len()), b, &opts_now()).map_err(public)?;
        record(s, parts);
        Ok(())
    };
    let write = |pts: PointColumns, parts: &mut Vec<PartSummary>| -> Result<()> {
        let bounds = pts.bounds();
        write_chunks(vec![pts], &bounds, parts)
    };

    // The builder of a part collected while reading, around the centre of the
    // bounds the input declares (LAS) or else of its first window (`here`).
    let new_part = |here: Bounds| {
        let centre = info.declared_bounds.unwrap_or(here).center();
        let expect = info.declared_points.unwrap_or(0).min(per_part);
        store::PartBuilder::new(centre, None, expect as usize)
    };
    let mut total = 0u64;
    // Whether attribute values were noted to lose precision on a common offset.
    let rebased = Cell::new(false);
    // A pass starts with the clock and the write time so far; its time is the
    // wall time since, less the parts written meanwhile.
    let begin = || (Stamp::now(), written.get());
    let pass = |name: &str, (since, before): (Stamp, Span)| {
        let writes = written.get().saturating_sub(before);
        timings
            .borrow_mut()
            .add(name, since.elapsed().saturating_sub(writes));
    };
    let t_read = begin();
    match o.partition {
        Partition::Stream => {
            // Parts are written while the input is read: the pass is listed first.
            timings.borrow_mut().add("read", Span::default());
            let mut acc: Option<PointColumns> = None;
            while let Some(mut chunk) = reader.next_chunk()? {
                check_cancel(o)?;
                total += chunk.len() as u64;
                progress.advance(reader.bytes_done(), total);
                let a = acc.get_or_insert_with(|| chunk.empty_like());
                normalize(&mut chunk, a, progress, &rebased);
                // Fill the current part up to the budget; the rest starts the next.
                // A full part is written once more points arrive (so an input of
                // exactly one part's size still fits a single-file output).
                let mut from = 0;
                while from < chunk.len() {
                    if a.len() as u64 >= per_part {
                        if as_file {
                            anyhow::bail!(too_many_parts(&o.output, per_part, o.memory));
                        }
                        let full = std::mem::replace(a, chunk.empty_like());
                        write(full, &mut parts)?;
                    }
                    let take = ((per_part as usize) - a.len()).min(chunk.len() - from);
                    a.append_range(&chunk, from, from + take);
                    from += take;
                }
            }
            pass("read", t_read);
            if let Some(a) = acc.filter(|a| !a.is_empty()) {
                write(a, &mut parts)?;
            }
        }
        Partition::Spatial
            if collect == Collect::Extents
                && o.layout != Layout::Paper
                && info.declared_points.is_some_and(|n| n <= per_part)
                && reader.gives_extents()? =>
        {
            // Pass 1 over the chunks' extents: the reader gives every point
            // again when the part is written, and the input holds no more
            // points than one part.
            let mut bounds = Bounds::EMPTY;
            let mut built: Option<store::PartBuilder> = None;
            while let Some(e) = reader.next_extent()? {
                check_cancel(o)?;
                total += e.len as u64;
                progress.advance(reader.bytes_done(), total);
                bounds = bounds.union(&e.bounds);
                let b = match built.as_mut() {
                    Some(b) => b,
                    None => {
                        let mut b = new_part(e.bounds);
                        let Some(rows) = reader.row_source() else {
                            return Err(NeedColumns.into());
                        };
                        b.rows_from(rows);
                        built.insert(b)
                    }
                };
                if (b.len() + e.len) as u64 > per_part {
                    return Err(NeedColumns.into());
                }
                b.push_extent(&part_path(0), &e).map_err(public)?;
            }
            pass("read", t_read);
            if !as_file && too_wide(&bounds) {
                return Err(NeedColumns.into());
            }
            let held_points = total;
            progress.phase("write", held_points, "points");
            last_part.set(true);
            if let Some(b) = built.filter(|b| !b.is_empty()) {
                write_built(b, true, &mut parts)?;
            }
            progress.advance(held_points, held_points);
        }
        Partition::Spatial => {
            // Pass 1: bounds and a sample; points kept while they fit one part.
            let mut bounds = Bounds::EMPTY;
            // The points so far while they fit one part: converted for the store
            // as they arrive (`early`), around the centre of the bounds the input
            // declares (LAS) or else of its first window, so each window is freed
            // at once and its memory reused for the next; or (when that origin
            // proved too far) the chunks as read, no copy.
            let mut held: Vec<PointColumns> = Vec::new();
            let mut built: Option<store::PartBuilder> = None;
            let mut held_points = 0u64;
            let mut overflow = false;
            let mut sample = Sample::new(1 << 21);
            let mut like: Option<PointColumns> = None;
            // Points each delivered point stands for: 1, or more once the reader
            // samples (then `total` is an estimate until pass 2 counts).
            let mut weight = 1u64;
            while let Some(mut chunk) = reader.next_chunk()? {
                check_cancel(o)?;
                total += chunk.len() as u64 * weight;
                progress.advance(reader.bytes_done(), total);
                let l = like.get_or_insert_with(|| chunk.empty_like());
                normalize(&mut chunk, l, progress, &rebased);
                let here = chunk.bounds();
                bounds = bounds.union(&here);
                // The sample is only needed once the points overflow one part.
                // Held chunks give it then (the same sample as taking it chunk by
                // chunk); converted ones are not kept as read, so with them it is
                // taken from the start.
                if overflow || early {
                    sample.add(&chunk, weight);
                }
                if overflow || chunk.is_empty() {
                    continue;
                }
                if held_points + chunk.len() as u64 <= per_part {
                    held_points += chunk.len() as u64;
                    if early {
                        let b = built.get_or_insert_with(|| {
                            let mut b = new_part(here);
                            // Attribute rows the reader can give again (LAS) are
                            // not copied: the tiles take them from the input.
                            if let Some(rows) = reader.row_source() {
                                b.rows_from(rows);
                            }
                            if o.layout == Layout::Paper {
                                b.hold_positions();
                            }
                            b
                        });
                        b.push(&part_path(0), &chunk).map_err(public)?;
                    } else {
                        held.push(chunk);
                    }
                } else {
                    overflow = true;
                    built = None;
                    for c in held.drain(..) {
                        sample.add(&c, 1);
                    }
                    if !early {
                        sample.add(&chunk, 1);
                    }
                    // More than one part: the rest of this pass only places the
                    // regions, and a sample of it does (pass 2 reads every point).
                    let read_bytes = reader.bytes_done().max(1);
                    let left = info.file_bytes.saturating_sub(read_bytes);
                    let rest = left as f64 * total as f64 / read_bytes as f64;
                    let wanted = o.sample_points.max(MIN_SAMPLE) as f64;
                    let every = (rest / wanted) as u64;
                    if every >= 2 && reader.sample_rest(every) {
                        weight = every;
                    }
                }
            }
            pass("read", t_read);
            // Points that fit one part but spread wider than f32 keeps 1 mm across
            // are partitioned all the same (into a directory of parts).
            if !overflow && !as_file && too_wide(&bounds) {
                overflow = true;
                built = None;
                for c in held.drain(..) {
                    sample.add(&c, 1);
                }
            }
            if !overflow {
                // One part: its sort and tiles are the last phase.
                progress.phase("write", held_points, "points");
                last_part.set(true);
                if let Some(b) = built.filter(|b| !b.is_empty()) {
                    write_built(b, true, &mut parts)?;
                } else if held_points > 0 {
                    write_chunks(held, &bounds, &mut parts)?;
                }
                progress.advance(held_points, held_points);
            } else {
                if as_file {
                    anyhow::bail!(too_many_parts(&o.output, per_part, o.memory));
                }
                let like = like.unwrap_or_default();
                // Regions from the sample (and `extra` points: see below), with
                // margin for its error, and the origin of each.
                let scale = sample.seen as f64 / sample.pts.len().max(1) as f64;
                let target = ((per_part as f64 * 0.85) / scale).max(1.0) as u64;
                let plan = |bounds: Bounds, occupied: &[bool]| {
                    let mut grid = CountGrid::new(bounds);
                    for p in &sample.pts {
                        grid.add(*p);
                    }
                    for (c, _) in grid.counts.iter_mut().zip(occupied).filter(|(_, o)| **o) {
                        *c = (*c).max(1);
                    }
                    let regions = partition::split(&grid, target, MAX_EXTENT);
                    let cell_region = partition::cell_regions(&grid, &regions);
                    let origins: Vec<[f64; 3]> = regions
                        .iter()
                        .map(|r| partition::occupied(&grid, *r).centre(&grid))
                        .collect();
                    (grid, regions, cell_region, origins)
                };
                let (mut grid, mut regions, mut cell_region, mut origins) = plan(bounds, &[]);
                let nattr = like.attributes.len();
                progress.note(&format!(
                    "{}{} points over {} spatial regions",
                    if weight > 1 { "about " } else { "" },
                    crate::text::count(total),
                    regions.len()
                ));
                // Pass 2: distribute points into one temporary file per region,
                // stored relative to the centre of the region's occupied cells.
                let tmp = spill::TempDir::beside(&o.output, "pcimg-spill")?;
                let t_partition = begin();
                let spill_with = |reader: &mut Box<dyn ingest::PointReader>,
                                  grid: &CountGrid,
                                  regions: &[partition::Region],
                                  cell_region: &[u32],
                                  origins: &[[f64; 3]]| {
                    distribute(
                        reader,
                        inputs,
                        &read,
                        o,
                        progress,
                        grid,
                        regions,
                        cell_region,
                        origins,
                        &like,
                        &tmp.path,
                        &rebased,
                    )
                };
                let mut files = spill_with(&mut reader, &grid, &regions, &cell_region, &origins)?;
                // Points far outside the bounds the sample saw join the nearest
                // region, which can then spread wider than f32 keeps 1 mm across
                // wherever its origin. The regions are then placed again over
                // every point's bounds, every grid cell that holds a point of
                // such a region counted as occupied (read back from its file:
                // its f32 offsets place points well enough for that), so the far
                // points get regions of their own.
                let wide = |f: &Spilled| reach(&f.bounds, f.bounds.center()) >= F32_MM_RADIUS;
                if files.iter().any(wide) {
                    progress.note(
                        "points lie far outside the bounds the sample saw: partitioning again",
                    );
                    let all = files.iter().fold(Bounds::EMPTY, |a, f| a.union(&f.bounds));
                    let probe = CountGrid::new(all);
                    let mut occupied = vec![false; probe.counts.len()];
                    for f in files.iter().filter(|f| wide(f)) {
                        let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
                        while let Some(c) = blocks.next_block(&like, 1 << 20, f.origin)? {
                            check_cancel(o)?;
                            for i in 0..c.len() {
                                occupied[probe.index(probe.cell([c.x[i], c.y[i], c.z[i]]))] = true;
                            }
                        }
                    }
                    (grid, regions, cell_region, origins) = plan(all, &occupied);
                    files = spill_with(&mut reader, &grid, &regions, &cell_region, &origins)?;
                }
                // Points the sample never saw can lie far outside their region's
                // box. Where f32 then lost 1 mm around the box's centre but would
                // not around the centre of the region's own bounds, the pass is
                // run again around those centres (the parts' own check then holds).
                let far = |f: &Spilled| {
                    reach(&f.bounds, f.origin) >= F32_MM_RADIUS
                        && reach(&f.bounds, f.bounds.center()) < F32_MM_RADIUS
                };
                if files.iter().any(far) {
                    progress.note("points lie far outside their regions: partitioning again");
                    for (origin, f) in origins.iter_mut().zip(&files) {
                        if !f.bounds.is_empty() {
                            *origin = f.bounds.center();
                        }
                    }
                    files = spill_with(&mut reader, &grid, &regions, &cell_region, &origins)?;
                }
                pass("partition", t_partition);
                total = files.iter().map(|f| f.points).sum();
                // Pass 3: each region becomes one part, streamed from its file into
                // a store builder around the region's origin. A region
                // the sample underestimated is first split again, exactly, by a
                // count grid over its own points; a grid cell that alone holds more
                // than a part (points denser than the grid resolves) becomes
                // parts in file order. Either way no part exceeds the budget.
                progress.phase("write", total, "points");
                let mut done = 0u64;
                let mut splits = 0usize;
                let names: Vec<(String, f64)> = like
                    .attributes
                    .iter()
                    .map(|a| (a.name.clone(), a.offset))
                    .collect();
                let mut stack: Vec<(Spilled, bool)> =
                    files.into_iter().rev().map(|f| (f, false)).collect();
                while let Some((f, split)) = stack.pop() {
                    check_cancel(o)?;
                    if f.points == 0 {
                        let _ = std::fs::remove_file(&f.path);
                        continue;
                    }
                    let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
                    // The file's origin, so the builder stores the f32 offsets
                    // the file holds, exactly.
                    let new_part = || {
                        let n = f.points.min(per_part) as usize;
                        store::PartBuilder::new(f.origin, None, n)
                    };
                    if f.points <= per_part {
                        let t_back = begin();
                        let mut b = new_part();
                        while let Some(r) = blocks.next_records(usize::MAX)? {
                            b.push_packed(&part_path(parts.len()), r, &names)
                                .map_err(public)?;
                        }
                        // The region's bounds, kept in f64 while spilling.
                        b.set_source_bounds(f.bounds);
                        drop(blocks);
                        let _ = std::fs::remove_file(&f.path);
                        pass("read back", t_back);
                        write_built(b, false, &mut parts)?;
                    } else if !split {
                        let t_split = begin();
                        let mut grid = CountGrid::new(f.bounds);
                        while let Some(c) = blocks.next_block(&like, usize::MAX, f.origin)? {
                            for i in 0..c.len() {
                                grid.add([c.x[i], c.y[i], c.z[i]]);
                            }
                        }
                        let subs = partition::split(&grid, per_part, MAX_EXTENT);
                        let map = partition::cell_regions(&grid, &subs);
                        drop(blocks);
                        let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
                        splits += 1;
                        let tag = format!("split{splits}");
                        // The pieces keep the region's origin (their offsets are
                        // then the same f32 values, not rounded again).
                        let origins = vec![f.origin; subs.len()];
                        let pieces =
                            spill_all(o, &grid, &subs, &map, &origins, &tmp.path, &tag, |sink| {
                                while let Some(c) =
                                    blocks.next_block(&like, usize::MAX, f.origin)?
                                {
                                    sink(c)?;
                                }
                                Ok(())
                            })?;
                        drop(blocks);
                        let _ = std::fs::remove_file(&f.path);
                        pass("split", t_split);
                        stack.extend(pieces.into_iter().rev().map(|p| (p, true)));
                        continue;
                    } else {
                        let mut b = new_part();
                        let room = |b: &store::PartBuilder| per_part as usize - b.len();
                        while let Some(r) = blocks.next_records(room(&b))? {
                            b.push_packed(&part_path(parts.len()), r, &names)
                                .map_err(public)?;
                            if room(&b) == 0 {
                                write_built(
                                    std::mem::replace(&mut b, new_part()),
                                    false,
                                    &mut parts,
                                )?;
                            }
                        }
                        drop(blocks);
                        let _ = std::fs::remove_file(&f.path);
                        if !b.is_empty() {
                            write_built(b, false, &mut parts)?;
                        }
                    }
                    done += f.points;
                    progress.advance(done, done);
                }
            }
        }
    }
    if total == 0 {
        match inputs {
            [one] => anyhow::bail!("{}: no points in the input", one.display()),
            _ => anyhow::bail!(
                "{} … {}: no points in the {} input files",
                inputs[0].display(),
                inputs[inputs.len() - 1].display(),
                inputs.len()
            ),
        }
    }
    // The index and overview, last: their presence marks a finished dataset.
    let mut index = None;
    if let Some(stage) = &staging {
        let t_index = begin();
        let io = store::overview::IndexOptions {
            compression: Some(o.compression),
            cancel: Some(o.cancel.clone()),
        };
        progress.phase("overview", parts.len() as u64 / 3 + 1, "nodes");
        let done = |d: usize, _: usize| progress.advance(d as u64, 0);
        index = Some(store::overview::build_index(&stage.path, &io, &done).map_err(public)?);
        pass("index and overview", t_index);
    }
    // Publish: move the staged parts into place.
    let t_publish = begin();
    if let Some(stage) = &staging {
        if o.output.exists() {
            if o.output.is_dir() {
                std::fs::remove_dir_all(&o.output)?;
            } else {
                std::fs::remove_file(&o.output)?;
            }
        }
        std::fs::rename(&stage.path, &o.output)?;
        let moved: Vec<PartSummary> = parts
            .into_iter()
            .map(|mut p| {
                if let Some(name) = p.path.file_name() {
                    p.path = o.output.join(name);
                }
                p
            })
            .collect();
        parts = moved;
    }
    pass("publish", t_publish);
    let phases = timings.into_inner().0;
    let worst = parts
        .iter()
        .map(|p| p.max_quantization_error)
        .fold(0.0, f64::max);
    Ok(ConvertSummary {
        inputs: inputs.to_vec(),
        output: o.output.clone(),
        format: info.format.clone(),
        input_bytes: info.file_bytes,
        points: total,
        skipped: reader.skipped(),
        clamped_colours: reader.clamped_colours(),
        parts,
        points_per_part: per_part,
        elapsed: start.elapsed(),
        max_quantization_error: worst,
        phases,
        index,
    })
}

fn too_many_parts(out: &Path, per_part: u64, memory: u64) -> String {
    format!(
        "{}: the input needs more than one part at --memory {} ({} points per part); \
         give a directory as output (e.g. -o {}/) or a larger --memory",
        out.display(),
        crate::text::bytes(memory),
        crate::text::count(per_part),
        out.with_extension("").display()
    )
}

/// How far the points inside `b` lie from `origin` at most, along any axis.
fn reach(b: &Bounds, origin: [f64; 3]) -> f64 {
    (0..3)
        .map(|a| {
            (b.max[a] - origin[a])
                .abs()
                .max((b.min[a] - origin[a]).abs())
        })
        .fold(0f64, f64::max)
}

/// Refuses a part whose points lie farther from its origin than f32 keeps 1 mm;
/// the message names `about`, the input.
fn check_precision(
    about: &str,
    b: &Bounds,
    origin: [f64; 3],
    part: usize,
    o: &ConvertOptions,
    as_file: bool,
) -> Result<()> {
    let reach = reach(b, origin);
    if reach >= F32_MM_RADIUS && !o.allow_lossy {
        // What would split the points into parts narrow enough.
        let instead = if as_file {
            ", or a directory output (-o NAME.pcimg): spatial parts are then kept narrow enough"
        } else if o.partition == Partition::Stream {
            ", or the default spatial partitioning: its parts are kept narrow enough"
        } else {
            ""
        };
        anyhow::bail!(
            "{}: part {} spans {:.1} km: stored as f32 relative to a point {:.1} km from its \
             farthest points, coordinates would move by up to {:.2} mm (f32 keeps 1 mm within \
             {:.1} km); use --allow-lossy to accept it{instead}",
            crate::text::sanitize(about),
            part + 1,
            b.extent().iter().fold(0f64, |m, &e| m.max(e)) / 1000.0,
            reach / 1000.0,
            f32_rounding(reach) * 1000.0,
            F32_MM_RADIUS / 1000.0
        );
    }
    Ok(())
}
