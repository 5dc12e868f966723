//! Collects the points of one part as they arrive, chunk after chunk, in the form
//! the writer sorts and tiles: coordinates as `f32` relative to an origin fixed in
//! advance, and the attributes interleaved point by point (one row of values a
//! point). A pushed chunk is converted at once, so the caller can drop it: a
//! reader's `f64` window is never held for the whole part, and its memory is
//! reused for the next window. Where the reader can give the attribute rows again
//! ([`RowSource`]), the builder keeps only their ranges and the writer asks the
//! source for each tile's rows.

use crate::error::{Result, StoreError};
use crate::points::{Attribute, Bounds, ChunkExtent, PointColumns, RowSource};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;

/// One part's points, relative to `origin`, ready for [`crate::write::part`].
pub struct PartBuilder {
    pub(crate) origin: [f64; 3],
    /// Every point must lie inside these bounds (checked as points arrive).
    expect: Option<Bounds>,
    /// The positions, unless the source gives them ([`PartBuilder::rows_from`]).
    pub(crate) pos: Vec<[f32; 3]>,
    /// Points pushed so far.
    pub(crate) count: usize,
    /// Points expected: `pos`'s capacity once it is first needed.
    capacity: usize,
    /// Positions are held even if the source gives them.
    hold_positions: bool,
    /// `attributes.len()` values a point, in the order of `attributes`.
    pub(crate) rows: Vec<f32>,
    /// Where the rows come from instead, when the part holds none.
    pub(crate) source: Option<Arc<dyn RowSource>>,
    /// Attribute names and offsets, from the first chunk.
    pub(crate) attributes: Vec<(String, f64)>,
    /// Each attribute's smallest and largest stored value (NaN ignored; one
    /// entry per attribute once a chunk was pushed, even an empty one).
    pub(crate) ranges: Vec<(f32, f32)>,
    /// Bounds of the points pushed so far, from their `f64` coordinates.
    pub(crate) bounds: Bounds,
}

/// Points converted a parallel piece at a time.
const PIECE: usize = 1 << 14;

impl PartBuilder {
    /// An empty part whose coordinates will be stored relative to `origin`;
    /// `expect`, when given, bounds every point (a point outside is an error).
    /// `capacity`: the points expected, if known (saves regrowing).
    pub fn new(origin: [f64; 3], expect: Option<Bounds>, capacity: usize) -> PartBuilder {
        PartBuilder {
            origin,
            expect,
            pos: Vec::new(),
            count: 0,
            capacity,
            hold_positions: false,
            rows: Vec::new(),
            source: None,
            attributes: Vec::new(),
            ranges: Vec::new(),
            bounds: Bounds::EMPTY,
        }
    }

    /// The origin the coordinates are stored relative to.
    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }

    /// Points so far.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Whether the positions stay with the source ([`PartBuilder::rows_from`]).
    pub(crate) fn positions_from_source(&self) -> bool {
        !self.hold_positions && self.source.as_ref().is_some_and(|s| s.has_positions())
    }

    /// Holds the positions even where the source could give them again (the
    /// paper's layout reads every position in input order: decoding them twice
    /// would cost a pass).
    pub fn hold_positions(&mut self) {
        if self.is_empty() {
            self.hold_positions = true;
        }
    }

    /// Makes room for `len` more positions (the expected count at first).
    fn reserve_positions(&mut self, len: usize) {
        if self.pos.capacity() == 0 {
            self.pos = crate::bigvec::with_capacity(self.capacity.max(self.count + len));
        }
        self.pos.reserve(len);
    }

    /// The bounds of the points so far (`Bounds::EMPTY` when none).
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    /// Records `b`, the bounds of the points' source coordinates, as the part's
    /// bounds: points pushed as f32 offsets (`push_packed`) are bounded from those,
    /// which lie within the quantization error of the source. Ignored unless `b`
    /// holds the bounds so far to within that error.
    pub fn set_source_bounds(&mut self, b: Bounds) {
        let tolerance = crate::write::part::quantization_bound(&b, self.origin) * 2.0 + 1e-9;
        let close = (0..3).all(|a| {
            (b.min[a] - self.bounds.min[a]).abs() <= tolerance
                && (b.max[a] - self.bounds.max[a]).abs() <= tolerance
        });
        if close {
            self.bounds = b;
        }
    }

    /// Widens the attributes' ranges by `ranges` (one per attribute). The
    /// whole numbers that make GPS time exact keep the range they may take
    /// (`time::EXACT_RANGE`), whatever they hold: readers need not split every
    /// time an extra time to find it.
    fn widen_ranges(&mut self, ranges: Vec<(f32, f32)>) {
        self.ranges = if self.ranges.is_empty() {
            ranges
        } else {
            widen(&self.ranges, &ranges)
        };
        for (r, (name, _)) in self.ranges.iter_mut().zip(&self.attributes) {
            if pcimg_core::time::is_exact_band(name) {
                *r = pcimg_core::time::EXACT_RANGE;
            }
        }
    }

    /// Takes the attribute rows from `src` when the part is written instead of
    /// holding them: pushed chunks then add their positions and widen their
    /// attributes' ranges, and nothing else; where `src` gives positions too, the
    /// pushed chunks are only checked and bounded (the writer asks `src` for the
    /// positions, which it gives exactly as pushing would). The points pushed must be the
    /// source's points 0, 1, 2, ... in order (the writer checks their count and
    /// the row width). Ignored once points were pushed.
    pub fn rows_from(&mut self, src: Arc<dyn RowSource>) {
        if self.is_empty() && self.rows.is_empty() {
            self.source = Some(src);
        }
    }

    /// Appends the points of `c`; `path` names the part in errors. Every chunk must
    /// have the attributes (names and offsets) of the first; coordinates must be
    /// finite (and inside the expected bounds, if any). On an error the builder
    /// is unchanged.
    pub fn push(&mut self, path: &Path, c: &PointColumns) -> Result<()> {
        c.check_lengths().map_err(|m| StoreError::new(path, m))?;
        self.push_positions(path, c)?;
        self.push_rows(&c.attributes, c.len());
        Ok(())
    }

    /// Appends points known only by their [`ChunkExtent`], for a part whose
    /// source gives their positions and rows ([`PartBuilder::rows_from`]): what
    /// [`PartBuilder::push`] keeps of their chunk, with the same checks. A part
    /// that holds its positions, or expects bounds, needs the points themselves.
    /// On an error the builder is unchanged.
    pub fn push_extent(&mut self, path: &Path, e: &ChunkExtent) -> Result<()> {
        if !self.positions_from_source() || self.expect.is_some() {
            return Err(StoreError::new(
                path,
                "this part holds its points or checks them against bounds: push its chunks",
            ));
        }
        if e.ranges.len() != e.attributes.len() {
            return Err(StoreError::new(
                path,
                format!(
                    "a chunk's extent has {} attribute ranges for {} attributes",
                    e.ranges.len(),
                    e.attributes.len()
                ),
            ));
        }
        let first = self.admit(path, &e.attributes, e.len)?;
        if let Some((i, p)) = e.not_finite {
            return Err(bad_point(path, self.count + i, p));
        }
        self.count += e.len;
        self.bounds = self.bounds.union(&e.bounds);
        if first {
            self.attributes = e.attributes.clone();
        }
        if !e.attributes.is_empty() {
            self.widen_ranges(e.ranges.clone());
        }
        Ok(())
    }

    /// Appends the points of `chunks` as [`PartBuilder::push`] would, freeing each
    /// chunk's coordinates once converted and only then its attributes: the
    /// attribute rows are allocated after all coordinates are freed, so they reuse
    /// that memory. On an error nothing is appended.
    pub(crate) fn push_all(&mut self, path: &Path, chunks: Vec<PointColumns>) -> Result<()> {
        let (len, first, bounds) = (self.count, self.attributes.clone(), self.bounds);
        let mut attrs: Vec<(Vec<Attribute>, usize)> = Vec::with_capacity(chunks.len());
        for mut c in chunks {
            let pushed = c
                .check_lengths()
                .map_err(|m| StoreError::new(path, m))
                .and_then(|_| self.push_positions(path, &c));
            if let Err(e) = pushed {
                self.pos.truncate(len);
                self.count = len;
                self.attributes = first;
                self.bounds = bounds;
                return Err(e);
            }
            attrs.push((std::mem::take(&mut c.attributes), c.len()));
        }
        let m = self.attributes.len();
        let want = (self.count - len) * m;
        if self.source.is_none() {
            if self.rows.capacity() == 0 {
                self.rows = crate::bigvec::with_capacity(want);
            } else {
                self.rows.reserve_exact(want);
            }
        }
        for (a, n) in attrs {
            self.push_rows(&a, n);
        }
        Ok(())
    }

    /// Checks that `this` (attribute names and offsets) matches the part's
    /// attributes and that `len` more points fit a part; true for the first push.
    fn admit(&self, path: &Path, this: &[(String, f64)], len: usize) -> Result<bool> {
        let first = self.is_empty() && self.attributes.is_empty();
        if !first && this != self.attributes {
            return Err(StoreError::new(
                path,
                "the chunks of a part differ in their attribute columns or offsets",
            ));
        }
        let base = self.count;
        if (base + len) as u64 > u32::MAX as u64 {
            return Err(StoreError::new(
                path,
                format!(
                    "{} points are more than one part holds (4,294,967,295); split the input",
                    base + len
                ),
            ));
        }
        Ok(first)
    }

    /// The bounds every point must lie in (all space when none were given).
    fn limits(&self) -> ([f64; 3], [f64; 3]) {
        match self.expect {
            Some(b) => (b.min, b.max),
            None => ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3]),
        }
    }

    /// Appends the positions of `c`, checking them and its attributes' names and
    /// offsets.
    fn push_positions(&mut self, path: &Path, c: &PointColumns) -> Result<()> {
        let this: Vec<(String, f64)> = c
            .attributes
            .iter()
            .map(|a| (a.name.clone(), a.offset))
            .collect();
        let len = c.len();
        let first = self.admit(path, &this, len)?;
        let base = self.count;
        let (origin, (lo, hi)) = (self.origin, self.limits());
        // Each piece checked and bounded; its positions made relative, unless the
        // source keeps them.
        let merge = |x: (bool, Bounds), y: (bool, Bounds)| (x.0 & y.0, x.1.union(&y.1));
        let keep = !self.positions_from_source();
        let (ok, b) = if keep {
            self.reserve_positions(len);
            let dst = &mut self.pos.spare_capacity_mut()[..len];
            dst.par_chunks_mut(PIECE)
                .enumerate()
                .map(|(k, d)| {
                    let from = k * PIECE;
                    for (i, d) in d.iter_mut().enumerate() {
                        let p = [c.x[from + i], c.y[from + i], c.z[from + i]];
                        let r = |a: usize| (p[a] - origin[a]) as f32;
                        d.write([r(0), r(1), r(2)]);
                    }
                    check_piece(c, from..from + d.len(), lo, hi)
                })
                .reduce(|| (true, Bounds::EMPTY), merge)
        } else {
            (0..len.div_ceil(PIECE))
                .into_par_iter()
                .map(|k| check_piece(c, k * PIECE..(k * PIECE + PIECE).min(len), lo, hi))
                .reduce(|| (true, Bounds::EMPTY), merge)
        };
        if !ok {
            let bad = |i: usize| {
                let p = [c.x[i], c.y[i], c.z[i]];
                !(0..3).all(|a| p[a].is_finite() && p[a] >= lo[a] && p[a] <= hi[a])
            };
            let i = (0..len).find(|&i| bad(i)).unwrap_or(0);
            return Err(bad_point(path, base + i, [c.x[i], c.y[i], c.z[i]]));
        }
        if keep {
            // SAFETY: every slot base..base + len was written above.
            unsafe { self.pos.set_len(base + len) };
        }
        self.count = base + len;
        self.bounds = self.bounds.union(&b);
        if first {
            self.attributes = this;
        }
        Ok(())
    }

    /// Appends points given as packed records of [`packed_size`]`(m)` bytes,
    /// little-endian: x y z as `f32` relative to this builder's origin, then the
    /// values of the m `attributes` (names and offsets). The values are stored as
    /// given, so records written around the same origin come back exactly, with
    /// no conversion through `f64`. Checks as [`PartBuilder::push`] does; on an
    /// error the builder is unchanged.
    pub fn push_packed(
        &mut self,
        path: &Path,
        records: &[u8],
        attributes: &[(String, f64)],
    ) -> Result<()> {
        let m = attributes.len();
        let rs = packed_size(m);
        if self.source.is_some() {
            return Err(StoreError::new(
                path,
                "packed records carry their own attribute rows: this part takes them from \
                 its reader",
            ));
        }
        if !records.len().is_multiple_of(rs) {
            return Err(StoreError::new(
                path,
                format!("{} bytes are not whole {rs}-byte records", records.len()),
            ));
        }
        let len = records.len() / rs;
        let first = self.admit(path, attributes, len)?;
        let base = self.count;
        let (origin, (lo, hi)) = (self.origin, self.limits());
        let point = |r: &[u8]| [0, 1, 2].map(|a| origin[a] + f64::from(f32_at(r, 4 * a)));
        self.reserve_positions(len);
        if m > 0 && self.rows.capacity() == 0 {
            self.rows = crate::bigvec::with_capacity(self.pos.capacity() * m);
        }
        self.rows.reserve(len * m);
        let rows_at = self.rows.len();
        let pos = &mut self.pos.spare_capacity_mut()[..len];
        let rows = &mut self.rows.spare_capacity_mut()[..len * m];
        // Each piece's rows (empty ones when there are no attributes).
        let pieces = len.div_ceil(PIECE);
        let mut row_pieces: Vec<&mut [std::mem::MaybeUninit<f32>]> = Vec::with_capacity(pieces);
        if m > 0 {
            row_pieces.extend(rows.chunks_mut(PIECE * m));
        } else {
            row_pieces.resize_with(pieces, || &mut []);
        }
        let (ok, b, ranges) = records
            .par_chunks(PIECE * rs)
            .zip(pos.par_chunks_mut(PIECE))
            .zip(row_pieces)
            .map(|((recs, pos), rows)| {
                let piece = Piece {
                    recs,
                    pos,
                    rows,
                    origin,
                    lo,
                    hi,
                };
                match m {
                    0 => piece.unpack::<0>(),
                    1 => piece.unpack::<1>(),
                    2 => piece.unpack::<2>(),
                    3 => piece.unpack::<3>(),
                    4 => piece.unpack::<4>(),
                    5 => piece.unpack::<5>(),
                    6 => piece.unpack::<6>(),
                    7 => piece.unpack::<7>(),
                    8 => piece.unpack::<8>(),
                    _ => piece.unpack_any(m),
                }
            })
            .reduce(
                || (true, Bounds::EMPTY, vec![EMPTY_RANGE; m]),
                |x, y| (x.0 & y.0, x.1.union(&y.1), widen(&x.2, &y.2)),
            );
        if !ok {
            let bad =
                |p: [f64; 3]| !(0..3).all(|a| p[a].is_finite() && p[a] >= lo[a] && p[a] <= hi[a]);
            let (i, p) = records
                .chunks_exact(rs)
                .map(point)
                .enumerate()
                .find(|&(_, p)| bad(p))
                .unwrap_or((0, [f64::NAN; 3]));
            return Err(bad_point(path, base + i, p));
        }
        // SAFETY: the pieces wrote every slot base..base + len of the positions
        // and rows_at..rows_at + len * m of the rows.
        unsafe {
            self.pos.set_len(base + len);
            self.rows.set_len(rows_at + len * m);
        }
        self.count = base + len;
        self.bounds = self.bounds.union(&b);
        if first {
            self.attributes = attributes.to_vec();
        }
        self.widen_ranges(ranges);
        Ok(())
    }

    /// Appends the values of `attrs` (`len` points), interleaved, and widens the
    /// attributes' ranges.
    fn push_rows(&mut self, attrs: &[Attribute], len: usize) {
        let m = attrs.len();
        if m == 0 {
            return;
        }
        if self.source.is_some() {
            // The rows stay with the source: only their ranges are kept.
            let ranges = attrs
                .par_iter()
                .map(|a| {
                    a.values[..len]
                        .iter()
                        .fold(EMPTY_RANGE, |r, &v| (r.0.min(v), r.1.max(v)))
                })
                .collect();
            self.widen_ranges(ranges);
            return;
        }
        let at = self.rows.len();
        if self.rows.capacity() == 0 {
            self.rows = crate::bigvec::with_capacity(self.capacity.max(self.count) * m);
        }
        self.rows.reserve(len * m);
        let dst = &mut self.rows.spare_capacity_mut()[..len * m];
        let cols: Vec<&[f32]> = attrs.iter().map(|a| &a.values[..]).collect();
        let ranges = dst
            .par_chunks_mut(PIECE * m)
            .enumerate()
            .map(|(k, d)| {
                let from = k * PIECE;
                let n = d.len() / m;
                match m {
                    1 => interleave::<1>(d, &cols, from, n),
                    2 => interleave::<2>(d, &cols, from, n),
                    3 => interleave::<3>(d, &cols, from, n),
                    4 => interleave::<4>(d, &cols, from, n),
                    5 => interleave::<5>(d, &cols, from, n),
                    6 => interleave::<6>(d, &cols, from, n),
                    7 => interleave::<7>(d, &cols, from, n),
                    8 => interleave::<8>(d, &cols, from, n),
                    _ => interleave_any(d, &cols, from, n),
                }
            })
            .reduce(|| vec![EMPTY_RANGE; m], |a, b| widen(&a, &b));
        // SAFETY: every slot at..at + len * m was written above.
        unsafe { self.rows.set_len(at + len * m) };
        self.widen_ranges(ranges);
    }
}

/// Whether the points `r` of `c` are finite and inside `lo..=hi`, and their bounds:
/// an axis at a time over its column, a loop that vectorizes (a NaN fails every
/// comparison, so `ok` also catches it).
fn check_piece(
    c: &PointColumns,
    r: std::ops::Range<usize>,
    lo: [f64; 3],
    hi: [f64; 3],
) -> (bool, Bounds) {
    let mut ok = true;
    let mut b = Bounds::EMPTY;
    for (a, col) in [&c.x, &c.y, &c.z].into_iter().enumerate() {
        let (lo, hi) = (lo[a], hi[a]);
        for &v in &col[r.clone()] {
            // `&`, not `&&`: no branches in the loop.
            ok &= (v >= lo) & (v <= hi) & v.is_finite();
            b.min[a] = b.min[a].min(v);
            b.max[a] = b.max[a].max(v);
        }
    }
    (ok, b)
}

/// The `f32` at byte `o` of `r`, little-endian.
#[inline(always)]
fn f32_at(r: &[u8], o: usize) -> f32 {
    f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]])
}

/// One parallel piece of [`PartBuilder::push_packed`]: its records and the slots
/// its positions and rows go to.
struct Piece<'a> {
    recs: &'a [u8],
    pos: &'a mut [std::mem::MaybeUninit<[f32; 3]>],
    rows: &'a mut [std::mem::MaybeUninit<f32>],
    origin: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
}

/// A piece's result: all points valid, their bounds, each attribute's range.
type Unpacked = (bool, Bounds, Vec<(f32, f32)>);

impl Piece<'_> {
    /// The piece's positions: stored as given; checked and bounded in `f64`.
    fn positions(&mut self, rs: usize) -> (bool, Bounds) {
        let mut ok = true;
        let mut b = Bounds::EMPTY;
        for (r, d) in self.recs.chunks_exact(rs).zip(self.pos.iter_mut()) {
            let q = [f32_at(r, 0), f32_at(r, 4), f32_at(r, 8)];
            d.write(q);
            for a in 0..3 {
                let p = self.origin[a] + f64::from(q[a]);
                // `&`, not `&&`: no branches in the loop.
                ok &= (p >= self.lo[a]) & (p <= self.hi[a]) & p.is_finite();
                b.min[a] = b.min[a].min(p);
                b.max[a] = b.max[a].max(p);
            }
        }
        (ok, b)
    }

    /// [`Piece::positions`], then the `M` attribute values of each record as one
    /// row, with their ranges.
    fn unpack<const M: usize>(mut self) -> Unpacked {
        let rs = packed_size(M);
        let (ok, b) = self.positions(rs);
        let mut lo = [f32::INFINITY; M];
        let mut hi = [f32::NEG_INFINITY; M];
        for (r, row) in self
            .recs
            .chunks_exact(rs)
            .zip(self.rows.chunks_exact_mut(M.max(1)))
        {
            for j in 0..M {
                let v = f32_at(r, 12 + 4 * j);
                row[j].write(v);
                lo[j] = lo[j].min(v);
                hi[j] = hi[j].max(v);
            }
        }
        (ok, b, (0..M).map(|j| (lo[j], hi[j])).collect())
    }

    /// [`Piece::unpack`] for any number of attributes.
    fn unpack_any(mut self, m: usize) -> Unpacked {
        let rs = packed_size(m);
        let (ok, b) = self.positions(rs);
        let mut ranges = vec![EMPTY_RANGE; m];
        for (r, row) in self
            .recs
            .chunks_exact(rs)
            .zip(self.rows.chunks_exact_mut(m))
        {
            for (j, (v, range)) in row.iter_mut().zip(&mut ranges).enumerate() {
                let x = f32_at(r, 12 + 4 * j);
                v.write(x);
                *range = (range.0.min(x), range.1.max(x));
            }
        }
        (ok, b, ranges)
    }
}

/// Bytes of one record of [`PartBuilder::push_packed`] with `m` attributes.
pub fn packed_size(m: usize) -> usize {
    12 + 4 * m
}

/// The error for point `i` at `p`: not finite, or outside the expected bounds.
fn bad_point(path: &Path, i: usize, p: [f64; 3]) -> StoreError {
    let what = if p.iter().all(|v| v.is_finite()) {
        "lies outside the bounds given for the part"
    } else {
        "has a coordinate that is not a finite number"
    };
    StoreError::new(
        path,
        format!("point {i} {what} ({}, {}, {})", p[0], p[1], p[2]),
    )
}

/// A range no value has widened yet.
const EMPTY_RANGE: (f32, f32) = (f32::INFINITY, f32::NEG_INFINITY);

/// Both ranges' union, attribute by attribute (NaN never widens a range).
fn widen(a: &[(f32, f32)], b: &[(f32, f32)]) -> Vec<(f32, f32)> {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a.0.min(b.0), a.1.max(b.1)))
        .collect()
}

/// Rows `from..from + n` of the `M` columns into `d`, row after row; their ranges.
fn interleave<const M: usize>(
    d: &mut [std::mem::MaybeUninit<f32>],
    cols: &[&[f32]],
    from: usize,
    n: usize,
) -> Vec<(f32, f32)> {
    let cols: [&[f32]; M] = std::array::from_fn(|j| &cols[j][from..from + n]);
    let mut lo = [f32::INFINITY; M];
    let mut hi = [f32::NEG_INFINITY; M];
    for (r, row) in d.chunks_exact_mut(M).enumerate() {
        for j in 0..M {
            let v = cols[j][r];
            row[j].write(v);
            lo[j] = lo[j].min(v);
            hi[j] = hi[j].max(v);
        }
    }
    (0..M).map(|j| (lo[j], hi[j])).collect()
}

/// [`interleave`] for any number of columns.
fn interleave_any(
    d: &mut [std::mem::MaybeUninit<f32>],
    cols: &[&[f32]],
    from: usize,
    n: usize,
) -> Vec<(f32, f32)> {
    let m = cols.len();
    let mut ranges = vec![EMPTY_RANGE; m];
    for (j, col) in cols.iter().enumerate() {
        for (r, &v) in col[from..from + n].iter().enumerate() {
            d[r * m + j].write(v);
            ranges[j] = (ranges[j].0.min(v), ranges[j].1.max(v));
        }
    }
    ranges
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chunk(xs: &[f64], a: &[f32], offset: f64) -> PointColumns {
        PointColumns {
            x: xs.to_vec(),
            y: xs.iter().map(|v| v * 2.0).collect(),
            z: xs.iter().map(|v| -v).collect(),
            attributes: vec![
                Attribute::new("i", a.to_vec()),
                Attribute {
                    name: "t".into(),
                    offset,
                    values: a.iter().map(|v| v + 0.5).collect(),
                },
            ],
        }
    }

    #[test]
    fn points_become_relative_rows_and_bounds() {
        let p = Path::new("part.tif");
        let mut b = PartBuilder::new([10.0, 20.0, 0.0], None, 0);
        b.push(p, &chunk(&[11.0, 12.0], &[1.0, 2.0], 5.0)).unwrap();
        b.push(p, &chunk(&[9.0], &[3.0], 5.0)).unwrap();
        assert_eq!(b.len(), 3);
        assert_eq!(
            b.pos,
            vec![[1.0, 2.0, -11.0], [2.0, 4.0, -12.0], [-1.0, -2.0, -9.0]]
        );
        assert_eq!(b.rows, vec![1.0, 1.5, 2.0, 2.5, 3.0, 3.5]);
        assert_eq!(b.ranges, vec![(1.0, 3.0), (1.5, 3.5)]);
        assert_eq!(b.bounds().min, [9.0, 18.0, -12.0]);
        assert_eq!(b.bounds().max, [12.0, 24.0, -9.0]);
        // Other offsets, a NaN, a point outside the expected bounds: refused, and
        // the builder keeps what it had.
        let e = b
            .push(p, &chunk(&[1.0], &[1.0], 6.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("part.tif") && e.contains("offsets"), "{e}");
        let e = b
            .push(p, &chunk(&[1.0, f64::NAN], &[1.0, 2.0], 5.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("point 4 ") && e.contains("not a finite"), "{e}");
        assert_eq!((b.len(), b.rows.len()), (3, 6));
        let mut tight = PartBuilder::new([0.0; 3], Some(b.bounds()), 0);
        let e = tight
            .push(p, &chunk(&[10.0, 13.0], &[1.0, 1.0], 0.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("point 1 lies outside"), "{e}");
    }

    /// A source that claims positions (its rows are never asked for here).
    struct Positions(usize);

    impl RowSource for Positions {
        fn len(&self) -> usize {
            self.0
        }
        fn width(&self) -> usize {
            2
        }
        fn gather(&self, _: &[u32], _: &mut Vec<f32>) {}
        fn has_positions(&self) -> bool {
            true
        }
    }

    /// A part whose source gives positions and rows keeps the same count,
    /// bounds and ranges from the chunks' extents as from the chunks, and
    /// refuses a non-finite point by its number; a part that holds its
    /// positions refuses extents.
    #[test]
    fn extents_count_as_their_chunks() {
        let p = Path::new("part.tif");
        let chunks = [
            chunk(&[11.0, 12.0], &[1.0, 2.0], 5.0),
            chunk(&[9.0], &[f32::NAN], 5.0),
        ];
        let source = || {
            let mut b = PartBuilder::new([10.0, 20.0, 0.0], None, 0);
            b.rows_from(Arc::new(Positions(3)));
            b
        };
        let (mut a, mut b) = (source(), source());
        for c in &chunks {
            a.push(p, c).unwrap();
            b.push_extent(p, &ChunkExtent::of(c)).unwrap();
        }
        assert_eq!(
            (b.len(), b.bounds(), &b.ranges),
            (a.len(), a.bounds(), &a.ranges)
        );
        assert_eq!(b.attributes, a.attributes);
        assert!(b.pos.is_empty() && b.rows.is_empty());
        let e = b
            .push_extent(
                p,
                &ChunkExtent::of(&chunk(&[1.0, f64::INFINITY], &[1.0, 2.0], 5.0)),
            )
            .unwrap_err()
            .to_string();
        assert!(e.contains("point 4 ") && e.contains("not a finite"), "{e}");
        let e = b
            .push_extent(p, &ChunkExtent::of(&chunk(&[1.0], &[1.0], 6.0)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("offsets"), "{e}");
        assert_eq!(b.len(), 3);
        let mut held = PartBuilder::new([0.0; 3], None, 0);
        assert!(held.push_extent(p, &ChunkExtent::of(&chunks[0])).is_err());
        held.rows_from(Arc::new(Positions(3)));
        held.hold_positions();
        assert!(held.push_extent(p, &ChunkExtent::of(&chunks[0])).is_err());
        assert!(held.is_empty());
    }

    /// `c`'s points packed around `origin`, as a spill file holds them.
    fn packed(c: &PointColumns, origin: [f64; 3]) -> Vec<u8> {
        let mut out = Vec::new();
        for i in 0..c.len() {
            for (a, v) in [c.x[i], c.y[i], c.z[i]].iter().enumerate() {
                out.extend_from_slice(&((v - origin[a]) as f32).to_le_bytes());
            }
            for a in &c.attributes {
                out.extend_from_slice(&a.values[i].to_le_bytes());
            }
        }
        out
    }

    #[test]
    fn packed_records_fill_the_builder_as_columns_do() {
        let p = Path::new("part.tif");
        let origin = [10.0, 20.0, 0.0];
        let a = chunk(&[11.0, 12.0, 10.5], &[1.0, 2.0, -4.0], 5.0);
        let b = chunk(&[9.0], &[3.0], 5.0);
        let names: Vec<(String, f64)> = a
            .attributes
            .iter()
            .map(|t| (t.name.clone(), t.offset))
            .collect();
        let mut cols = PartBuilder::new(origin, None, 0);
        cols.push(p, &a).unwrap();
        cols.push(p, &b).unwrap();
        let mut recs = PartBuilder::new(origin, None, 0);
        recs.push_packed(p, &packed(&a, origin), &names).unwrap();
        recs.push_packed(p, &packed(&b, origin), &names).unwrap();
        assert_eq!((&recs.pos, &recs.rows), (&cols.pos, &cols.rows));
        assert_eq!(
            (&recs.ranges, &recs.attributes),
            (&cols.ranges, &cols.attributes)
        );
        assert_eq!(
            (recs.bounds.min, recs.bounds.max),
            (cols.bounds.min, cols.bounds.max)
        );
        // No attributes: positions only.
        let mut bare = PartBuilder::new(origin, None, 0);
        let xyz = PointColumns {
            attributes: vec![],
            ..a.clone()
        };
        bare.push_packed(p, &packed(&xyz, origin), &[]).unwrap();
        assert_eq!((bare.len(), bare.rows.len()), (3, 0));
        // A partial record, other attributes, a NaN, a point outside the expected
        // bounds: refused, and the builder keeps what it had.
        let bytes = packed(&b, origin);
        let e = recs
            .push_packed(p, &bytes[..bytes.len() - 1], &names)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("part.tif") && e.contains("whole 20-byte records"),
            "{e}"
        );
        let mut other = names.clone();
        other[1].1 = 6.0;
        let e = recs.push_packed(p, &bytes, &other).unwrap_err().to_string();
        assert!(e.contains("offsets"), "{e}");
        let nan = packed(&chunk(&[1.0, f64::NAN], &[1.0, 2.0], 5.0), origin);
        let e = recs.push_packed(p, &nan, &names).unwrap_err().to_string();
        assert!(e.contains("point 5 ") && e.contains("not a finite"), "{e}");
        assert_eq!((recs.len(), recs.rows.len()), (4, 8));
        let mut tight = PartBuilder::new(origin, Some(cols.bounds()), 0);
        let far = packed(&chunk(&[10.0, 13.0], &[1.0, 1.0], 5.0), origin);
        let e = tight.push_packed(p, &far, &names).unwrap_err().to_string();
        assert!(e.contains("point 1 lies outside"), "{e}");
        assert!(tight.is_empty());
    }
}
