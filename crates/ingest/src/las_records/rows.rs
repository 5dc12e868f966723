//! The attribute rows and positions of an uncompressed LAS file's records given
//! again from its memory map ([`LasRows`], the reader's `RowSource`): a tile's
//! records copied out first (prefetched: they lie in file order, the points in
//! curve order), then decoded a field at a time, exactly as the chunks were.

use super::{Fields, coordinate, fill_field};
use crate::bigvec;
use crate::color::ColorScale;
use crate::points::RowSource;
use std::mem::MaybeUninit;

/// The attribute rows of an uncompressed LAS file's records, decoded from its
/// memory map on demand: a record's values exactly as [`super::RecordReader`]'s chunks
/// deliver them (same offsets, same colour scale).
pub(super) struct LasRows {
    pub(super) map: std::sync::Arc<memmap2::Mmap>,
    /// The reader's token: it keeps the pages mapped while this lives.
    pub(super) _offered: std::sync::Arc<()>,
    pub(super) start: usize,
    pub(super) total: usize,
    pub(super) fields: Fields,
    pub(super) gps_offset: f64,
    pub(super) colour: ColorScale,
    pub(super) width: usize,
}

impl RowSource for LasRows {
    fn len(&self) -> usize {
        self.total
    }

    fn width(&self) -> usize {
        self.width
    }

    fn gather(&self, idx: &[u32], out: &mut Vec<f32>) {
        self.positions_and_rows_maybe(idx, None, out);
    }

    fn gather_columns(&self, idx: &[u32], cols: &mut [&mut [f32]]) {
        let n = idx.len();
        let mut cols: Vec<&mut [MaybeUninit<f32>]> = cols
            .iter_mut()
            .map(|c| {
                let c = &mut c[..n];
                // SAFETY: `MaybeUninit<f32>` has `f32`'s layout, and the
                // decoder only writes initialized values through it.
                unsafe { std::slice::from_raw_parts_mut(c.as_mut_ptr().cast(), n) }
            })
            .collect();
        RECORDS.with_borrow_mut(|buf| {
            self.copy_records(idx, buf);
            let colour = Some(self.colour);
            super::decode_attributes(buf, &self.fields, self.gps_offset, colour, &mut cols);
        });
    }

    fn has_positions(&self) -> bool {
        true
    }

    fn positions(&self, idx: &[u32], origin: [f64; 3], out: &mut Vec<[f32; 3]>) {
        let t = self.fields.transforms;
        out.reserve(idx.len());
        self.each_record(idx, |_, r| out.push(relative(r, &t, origin)));
    }

    fn positions_and_rows(
        &self,
        idx: &[u32],
        origin: [f64; 3],
        pos: &mut Vec<[f32; 3]>,
        rows: &mut Vec<f32>,
    ) {
        self.positions_and_rows_maybe(idx, Some((origin, pos)), rows);
    }

    fn positions_in(
        &self,
        range: std::ops::Range<usize>,
        origin: [f64; 3],
        out: &mut Vec<[f32; 3]>,
    ) {
        let stride = self.fields.stride;
        let recs = &self.map[self.start + range.start * stride..self.start + range.end * stride];
        let t = self.fields.transforms;
        let at = out.len();
        out.reserve(range.len());
        for (d, r) in out.spare_capacity_mut()[..range.len()]
            .iter_mut()
            .zip(recs.chunks_exact(stride))
        {
            d.write(relative(r, &t, origin));
        }
        // SAFETY: one record a slot: all range.len() slots were written.
        unsafe { out.set_len(at + range.len()) };
    }
}

impl LasRows {
    /// Calls `f(k, record)` with the record of each point `idx[k]`, in turn,
    /// asking for the records ahead ([`prefetch_ahead`]).
    #[inline(always)]
    fn each_record(&self, idx: &[u32], mut f: impl FnMut(usize, &[u8])) {
        let stride = self.fields.stride;
        let recs = &self.map[self.start..self.start + self.total * stride];
        for (k, &i) in idx.iter().enumerate() {
            prefetch_ahead(recs, idx, k, stride);
            let r = i as usize * stride;
            f(k, &recs[r..r + stride]);
        }
    }

    /// The records of points `idx`, one after the other, into `buf`: each copy
    /// of a fixed size for the standard record lengths (a call to `memcpy` a
    /// record cost as much as the copy).
    fn copy_records(&self, idx: &[u32], buf: &mut Vec<u8>) {
        fn fixed<const S: usize>(rows: &LasRows, idx: &[u32], buf: &mut Vec<u8>) {
            buf.resize(idx.len() * S, 0);
            let mut out = buf.chunks_exact_mut(S);
            rows.each_record(idx, |_, r| {
                if let (Some(d), Some(r)) = (out.next(), r.first_chunk::<S>()) {
                    d.copy_from_slice(r);
                }
            });
        }
        match self.fields.stride {
            // Point formats 0, 1, 2, 3, 6, 7, 8.
            20 => fixed::<20>(self, idx, buf),
            28 => fixed::<28>(self, idx, buf),
            26 => fixed::<26>(self, idx, buf),
            34 => fixed::<34>(self, idx, buf),
            30 => fixed::<30>(self, idx, buf),
            36 => fixed::<36>(self, idx, buf),
            38 => fixed::<38>(self, idx, buf),
            stride => {
                buf.clear();
                buf.reserve(idx.len() * stride);
                self.each_record(idx, |_, r| buf.extend_from_slice(r));
            }
        }
    }

    /// The rows of points `idx` appended to `rows`, and, given an origin, their
    /// positions to `pos`: each record read once for both. The records are copied
    /// out first (the reads that miss the cache, prefetched), then decoded a field
    /// at a time from the copy, each field's loop with its constants fixed
    /// ([`decode_rows`]): a record at a time, with a `match` per field, cost twice
    /// as much.
    #[inline(always)]
    fn positions_and_rows_maybe(
        &self,
        idx: &[u32],
        pos: Option<([f64; 3], &mut Vec<[f32; 3]>)>,
        rows: &mut Vec<f32>,
    ) {
        let (t, m, stride) = (self.fields.transforms, self.width, self.fields.stride);
        let n = idx.len();
        RECORDS.with_borrow_mut(|buf| {
            self.copy_records(idx, buf);
            if let Some((origin, p)) = pos {
                p.extend(buf.chunks_exact(stride).map(|r| relative(r, &t, origin)));
            }
            let at = rows.len();
            rows.reserve(n * m);
            let dst = &mut rows.spare_capacity_mut()[..n * m];
            decode_rows(buf, &self.fields, self.gps_offset, self.colour, m, dst);
            // SAFETY: `decode_rows` wrote every value of every row (m of each).
            unsafe { rows.set_len(at + n * m) };
        });
    }
}

thread_local! {
    /// [`LasRows`]' copies of the records it gathers, kept between calls.
    static RECORDS: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The attribute rows of the records `rec` (a whole number of records) into
/// `dst` (`m` values a record: [`super::decode_window`]'s columns, NaN beyond the
/// record's fields), colour scaled by `colour`: a loop per field, as
/// [`super::decode_window`] does.
fn decode_rows(
    rec: &[u8],
    f: &Fields,
    gps_offset: f64,
    colour: ColorScale,
    m: usize,
    dst: &mut [MaybeUninit<f32>],
) {
    let fields = f.attributes();
    // GPS time and the three whole numbers that make it exact: one pass, one
    // split a record.
    let time = super::time_columns(&fields, m);
    if let Some((k, at)) = time {
        for (row, r) in dst.chunks_exact_mut(m).zip(rec.chunks_exact(f.stride)) {
            let parts = super::split(super::f64_at(r, at), gps_offset);
            for (slot, v) in row[k..k + 4].iter_mut().zip(parts) {
                slot.write(v);
            }
        }
    }
    for j in 0..m {
        if time.is_some_and(|(t, _)| (t..t + 4).contains(&j)) {
            continue;
        }
        let field = fields.get(j);
        let scale = field.filter(|a| a.1).map(|_| colour);
        fill_field(
            rec,
            f.stride,
            field.map(|a| a.0),
            scale,
            gps_offset,
            dst,
            m,
            j,
        );
    }
}

/// Asks for the record of point `idx[k + PREFETCH_AHEAD]` of `recs`: the records
/// lie in file order, the indices in curve order, so nearly every record misses
/// the cache. A record may straddle two cache lines: both are asked for.
#[inline(always)]
fn prefetch_ahead(recs: &[u8], idx: &[u32], k: usize, stride: usize) {
    if let Some(&ahead) = idx.get(k + bigvec::PREFETCH_AHEAD) {
        let r = ahead as usize * stride;
        bigvec::prefetch(recs, r);
        bigvec::prefetch(recs, r + stride - 1);
    }
}

/// A record's coordinates less `origin`, as `f32`: the `f64` values
/// [`super::decode_window`] delivers ([`coordinate`]), then the store's rounding.
#[inline(always)]
fn relative(r: &[u8], t: &[(f64, f64); 3], origin: [f64; 3]) -> [f32; 3] {
    // Written out: `[0, 1, 2].map` is not inlined here, and this runs for every
    // point twice.
    let c = |a: usize| (coordinate(r, t, a) - origin[a]) as f32;
    [c(0), c(1), c(2)]
}
