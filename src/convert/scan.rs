//! Pass 1, the scan: the input read once, in one of three ways. The paper's
//! stream partitioning writes parts in file order as it reads ([`stream`]); a
//! spatial conversion either reads only the chunks' extents of an input that
//! fits one part and gives its points again ([`extents`]), or reads the points,
//! keeping them while they fit one part, and their bounds and a sample for the
//! spatial plan once they do not ([`scan`]).

use super::job::{Job, PassStart};
use super::sample::{MIN_SAMPLE, Sample};
use super::{Outcome, Result, Retry, check_cancel, normalize, too_wide};
use crate::ingest::PointReader;
use crate::points::{Bounds, PointColumns};
use crate::store::{Layout, PartBuilder};

/// What the scan hands on: the points of one part, or what places the regions
/// of several.
pub(super) enum Scanned {
    One(OnePart),
    Many(Overflow),
}

/// A single part's points as the scan collected them: in a store builder, or
/// (when the origin chosen while reading proved too far) the chunks as read.
pub(super) struct OnePart {
    pub(super) built: Option<PartBuilder>,
    pub(super) held: Vec<PointColumns>,
    /// The points' bounds.
    pub(super) bounds: Bounds,
    pub(super) points: u64,
}

/// More points than one part (or wider than f32 keeps 1 mm across): what the
/// spatial plan is made from.
pub(super) struct Overflow {
    /// An even sample of the points' positions.
    pub(super) sample: Sample,
    pub(super) bounds: Bounds,
    /// The attributes' names and offsets every chunk was brought to (no points).
    pub(super) like: PointColumns,
    /// Points each point read stood for at the end (1, or more once the reader
    /// sampled: `points` is then an estimate).
    pub(super) weight: u64,
    pub(super) points: u64,
}

/// The paper's single pass: parts in file order, written as the input is read.
/// Returns the points written.
pub(super) fn stream(
    job: &mut Job,
    reader: &mut dyn PointReader,
    t_read: PassStart,
) -> Result<u64> {
    let (o, progress, per_part) = (job.o, job.progress, job.per_part);
    // Parts are written while the input is read: the pass is listed first.
    job.list_phase("read");
    let mut total = 0u64;
    let mut acc: Option<PointColumns> = None;
    while let Some(mut chunk) = reader.next_chunk()? {
        check_cancel(o)?;
        total += chunk.len() as u64;
        progress.advance(reader.bytes_done(), total);
        let a = acc.get_or_insert_with(|| chunk.empty_like());
        normalize(&mut chunk, a, progress, &job.rebased);
        // Fill the current part up to the budget; the rest starts the next.
        // A full part is written once more points arrive (so an input of
        // exactly one part's size still fits a single-file output).
        let mut from = 0;
        while from < chunk.len() {
            if a.len() as u64 >= per_part {
                if job.as_file {
                    return Err(job.too_many_parts());
                }
                let full = std::mem::replace(a, chunk.empty_like());
                job.write(full)?;
            }
            let take = ((per_part as usize) - a.len()).min(chunk.len() - from);
            a.append_range(&chunk, from, from + take);
            from += take;
        }
    }
    job.pass("read", t_read);
    if let Some(a) = acc.filter(|a| !a.is_empty()) {
        job.write(a)?;
    }
    Ok(total)
}

/// Pass 1 over the chunks' extents: the reader gives every point again when the
/// part is written, and the input declares no more points than one part. Comes
/// to [`Retry::NeedColumns`] where the points must be read whole after all.
pub(super) fn extents(
    job: &mut Job,
    reader: &mut dyn PointReader,
    t_read: PassStart,
) -> Result<Outcome<OnePart>> {
    let mut total = 0u64;
    let mut bounds = Bounds::EMPTY;
    let mut built: Option<PartBuilder> = None;
    while let Some(e) = reader.next_extent()? {
        check_cancel(job.o)?;
        total += e.len as u64;
        job.progress.advance(reader.bytes_done(), total);
        bounds = bounds.union(&e.bounds);
        let b = match built.as_mut() {
            Some(b) => b,
            None => {
                let mut b = job.new_part(e.bounds);
                let Some(rows) = reader.row_source() else {
                    return Ok(Outcome::Retry(Retry::NeedColumns));
                };
                b.rows_from(rows);
                built.insert(b)
            }
        };
        if (b.len() + e.len) as u64 > job.per_part {
            return Ok(Outcome::Retry(Retry::NeedColumns));
        }
        b.push_extent(&job.part_path(0), &e)
            .map_err(|e| job.public(e))?;
    }
    job.pass("read", t_read);
    if !job.as_file && too_wide(&bounds, job.max_extent) {
        return Ok(Outcome::Retry(Retry::NeedColumns));
    }
    Ok(Outcome::Done(OnePart {
        built,
        held: Vec::new(),
        bounds,
        points: total,
    }))
}

/// Pass 1 of spatial partitioning: bounds and a sample; points kept while they
/// fit one part: converted for the store as they arrive (`early`), around the
/// centre of the bounds the input declares (LAS) or else of its first window,
/// so each window is freed at once and its memory reused for the next; or (when
/// that origin proved too far) the chunks as read, no copy.
pub(super) fn scan(
    job: &mut Job,
    reader: &mut dyn PointReader,
    early: bool,
    t_read: PassStart,
) -> Result<Scanned> {
    let (o, progress, per_part) = (job.o, job.progress, job.per_part);
    let mut total = 0u64;
    let mut bounds = Bounds::EMPTY;
    let mut held: Vec<PointColumns> = Vec::new();
    let mut built: Option<PartBuilder> = None;
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
        normalize(&mut chunk, l, progress, &job.rebased);
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
                    let mut b = job.new_part(here);
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
                b.push(&job.part_path(0), &chunk)
                    .map_err(|e| job.public(e))?;
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
            let left = job.info.file_bytes.saturating_sub(read_bytes);
            let rest = left as f64 * total as f64 / read_bytes as f64;
            let wanted = o.sample_points.max(MIN_SAMPLE) as f64;
            let every = (rest / wanted) as u64;
            if every >= 2 && reader.sample_rest(every) {
                weight = every;
            }
        }
    }
    job.pass("read", t_read);
    // Points that fit one part but spread wider than f32 keeps 1 mm across
    // are partitioned all the same (into a directory of parts).
    if !overflow && !job.as_file && too_wide(&bounds, job.max_extent) {
        overflow = true;
        built = None;
        for c in held.drain(..) {
            sample.add(&c, 1);
        }
    }
    if !overflow {
        return Ok(Scanned::One(OnePart {
            built,
            held,
            bounds,
            points: total,
        }));
    }
    Ok(Scanned::Many(Overflow {
        sample,
        bounds,
        like: like.unwrap_or_default(),
        weight,
        points: total,
    }))
}
