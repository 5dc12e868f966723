//! Pass 2 of spatial partitioning, distribution: every point appended to its
//! region's temporary file (`spill.rs`), by the plan's count grid cell, on a
//! writer thread of its own, the plan corrected where points the sample never
//! saw need it; also used to split a region the sample underestimated.

use super::job::Job;
use super::partition::{CountGrid, Region};
use super::plan::{Cells, Placer, Plan};
use super::{ConvertOptions, Result, beyond, check_cancel, normalize, spill};
use crate::ingest::{self, PointReader};
use crate::points::{Bounds, PointColumns};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// A temporary region file: its path, points, their bounds and the origin its
/// coordinates are relative to.
pub(super) struct Spilled {
    pub(super) path: PathBuf,
    pub(super) points: u64,
    pub(super) bounds: Bounds,
    pub(super) origin: [f64; 3],
}

/// Pass 2 of spatial partitioning, as the plan says: every point in its region's
/// file. Where points the sample never saw make that impossible, the plan is
/// corrected and the pass run again (see below). Returns each region's file.
pub(super) fn regions(
    job: &Job,
    reader: &mut Box<dyn PointReader>,
    plan: &mut Plan,
    cells: Cells,
    placer: &Placer,
    dir: &Path,
) -> Result<Vec<Spilled>> {
    let like = plan.like();
    let nattr = like.attributes.len();
    let mut cells = cells;
    let mut files = distribute(job, reader, plan, &cells, &like, dir)?;
    // Points far outside the bounds the sample saw join the nearest region,
    // which can then spread wider than a part keeps them (f32's 1 mm, or the
    // input's lattice: `super::max_extent`) wherever its origin. The regions are then placed again over every point's bounds,
    // every grid cell that holds a point of such a region counted as occupied
    // (read back from its file: its f32 offsets place points well enough for
    // that), so the far points get regions of their own.
    let wide = |f: &Spilled| beyond(&f.bounds, f.bounds.center(), job.max_extent);
    if files.iter().any(wide) {
        job.progress
            .note("points lie far outside the bounds the sample saw: partitioning again");
        let all = files.iter().fold(Bounds::EMPTY, |a, f| a.union(&f.bounds));
        let probe = CountGrid::new(all);
        let mut occupied = vec![false; probe.counts.len()];
        for f in files.iter().filter(|f| wide(f)) {
            let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
            while let Some(c) = blocks.next_block(&like, 1 << 20, f.origin)? {
                check_cancel(job.o)?;
                for i in 0..c.len() {
                    occupied[probe.index(probe.cell([c.x[i], c.y[i], c.z[i]]))] = true;
                }
            }
        }
        cells = plan.place_again(placer, all, &occupied);
        files = distribute(job, reader, plan, &cells, &like, dir)?;
    }
    // Points the sample never saw can lie far outside their region's box.
    // Where they then lie beyond a part's reach around the box's centre but
    // not around the centre of the region's own bounds, the pass is run again
    // around those centres (the parts' own check then holds).
    let far = |f: &Spilled| {
        beyond(&f.bounds, f.origin, job.max_extent)
            && !beyond(&f.bounds, f.bounds.center(), job.max_extent)
    };
    if files.iter().any(far) {
        job.progress
            .note("points lie far outside their regions: partitioning again");
        for (origin, f) in plan.origins.iter_mut().zip(&files) {
            if !f.bounds.is_empty() {
                *origin = f.bounds.center();
            }
        }
        files = distribute(job, reader, plan, &cells, &like, dir)?;
    }
    Ok(files)
}

/// Re-reads the input and appends every point to its region's temporary file.
/// Returns each region's file, point count and bounds.
fn distribute(
    job: &Job,
    reader: &mut Box<dyn PointReader>,
    plan: &Plan,
    cells: &Cells,
    like: &PointColumns,
    dir: &Path,
) -> Result<Vec<Spilled>> {
    let (o, progress) = (job.o, job.progress);
    // (`ingest::open` refuses more attributes than a record carries:
    // `points::MAX_ATTRIBUTES`.)
    *reader = ingest::multi::open_all(&plan.inputs, &plan.read)?;
    progress.phase("partition", reader.info().file_bytes, "bytes");
    let mut seen = 0u64;
    let reader = &mut **reader;
    spill_all(
        o,
        &cells.grid,
        &plan.regions,
        &cells.cell_region,
        &plan.origins,
        dir,
        "region",
        |sink| {
            while let Some(mut chunk) = reader.next_chunk()? {
                check_cancel(o)?;
                normalize(&mut chunk, like, progress, &job.rebased);
                seen += chunk.len() as u64;
                sink(chunk)?;
                progress.advance(reader.bytes_done(), seen);
            }
            Ok(())
        },
    )
}

/// Appends the chunks that `feed` passes to its sink to one temporary file per
/// region (named `<tag>-<region>.bin` in `dir`, coordinates relative to the
/// region's entry in `origins`), by grid cell. The files are written on a thread
/// of their own while `feed` reads the next chunk (one chunk of records in
/// flight).
#[allow(clippy::too_many_arguments)]
pub(super) fn spill_all(
    o: &ConvertOptions,
    grid: &CountGrid,
    regions: &[Region],
    cell_region: &[u32],
    origins: &[[f64; 3]],
    dir: &Path,
    tag: &str,
    feed: impl FnOnce(&mut dyn FnMut(PointColumns) -> Result<()>) -> Result<()>,
) -> Result<Vec<Spilled>> {
    // A share of the budget for write buffers, shared by the regions.
    let buffer = super::budget::Budget::new(o.memory).spill_buffer(regions.len());
    let all: u64 = regions.iter().map(|r| r.points).sum();
    let mut writers: Vec<spill::SpillWriter> = (0..regions.len())
        .map(|r| spill::SpillWriter::create(dir.join(format!("{tag}-{r:05}.bin")), buffer, all))
        .collect::<std::io::Result<_>>()?;
    let mut bounds = vec![Bounds::EMPTY; regions.len()];
    let (send, recv) = std::sync::mpsc::sync_channel::<(Vec<u8>, Vec<usize>, usize)>(1);
    std::thread::scope(|scope| -> Result<Vec<Spilled>> {
        let writer = scope.spawn(move || -> std::io::Result<Vec<spill::SpillWriter>> {
            for (records, starts, rs) in recv {
                for (r, w) in writers.iter_mut().enumerate() {
                    let (a, b) = (starts[r], starts[r + 1]);
                    if b > a {
                        w.push_records(&records[a * rs..b * rs], (b - a) as u64)?;
                    }
                }
            }
            Ok(writers)
        });
        let fed = feed(&mut |chunk: PointColumns| -> Result<()> {
            let ids: Vec<u32> = (0..chunk.len())
                .into_par_iter()
                .with_min_len(1 << 14)
                .map(|i| {
                    let c = grid.cell([chunk.x[i], chunk.y[i], chunk.z[i]]);
                    match cell_region[grid.index(c)] {
                        // A cell the sample never saw belongs to the nearest region.
                        u32::MAX => nearest_region(regions, c) as u32,
                        r => r,
                    }
                })
                .collect();
            // Records grouped by region in parallel, then appended region by region.
            let (records, starts, boxes) = spill::records_by_region(&chunk, &ids, origins);
            for (b, x) in bounds.iter_mut().zip(&boxes) {
                *b = b.union(x);
            }
            let rs = spill::record_size(chunk.attributes.len());
            // A send fails only when the writer stopped on an error (reported
            // when it is joined below).
            send.send((records, starts, rs))
                .map_err(|_| anyhow::anyhow!("writing the temporary files stopped"))
        });
        // The writer ends once the last records are sent.
        drop(send);
        let writers = writer
            .join()
            .map_err(|_| anyhow::anyhow!("the temporary file writer panicked"))??;
        fed?;
        writers
            .into_iter()
            .zip(bounds.iter().zip(origins))
            .map(|(w, (b, origin))| {
                let (path, points) = w.finish()?;
                Ok(Spilled {
                    path,
                    points,
                    bounds: *b,
                    origin: *origin,
                })
            })
            .collect()
    })
}

/// The region whose box is nearest to cell `c` (for cells the sample missed).
pub(super) fn nearest_region(regions: &[Region], c: [usize; 3]) -> usize {
    let dist = |r: &Region| -> usize {
        (0..3)
            .map(|a| {
                if c[a] < r.lo[a] {
                    r.lo[a] - c[a]
                } else if c[a] >= r.hi[a] {
                    c[a] + 1 - r.hi[a]
                } else {
                    0
                }
            })
            .sum()
    };
    (0..regions.len())
        .min_by_key(|&i| dist(&regions[i]))
        .unwrap_or(0)
}
