//! One conversion's shared state, which every stage writes its parts through: the
//! input opened with the budget's window size, the staging directory and the
//! parts' names, writing a part (precision checks, errors naming the public
//! path), the phases' timings, and publishing the parts at the end.

use super::{
    Collect, ConvertOptions, ConvertSummary, F32_MM_RADIUS, Outcome, Progress, Result, Retry,
    Timings, budget, check_cancel, check_precision, f32_rounding, output, output_is_file, reach,
    source_name, spill,
};
use crate::clock::{Span, Stamp};
use crate::ingest::{self, PointReader, ReadOptions, SourceInfo};
use crate::points::{Bounds, PointColumns};
use crate::store::{self, PartSummary, WriteOptions};
use std::cell::Cell;
use std::path::PathBuf;
use std::time::Instant;

/// Inputs of at most this many points (as their headers declare) are written
/// with [`store::ZSTD_SMALL`]: 6.7 % smaller on `autzen_trim` (110,000
/// points, 0.10 → 0.12 s). Above it the default level keeps conversion fast
/// (level 6 took 1.3–1.6× the time on 47.7 M points; history 48).
const SMALL_INPUT: u64 = 2_000_000;

/// The start of a pass: the clock and the time spent writing parts so far
/// ([`Job::begin`]).
pub(super) type PassStart = (Stamp, Span);

/// A conversion under way (see the module's summary).
pub(super) struct Job<'a> {
    pub(super) inputs: &'a [PathBuf],
    pub(super) o: &'a ConvertOptions,
    pub(super) progress: &'a dyn Progress,
    /// The input's description (its first file's format, the files' bytes...).
    pub(super) info: SourceInfo,
    /// How the input is read: the options given, windows a share of the budget.
    pub(super) read: ReadOptions,
    /// Points one part holds at most.
    pub(super) per_part: u64,
    /// The widest a part may spread on each axis (`super::max_extent`).
    pub(super) max_extent: [f64; 3],
    /// The output is one `.tif` file, not a directory of parts.
    pub(super) as_file: bool,
    /// The parts written so far.
    pub(super) parts: Vec<PartSummary>,
    /// Whether attribute values were noted to lose precision on a common offset.
    pub(super) rebased: Cell<bool>,
    /// The single part of a conversion gives the allocator's pool back before its
    /// tiles: nothing after it would reuse that memory.
    pub(super) last_part: bool,
    /// What errors about the points as a whole name: the input.
    about: String,
    write_opts: WriteOptions,
    /// Parts go into a temporary directory renamed into place at the end (for a
    /// single-file output the store's own temporary file does this).
    staging: Option<spill::TempDir>,
    /// Parts are named `<part_prefix><k:05>.tif` (`part-`; a cluster shard's own).
    part_prefix: String,
    timings: Timings,
    /// Time spent writing parts so far (passes report their time less this).
    written: Span,
    start: Instant,
}

impl<'a> Job<'a> {
    /// Checks the output against the inputs, opens the input with windows of a
    /// share of the budget, and makes the staging directory. `collect` is the
    /// first pass's mode (the first attempt notes a budget below the smallest kept).
    pub(super) fn open(
        inputs: &'a [PathBuf],
        o: &'a ConvertOptions,
        progress: &'a dyn Progress,
        collect: Collect,
    ) -> Result<(Job<'a>, Box<dyn PointReader>)> {
        let start = Instant::now();
        let as_file = output_is_file(&o.output);
        for input in inputs {
            output::check(input, &o.output, as_file, o.force)?;
        }
        let mut read = o.read.clone();
        let opened = ingest::multi::open_all(inputs, &read)?;
        let info = opened.info().clone();
        let shares = budget::Budget::new(o.memory);
        let per_part = shares.points_per_part(info.attribute_names.len());
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
        // Freed large buffers are kept for the next ones (a part's sort keys reuse
        // the input columns' pages, the next part reuses this one's), within a
        // share of the budget.
        crate::alloc::set_pool_limit(shares.pool_limit());
        // Reader windows are a small share of the budget.
        read.chunk_points = read
            .chunk_points
            .min(shares.window_points(per_part) as usize);
        drop(opened);
        let reader = ingest::multi::open_all(inputs, &read)?;
        let about = match inputs {
            [one] => one.display().to_string(),
            _ => source_name(inputs).unwrap_or_default(),
        };
        let write_opts = WriteOptions {
            compression: o.compression,
            coord_max_error: coord_max_error(o.max_error, info.coordinate_step),
            lattice: match o.precision {
                Some(p) => Some(pcimg_core::points::Lattice {
                    step: [p; 3],
                    origin: [0.0; 3],
                }),
                None => info.coordinate_lattice,
            },
            lattice_round: o.precision.is_some(),
            layout: o.layout,
            source: source_name(inputs),
            crs: info.crs_wkt.clone(),
            from_source: info.metadata.clone(),
            force_bigtiff: false,
            cancel: Some(o.cancel.clone()),
            io: o.io,
            release_pool: false,
            // A dataset of many parts: small parts carry their levels down to
            // a quarter tile, the overview above them holding less. (A single
            // part has no overview: the levels would only add to it.)
            shallow_coarsest: !as_file && info.declared_points.is_none_or(|n| n > per_part),
            // A small input converts in a fraction of a second at any level:
            // Zstd's slower, tighter one there (see `SMALL_INPUT`).
            zstd_level: o.zstd_level.or_else(|| {
                info.declared_points
                    .is_some_and(|n| n <= SMALL_INPUT)
                    .then_some(store::ZSTD_SMALL)
            }),
        };
        progress.phase("read", info.file_bytes, "bytes");
        let staging = if as_file {
            None
        } else {
            Some(spill::TempDir::beside(&o.output, "pcimg-out")?)
        };
        let job = Job {
            inputs,
            o,
            progress,
            info,
            read,
            per_part,
            max_extent: super::max_extent(&write_opts),
            as_file,
            parts: Vec::new(),
            rebased: Cell::new(false),
            last_part: false,
            about,
            write_opts,
            staging,
            part_prefix: "part-".into(),
            timings: Timings::default(),
            written: Span::default(),
            start,
        };
        Ok((job, reader))
    }

    /// Where part `k` is written.
    pub(super) fn part_path(&self, k: usize) -> PathBuf {
        match &self.staging {
            Some(d) => d.path.join(format!("{}{k:05}.tif", self.part_prefix)),
            None => self.o.output.clone(),
        }
    }

    /// Writes the parts into `dir` (replacing the staging directory), named
    /// `<prefix><k:05>.tif`: a cluster shard publishes them itself.
    pub(super) fn stage_in(&mut self, dir: spill::TempDir, prefix: &str) {
        self.staging = Some(dir);
        self.part_prefix = prefix.to_string();
    }

    /// The staging directory, if any.
    pub(super) fn staging(&self) -> Option<&std::path::Path> {
        self.staging.as_ref().map(|d| d.path.as_path())
    }

    /// Where the next part is written.
    pub(super) fn next_path(&self) -> PathBuf {
        self.part_path(self.parts.len())
    }

    /// A store error naming the part where the user will look for it: the staging
    /// directory is gone by the time the message is read.
    pub(super) fn public(&self, mut e: store::StoreError) -> anyhow::Error {
        if let Some(rel) = self
            .staging
            .as_ref()
            .and_then(|d| e.path.strip_prefix(&d.path).ok())
        {
            e.path = self.o.output.join(rel);
        }
        e.into()
    }

    fn opts_now(&self) -> WriteOptions {
        WriteOptions {
            release_pool: self.last_part,
            ..self.write_opts.clone()
        }
    }

    /// Notes a written part: its timings and a progress line; hands it to the
    /// part hook (an upload) at once.
    fn record(&mut self, s: PartSummary) -> Result<()> {
        let after = match &self.o.on_part {
            Some(hook) => (hook.0)(&s.path)?,
            None => String::new(),
        };
        for (name, d) in &s.phases {
            self.timings.add(&format!("write: {name}"), *d);
            self.written = self.written + *d;
        }
        self.progress.note(&format!(
            "part {} written: {} points, {}{after}",
            self.parts.len() + 1,
            crate::text::count(s.points),
            crate::text::bytes(s.bytes)
        ));
        self.parts.push(s);
        Ok(())
    }

    /// Writes a part from consecutive chunks of points, whose bounds the caller
    /// has. It takes the chunks, so their coordinates are freed as soon as the
    /// store has read them.
    pub(super) fn write_chunks(
        &mut self,
        chunks: Vec<PointColumns>,
        bounds: &Bounds,
    ) -> Result<()> {
        check_cancel(self.o)?;
        let k = self.parts.len();
        check_precision(
            &self.about,
            bounds,
            bounds.center(),
            k,
            self.o,
            self.as_file,
        )?;
        let s =
            store::write_part_owned(&self.part_path(k), chunks, Some(*bounds), &self.opts_now())
                .map_err(|e| self.public(e))?;
        self.record(s)
    }

    /// Writes one set of columns as a part.
    pub(super) fn write(&mut self, pts: PointColumns) -> Result<()> {
        let bounds = pts.bounds();
        self.write_chunks(vec![pts], &bounds)
    }

    /// Writes a single part collected while it was read: its origin was chosen
    /// before the points' bounds were known, so a better one can be had by
    /// reading again ([`Retry::OriginTooFar`], nothing written); else as
    /// [`Job::write_built`].
    pub(super) fn write_collected(&mut self, b: store::PartBuilder) -> Result<Outcome<()>> {
        check_cancel(self.o)?;
        let (bounds, origin) = (b.bounds(), b.origin());
        let (here, best) = (reach(&bounds, origin), reach(&bounds, bounds.center()));
        let costly = f32_rounding(here) >= 1e-4 && f32_rounding(here) > 4.0 * f32_rounding(best);
        if (here >= F32_MM_RADIUS && best < F32_MM_RADIUS) || costly {
            return Ok(Outcome::Retry(Retry::OriginTooFar));
        }
        self.write_built(b)?;
        Ok(Outcome::Done(()))
    }

    /// Writes a part collected by a store builder (its own origin and bounds;
    /// a spatial region's origin is already placed from its own points, and
    /// reading again would place it the same way).
    pub(super) fn write_built(&mut self, b: store::PartBuilder) -> Result<()> {
        check_cancel(self.o)?;
        let (bounds, origin) = (b.bounds(), b.origin());
        let k = self.parts.len();
        check_precision(&self.about, &bounds, origin, k, self.o, self.as_file)?;
        let s = store::write_part_built(&self.part_path(k), b, &self.opts_now())
            .map_err(|e| self.public(e))?;
        self.record(s)
    }

    /// The builder of a part collected while reading, around the centre of the
    /// bounds the input declares (LAS) or else of its first window (`here`).
    pub(super) fn new_part(&self, here: Bounds) -> store::PartBuilder {
        let centre = self.info.declared_bounds.unwrap_or(here).center();
        let expect = self.info.declared_points.unwrap_or(0).min(self.per_part);
        store::PartBuilder::new(centre, None, expect as usize)
    }

    /// A pass starts with the clock and the write time so far ...
    pub(super) fn begin(&self) -> PassStart {
        (Stamp::now(), self.written)
    }

    /// ... and its time is the wall time since, less the parts written meanwhile.
    pub(super) fn pass(&mut self, name: &str, (since, before): PassStart) {
        let writes = self.written.saturating_sub(before);
        self.timings
            .add(name, since.elapsed().saturating_sub(writes));
    }

    /// Lists a phase with no time yet (so it comes first among the phases).
    pub(super) fn list_phase(&mut self, name: &str) {
        self.timings.add(name, Span::default());
    }

    /// The error of an output that needs more than one part but is one file.
    pub(super) fn too_many_parts(&self) -> anyhow::Error {
        anyhow::anyhow!(super::too_many_parts(
            &self.o.output,
            self.per_part,
            self.o.memory
        ))
    }

    /// Publishes the parts (a staging directory is moved into place) and sums the
    /// conversion up: `total` points were written; `reader` is the last one that
    /// read the input (its skipped lines and clamped colours).
    pub(super) fn finish(mut self, total: u64, reader: &dyn PointReader) -> Result<ConvertSummary> {
        let inputs = self.inputs;
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
        if let Some(stage) = &self.staging {
            let t_index = self.begin();
            let io = store::dataset::overview::IndexOptions {
                compression: Some(self.o.compression),
                cancel: Some(self.o.cancel.clone()),
                // (The parts' buffers are free by now: the whole budget.)
                memory: Some(self.o.memory),
                refuse_over_memory: false,
            };
            let progress = self.progress;
            progress.phase("overview", self.parts.len() as u64 / 3 + 1, "nodes");
            let done = |d: usize| progress.advance(d as u64, 0);
            let built = store::dataset::overview::build_index(&stage.path, &io, &done);
            index = Some(built.map_err(|e| self.public(e))?);
            self.pass("index and overview", t_index);
        }
        let output = &self.o.output;
        let t_publish = self.begin();
        if let Some(stage) = &self.staging {
            if output.exists() {
                if output.is_dir() {
                    std::fs::remove_dir_all(output)?;
                } else {
                    std::fs::remove_file(output)?;
                }
            }
            std::fs::rename(&stage.path, output)?;
            for p in &mut self.parts {
                if let Some(name) = p.path.file_name() {
                    p.path = output.join(name);
                }
            }
        }
        self.pass("publish", t_publish);
        let worst = self
            .parts
            .iter()
            .map(|p| p.max_quantization_error)
            .fold(0.0, f64::max);
        Ok(ConvertSummary {
            inputs: inputs.to_vec(),
            output: output.clone(),
            format: self.info.format.clone(),
            input_bytes: self.info.file_bytes,
            points: total,
            skipped: reader.skipped(),
            left_out: reader.left_out(),
            notes: self.info.notes.clone(),
            clamped_colours: reader.clamped_colours(),
            parts: std::mem::take(&mut self.parts),
            points_per_part: self.per_part,
            elapsed: self.start.elapsed(),
            max_quantization_error: worst,
            lattice: self
                .write_opts
                .lattice_extent()
                .and(self.write_opts.lattice),
            crs: self.info.crs_wkt.clone(),
            phases: std::mem::take(&mut self.timings.0),
            index,
            compression: self.write_opts.compression,
            zstd_level: (self.write_opts.compression == store::Compression::Zstd)
                .then(|| self.write_opts.zstd_level_used()),
        })
    }
}

/// The LERC codecs' error bound of each coordinate: the one asked for, else
/// half the input's lattice step (the coordinates come back on the lattice),
/// else 0 (lossless).
pub(crate) fn coord_max_error(asked: Option<f64>, step: Option<[f64; 3]>) -> [f64; 3] {
    match (asked, step) {
        (Some(e), _) => [e; 3],
        (None, Some(s)) if s.iter().all(|v| v.is_finite() && *v > 0.0) => s.map(|v| v / 2.0),
        _ => [0.0; 3],
    }
}
