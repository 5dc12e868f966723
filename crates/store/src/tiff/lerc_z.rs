//! Reading the LERC blobs of a Z-ordered tile straight into its points: one pass
//! that checks the blob, unpacks each micro-block's bits and writes the values
//! at the block's Z-order slots (an aligned `2^k` block is `4^k` consecutive
//! points), without the raster plane, the per-tile allocations or the separate
//! gather of the general path (`lerc-rs`, then `read.rs`'s gather).
//!
//! Written here because it is measured faster (bench/RESULTS.md, "Issue 30, part
//! 5"): `lerc-rs` decodes the raster into a `Vec<u32>` per block and a plane per
//! tile, and checks the mask bit by bit. It covers what pcimg and GDAL write for
//! one band of Float32: Lerc2 versions 3 to 6, one depth, one blob, the tiling
//! mode (raw, constant, bit-stuffed and look-up-table blocks). Anything else
//! (Huffman modes, several depths, other types) is left to `lerc-rs`: the caller
//! gets `Ok(false)`. Values are computed exactly as Esri's decoder computes them
//! (`offset + q · 2·maxZError` in `f64`, clamped to the blob's maximum, then
//! rounded to `f32`), so both paths agree bit for bit (tests below).

use crate::tiff::zorder::z_index;

/// `"Lerc2 "`, the blob's magic.
const MAGIC: &[u8; 6] = b"Lerc2 ";
/// LERC's data type code for Float32.
const FLOAT: i32 = 6;

/// What the blob's header says (the fields this decoder uses).
struct Header {
    version: i32,
    rows: usize,
    cols: usize,
    valid: usize,
    block: usize,
    size: usize,
    max_error: f64,
    z_min: f64,
    z_max: f64,
}

/// Little-endian reads at a cursor, each bounds-checked.
struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.b.len());
        let Some(end) = end else {
            return Err(format!(
                "LERC blob ends at byte {} but {n} more bytes are needed at byte {}",
                self.b.len(),
                self.pos
            ));
        };
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn i32(&mut self) -> Result<i32, String> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    /// An unsigned count of `n` bytes (1, 2 or 4).
    fn uint(&mut self, n: usize) -> Result<u32, String> {
        let b = self.take(n)?;
        Ok(match n {
            1 => b[0] as u32,
            2 => u16::from_le_bytes([b[0], b[1]]) as u32,
            _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        })
    }
}

/// Reads the header; `None` for blobs this decoder leaves to `lerc-rs`.
fn header(c: &mut Cursor) -> Result<Option<Header>, String> {
    if c.take(6)? != MAGIC {
        return Ok(None);
    }
    let version = c.i32()?;
    if !(3..=6).contains(&version) {
        return Ok(None);
    }
    let _checksum = c.i32()?;
    let rows = c.i32()?;
    let cols = c.i32()?;
    let depth = if version >= 4 { c.i32()? } else { 1 };
    let valid = c.i32()?;
    let block = c.i32()?;
    let size = c.i32()?;
    let data_type = c.i32()?;
    if version >= 6 {
        let blobs_more = c.i32()?;
        let pass_no_data = c.u8()?;
        c.take(3)?;
        if blobs_more != 0 || pass_no_data != 0 {
            return Ok(None);
        }
    }
    let max_error = c.f64()?;
    let z_min = c.f64()?;
    let z_max = c.f64()?;
    if version >= 6 {
        c.take(16)?;
    }
    if depth != 1 || data_type != FLOAT {
        return Ok(None);
    }
    let (Ok(rows), Ok(cols), Ok(valid), Ok(block), Ok(size)) = (
        usize::try_from(rows),
        usize::try_from(cols),
        usize::try_from(valid),
        usize::try_from(block),
        usize::try_from(size),
    ) else {
        return Err("LERC header has a negative size".into());
    };
    if valid > rows * cols || size < c.pos || size > c.b.len() {
        return Err(format!(
            "LERC header is inconsistent ({valid} valid of {rows}x{cols} pixels, \
             blob size {size} of {} bytes)",
            c.b.len()
        ));
    }
    Ok(Some(Header {
        version,
        rows,
        cols,
        valid,
        block,
        size,
        max_error,
        z_min,
        z_max,
    }))
}

/// LERC's Fletcher-32 (16-bit big-endian words, sums folded every 359 words):
/// the same result as `lerc::checksum::fletcher32`. Within a batch of 359 the
/// sums never pass 2^32, so the batch's effect can be summed in any order: with
/// words `w_i`, `s1 += Σ w_i` and `s2 += n·s1 + Σ (n − i)·w_i`. Eight lanes
/// (`a_j += w`, `c_j += a_j`, vectorized) give `Σ (n − i)·w_i = 8·Σ c_j −
/// Σ j·a_j` over whole groups of 8; the rest goes word by word.
fn fletcher32(data: &[u8]) -> u32 {
    let (mut s1, mut s2) = (0xffffu64, 0xffffu64);
    let words = data.len() / 2;
    let mut i = 0;
    while i < words {
        let n = (words - i).min(359);
        let mut groups = data[2 * i..2 * (i + n)].chunks_exact(16);
        let (mut a, mut c) = ([0u32; 8], [0u32; 8]);
        let mut k = 0u64;
        for g in groups.by_ref() {
            for j in 0..8 {
                a[j] += ((g[2 * j] as u32) << 8) | g[2 * j + 1] as u32;
                c[j] += a[j];
            }
            k += 1;
        }
        let sum_a: u64 = a.iter().map(|&v| v as u64).sum();
        let sum_c: u64 = c.iter().map(|&v| v as u64).sum();
        let ja: u64 = a
            .iter()
            .enumerate()
            .map(|(j, &v)| j as u64 * v as u64)
            .sum();
        s2 += 8 * k * s1 + 8 * sum_c - ja;
        s1 += sum_a;
        for w in groups.remainder().chunks_exact(2) {
            s1 += ((w[0] as u64) << 8) | w[1] as u64;
            s2 += s1;
        }
        s1 = (s1 & 0xffff) + (s1 >> 16);
        s2 = (s2 & 0xffff) + (s2 >> 16);
        i += n;
    }
    if data.len() % 2 == 1 {
        s1 += (data[data.len() - 1] as u64) << 8;
        s2 += s1;
    }
    s1 = (s1 & 0xffff) + (s1 >> 16);
    s2 = (s2 & 0xffff) + (s2 >> 16);
    ((s2 << 16) | s1) as u32
}

/// The validity mask, MSB first, from LERC's run-length code (`count: i16`;
/// positive: that many literal bytes, negative: one byte repeated, -32768 ends).
fn rle_mask(c: &mut Cursor, len: usize, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    loop {
        let n = i16::from_le_bytes(c.take(2)?.try_into().unwrap());
        if n == i16::MIN {
            break;
        }
        let k = n.unsigned_abs() as usize;
        if out.len() + k > len {
            return Err("LERC mask runs past the tile".into());
        }
        if n > 0 {
            out.extend_from_slice(c.take(k)?);
        } else {
            let b = c.u8()?;
            out.resize(out.len() + k, b);
        }
    }
    if out.len() != len {
        return Err(format!(
            "LERC mask holds {} bytes, {len} expected",
            out.len()
        ));
    }
    Ok(())
}

thread_local! {
    /// Each thread's mask buffer, kept between tiles.
    static MASK: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Decodes `blob`, a one-band Float32 LERC blob of a square `side × side`
/// Z-ordered tile, into `out`: slot `z` gets the pixel at Z-index `z` (NaN where
/// the mask says no value), for `z < out.len()`. Every slot is written when it
/// returns `Ok(true)`; `Ok(false)`: a blob this decoder does not cover, nothing
/// written (use `lerc-rs`).
pub(crate) fn decode(
    blob: &[u8],
    side: usize,
    out: &mut [std::mem::MaybeUninit<f32>],
) -> Result<bool, String> {
    let mut c = Cursor { b: blob, pos: 0 };
    let Some(h) = header(&mut c)? else {
        return Ok(false);
    };
    if h.rows != side || h.cols != side {
        return Err(format!(
            "LERC blob is {}x{}; a {side}x{side} tile expected",
            h.cols, h.rows
        ));
    }
    if out.len() > side * side {
        return Err(format!(
            "a {side}x{side} tile cannot hold {} points",
            out.len()
        ));
    }
    if !side.is_power_of_two() || !h.block.is_power_of_two() || h.block > side.min(16) {
        return Ok(false);
    }
    let got = fletcher32(&blob[14..h.size]);
    let want = u32::from_le_bytes(blob[10..14].try_into().unwrap());
    if got != want {
        return Err(format!(
            "LERC blob's checksum is {got:#010x}, its header says {want:#010x}"
        ));
    }
    let blob = &blob[..h.size];
    let mut c = Cursor {
        b: blob,
        pos: c.pos,
    };
    let mask_bytes = c.i32()?;
    let pixels = side * side;
    MASK.with(|m| {
        let mut mask = m.borrow_mut();
        let all = h.valid == pixels;
        if h.valid > 0 && !all {
            if mask_bytes <= 0 {
                return Err("LERC blob has no mask but some pixels lack values".to_string());
            }
            let mut mc = Cursor {
                b: c.take(mask_bytes as usize)?,
                pos: 0,
            };
            rle_mask(&mut mc, pixels.div_ceil(8), &mut mask)?;
        }
        let mask: Option<&[u8]> = (!all).then_some(&mask[..]);
        if h.valid == 0 {
            out.iter_mut().for_each(|o| {
                o.write(f32::NAN);
            });
            return Ok(true);
        }
        if h.z_min == h.z_max {
            let v = h.z_min as f32;
            for (z, o) in out.iter_mut().enumerate() {
                let (x, y) = crate::tiff::zorder::z_pixel(z as u64);
                o.write(if valid(mask, y as usize * side + x as usize) {
                    v
                } else {
                    f32::NAN
                });
            }
            return Ok(true);
        }
        if h.version >= 4 {
            // The one depth's range: the header's again.
            c.take(8)?;
        }
        if c.u8()? != 0 {
            // Every valid value raw, in raster order.
            return one_sweep(&mut c, side, mask, out).map(|()| true);
        }
        if h.version >= 6 && h.max_error == 0.0 && c.u8()? != 0 {
            // Lossless floating point's Huffman modes.
            return Ok(false);
        }
        tiles(&mut c, &h, side, mask, out)?;
        Ok(true)
    })
}

/// Whether raster pixel `k` has a value (`None`: every pixel has).
#[inline]
fn valid(mask: Option<&[u8]>, k: usize) -> bool {
    mask.is_none_or(|m| m[k >> 3] & (0x80 >> (k & 7)) != 0)
}

/// Values stored raw, one per valid pixel in raster order.
fn one_sweep(
    c: &mut Cursor,
    side: usize,
    mask: Option<&[u8]>,
    out: &mut [std::mem::MaybeUninit<f32>],
) -> Result<(), String> {
    let mut plane = vec![f32::NAN; side * side];
    for (k, p) in plane.iter_mut().enumerate() {
        if valid(mask, k) {
            *p = c.f32()?;
        }
    }
    for (z, o) in out.iter_mut().enumerate() {
        let (x, y) = crate::tiff::zorder::z_pixel(z as u64);
        o.write(plane[y as usize * side + x as usize]);
    }
    Ok(())
}

/// The micro-blocks, in raster order, each written to its Z-order slots.
fn tiles(
    c: &mut Cursor,
    h: &Header,
    side: usize,
    mask: Option<&[u8]>,
    out: &mut [std::mem::MaybeUninit<f32>],
) -> Result<(), String> {
    let m = h.block;
    let shift = 2 * m.trailing_zeros();
    // Z-index inside a block of each pixel of it, in raster order.
    let rel: Vec<u32> = (0..m * m)
        .map(|i| z_index((i % m) as u32, (i / m) as u32) as u32)
        .collect();
    let pattern: u8 = if h.version >= 5 { 14 } else { 15 };
    let inv_scale = 2.0 * h.max_error;
    let n = out.len();
    let mut q = [0u32; 256];
    let mut vals = [0f32; 256];
    let mut scratch = Scratch {
        q: [0; 256],
        vals: [0.0; 256],
    };
    let blocks = side / m;
    for by in 0..blocks {
        for bx in 0..blocks {
            let flag = c.u8()?;
            let j0 = bx * m;
            if ((flag >> 2) & pattern) != (((j0 as u8) >> 3) & pattern) {
                return Err(format!(
                    "LERC block at row {} column {j0} fails its integrity check (byte {})",
                    by * m,
                    c.pos - 1
                ));
            }
            if h.version >= 5 && flag & 4 != 0 && pattern == 14 {
                return Err("LERC block is difference-coded in a blob of one depth".into());
            }
            let base = (z_index(bx as u32, by as u32) as usize) << shift;
            // Raster indices of the block's pixels, valid ones counted.
            let k0 = by * m * side + j0;
            let count = match mask {
                None => m * m,
                Some(_) => (0..m * m)
                    .filter(|&i| valid(mask, k0 + (i / m) * side + i % m))
                    .count(),
            };
            let all_valid = count == m * m;
            match flag & 3 {
                0 => {
                    for v in vals[..count].iter_mut() {
                        *v = c.f32()?;
                    }
                }
                2 => vals[..count].fill(0.0),
                mode => {
                    let offset = match flag >> 6 {
                        0 => c.f32()? as f64,
                        1 => i16::from_le_bytes(c.take(2)?.try_into().unwrap()) as f64,
                        2 => c.u8()? as f64,
                        _ => return Err("LERC block has an invalid offset type".into()),
                    };
                    if mode == 3 {
                        vals[..count].fill(offset as f32);
                    } else {
                        let (bits, lut) = stuffed_head(c, count)?;
                        if count == m * m && base + count <= n {
                            // The common block: every pixel valid, every slot
                            // wanted: unpacked, scaled and placed in one go.
                            let slots = &mut out[base..base + count];
                            let scale = Scale {
                                offset,
                                step: inv_scale,
                                max: h.z_max,
                            };
                            let block = Block {
                                bits,
                                lut,
                                rel: &rel,
                                scale,
                            };
                            place(c, block, slots, &mut scratch)?;
                            continue;
                        }
                        unstuff(c, count, bits, lut, &mut q)?;
                        for (v, &q) in vals[..count].iter_mut().zip(&q[..count]) {
                            *v = (offset + q as f64 * inv_scale).min(h.z_max) as f32;
                        }
                    }
                }
            }
            if base >= n {
                continue;
            }
            let slots = &mut out[base..n.min(base + m * m)];
            if all_valid && slots.len() == m * m {
                for (&r, &v) in rel.iter().zip(&vals[..count]) {
                    slots[r as usize].write(v);
                }
            } else {
                let mut next = vals[..count].iter();
                for (i, &r) in rel.iter().enumerate() {
                    let v = if all_valid || valid(mask, k0 + (i / m) * side + i % m) {
                        *next.next().unwrap()
                    } else {
                        f32::NAN
                    };
                    if let Some(s) = slots.get_mut(r as usize) {
                        s.write(v);
                    }
                }
            }
        }
    }
    Ok(())
}

/// A bit-stuffed block's head: the bits a value takes and whether they index a
/// look-up table; its element count must be the block's `count` valid pixels.
fn stuffed_head(c: &mut Cursor, count: usize) -> Result<(u32, bool), String> {
    let head = c.u8()?;
    let width = match head >> 6 {
        0 => 4,
        1 => 2,
        2 => 1,
        _ => return Err("LERC block has an invalid element count size".into()),
    };
    let elements = c.uint(width)? as usize;
    if elements != count {
        return Err(format!(
            "LERC block holds {elements} values for {count} valid pixels"
        ));
    }
    Ok(((head & 31) as u32, head & 32 != 0))
}

/// How a block's integers become values: `offset + q · step` in `f64`, at most
/// `max`, then rounded to `f32` (Esri's `Lerc2::ReadTile`).
#[derive(Clone, Copy)]
struct Scale {
    offset: f64,
    step: f64,
    max: f64,
}

/// A bit-stuffed block as its head describes it.
#[derive(Clone, Copy)]
struct Block<'a> {
    /// Bits a value (or a look-up-table entry) takes.
    bits: u32,
    /// Whether the values index a look-up table.
    lut: bool,
    /// Z-index inside the block of each pixel, in raster order.
    rel: &'a [u32],
    scale: Scale,
}

/// A whole block of bit-stuffed integers straight to its slots: value `i` (raster
/// order) goes to `slots[rel[i]]`.
fn place(
    c: &mut Cursor,
    b: Block,
    slots: &mut [std::mem::MaybeUninit<f32>],
    scratch: &mut Scratch,
) -> Result<(), String> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("bmi2")
        && !tests_force_plain()
    {
        // SAFETY: this CPU has AVX2 and BMI2 (checked just now).
        return unsafe { place_avx2(c, b, slots, scratch) };
    }
    place_body(c, b, slots, scratch)
}

/// Whether a test asks for the portable path on a CPU with AVX2.
#[inline(always)]
fn tests_force_plain() -> bool {
    #[cfg(test)]
    return tests::PLAIN.with(|p| p.get());
    #[cfg(not(test))]
    false
}

/// [`place_body`] compiled for AVX2 and BMI2: the scaling four `f64` at a
/// time, shifts by a register without flags (not measured apart from the rest
/// of the decoder: bench/RESULTS.md, issue 30 part 5).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi2")]
unsafe fn place_avx2(
    c: &mut Cursor,
    b: Block,
    slots: &mut [std::mem::MaybeUninit<f32>],
    scratch: &mut Scratch,
) -> Result<(), String> {
    place_body(c, b, slots, scratch)
}

#[inline(always)]
fn place_body(
    c: &mut Cursor,
    b: Block,
    slots: &mut [std::mem::MaybeUninit<f32>],
    scratch: &mut Scratch,
) -> Result<(), String> {
    let Block {
        bits,
        lut,
        rel,
        scale: s,
    } = b;
    let count = rel.len();
    assert!(slots.len() == count && count.is_power_of_two());
    let wrap = count - 1;
    if bits == 0 && !lut {
        let v = s.offset.min(s.max) as f32;
        slots.iter_mut().for_each(|o| {
            o.write(v);
        });
        return Ok(());
    }
    if bits >= 32 {
        return Err(format!("LERC block packs {bits}-bit values"));
    }
    let q = &mut scratch.q[..count];
    if lut {
        // A table of the block's distinct values (the first, 0, not stored),
        // then each value's index into it.
        let mut table = [0u32; 256];
        let table = lut_table(c, bits, &mut table)?;
        let index_bits = u32::BITS - (table.len() as u32 - 1).leading_zeros();
        unpack_some(c, index_bits, q)?;
        for v in q.iter_mut() {
            *v = *table
                .get(*v as usize)
                .ok_or("LERC block indexes past its look-up table")? as i32;
        }
    } else {
        unpack_some(c, bits, q)?;
    }
    // Below 2^31 (bits < 32): exact through i32, which converts to f64 in one
    // instruction; the loop is vectorized.
    let vals = &mut scratch.vals[..count];
    for (v, &q) in vals.iter_mut().zip(q.iter()) {
        let z = s.offset + q as f64 * s.step;
        *v = if z > s.max { s.max } else { z } as f32;
    }
    for (&r, &v) in rel.iter().zip(vals.iter()) {
        // SAFETY: `slots.len()` is a power of two (checked above), so the
        // masked index is below it.
        unsafe { slots.get_unchecked_mut(r as usize & wrap) }.write(v);
    }
    Ok(())
}

/// A block's integers and values, kept between blocks (not zeroed for each).
struct Scratch {
    q: [i32; 256],
    vals: [f32; 256],
}

/// [`unpack_with`] for a multiple of 8 integers into `q`, with the width a
/// constant: 8 integers take exactly `bits` bytes, so each one's byte and shift
/// within its group of 8 are known when compiled.
#[inline(always)]
fn unpack_eights(c: &mut Cursor, bits: u32, q: &mut [i32]) -> Result<(), String> {
    #[inline(always)]
    fn run<const B: usize>(data: &[u8], q: &mut [i32]) {
        let mask = (1u64 << B) - 1;
        for (g, out) in q.chunks_exact_mut(8).enumerate() {
            let at = g * B;
            let d = &data[at..at + B + 8];
            for (j, o) in out.iter_mut().enumerate() {
                let bit = j * B;
                let w = u64::from_le_bytes(d[bit / 8..bit / 8 + 8].try_into().unwrap());
                *o = ((w >> (bit % 8)) & mask) as i32;
            }
        }
    }
    if !(1..32).contains(&bits) {
        return Err(format!("LERC block packs {bits}-bit values"));
    }
    let bytes = q.len() * bits as usize / 8;
    with_packed(c, bytes, |data| {
        macro_rules! widths {
        ($($b:literal)*) => {
            match bits {
                $($b => run::<$b>(data, q),)*
                _ => return Err(format!("LERC block packs {bits}-bit values")),
            }
        };
    }
        widths!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26 27 28 29 30 31);
        Ok(())
    })?
}

/// The next `bytes` bytes of packed integers handed to `f` with at least 8
/// readable bytes after the last one (so each integer can be read as a `u64`
/// from its first byte): straight from the blob where they follow (nearly
/// always), else from a zero-padded copy (at most a block of 256 31-bit values).
#[inline(always)]
fn with_packed<R>(c: &mut Cursor, bytes: usize, f: impl FnOnce(&[u8]) -> R) -> Result<R, String> {
    let start = c.pos;
    let src = c.take(bytes)?;
    Ok(match c.b.get(start..start + bytes + 8) {
        Some(d) => f(d),
        None => {
            let mut pad = [0u8; 256 * 4 + 8];
            let pad = pad
                .get_mut(..bytes + 8)
                .ok_or("LERC block packs more than 256 values")?;
            pad[..bytes].copy_from_slice(src);
            f(pad)
        }
    })
}

/// `count` integers of `bits` (1 to 31) bits each, packed least significant bit
/// first, handed to `put(i, value)`. Each is read as 8 bytes from its first
/// byte: straight from the blob where 8 bytes follow the last one (nearly
/// always), else from a padded copy.
#[inline(always)]
fn unpack_with(
    c: &mut Cursor,
    count: usize,
    bits: u32,
    mut put: impl FnMut(usize, u32),
) -> Result<(), String> {
    let bytes = (count * bits as usize).div_ceil(8);
    let mask = (1u64 << bits) - 1;
    with_packed(c, bytes, |data| {
        for i in 0..count {
            let bit = i * bits as usize;
            let at = bit >> 3;
            let w = u64::from_le_bytes(data[at..at + 8].try_into().unwrap());
            put(i, ((w >> (bit & 7)) & mask) as u32);
        }
    })
}

/// One block's bit-stuffed integers (Lerc2 v3 and later: least significant bit
/// first), plain or through a look-up table, into `q[..count]`.
fn unstuff(
    c: &mut Cursor,
    count: usize,
    bits: u32,
    lut: bool,
    q: &mut [u32; 256],
) -> Result<(), String> {
    if !lut {
        return unpack(c, count, bits, &mut q[..count]);
    }
    let mut table = [0u32; 256];
    let table = lut_table(c, bits, &mut table)?;
    let index_bits = u32::BITS - (table.len() as u32 - 1).leading_zeros();
    unpack(c, count, index_bits, &mut q[..count])?;
    for v in q[..count].iter_mut() {
        *v = *table
            .get(*v as usize)
            .ok_or("LERC block indexes past its look-up table")?;
    }
    Ok(())
}

/// A block's look-up table: its distinct values, the first (0) not stored.
fn lut_table<'t>(
    c: &mut Cursor,
    bits: u32,
    table: &'t mut [u32; 256],
) -> Result<&'t [u32], String> {
    if bits == 0 {
        return Err("LERC block has a look-up table of 0-bit values".into());
    }
    let entries = (c.u8()? as usize).wrapping_sub(1);
    if entries == 0 || entries > 254 {
        return Err("LERC block has a look-up table of fewer than 2 values".into());
    }
    let table = &mut table[..entries + 1];
    table[0] = 0;
    unpack(c, entries, bits, &mut table[1..])?;
    Ok(table)
}

/// [`unpack_eights`] where `q.len()` is a multiple of 8, else one at a time.
#[inline(always)]
fn unpack_some(c: &mut Cursor, bits: u32, q: &mut [i32]) -> Result<(), String> {
    if q.len().is_multiple_of(8) {
        unpack_eights(c, bits, q)
    } else {
        unpack_with(c, q.len(), bits, |i, v| q[i] = v as i32)
    }
}

/// `out.len()` integers of `bits` bits each, packed least significant bit first.
fn unpack(c: &mut Cursor, count: usize, bits: u32, out: &mut [u32]) -> Result<(), String> {
    if bits == 0 {
        out.fill(0);
        return Ok(());
    }
    if bits >= 32 {
        return Err(format!("LERC block packs {bits}-bit values"));
    }
    unpack_with(c, count, bits, |i, v| out[i] = v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::MaybeUninit;

    thread_local! {
        /// Set: `place` takes the portable path even where AVX2 is there.
        pub(crate) static PLAIN: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    }

    fn both(blob: &[u8], side: usize, n: usize) -> Option<(Vec<f32>, Vec<f32>)> {
        let mut plane = vec![0f32; side * side];
        lerc::decode_into_with_nodata(blob, &mut plane, f32::NAN).unwrap();
        let lut = crate::tiff::zorder::tile_z_to_raster(side.trailing_zeros());
        let want: Vec<f32> = lut[..n].iter().map(|&p| plane[p as usize]).collect();
        let mut got = vec![MaybeUninit::new(-7.0f32); n];
        if !decode(blob, side, &mut got).unwrap() {
            return None;
        }
        Some((
            got.iter()
                .map(|v| {
                    // SAFETY: decode wrote the first n values (it returned true).
                    unsafe { v.assume_init() }
                })
                .collect(),
            want,
        ))
    }

    fn same(a: &[f32], b: &[f32]) {
        assert_eq!(a.len(), b.len());
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
                "slot {i}: {x} against lerc-rs's {y}"
            );
        }
    }

    /// Blobs of every kind pcimg writes (bounded, whole numbers, constant,
    /// partly masked), decoded here and by `lerc-rs` then gathered: bit for bit.
    #[test]
    fn agrees_with_lerc_rs() {
        agree(false);
        agree(true);
    }

    fn agree(plain: bool) {
        PLAIN.with(|p| p.set(plain));
        let side = 64;
        let mut seed = 12345u64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let lut = crate::tiff::zorder::tile_z_to_raster(6);
        for case in 0..8 {
            let n = [4096, 4096, 1000, 4096, 3, 2500, 4096, 0][case];
            let mut plane = vec![f32::NAN; side * side];
            for z in 0..n {
                let v = match case {
                    0 => 1000.0 + (z as f64).sqrt() * 3.0 + rnd() * 0.5,
                    1 => (rnd() * 30.0).floor(),
                    2 => 7.25,
                    3 => rnd() * 1e6,
                    4 => 5.0,
                    5 => -40.0 + (z % 97) as f64 * 0.01,
                    // Few distinct values far apart: look-up-table blocks.
                    6 => [0.0, 100.0, 1000.0][(rnd() * 3.0) as usize],
                    _ => 1.0,
                };
                plane[lut[z] as usize] = v as f32;
            }
            // A point without a value inside the prefix.
            if n > 10 {
                plane[lut[7] as usize] = f32::NAN;
            }
            for err in [0.005, 0.5, 0.0] {
                let blob = crate::tiff::codec::encode_lerc(&plane, side, err).unwrap();
                let info = lerc::decode_info(&blob).unwrap();
                let Some((got, want)) = both(&blob, side, n) else {
                    // Only lossless floating point (Huffman-coded, v6) is left
                    // to lerc-rs.
                    assert!(err == 0.0 && info.version == 6, "case {case}, error {err}");
                    continue;
                };
                same(&got, &want);
                // Fewer slots than points: a prefix.
                let (got, want) = both(&blob, side, n / 2).unwrap();
                same(&got, &want);
            }
        }
    }

    /// Every width, a whole group of 8 at a time, against one at a time: read
    /// from the blob and from the padded copy (the block at the very end).
    #[test]
    fn unpacking_by_eights_agrees() {
        let raw: Vec<u8> = (0..2000u32)
            .map(|i| (i.wrapping_mul(2654435761u32) >> 13) as u8)
            .collect();
        for bits in 1..32u32 {
            for count in [8usize, 64, 256] {
                let bytes = count * bits as usize / 8;
                for tail in [0usize, 8] {
                    let b = &raw[..bytes + tail];
                    let mut a = vec![0i32; count];
                    unpack_eights(&mut Cursor { b, pos: 0 }, bits, &mut a).unwrap();
                    let mut w = vec![0u32; count];
                    unpack(&mut Cursor { b, pos: 0 }, count, bits, &mut w).unwrap();
                    assert!(
                        a.iter().zip(&w).all(|(&a, &w)| a as u32 == w),
                        "{bits} bits"
                    );
                }
            }
        }
    }

    #[test]
    fn fletcher_matches_lerc_rs() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i * 7919 % 251) as u8).collect();
        for len in [0, 1, 2, 15, 16, 17, 717, 718, 719, 720, 1436, 1437, 5000] {
            assert_eq!(
                fletcher32(&data[..len]),
                lerc::checksum::fletcher32(&data[..len])
            );
        }
        let ones = vec![0xffu8; 4001];
        assert_eq!(fletcher32(&ones), lerc::checksum::fletcher32(&ones));
    }

    #[test]
    fn corrupt_blobs_are_errors() {
        let side = 64;
        let plane: Vec<f32> = (0..side * side).map(|i| (i as f32).sqrt()).collect();
        let blob = crate::tiff::codec::encode_lerc(&plane, side, 0.01).unwrap();
        let mut out = vec![MaybeUninit::new(0f32); side * side];
        for at in (0..blob.len()).step_by(3) {
            let mut b = blob.clone();
            b[at] ^= 0x5a;
            // The checksum made right again, so the parser meets the damage.
            if at >= 14 {
                let sum = fletcher32(&b[14..]);
                b[10..14].copy_from_slice(&sum.to_le_bytes());
            }
            // Never a panic: an error, or (the magic or version changed) left
            // to lerc-rs.
            let _ = decode(&b, side, &mut out);
        }
        for cut in [0, 10, 60, blob.len() / 2, blob.len() - 1] {
            assert!(decode(&blob[..cut], side, &mut out).is_err() || cut < 10);
        }
        let mut b = blob.clone();
        let last = b.len() - 1;
        b[last] ^= 1;
        assert!(decode(&b, side, &mut out).unwrap_err().contains("checksum"));
    }
}
