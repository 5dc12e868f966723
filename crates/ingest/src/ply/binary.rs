//! Binary PLY vertices (little- and big-endian): a fixed-stride decoder over the
//! memory map with a precomputed byte offset per property, byte-swapped for
//! big-endian, in parallel over each window with rayon; the elements before the
//! vertex element skipped by size (item by item when they have list properties),
//! those after it walked once the vertices are read, so a file cut short inside
//! them is an error too.

use super::{Element, Encoding, Header, PropKind, Scalar, VertexPlan};
use crate::bigvec;
use crate::color::ColorNormalizer;
use crate::error::IngestError;
use crate::lines::Role;
use crate::points::{Attribute, PointColumns};
use crate::value::Val;
use crate::{PointReader, ReadOptions, SourceInfo};
use memmap2::Mmap;
use rayon::prelude::*;
use std::path::Path;

/// The reader of a binary PLY file's vertices (`map`, its header and vertex plan
/// already parsed).
pub(super) fn open(
    path: &Path,
    opts: &ReadOptions,
    map: Mmap,
    header: &Header,
    plan: VertexPlan,
    info: SourceInfo,
) -> Result<Box<dyn PointReader>, IngestError> {
    let count = header.elements[plan.element].count;
    let be = header.encoding == Encoding::BinaryBe;
    // Skip the elements before the vertex element.
    let mut pos = header.len as u64;
    for el in &header.elements[..plan.element] {
        pos = skip_binary_element(path, &map, pos, el, be)?;
    }
    let needed = count
        .checked_mul(plan.stride as u64)
        .and_then(|b| b.checked_add(pos))
        .ok_or_else(|| IngestError::binary(path, pos, "vertex count is too large"))?;
    if needed > map.len() as u64 {
        let whole = (map.len() as u64).saturating_sub(pos) / (plan.stride.max(1) as u64);
        return Err(IngestError::binary(
            path,
            map.len() as u64,
            format!(
                "truncated file: the header declares {count} vertices of {} bytes from byte {pos} \
                 (ending at byte {needed}), but the file ends at byte {} after {whole} complete vertices",
                plan.stride,
                map.len()
            ),
        ));
    }
    // Attribute offsets from the first vertices.
    let mut plan = plan;
    let first = count.min(crate::OFFSET_SAMPLE as u64) as usize;
    let recs = &map[pos as usize..pos as usize + first * plan.stride];
    let mut offsets = vec![0.0; plan.layout.attr_names.len()];
    for &(off, s, role) in &plan.fields {
        if let Role::Attr(a) = role {
            let mut v = vec![0f64; first];
            if be {
                decode_column::<true, f64>(recs, plan.stride, off, s, &mut v, 0.0);
            } else {
                decode_column::<false, f64>(recs, plan.stride, off, s, &mut v, 0.0);
            }
            offsets[a] = crate::attribute_offset(&mut v, plan.layout.attr_names[a] == "gps_time");
        }
    }
    plan.layout.offsets = offsets;
    let after = header.elements[plan.element + 1..].to_vec();
    let map = std::sync::Arc::new(map);
    let ahead = crate::ahead::Ahead::new(
        map.clone(),
        pos,
        pos.saturating_add(count.saturating_mul(plan.stride as u64)),
    );
    Ok(Box::new(BinaryPly {
        info,
        map,
        ahead,
        start: pos as usize,
        count,
        done: 0,
        be,
        plan,
        chunk_points: opts.chunk_points,
        colors: None,
        skip_invalid: opts.skip_invalid,
        skipped: 0,
        released: 0,
        after,
    }))
}

/// Skips one binary element starting at byte `pos`; returns the byte after it.
fn skip_binary_element(
    path: &Path,
    data: &[u8],
    pos: u64,
    el: &Element,
    be: bool,
) -> Result<u64, IngestError> {
    let name = pcimg_core::text::sanitize(&el.name);
    let trunc = |at: u64| {
        IngestError::binary(
            path,
            at,
            format!("truncated file: the file ends inside element '{name}'"),
        )
    };
    if let Some(size) = el.fixed_size() {
        let end = el
            .count
            .checked_mul(size as u64)
            .and_then(|b| b.checked_add(pos))
            .ok_or_else(|| trunc(pos))?;
        if end > data.len() as u64 {
            return Err(trunc(data.len() as u64));
        }
        return Ok(end);
    }
    let mut p = pos as usize;
    for _ in 0..el.count {
        for prop in &el.props {
            match prop.kind {
                PropKind::Scalar(s) => p += s.size(),
                PropKind::List { count, item } => {
                    let b = data
                        .get(p..p + count.size())
                        .ok_or_else(|| trunc(p as u64))?;
                    let n = if be {
                        count.decode::<true>(b)
                    } else {
                        count.decode::<false>(b)
                    };
                    if n < 0.0 {
                        return Err(IngestError::binary(
                            path,
                            p as u64,
                            format!("negative list length in element '{name}'"),
                        ));
                    }
                    p += count.size() + n as usize * item.size();
                }
            }
            if p > data.len() {
                return Err(trunc(data.len() as u64));
            }
        }
    }
    Ok(p as u64)
}

/// Binary PLY: fixed-stride records.
struct BinaryPly {
    info: SourceInfo,
    map: std::sync::Arc<Mmap>,
    /// Reading the next chunk's records ahead of the decoders.
    ahead: crate::ahead::Ahead,
    start: usize,
    count: u64,
    done: u64,
    be: bool,
    plan: VertexPlan,
    chunk_points: usize,
    colors: Option<ColorNormalizer>,
    skip_invalid: bool,
    skipped: u64,
    released: usize,
    /// The elements after the vertex element: never read, but walked once the
    /// vertices are, since a file cut short inside them is truncated all the same.
    after: Vec<Element>,
}

/// Output slices for a run of records.
struct Task<'a> {
    first: usize,
    x: &'a mut [f64],
    y: &'a mut [f64],
    z: &'a mut [f64],
    attrs: Vec<&'a mut [f32]>,
}

/// Decodes one property of consecutive records into `out`: one tight loop per
/// (type, endianness), so the type dispatch happens once per column and task.
fn decode_column<const BE: bool, O: Val>(
    recs: &[u8],
    stride: usize,
    off: usize,
    s: Scalar,
    out: &mut [O],
    offset: f64,
) {
    macro_rules! col {
        ($t:ty, $n:expr) => {
            for (rec, o) in recs.chunks_exact(stride).zip(out.iter_mut()) {
                if let Some(b) = rec.get(off..off + $n) {
                    let mut a = [0u8; $n];
                    a.copy_from_slice(b);
                    let v = if BE {
                        <$t>::from_be_bytes(a)
                    } else {
                        <$t>::from_le_bytes(a)
                    };
                    *o = O::from_f64(v as f64 - offset);
                }
            }
        };
    }
    match s {
        Scalar::I8 => col!(i8, 1),
        Scalar::U8 => col!(u8, 1),
        Scalar::I16 => col!(i16, 2),
        Scalar::U16 => col!(u16, 2),
        Scalar::I32 => col!(i32, 4),
        Scalar::U32 => col!(u32, 4),
        Scalar::F32 => col!(f32, 4),
        Scalar::F64 => col!(f64, 8),
    }
}

/// Decodes a run of records; returns whether every coordinate is finite
/// (checked while the run is still in cache).
fn decode_task<const BE: bool>(
    data: &[u8],
    stride: usize,
    fields: &[(usize, Scalar, Role)],
    offsets: &[f64],
    t: Task<'_>,
) -> bool {
    let Task {
        first,
        x,
        y,
        z,
        mut attrs,
    } = t;
    let Some(recs) = data.get(first * stride..(first + x.len()) * stride) else {
        return true;
    };
    for &(off, s, role) in fields {
        match role {
            Role::X => decode_column::<BE, f64>(recs, stride, off, s, x, 0.0),
            Role::Y => decode_column::<BE, f64>(recs, stride, off, s, y, 0.0),
            Role::Z => decode_column::<BE, f64>(recs, stride, off, s, z, 0.0),
            Role::Attr(a) => {
                if let Some(col) = attrs.get_mut(a) {
                    let offset = offsets.get(a).copied().unwrap_or(0.0);
                    decode_column::<BE, f32>(recs, stride, off, s, col, offset);
                }
            }
            Role::Skip => {}
        }
    }
    x.iter()
        .zip(y.iter())
        .zip(z.iter())
        .all(|((x, y), z)| x.is_finite() && y.is_finite() && z.is_finite())
}

impl BinaryPly {
    /// Reads the next window; `Some(empty)` when every point of it was skipped.
    fn next_window(&mut self) -> Result<Option<PointColumns>, IngestError> {
        if self.done >= self.count {
            let mut end = (self.start + self.count as usize * self.plan.stride) as u64;
            for el in std::mem::take(&mut self.after) {
                end = skip_binary_element(&self.info.path, &self.map, end, &el, self.be)?;
            }
            return Ok(None);
        }
        let n = (self.count - self.done).min(self.chunk_points as u64) as usize;
        let stride = self.plan.stride;
        let from = self.start + self.done as usize * stride;
        // This chunk and the next are asked for while this one is decoded.
        self.ahead.want((from + 2 * n * stride) as u64);
        let Some(data) = self.map.get(from..from + n * stride) else {
            return Err(IngestError::binary(
                self.path_ref(),
                from as u64,
                "truncated file: vertex data ends early",
            ));
        };
        let mut cols = PointColumns {
            x: bigvec::zeroed(n),
            y: bigvec::zeroed(n),
            z: bigvec::zeroed(n),
            attributes: self
                .plan
                .layout
                .attr_names
                .iter()
                .zip(&self.plan.layout.offsets)
                .map(|(a, &offset)| Attribute {
                    name: a.clone(),
                    offset,
                    values: bigvec::zeroed(n),
                })
                .collect(),
        };
        let threads = rayon::current_num_threads().max(1);
        let m = (n / (threads * 4)).max(16 << 10);
        let mut tasks = Vec::new();
        {
            let mut xs = cols.x.chunks_mut(m);
            let mut ys = cols.y.chunks_mut(m);
            let mut zs = cols.z.chunks_mut(m);
            let mut ats: Vec<_> = cols
                .attributes
                .iter_mut()
                .map(|a| a.values.chunks_mut(m))
                .collect();
            let mut first = 0;
            while let (Some(x), Some(y), Some(z)) = (xs.next(), ys.next(), zs.next()) {
                let len = x.len();
                let attrs: Vec<&mut [f32]> = ats.iter_mut().filter_map(|it| it.next()).collect();
                tasks.push(Task {
                    first,
                    x,
                    y,
                    z,
                    attrs,
                });
                first += len;
            }
        }
        let fields = &self.plan.fields;
        let offsets = &self.plan.layout.offsets;
        // Every task runs (no short-circuit): `all_finite` is a reduction.
        let all_finite = if self.be {
            tasks
                .into_par_iter()
                .map(|t| decode_task::<true>(data, stride, fields, offsets, t))
                .reduce(|| true, |a, b| a && b)
        } else {
            tasks
                .into_par_iter()
                .map(|t| decode_task::<false>(data, stride, fields, offsets, t))
                .reduce(|| true, |a, b| a && b)
        };
        self.done += n as u64;
        let consumed = from + n * stride;
        crate::release_consumed(&self.map, &mut self.released, consumed);
        // Non-finite coordinates cannot be stored: skip them or report the first.
        if !all_finite {
            if self.skip_invalid {
                self.skipped += cols.drop_non_finite();
                if cols.is_empty() {
                    return Ok(Some(cols));
                }
            } else if let Some(i) = (0..n).find(|&i| !cols.finite_at(i)) {
                let vertex = self.done - n as u64 + i as u64;
                return Err(IngestError::binary(
                    &self.info.path,
                    (from + i * stride) as u64,
                    format!("vertex {vertex} has a non-finite coordinate (NaN or infinity)"),
                ));
            }
        }
        if self.plan.u8_color {
            return Ok(Some(cols));
        }
        let float_color = self.plan.float_color;
        self.colors
            .get_or_insert_with(|| ColorNormalizer::new(float_color))
            .apply(&mut cols);
        Ok(Some(cols))
    }
}

impl PointReader for BinaryPly {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        loop {
            match self.next_window()? {
                Some(c) if c.is_empty() => continue,
                other => return Ok(other),
            }
        }
    }

    fn bytes_done(&self) -> u64 {
        if self.done >= self.count {
            self.map.len() as u64
        } else {
            (self.start as u64 + self.done * self.plan.stride as u64).min(self.map.len() as u64)
        }
    }

    fn skipped(&self) -> u64 {
        self.skipped
    }

    fn clamped_colours(&self) -> u64 {
        self.colors.as_ref().map_or(0, |c| {
            c.clamped().load(std::sync::atomic::Ordering::Relaxed)
        })
    }
}

impl BinaryPly {
    fn path_ref(&self) -> &Path {
        &self.info.path
    }
}
