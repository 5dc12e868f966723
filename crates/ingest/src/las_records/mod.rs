//! Uncompressed LAS point records (formats 0–10) decoded straight from a memory
//! map: a fixed-stride reader. Each chunk is cut into windows of records that stay
//! in cache, decoded in parallel (rayon) into disjoint slices of the chunk's
//! columns. The columns and their meaning are exactly those of the `las`-crate
//! path in [`super::las`] (which still reads LAZ): the tests compare the two.
//! The same map gives any record's attributes again (`LasRows`, `rows.rs`), so
//! a part need not hold a copy of them.

mod rows;

use super::color::{ColorNormalizer, ColorScale};
use super::error::IngestError;
use super::las::Opened;
use super::{PointReader, ReadOptions, SourceInfo};
use crate::bigvec;
use crate::points::{Attribute, Bounds, ChunkExtent, PointColumns, RowSource};
use pcimg_core::time::split;
use rayon::prelude::*;
use rows::LasRows;
use std::mem::MaybeUninit;
use std::path::Path;

/// Records decoded per parallel job (about half a megabyte of records).
const WINDOW: usize = 16 * 1024;
/// Records per window when sampling.
const SAMPLE_WINDOW: usize = 1024;

/// Where the fields of one record format are.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Fields {
    pub(crate) stride: usize,
    extended: bool,
    pub(crate) gps: Option<usize>,
    rgb: Option<usize>,
    nir: Option<usize>,
    /// Scale and offset per axis (`value = scale · raw + offset`, as the `las`
    /// crate computes it).
    transforms: [(f64, f64); 3],
}

impl Fields {
    pub(crate) fn new(
        path: &Path,
        f: &las::point::Format,
        stride: usize,
        h: &las::Header,
    ) -> Result<Self, IngestError> {
        let (base, gps, rgb, nir) = if f.is_extended {
            (
                30,
                Some(22),
                f.has_color.then_some(30),
                f.has_nir.then_some(36),
            )
        } else {
            let gps = f.has_gps_time.then_some(20);
            let rgb = f.has_color.then_some(if f.has_gps_time { 28 } else { 20 });
            (20, gps, rgb, None)
        };
        let need = [
            Some(base),
            gps.map(|g| g + 8),
            rgb.map(|c| c + 6),
            nir.map(|n| n + 2),
        ]
        .into_iter()
        .flatten()
        .max()
        .unwrap_or(base);
        if stride < need {
            return Err(IngestError::binary(
                path,
                0,
                format!(
                    "point records of {stride} bytes are too short for point format {} \
                     ({need} bytes at least)",
                    f.to_u8().unwrap_or(255)
                ),
            ));
        }
        let t = h.transforms();
        Ok(Fields {
            stride,
            extended: f.is_extended,
            gps,
            rgb,
            nir,
            transforms: [
                (t.x.scale, t.x.offset),
                (t.y.scale, t.y.offset),
                (t.z.scale, t.z.offset),
            ],
        })
    }
}

#[inline]
fn u16_at(r: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([r[at], r[at + 1]])
}

#[inline]
fn i32_at(r: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]])
}

#[inline]
fn f64_at(r: &[u8], at: usize) -> f64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&r[at..at + 8]);
    f64::from_le_bytes(b)
}

/// The output slices of one window: x, y, z and the attributes in
/// [`attribute_names`] order.
///
/// Columns are written, not read: their memory is not zeroed first (every slot
/// is written, see the end of `decode_window`).
struct Out<'a> {
    xyz: [&'a mut [MaybeUninit<f64>]; 3],
    attrs: Vec<&'a mut [MaybeUninit<f32>]>,
}

/// One attribute of a record: where it lies and how it becomes a value.
#[derive(Debug, Clone, Copy)]
enum Field {
    /// A little-endian `u16` at this byte (intensity, colour, NIR).
    U16(usize),
    /// `(byte >> shift) & mask` of this byte (returns, classification).
    Bits(usize, u8, u8),
    /// GPS time: the `f64` at this byte, less the reader's GPS offset.
    Gps(usize),
    /// One of the whole numbers that make that GPS time exact: part `k` (1 to
    /// 3) of `pcimg_core::time::split`.
    GpsExact(usize, usize),
    /// The scan angle in degrees: the older formats' `i8` of whole degrees at
    /// this byte, or (`true`) the extended formats' `i16` of 0.006° steps.
    Angle(usize, bool),
    /// The older formats' flags, packed as the `las_flags` band packs them.
    LegacyFlags,
}

impl Field {
    /// The field's value in record `r`, less `gps_offset` for GPS time.
    #[inline(always)]
    fn value(self, r: &[u8], gps_offset: f64) -> f32 {
        match self {
            Field::U16(at) => f32::from(u16_at(r, at)),
            Field::Bits(at, shift, mask) => f32::from((r[at] >> shift) & mask),
            Field::Gps(at) => (f64_at(r, at) - gps_offset) as f32,
            Field::GpsExact(at, k) => split(f64_at(r, at), gps_offset)[k],
            // As the `las` crate gives them (f32 arithmetic).
            Field::Angle(at, false) => f32::from(r[at] as i8),
            Field::Angle(at, true) => f32::from(u16_at(r, at) as i16) * 0.006,
            Field::LegacyFlags => f32::from(crate::las::las_flags(r, false)),
        }
    }
}

impl Fields {
    /// The record's attributes in the order of the columns (`las::attribute_names`),
    /// each with whether it is a colour channel (which a colour scale applies to).
    fn attributes(&self) -> Vec<(Field, bool)> {
        let mut v = vec![(Field::U16(12), false)];
        if self.extended {
            v.extend(
                [
                    Field::Bits(14, 0, 15),
                    Field::Bits(14, 4, 15),
                    Field::Bits(16, 0, 0xff),
                ]
                .map(|f| (f, false)),
            );
        } else {
            v.extend(
                [
                    Field::Bits(14, 0, 7),
                    Field::Bits(14, 3, 7),
                    Field::Bits(15, 0, 0b0001_1111),
                ]
                .map(|f| (f, false)),
            );
        }
        if let Some(g) = self.gps {
            v.extend((0..4).map(|k| match k {
                0 => (Field::Gps(g), false),
                k => (Field::GpsExact(g, k), false),
            }));
        }
        if let Some(c) = self.rgb {
            v.extend((0..3).map(|j| (Field::U16(c + 2 * j), true)));
        }
        v.extend(self.nir.map(|n| (Field::U16(n), false)));
        // Scan angle, user data, point source ID and the flags (`LAS_BANDS`).
        if self.extended {
            v.extend(
                [
                    Field::Angle(18, true),
                    Field::Bits(17, 0, 0xff),
                    Field::U16(20),
                    Field::Bits(15, 0, 0xff),
                ]
                .map(|f| (f, false)),
            );
        } else {
            v.extend(
                [
                    Field::Angle(16, false),
                    Field::Bits(17, 0, 0xff),
                    Field::U16(18),
                    Field::LegacyFlags,
                ]
                .map(|f| (f, false)),
            );
        }
        v
    }
}

/// Where GPS time's four columns begin among `m` columns of `fields` (its
/// Float32 and the three whole numbers that make it exact,
/// `pcimg_core::time::split`), and the byte of the time in a record.
fn time_columns(fields: &[(Field, bool)], m: usize) -> Option<(usize, usize)> {
    let k = fields.iter().position(|a| matches!(a.0, Field::Gps(_)))?;
    match fields[k].0 {
        Field::Gps(at) if k + 4 <= m => Some((k, at)),
        _ => None,
    }
}

/// Decodes the records `rec` (a whole number of records) into `out`.
fn decode_window(rec: &[u8], f: &Fields, gps_offset: f64, out: Out<'_>) {
    let records = || rec.chunks_exact(f.stride);
    let Out { xyz, mut attrs } = out;
    for (axis, col) in xyz.into_iter().enumerate() {
        for (v, r) in col.iter_mut().zip(records()) {
            v.write(coordinate(r, &f.transforms, axis));
        }
    }
    decode_attributes(rec, f, gps_offset, None, &mut attrs);
}

/// Decodes the attributes of the records `rec` (a whole number of records)
/// into the columns `attrs` (one per attribute field, as `attribute_names`
/// lists them, each at least a value a record), colour scaled by `colour`
/// where given: GPS time split once a record into its four columns, every
/// other column a loop of its own.
pub(super) fn decode_attributes(
    rec: &[u8],
    f: &Fields,
    gps_offset: f64,
    colour: Option<ColorScale>,
    attrs: &mut [&mut [MaybeUninit<f32>]],
) {
    let records = || rec.chunks_exact(f.stride);
    let fields = f.attributes();
    // GPS time and the three whole numbers that make it exact: one pass, one
    // split a record.
    let time = time_columns(&fields, attrs.len());
    if let Some((k, at)) = time
        && let [c0, c1, c2, c3] = &mut attrs[k..k + 4]
    {
        for (i, r) in records().enumerate() {
            let [v, lo, mid, hi] = split(f64_at(r, at), gps_offset);
            c0[i].write(v);
            c1[i].write(lo);
            c2[i].write(mid);
            c3[i].write(hi);
        }
    }
    for (k, col) in attrs.iter_mut().enumerate() {
        if time.is_some_and(|(t, _)| (t..t + 4).contains(&k)) {
            continue;
        }
        // Every column is written (attribute_names lists the fields); any left
        // over would be NaN rather than unwritten memory.
        let field = fields.get(k);
        fill_field(
            rec,
            f.stride,
            field.map(|a| a.0),
            colour.filter(|_| field.is_some_and(|a| a.1)),
            gps_offset,
            col,
            1,
            0,
        );
    }
}

/// Decodes the whole records `rec` into columns named `names` (those of
/// `las::attribute_names` for the format), GPS time less `gps_offset`. One
/// window: callers decode many at once in parallel (COPC nodes).
pub(crate) fn decode_records(
    rec: &[u8],
    f: &Fields,
    gps_offset: f64,
    names: &[String],
) -> PointColumns {
    let n = rec.len() / f.stride;
    let mut xyz: [Vec<f64>; 3] = std::array::from_fn(|_| Vec::with_capacity(n));
    let mut attrs: Vec<Vec<f32>> = names.iter().map(|_| Vec::with_capacity(n)).collect();
    {
        let [x, y, z] = &mut xyz;
        let out = Out {
            xyz: [
                &mut x.spare_capacity_mut()[..n],
                &mut y.spare_capacity_mut()[..n],
                &mut z.spare_capacity_mut()[..n],
            ],
            attrs: attrs
                .iter_mut()
                .map(|a| &mut a.spare_capacity_mut()[..n])
                .collect(),
        };
        decode_window(&rec[..n * f.stride], f, gps_offset, out);
    }
    for c in xyz.iter_mut() {
        // SAFETY: `decode_window` wrote every one of the n slots of each column.
        unsafe { c.set_len(n) };
    }
    for c in attrs.iter_mut() {
        // SAFETY: as above.
        unsafe { c.set_len(n) };
    }
    let [x, y, z] = xyz;
    PointColumns {
        x,
        y,
        z,
        attributes: names
            .iter()
            .zip(attrs)
            .map(|(name, values)| {
                let mut a = Attribute::new(name.clone(), values);
                if name == "gps_time" {
                    a.offset = gps_offset;
                }
                a
            })
            .collect(),
    }
}

/// GPS time of record `r` (for the offset the columns keep it relative to).
pub(crate) fn gps_of(r: &[u8], f: &Fields) -> Option<f64> {
    f.gps.map(|g| f64_at(r, g))
}

/// Value `j` of each row of `dst` (`m` values a row, one row a record of `rec`):
/// `field`'s value (NaN when none), colour scaled by `colour` when given. A loop
/// per kind of field, each with its constants fixed.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn fill_field(
    rec: &[u8],
    stride: usize,
    field: Option<Field>,
    colour: Option<ColorScale>,
    gps_offset: f64,
    dst: &mut [MaybeUninit<f32>],
    m: usize,
    j: usize,
) {
    #[inline(always)]
    fn fill(
        rec: &[u8],
        stride: usize,
        dst: &mut [MaybeUninit<f32>],
        m: usize,
        j: usize,
        value: impl Fn(&[u8]) -> f32,
    ) {
        for (row, r) in dst.chunks_exact_mut(m).zip(rec.chunks_exact(stride)) {
            row[j].write(value(r));
        }
    }
    let (s, g) = (stride, gps_offset);
    match (field, colour) {
        (Some(Field::U16(at)), None) => fill(rec, s, dst, m, j, |r| f32::from(u16_at(r, at))),
        (Some(Field::U16(at)), Some(c)) => {
            fill(rec, s, dst, m, j, |r| c.one(f32::from(u16_at(r, at))))
        }
        (Some(Field::Bits(at, shift, mask)), _) => {
            fill(rec, s, dst, m, j, |r| f32::from((r[at] >> shift) & mask))
        }
        (Some(Field::Gps(at)), _) => fill(rec, s, dst, m, j, |r| (f64_at(r, at) - g) as f32),
        (Some(Field::GpsExact(at, k)), _) => {
            fill(rec, s, dst, m, j, |r| split(f64_at(r, at), g)[k])
        }
        (Some(f @ (Field::Angle(..) | Field::LegacyFlags)), _) => {
            fill(rec, s, dst, m, j, |r| f.value(r, g))
        }
        (None, _) => fill(rec, s, dst, m, j, |_| f32::NAN),
    }
}

/// What [`RecordReader::next_extent`] finds in a window of records: each axis's
/// smallest and largest stored integer, each field's smallest and largest raw
/// value (NaN ignored), and how many colour values the colour scale clamps.
struct Scan {
    lo: [i32; 3],
    hi: [i32; 3],
    ranges: Vec<(f64, f64)>,
    clamped: u64,
}

impl Scan {
    /// The scan of the records `rec` (a whole number of them, at least one).
    fn of(rec: &[u8], stride: usize, fields: &[(Field, bool)], colour: ColorScale) -> Scan {
        let (mut lo, mut hi) = ([i32::MAX; 3], [i32::MIN; 3]);
        for r in rec.chunks_exact(stride) {
            for a in 0..3 {
                let v = i32_at(r, 4 * a);
                lo[a] = lo[a].min(v);
                hi[a] = hi[a].max(v);
            }
        }
        let records = || rec.chunks_exact(stride);
        let mut clamped = 0;
        let ranges = fields
            .iter()
            .map(|&(field, is_colour)| match field {
                Field::U16(at) => {
                    let (l, h) = records()
                        .map(|r| u16_at(r, at))
                        .fold((u16::MAX, 0), |(l, h), v| (l.min(v), h.max(v)));
                    if is_colour {
                        clamped += records()
                            .filter(|r| colour.clamps(f32::from(u16_at(r, at))))
                            .count() as u64;
                    }
                    (f64::from(l), f64::from(h))
                }
                Field::Bits(at, shift, mask) => {
                    let (l, h) = records()
                        .map(|r| (r[at] >> shift) & mask)
                        .fold((u8::MAX, 0), |(l, h), v| (l.min(v), h.max(v)));
                    (f64::from(l), f64::from(h))
                }
                Field::Gps(at) => records()
                    .map(|r| f64_at(r, at))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                        (l.min(v), h.max(v))
                    }),
                // The store records the range these may take
                // (`pcimg_core::time::EXACT_RANGE`), not what they hold.
                Field::GpsExact(..) => pcimg_core::time::EXACT_RANGE_F64,
                Field::Angle(..) | Field::LegacyFlags => records()
                    .map(|r| f64::from(field.value(r, 0.0)))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                        (l.min(v), h.max(v))
                    }),
            })
            .collect();
        Scan {
            lo,
            hi,
            ranges,
            clamped,
        }
    }

    /// Both scans' union.
    fn union(mut self, o: Scan) -> Scan {
        for a in 0..3 {
            self.lo[a] = self.lo[a].min(o.lo[a]);
            self.hi[a] = self.hi[a].max(o.hi[a]);
        }
        for (r, q) in self.ranges.iter_mut().zip(o.ranges) {
            *r = (r.0.min(q.0), r.1.max(q.1));
        }
        self.clamped += o.clamped;
        self
    }
}

/// Coordinate `axis` of record `r`: its integer scaled and offset by the
/// header's transform `t` (what [`decode_window`] delivers).
#[inline(always)]
fn coordinate(r: &[u8], t: &[(f64, f64); 3], axis: usize) -> f64 {
    transformed(t, axis, i32_at(r, 4 * axis))
}

/// The stored integer `v` of axis `axis` scaled and offset by the header's
/// transform `t` (monotonic in `v`).
#[inline(always)]
fn transformed(t: &[(f64, f64); 3], axis: usize, v: i32) -> f64 {
    let (scale, offset) = t[axis];
    scale * f64::from(v) + offset
}

/// Reader of uncompressed LAS files.
pub struct RecordReader {
    info: SourceInfo,
    map: std::sync::Arc<memmap2::Mmap>,
    fields: Fields,
    start: usize,
    total: usize,
    done: usize,
    chunk: usize,
    gps_offset: f64,
    colors: ColorNormalizer,
    released: usize,
    /// Records per record delivered: 1, or more once sampling (see
    /// [`PointReader::sample_rest`]).
    every: usize,
    /// Reading the next chunk's records ahead of the decoders (while every
    /// record is read).
    ahead: super::ahead::Ahead,
    /// Held by every [`LasRows`] given out: while one lives, consumed pages of
    /// the map stay mapped.
    offered: std::sync::Arc<()>,
}

impl RecordReader {
    pub(crate) fn new(path: &Path, o: Opened, opts: &ReadOptions) -> Result<Self, IngestError> {
        let map = std::sync::Arc::new(super::map_file(path)?);
        let stride = o.record_len as usize;
        let fields = Fields::new(path, o.header.point_format(), stride, &o.header)?;
        let total = o.header.number_of_points() as usize;
        let start = o.start as usize;
        // open_header checked that the declared records lie inside the file; the
        // map is the same file, checked again so no slice below can go out of it.
        total
            .checked_mul(stride)
            .and_then(|b| b.checked_add(start))
            .filter(|&e| e <= map.len())
            .ok_or_else(|| {
                IngestError::binary(
                    path,
                    map.len() as u64,
                    format!("truncated file: {total} records of {stride} bytes from byte {start}"),
                )
            })?;
        let gps_offset = match fields.gps {
            Some(g) => {
                let first = total.min(super::OFFSET_SAMPLE);
                let mut t: Vec<f64> = map[start..start + first * stride]
                    .chunks_exact(stride)
                    .map(|r| f64_at(r, g))
                    .collect();
                super::attribute_offset(&mut t, true)
            }
            None => 0.0,
        };
        let ahead =
            super::ahead::Ahead::new(map.clone(), start as u64, (start + total * stride) as u64);
        Ok(RecordReader {
            info: o.info,
            map,
            fields,
            start,
            total,
            done: 0,
            chunk: opts.chunk_points.max(1),
            gps_offset,
            colors: ColorNormalizer::new(false),
            released: 0,
            every: 1,
            ahead,
            offered: std::sync::Arc::new(()),
        })
    }
}

impl RecordReader {
    /// The offset of attribute `name`'s values.
    fn offset_of(&self, name: &str) -> f64 {
        if name == "gps_time" {
            self.gps_offset
        } else {
            0.0
        }
    }

    /// Whether [`PointReader::row_source`] gives every point's rows (once the
    /// colour scale is decided): while every record is read, and only when they
    /// are no larger than the f64 columns the memory budget counts for each point
    /// (`convert::budget::bytes_per_point`: the mapped records take their place
    /// while a part's tiles are written), so larger ones (extra bytes) are copied
    /// as usual.
    fn gives_rows(&self) -> bool {
        self.every == 1 && self.fields.stride <= 24 + 4 * self.info.attribute_names.len()
    }

    /// Moves past the `stretch` records from byte `first`. While a part takes its
    /// rows from the map (`row_source`), its records are read again: their
    /// pages stay mapped.
    fn consumed(&mut self, first: usize, stretch: usize) {
        self.done += stretch;
        if std::sync::Arc::strong_count(&self.offered) == 1 {
            let end = first + stretch * self.fields.stride;
            super::release_consumed(&self.map, &mut self.released, end);
        }
    }
}

impl PointReader for RecordReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        if self.done >= self.total {
            return Ok(None);
        }
        // A stretch of records, of which n are decoded: all of them, or when
        // sampling, windows spread evenly over it.
        let stretch = self
            .chunk
            .saturating_mul(self.every)
            .min(self.total - self.done);
        let n = (stretch / self.every).clamp(1, stretch);
        let names = &self.info.attribute_names;
        let mut xyz: [Vec<f64>; 3] = std::array::from_fn(|_| bigvec::with_capacity(n));
        let mut attrs: Vec<Vec<f32>> = names.iter().map(|_| bigvec::with_capacity(n)).collect();
        // One Out per window, each holding that window's slice of every column.
        // Sampled windows are small, so that many spread over the stretch.
        let window = if n < stretch { SAMPLE_WINDOW } else { WINDOW };
        let windows = n.div_ceil(window);
        let mut outs: Vec<Out<'_>> = Vec::with_capacity(windows);
        {
            let [x, y, z] = &mut xyz;
            let mut xs = x.spare_capacity_mut()[..n].chunks_mut(window);
            let mut ys = y.spare_capacity_mut()[..n].chunks_mut(window);
            let mut zs = z.spare_capacity_mut()[..n].chunks_mut(window);
            let mut per_attr: Vec<std::slice::ChunksMut<'_, MaybeUninit<f32>>> = attrs
                .iter_mut()
                .map(|a| a.spare_capacity_mut()[..n].chunks_mut(window))
                .collect();
            for _ in 0..windows {
                let (Some(x), Some(y), Some(z)) = (xs.next(), ys.next(), zs.next()) else {
                    break;
                };
                outs.push(Out {
                    xyz: [x, y, z],
                    attrs: per_attr.iter_mut().filter_map(|c| c.next()).collect(),
                });
            }
        }
        let f = self.fields;
        let first = self.start + self.done * f.stride;
        // This chunk and the next are asked for while this one is decoded.
        if self.every == 1 {
            self.ahead.want((first + 2 * self.chunk * f.stride) as u64);
        }
        let bytes = &self.map[first..first + stretch * f.stride];
        let gps_offset = self.gps_offset;
        // When sampling, each window sits at a random place in its slot of the
        // stretch (so a periodic layout cannot alias with the windows).
        let slot = if n < stretch {
            stretch / windows
        } else {
            window
        };
        let done = self.done;
        outs.into_par_iter().enumerate().for_each(|(w, out)| {
            let len = out.xyz[0].len();
            let jitter = if n < stretch {
                super::mix((done + w) as u64) as usize % (slot.saturating_sub(len) + 1)
            } else {
                0
            };
            let s = (w * slot + jitter).min(stretch - len) * f.stride;
            decode_window(&bytes[s..s + len * f.stride], &f, gps_offset, out);
        });
        // SAFETY: the windows cover all n slots of every column and
        // `decode_window` writes each slot of its window.
        for c in xyz.iter_mut() {
            // SAFETY: as above: every slot of this column was written.
            unsafe { c.set_len(n) };
        }
        for c in attrs.iter_mut() {
            // SAFETY: as above: every slot of this column was written.
            unsafe { c.set_len(n) };
        }
        let [x, y, z] = xyz;
        let mut cols = PointColumns {
            x,
            y,
            z,
            attributes: names
                .iter()
                .zip(attrs)
                .map(|(name, values)| {
                    let mut a = Attribute::new(name.clone(), values);
                    a.offset = self.offset_of(name);
                    a
                })
                .collect(),
        };
        self.consumed(first, stretch);
        self.colors.apply(&mut cols);
        Ok(Some(cols))
    }

    fn gives_extents(&mut self) -> Result<bool, IngestError> {
        Ok(self.gives_rows())
    }

    /// The extent of the next chunk's records, scanned straight from the map: no
    /// column is decoded, the coordinates' bounds come from each axis's smallest
    /// and largest integer (the transform is monotonic) and each attribute's
    /// range from its smallest and largest raw value; exactly what
    /// [`ChunkExtent::of`] makes of the chunk `next_chunk` would have delivered.
    fn next_extent(&mut self) -> Result<Option<ChunkExtent>, IngestError> {
        if !self.gives_rows() {
            return Ok(self.next_chunk()?.map(|c| ChunkExtent::of(&c)));
        }
        if self.done >= self.total {
            return Ok(None);
        }
        let stretch = self.chunk.min(self.total - self.done);
        let f = self.fields;
        let first = self.start + self.done * f.stride;
        self.ahead.want((first + 2 * self.chunk * f.stride) as u64);
        let bytes = &self.map[first..first + stretch * f.stride];
        let fields = f.attributes();
        let colour = match f.rgb {
            // As `next_chunk` decides it: from the first chunk's first points.
            Some(c) => {
                let n = stretch.min(super::color::DECIDE_POINTS);
                let first: Vec<Vec<f32>> = (0..3)
                    .map(|j| {
                        bytes[..n * f.stride]
                            .chunks_exact(f.stride)
                            .map(|r| f32::from(u16_at(r, c + 2 * j)))
                            .collect()
                    })
                    .collect();
                self.colors.decide(first.iter().map(|v| &v[..]))
            }
            None => ColorScale::Identity,
        };
        let scan = bytes
            .par_chunks(WINDOW * f.stride)
            .map(|w| Scan::of(w, f.stride, &fields, colour))
            .reduce_with(Scan::union)
            .expect("a stretch holds at least one record");
        self.colors.add_clamped(scan.clamped);
        let mut bounds = Bounds::EMPTY;
        let mut finite = true;
        for a in 0..3 {
            let ends = [scan.lo[a], scan.hi[a]].map(|v| transformed(&f.transforms, a, v));
            finite &= ends.iter().all(|v| v.is_finite());
            bounds.min[a] = ends[0].min(ends[1]);
            bounds.max[a] = ends[0].max(ends[1]);
        }
        // Rare (a header's transform that overflows): found record by record.
        let not_finite = (!finite)
            .then(|| {
                bytes.chunks_exact(f.stride).enumerate().find_map(|(i, r)| {
                    let p = [0, 1, 2].map(|a| coordinate(r, &f.transforms, a));
                    (!p.iter().all(|v| v.is_finite())).then_some((i, p))
                })
            })
            .flatten();
        let gps_offset = self.gps_offset;
        let ranges = fields
            .iter()
            .zip(scan.ranges)
            .map(|(&(field, is_colour), (l, h))| match field {
                Field::Gps(_) => ((l - gps_offset) as f32, (h - gps_offset) as f32),
                _ if is_colour => (colour.one(l as f32), colour.one(h as f32)),
                _ => (l as f32, h as f32),
            })
            .collect();
        self.consumed(first, stretch);
        Ok(Some(ChunkExtent {
            len: stretch,
            bounds,
            attributes: self
                .info
                .attribute_names
                .iter()
                .map(|name| (name.clone(), self.offset_of(name)))
                .collect(),
            ranges,
            not_finite,
        }))
    }

    fn bytes_done(&self) -> u64 {
        if self.done >= self.total {
            self.info.file_bytes
        } else {
            (self.start + self.done * self.fields.stride) as u64
        }
    }

    fn skipped(&self) -> u64 {
        0
    }

    fn clamped_colours(&self) -> u64 {
        self.colors
            .clamped()
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    fn row_source(&self) -> Option<std::sync::Arc<dyn RowSource>> {
        let m = self.info.attribute_names.len();
        let colour = match (self.fields.rgb, self.colors.scale()) {
            (None, _) => ColorScale::Identity,
            (Some(_), Some(s)) => s,
            // The colour scale is not decided yet (no chunk read).
            (Some(_), None) => return None,
        };
        if !self.gives_rows() {
            return None;
        }
        Some(std::sync::Arc::new(LasRows {
            map: self.map.clone(),
            _offered: self.offered.clone(),
            start: self.start,
            total: self.total,
            fields: self.fields,
            gps_offset: self.gps_offset,
            colour,
            width: m,
        }))
    }

    fn sample_rest(&mut self, every: u64) -> bool {
        self.every = every.clamp(1, 1 << 20) as usize;
        // Sampled windows are sparse: reading everything ahead would be waste.
        if self.every > 1 {
            self.ahead.stop();
        }
        self.every > 1
    }
}

#[cfg(test)]
mod tests {
    use super::super::las::LasReader;
    use super::super::{PointReader, ReadOptions, open};
    use crate::points::{ChunkExtent, PointColumns};

    /// Writes `n` points of point format `format` with varied field values.
    fn write(path: &std::path::Path, format: u8, n: usize) {
        let mut b = las::Builder::default();
        b.version = las::Version::new(1, 4);
        b.point_format = las::point::Format::new(format).unwrap();
        b.transforms = las::Vector {
            x: las::Transform {
                scale: 0.001,
                offset: 500_000.0,
            },
            y: las::Transform {
                scale: 0.01,
                offset: 4_000_000.0,
            },
            z: las::Transform {
                scale: 0.001,
                offset: -10.0,
            },
        };
        let header = b.into_header().unwrap();
        let mut w = las::Writer::from_path(path, header).unwrap();
        let f = las::point::Format::new(format).unwrap();
        let mut r = crate::rng::Rng::new(u64::from(format));
        for i in 0..n {
            let nr = if f.is_extended { 15 } else { 7 };
            let returns = 1 + (r.next_u64() % nr) as u8;
            let class = (r.next_u64() % if f.is_extended { 256 } else { 32 }) as u8;
            w.write_point(las::Point {
                x: 500_000.0 + r.f64() * 1000.0,
                y: 4_000_000.0 + r.f64() * 2000.0,
                z: -10.0 + r.f64() * 100.0,
                intensity: r.next_u64() as u16,
                return_number: 1 + (i as u8 % returns),
                number_of_returns: returns,
                classification: las::point::Classification::new(class)
                    .unwrap_or(las::point::Classification::Ground),
                gps_time: f.has_gps_time.then_some(4e8 + i as f64 * 3e-5),
                color: f.has_color.then(|| {
                    las::Color::new(
                        r.next_u64() as u16,
                        r.next_u64() as u16,
                        r.next_u64() as u16,
                    )
                }),
                nir: f.has_nir.then(|| r.next_u64() as u16),
                waveform: f.has_waveform.then(Default::default),
                scan_angle: if f.is_extended {
                    (r.next_u64() % 60001) as f32 * 0.006 - 180.0
                } else {
                    (r.next_u64() % 181) as f32 - 90.0
                },
                user_data: r.next_u64() as u8,
                point_source_id: r.next_u64() as u16,
                scan_direction: if r.next_u64().is_multiple_of(2) {
                    las::point::ScanDirection::LeftToRight
                } else {
                    las::point::ScanDirection::RightToLeft
                },
                is_edge_of_flight_line: r.next_u64().is_multiple_of(3),
                is_synthetic: r.next_u64().is_multiple_of(2),
                is_key_point: r.next_u64().is_multiple_of(5),
                is_withheld: r.next_u64().is_multiple_of(7),
                is_overlap: f.is_extended && r.next_u64().is_multiple_of(2),
                scanner_channel: if f.is_extended {
                    (r.next_u64() % 4) as u8
                } else {
                    0
                },
                ..Default::default()
            })
            .unwrap();
        }
        w.close().unwrap();
    }

    fn drain(mut r: Box<dyn PointReader>) -> PointColumns {
        let names = r.info().attribute_names.clone();
        let mut all = PointColumns {
            attributes: names
                .iter()
                .map(|n| crate::points::Attribute::new(n.clone(), Vec::new()))
                .collect(),
            ..Default::default()
        };
        while let Some(c) = r.next_chunk().unwrap() {
            all.append(&c).unwrap();
        }
        assert_eq!(r.bytes_done(), r.info().file_bytes);
        all
    }

    /// Points in each file of [`every_format`].
    const N: usize = 40_000;

    /// A file of [`N`] points in every point format 0–10 (in `dir`), and options
    /// that read them in chunks of more points than a window, not dividing it.
    fn every_format(dir: &std::path::Path) -> (ReadOptions, Vec<(u8, std::path::PathBuf)>) {
        let opts = ReadOptions {
            chunk_points: 17_000,
            ..Default::default()
        };
        let files = (0..=10u8)
            .map(|format| {
                let path = dir.join(format!("f{format}.las"));
                write(&path, format, N);
                (format, path)
            })
            .collect();
        (opts, files)
    }

    #[test]
    fn every_point_format_matches_the_las_crate() {
        let dir = tempfile::tempdir().unwrap();
        let (opts, files) = every_format(dir.path());
        let n = N;
        for (format, path) in files {
            let ours = drain(open(&path, &opts).unwrap());
            let theirs = drain(Box::new(LasReader::open(&path, &opts).unwrap()));
            assert_eq!(ours.len(), n, "format {format}");
            assert!(
                ours.x == theirs.x && ours.y == theirs.y && ours.z == theirs.z,
                "format {format}"
            );
            assert_eq!(ours.attributes.len(), theirs.attributes.len());
            for (a, b) in ours.attributes.iter().zip(&theirs.attributes) {
                assert_eq!(a.name, b.name, "format {format}");
                assert_eq!(a.offset, b.offset, "format {format} {}", a.name);
                assert!(a.values == b.values, "format {format} {}", a.name);
            }
        }
    }

    /// The extents read straight from the map equal those of the chunks
    /// `next_chunk` delivers, chunk by chunk, in every point format: bounds,
    /// attribute ranges (16-bit colour scaled), offsets; and so do the counts
    /// of clamped colour values when 8-bit colour in 16-bit fields breaks the
    /// pattern later, or GPS times are NaN.
    #[test]
    fn extents_from_the_map_match_the_chunks() {
        let dir = tempfile::tempdir().unwrap();
        let (opts, mut files) = every_format(dir.path());
        // 8-bit colour in the first chunk, some larger values after it; some
        // NaN GPS times.
        let odd = dir.path().join("odd.las");
        let mut b = las::Builder::from((1, 2));
        b.point_format = las::point::Format::new(3).unwrap();
        let mut w = las::Writer::from_path(&odd, b.into_header().unwrap()).unwrap();
        for i in 0..N {
            let c = if i > 20_000 && i.is_multiple_of(7) {
                300 + i as u16 % 50
            } else {
                i as u16 % 200
            };
            w.write_point(las::Point {
                x: i as f64,
                y: -(i as f64),
                z: (i % 13) as f64,
                gps_time: Some(if i.is_multiple_of(5) {
                    f64::NAN
                } else {
                    i as f64
                }),
                color: Some(las::Color::new(c, 255 - c.min(255), 7)),
                ..Default::default()
            })
            .unwrap();
        }
        w.close().unwrap();
        files.push((3, odd));
        for (format, path) in files {
            let mut chunks = open(&path, &opts).unwrap();
            let mut extents = open(&path, &opts).unwrap();
            // (Waveform formats too: their records, 57 to 67 bytes, are no
            // larger than the columns they hold, 60 to 72.)
            assert!(extents.gives_extents().unwrap(), "format {format}");
            let mut k = 0;
            while let Some(c) = chunks.next_chunk().unwrap() {
                let e = extents
                    .next_extent()
                    .unwrap()
                    .expect("as many extents as chunks");
                assert_eq!(e, ChunkExtent::of(&c), "format {format}, chunk {k}");
                assert_eq!(extents.bytes_done(), chunks.bytes_done());
                k += 1;
            }
            assert!(extents.next_extent().unwrap().is_none());
            assert_eq!(k, N.div_ceil(17_000), "format {format}");
            assert_eq!(extents.clamped_colours(), chunks.clamped_colours());
            if path.ends_with("odd.las") {
                assert!(chunks.clamped_colours() > 0);
            }
        }
    }

    /// Rows given again from the map equal the chunks' values, bit for bit, in
    /// any order, for every point format (16-bit colour scaled as the chunks
    /// are).
    #[test]
    fn rows_from_the_map_match_the_chunks() {
        let dir = tempfile::tempdir().unwrap();
        let (opts, files) = every_format(dir.path());
        let n = N;
        for (format, path) in files {
            let mut r = open(&path, &opts).unwrap();
            if [2, 3, 5, 7, 8, 10].contains(&format) {
                assert!(
                    r.row_source().is_none(),
                    "format {format}: colour scale undecided"
                );
            }
            let first = r.next_chunk().unwrap().unwrap();
            let src = r.row_source().expect("uncompressed LAS gives its rows");
            let mut all = first;
            while let Some(c) = r.next_chunk().unwrap() {
                all.append(&c).unwrap();
            }
            let m = all.attributes.len();
            assert_eq!((src.len(), src.width()), (n, m), "format {format}");
            // A scattered order, as a tile's points come.
            let idx: Vec<u32> = (0..n as u64)
                .map(|i| (i * 7919 % n as u64) as u32)
                .collect();
            let mut rows = vec![1.5f32];
            src.gather(&idx, &mut rows);
            assert_eq!(rows.len(), 1 + n * m);
            for (k, &i) in idx.iter().enumerate() {
                for (j, a) in all.attributes.iter().enumerate() {
                    let (got, want) = (rows[1 + k * m + j], a.values[i as usize]);
                    assert_eq!(got.to_bits(), want.to_bits(), "format {format} {}", a.name);
                }
            }
            // The same as columns, written straight by field (the trait's
            // default, rows moved over, alike): only the first `n` of each
            // column, the rest untouched.
            let mut cols = vec![vec![7.0f32; n + 3]; m];
            let mut views: Vec<&mut [f32]> = cols.iter_mut().map(|c| &mut c[..]).collect();
            src.gather_columns(&idx, &mut views);
            let mut moved = vec![vec![7.0f32; n + 3]; m];
            let mut views: Vec<&mut [f32]> = moved.iter_mut().map(|c| &mut c[..]).collect();
            crate::points::columns_of_rows(&rows[1..], m, &mut views);
            for (j, (col, mv)) in cols.iter().zip(&moved).enumerate() {
                let name = &all.attributes[j].name;
                for (k, &i) in idx.iter().enumerate() {
                    let want = all.attributes[j].values[i as usize].to_bits();
                    assert_eq!(col[k].to_bits(), want, "format {format} {name} column");
                    assert_eq!(mv[k].to_bits(), want, "format {format} {name} moved");
                }
                assert!(col[n..].iter().chain(&mv[n..]).all(|&v| v == 7.0));
            }
            // Positions as the store would make them from the chunks, gathered,
            // in a range, and read with the rows.
            assert!(src.has_positions());
            let origin = [500_010.5, 4_000_020.25, 3.0];
            let want = |i: usize| {
                let p = [all.x[i], all.y[i], all.z[i]];
                [0, 1, 2].map(|a| ((p[a] - origin[a]) as f32).to_bits())
            };
            let bits = |v: &[[f32; 3]]| -> Vec<[u32; 3]> {
                v.iter().map(|p| p.map(f32::to_bits)).collect()
            };
            let mut pos = Vec::new();
            src.positions(&idx, origin, &mut pos);
            let expect: Vec<[u32; 3]> = idx.iter().map(|&i| want(i as usize)).collect();
            assert_eq!(bits(&pos), expect, "format {format}");
            let (mut both, mut rows2) = (Vec::new(), Vec::new());
            src.positions_and_rows(&idx, origin, &mut both, &mut rows2);
            assert_eq!(bits(&both), expect, "format {format}");
            let row_bits = |v: &[f32]| -> Vec<u32> { v.iter().map(|x| x.to_bits()).collect() };
            assert_eq!(row_bits(&rows2), row_bits(&rows[1..]), "format {format}");
            pos.clear();
            src.positions_in(10..n - 3, origin, &mut pos);
            let expect: Vec<[u32; 3]> = (10..n - 3).map(want).collect();
            assert_eq!(bits(&pos), expect, "format {format}");
        }
    }

    /// A sampling reader's rows are not every point's: it offers none.
    #[test]
    fn a_sampling_reader_offers_no_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.las");
        write(&path, 1, 5_000);
        let mut r = open(&path, &ReadOptions::default()).unwrap();
        r.next_chunk().unwrap();
        assert!(r.row_source().is_some());
        assert!(r.sample_rest(4));
        assert!(r.row_source().is_none());
    }

    #[test]
    fn short_records_are_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.las");
        write(&path, 3, 10);
        // Shrink the declared record length (header byte 105) below format 3's 34.
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[105..107].copy_from_slice(&20u16.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = open(&path, &ReadOptions::default())
            .err()
            .expect("an error");
        let msg = e.to_string();
        assert!(msg.contains("short.las"), "{msg}");
    }
}
