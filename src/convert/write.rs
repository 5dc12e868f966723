//! The last stage, writing parts: a single part as the scan collected it
//! ([`one_part`]), or pass 3 of spatial partitioning, each region's temporary
//! file streamed into a part around the region's origin ([`regions`], one region
//! at a time: [`region`]).

use super::distribute::{Spilled, spill_all};
use super::job::Job;
use super::partition::{self, CountGrid};
use super::plan::Plan;
use super::scan::OnePart;
use super::{Outcome, Result, check_cancel, spill};
use crate::store::PartBuilder;
use std::path::Path;

/// Writes the single part the scan collected; returns its points (or the
/// [`Retry`](super::Retry) a part collected while reading came to).
pub(super) fn one_part(job: &mut Job, one: OnePart) -> Result<Outcome<u64>> {
    let OnePart {
        built,
        held,
        bounds,
        points,
    } = one;
    // One part: its sort and tiles are the last phase.
    job.progress.phase("write", points, "points");
    job.last_part = true;
    if let Some(b) = built.filter(|b| !b.is_empty()) {
        if let Outcome::Retry(why) = job.write_collected(b)? {
            return Ok(Outcome::Retry(why));
        }
    } else if points > 0 {
        job.write_chunks(held, &bounds)?;
    }
    job.progress.advance(points, points);
    Ok(Outcome::Done(points))
}

/// Pass 3: each region's file (in `dir`, `total` points in all) becomes one part,
/// or several where the sample underestimated it (see [`region`]).
pub(super) fn regions(
    job: &mut Job,
    plan: &Plan,
    files: Vec<Spilled>,
    total: u64,
    dir: &Path,
) -> Result<()> {
    job.progress.phase("write", total, "points");
    let mut done = 0u64;
    let mut splits = 0usize;
    let mut stack: Vec<(Spilled, bool)> = files.into_iter().rev().map(|f| (f, false)).collect();
    while let Some((f, split)) = stack.pop() {
        check_cancel(job.o)?;
        if f.points == 0 {
            let _ = std::fs::remove_file(&f.path);
            continue;
        }
        if let Some(pieces) = region(job, plan, &f, split, dir, &mut splits)? {
            stack.extend(pieces.into_iter().rev().map(|p| (p, true)));
            continue;
        }
        done += f.points;
        job.progress.advance(done, done);
    }
    Ok(())
}

/// Writes one region's file `f` (removed once read), streamed into a store
/// builder around the region's origin. A region the sample underestimated is
/// first split again, exactly, by a count grid over its own points: the pieces
/// (files in `dir`) are returned to be written in its place (`splits` counts
/// such splits, naming the pieces). A piece that still holds more than a part
/// (`split`: a grid cell alone holds that many, points denser than the grid
/// resolves) becomes parts in file order. Either way no part exceeds the budget.
pub(super) fn region(
    job: &mut Job,
    plan: &Plan,
    f: &Spilled,
    split: bool,
    dir: &Path,
    splits: &mut usize,
) -> Result<Option<Vec<Spilled>>> {
    let per_part = job.per_part;
    let nattr = plan.attributes.len();
    let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
    // The file's origin, so the builder stores the f32 offsets the file holds,
    // exactly.
    let new_part = || {
        let n = f.points.min(per_part) as usize;
        PartBuilder::new(f.origin, None, n)
    };
    let names = &plan.attributes;
    if f.points <= per_part {
        let t_back = job.begin();
        let mut b = new_part();
        while let Some(r) = blocks.next_records(usize::MAX)? {
            b.push_packed(&job.next_path(), r, names)
                .map_err(|e| job.public(e))?;
        }
        // The region's bounds, kept in f64 while spilling.
        b.set_source_bounds(f.bounds);
        drop(blocks);
        let _ = std::fs::remove_file(&f.path);
        job.pass("read back", t_back);
        job.write_built(b)?;
    } else if !split {
        let t_split = job.begin();
        let like = plan.like();
        let mut grid = CountGrid::new(f.bounds);
        while let Some(c) = blocks.next_block(&like, usize::MAX, f.origin)? {
            for i in 0..c.len() {
                grid.add([c.x[i], c.y[i], c.z[i]]);
            }
        }
        let subs = partition::split(&grid, per_part, job.max_extent);
        let map = partition::cell_regions(&grid, &subs);
        drop(blocks);
        let mut blocks = spill::SpillReader::open(&f.path, nattr)?;
        *splits += 1;
        let tag = format!("split{splits}");
        // The pieces keep the region's origin (their offsets are then the same
        // f32 values, not rounded again).
        let origins = vec![f.origin; subs.len()];
        let pieces = spill_all(job.o, &grid, &subs, &map, &origins, dir, &tag, |sink| {
            while let Some(c) = blocks.next_block(&like, usize::MAX, f.origin)? {
                sink(c)?;
            }
            Ok(())
        })?;
        drop(blocks);
        let _ = std::fs::remove_file(&f.path);
        job.pass("split", t_split);
        return Ok(Some(pieces));
    } else {
        let mut b = new_part();
        let room = |b: &PartBuilder| per_part as usize - b.len();
        while let Some(r) = blocks.next_records(room(&b))? {
            b.push_packed(&job.next_path(), r, names)
                .map_err(|e| job.public(e))?;
            if room(&b) == 0 {
                job.write_built(std::mem::replace(&mut b, new_part()))?;
            }
        }
        drop(blocks);
        let _ = std::fs::remove_file(&f.path);
        if !b.is_empty() {
            job.write_built(b)?;
        }
    }
    Ok(None)
}
