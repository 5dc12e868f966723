//! Pass 2 of spatial partitioning: every point appended to its region's temporary
//! file (`spill.rs`), by the count grid's cell, on a writer thread of its own;
//! also used to split a region the sample underestimated.

use super::partition::{CountGrid, Region};
use super::{ConvertOptions, Progress, Result, check_cancel, normalize, spill};
use crate::ingest::{self, PointReader, ReadOptions};
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

/// Pass 2 of spatial partitioning: re-reads the input and appends every point to
/// its region's temporary file. Returns each region's file, point count and bounds.
#[allow(clippy::too_many_arguments)]
pub(super) fn distribute(
    reader: &mut Box<dyn PointReader>,
    inputs: &[PathBuf],
    read: &ReadOptions,
    o: &ConvertOptions,
    progress: &dyn Progress,
    grid: &CountGrid,
    regions: &[Region],
    cell_region: &[u32],
    origins: &[[f64; 3]],
    like: &PointColumns,
    dir: &Path,
    rebased: &std::cell::Cell<bool>,
) -> Result<Vec<Spilled>> {
    // (`ingest::open` refuses more attributes than a record carries:
    // `points::MAX_ATTRIBUTES`.)
    *reader = ingest::multi::open_all(inputs, read)?;
    progress.phase("partition", reader.info().file_bytes, "bytes");
    let mut seen = 0u64;
    let reader = &mut **reader;
    spill_all(
        o,
        grid,
        regions,
        cell_region,
        origins,
        dir,
        "region",
        |sink| {
            while let Some(mut chunk) = reader.next_chunk()? {
                check_cancel(o)?;
                normalize(&mut chunk, like, progress, rebased);
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
    // A quarter of the budget for write buffers, shared by the regions.
    let buffer = (o.memory / 4 / regions.len().max(1) as u64).clamp(64 << 10, 8 << 20) as usize;
    let mut writers: Vec<spill::SpillWriter> = (0..regions.len())
        .map(|r| spill::SpillWriter::create(dir.join(format!("{tag}-{r:05}.bin")), buffer))
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
fn nearest_region(regions: &[Region], c: [usize; 3]) -> usize {
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
