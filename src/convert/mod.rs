//! The conversion pipeline (the paper's storage phase, out of core): input readers
//! deliver windows of points; the memory budget decides how many points make one
//! image; spatial partitioning (default) or the paper's single stream pass groups
//! them into parts, each written through the image store. This module holds the
//! options, the summary and the retries; the stages are `scan` (pass 1), `plan`
//! (the spatial [`Plan`]), `distribute` (pass 2) and `write` (pass 3, or the
//! single part), sharing one conversion's state through `job::Job`.

pub mod budget;
pub mod cluster;
mod distribute;
mod job;
pub mod output;
pub mod partition;
mod plan;
mod sample;
mod scan;
pub mod spill;
pub mod upload;
mod write;

use job::Job;
use plan::Placer;
pub use plan::Plan;
pub use sample::DEFAULT_SAMPLE_POINTS;
use scan::Scanned;

use crate::clock::Span;
use crate::ingest::{self, ReadOptions};
use crate::points::{Bounds, PointColumns};
use crate::store::{self, Compression, Layout, PartSummary};
use crate::time;
use rayon::prelude::*;
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

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
    /// Zstd's level for `zstd` tiles (`--zstd-level`). `None`: by the input's
    /// size, level 6 for inputs that declare at most 2 M points, else 1.
    pub zstd_level: Option<i32>,
    /// The LERC codecs: the largest error allowed in a coordinate, in source
    /// units. `None`: half the input's coordinate step where it has one (LAS
    /// scale factors: the coordinates come back on their lattice), else
    /// lossless.
    pub max_error: Option<f64>,
    /// `--precision`: keep coordinates as whole multiples of this step, each
    /// rounded to the nearest (the lossless predictor codecs), instead of the
    /// lattice the input has (a LAS file's scale, a text file's decimals).
    pub precision: Option<f64>,
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
    /// Called with each part's path as soon as it is written (complete, under
    /// its final name in the staging directory): an upload to object storage.
    pub on_part: Option<PartHook>,
}

/// What is done with each part as soon as it is written ([`ConvertOptions::on_part`]):
/// text to add to the part's progress line, or an error that stops the conversion.
#[derive(Clone)]
pub struct PartHook(pub Arc<PartFn>);

/// The function a [`PartHook`] calls with a written part's path.
pub type PartFn = dyn Fn(&Path) -> anyhow::Result<String> + Send + Sync + std::panic::RefUnwindSafe;

impl std::fmt::Debug for PartHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PartHook")
    }
}

/// Receives progress; the command line draws bars from it.
pub trait Progress: Sync {
    /// A new phase over `total` units (`bytes` or `points`).
    fn phase(&self, name: &str, total: u64, unit: &'static str);
    /// Units done so far in the phase, and points seen.
    fn advance(&self, done: u64, points: u64);
    /// A line of information.
    fn note(&self, msg: &str);
    /// A line that says what was removed or left behind: shown even where
    /// routine notes are not (`convert -q`).
    fn notice(&self, msg: &str) {
        self.note(msg)
    }
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
    /// Points the input marks as holding no measurement (PCD NaN slots, E57
    /// invalid states), left out.
    pub left_out: u64,
    /// What the reader left aside (embedded images, fields too wide to be bands).
    pub notes: Vec<String>,
    /// Colour values beyond the colour scale decided on the input's first points,
    /// clamped to 0–255.
    pub clamped_colours: u64,
    pub parts: Vec<PartSummary>,
    pub points_per_part: u64,
    pub elapsed: Duration,
    pub max_quantization_error: f64,
    /// The input's coordinate reference system (WKT or `EPSG:n`), if it names one.
    pub crs: Option<String>,
    /// Wall and CPU time per phase, in first-seen order: the passes over the
    /// input, then the store's phases summed over parts.
    pub phases: Vec<(String, Span)>,
    /// The index and overview of a directory output.
    pub index: Option<store::dataset::overview::IndexReport>,
    /// How the tiles were compressed, and Zstd's level where that is Zstd
    /// (`None` for the other codecs).
    pub compression: store::Compression,
    pub zstd_level: Option<i32>,
    /// The lattice the parts were to keep their coordinates on (the input's, or
    /// `--precision`'s), where the codec keeps one; each part says whether it
    /// did (`PartSummary::lattice`).
    pub lattice: Option<crate::points::Lattice>,
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

/// The widest a part may spread on each axis: [`MAX_EXTENT`], or less where the
/// codec keeps coordinates on the input's lattice and its steps are finer than
/// 4 mm (`WriteOptions::lattice_extent`: a 1 mm LAS file's parts at most
/// 16.8 km wide, so that they keep its coordinates exactly).
fn max_extent(opts: &store::WriteOptions) -> [f64; 3] {
    let mut e = [MAX_EXTENT; 3];
    if let Some(l) = opts.lattice_extent() {
        for a in 0..3 {
            e[a] = e[a].min(l[a]);
        }
    }
    e
}

/// Whether points within `b` spread too wide for one part (see [`max_extent`]).
fn too_wide(b: &Bounds, max_extent: [f64; 3]) -> bool {
    !b.is_empty() && (0..3).any(|a| b.extent()[a] >= max_extent[a])
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
    resplit_time(chunk, like);
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

/// Brings `gps_time` to the offset of `like`'s where `chunk` has the bands
/// that make it exact (`pcimg_core::time`): each time is joined and split
/// again around the new offset (shifting the Float32 would leave the whole
/// numbers pointing at other times).
fn resplit_time(chunk: &mut PointColumns, like: &PointColumns) {
    let find = |c: &PointColumns, name: &str| c.attributes.iter().position(|a| a.name == name);
    let (Some(t), Some(r)) = (find(chunk, time::TIME_BAND), find(like, time::TIME_BAND)) else {
        return;
    };
    let [lo, mid, hi] = time::EXACT_BANDS.map(|b| find(chunk, b));
    let (Some(lo), Some(mid), Some(hi)) = (lo, mid, hi) else {
        return;
    };
    let (from, to) = (chunk.attributes[t].offset, like.attributes[r].offset);
    if from == to {
        return;
    }
    let a = &mut chunk.attributes;
    let parts: Vec<[f32; 4]> = (0..a[t].values.len())
        .into_par_iter()
        .map(|i| {
            let v = [t, lo, mid, hi].map(|k| a[k].values[i]);
            time::split(time::join(from, v[0], v[1], v[2], v[3]), to)
        })
        .collect();
    for (j, k) in [t, lo, mid, hi].into_iter().enumerate() {
        a[k].values
            .iter_mut()
            .zip(&parts)
            .for_each(|(v, p)| *v = p[j]);
    }
    a[t].offset = to;
}

/// What an attempt at a conversion (or one of its stages) came to: done, or to
/// be started over in the next [`Collect`] mode, for a [`Retry`] reason. The
/// callers match it; no error is inspected for its type.
#[must_use]
enum Outcome<T> {
    Done(T),
    Retry(Retry),
}

/// Why an attempt starts over ([`Outcome::Retry`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Retry {
    /// The first pass read only the points' extents ([`Collect::Extents`]) but
    /// the points must be read whole: they spread wider than f32 keeps 1 mm
    /// across, so they are partitioned from a sample of them. The conversion
    /// starts over.
    NeedColumns,
    /// The part collected while reading, around the centre of the input's
    /// declared bounds or of its first window, reaches farther from it than f32
    /// keeps 1 mm, though not from its own centre; or loses 0.1 mm or more
    /// there, over 4 times what its own centre would (a wrong header): the
    /// conversion starts over, holding the points as read until their bounds
    /// are known.
    OriginTooFar,
}

impl Retry {
    /// The mode an attempt in mode `from` starts over in, if any is left.
    fn next(self, from: Collect) -> Option<Collect> {
        match self {
            Retry::NeedColumns if from == Collect::Extents => Some(Collect::Early),
            Retry::OriginTooFar if from != Collect::Held => Some(Collect::Held),
            _ => None,
        }
    }

    /// What the user is told when the conversion starts over.
    fn note(self) -> &'static str {
        match self {
            Retry::NeedColumns => {
                "the points spread wider than f32 keeps 1 mm across: reading the input \
                 again to partition them"
            }
            Retry::OriginTooFar => {
                "the points lie too far from the centre of the header's bounds or of the \
                 first window for f32 to keep their precision: reading the input again \
                 around their own centre"
            }
        }
    }
}

impl std::fmt::Display for Retry {
    /// The error of a retry no mode is left for.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Retry::NeedColumns => "the points must be read whole to be partitioned",
            Retry::OriginTooFar => "the points reach too far from the origin chosen while reading",
        })
    }
}

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
    // One run at a time on an output; what killed runs left goes first.
    let _lock = output::lock(&o.output)?;
    for gone in output::remove_leftovers(&o.output) {
        progress.notice(&format!(
            "removed {}, left by a run that was stopped",
            crate::text::sanitize(&gone.display().to_string())
        ));
    }
    // Extents, then Early where the points must be read whole, then Held where
    // the origin chosen while reading proved too far.
    let mut collect = Collect::Extents;
    let r = loop {
        match convert_with(inputs, o, progress, collect) {
            Ok(Outcome::Done(s)) => break Ok(s),
            Ok(Outcome::Retry(why)) => match why.next(collect) {
                Some(next) => {
                    progress.note(why.note());
                    collect = next;
                }
                None => break Err(anyhow::anyhow!("{why}")),
            },
            Err(e) => break Err(e),
        }
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
/// the next when it cannot finish: [`Retry`]).
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

/// [`convert`], the first pass collecting a single part as `collect` says:
/// scan, then write the single part; or, for several spatial parts, scan → plan
/// → distribute → write. A [`Retry`] leaves nothing written.
fn convert_with(
    inputs: &[PathBuf],
    o: &ConvertOptions,
    progress: &dyn Progress,
    collect: Collect,
) -> Result<Outcome<ConvertSummary>> {
    let (mut job, mut reader) = Job::open(inputs, o, progress, collect)?;
    let t_read = job.begin();
    let written = match o.partition {
        Partition::Stream => Outcome::Done(scan::stream(&mut job, &mut *reader, t_read)?),
        Partition::Spatial
            if collect == Collect::Extents
                && o.layout != Layout::Paper
                && job.info.declared_points.is_some_and(|n| n <= job.per_part)
                && reader.gives_extents()? =>
        {
            match scan::extents(&mut job, &mut *reader, t_read)? {
                Outcome::Done(one) => write::one_part(&mut job, one)?,
                Outcome::Retry(why) => Outcome::Retry(why),
            }
        }
        Partition::Spatial => {
            match scan::scan(&mut job, &mut *reader, collect != Collect::Held, t_read)? {
                Scanned::One(one) => write::one_part(&mut job, one)?,
                Scanned::Many(over) => Outcome::Done(spatial_parts(&mut job, &mut reader, over)?),
            }
        }
    };
    Ok(match written {
        Outcome::Done(total) => Outcome::Done(job.finish(total, &*reader)?),
        Outcome::Retry(why) => Outcome::Retry(why),
    })
}

/// Several spatial parts from what the scan found: the plan, pass 2's
/// distribution into one temporary file per region (stored relative to the
/// centre of the region's occupied cells), then pass 3 writing the parts.
/// Returns the points written.
fn spatial_parts(
    job: &mut Job,
    reader: &mut Box<dyn ingest::PointReader>,
    over: scan::Overflow,
) -> Result<u64> {
    if job.as_file {
        return Err(job.too_many_parts());
    }
    let placer = Placer::new(&over.sample, job.per_part, job.max_extent);
    let (mut plan, cells) = Plan::new(job, &placer, &over);
    job.progress.note(&format!(
        "{}{} points over {} spatial regions",
        if over.weight > 1 { "about " } else { "" },
        crate::text::count(over.points),
        plan.regions.len()
    ));
    let tmp = spill::TempDir::beside(&job.o.output, "pcimg-spill")?;
    let t_partition = job.begin();
    let files = distribute::regions(job, reader, &mut plan, cells, &placer, &tmp.path)?;
    job.pass("partition", t_partition);
    let total = files.iter().map(|f| f.points).sum();
    write::regions(job, &plan, files, total, &tmp.path)?;
    Ok(total)
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
/// Whether points within `b` reach half of `max_extent` or farther from `origin`
/// on some axis: farther than a part keeps them (see [`max_extent`]).
fn beyond(b: &Bounds, origin: [f64; 3], max_extent: [f64; 3]) -> bool {
    !b.is_empty()
        && (0..3).any(|a| {
            let r = (b.max[a] - origin[a])
                .abs()
                .max((b.min[a] - origin[a]).abs());
            r >= max_extent[a] / 2.0
        })
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::Attribute;

    /// Columns of GPS times `t` around `offset`, with the bands that make
    /// them exact.
    fn timed(t: &[f64], offset: f64) -> PointColumns {
        let parts: Vec<[f32; 4]> = t.iter().map(|&t| time::split(t, offset)).collect();
        let mut names = vec![time::TIME_BAND];
        names.extend(time::EXACT_BANDS);
        PointColumns {
            x: vec![0.0; t.len()],
            y: vec![0.0; t.len()],
            z: vec![0.0; t.len()],
            attributes: names
                .iter()
                .enumerate()
                .map(|(k, name)| Attribute {
                    name: name.to_string(),
                    offset: if k == 0 { offset } else { 0.0 },
                    values: parts.iter().map(|p| p[k]).collect(),
                })
                .collect(),
        }
    }

    #[test]
    fn files_brought_to_one_offset_keep_their_times_bit_for_bit() {
        // Week seconds of two flights an hour apart, and a time of 0.
        let t: Vec<f64> = (0..5000)
            .map(|i| 248_000.123_456_789 + i as f64 * 1.007_923_86e-5)
            .chain([0.0, 245_380.5])
            .collect();
        let mut chunk = timed(&t, 248_000.0);
        let like = timed(&[], 244_400.0);
        normalize(&mut chunk, &like, &Quiet, &Cell::new(false));
        let a = &chunk.attributes;
        assert_eq!(a[0].offset, 244_400.0);
        for (i, &t) in t.iter().enumerate() {
            let back = time::join(
                a[0].offset,
                a[0].values[i],
                a[1].values[i],
                a[2].values[i],
                a[3].values[i],
            );
            assert_eq!(back.to_bits(), t.to_bits(), "{t}");
        }
    }
}
