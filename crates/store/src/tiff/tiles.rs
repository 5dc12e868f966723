//! A tile's bands as pixels: each band's samples placed at their pixels (a
//! Z-ordered tile a 16 × 16 block at a time, each row of 16 pixels one cache line
//! written with streaming stores; any other placement through its pixel table),
//! the attribute rows gathered through the permutation (prefetched), and the
//! parallel jobs a tile's bands are made in (`groups`, `hilbert_bands`), shared
//! by the writer (`writer.rs`) and the coarse levels (`coarse.rs`).

use crate::bigvec;
use crate::spec::TILE_SIZE;
use crate::write::out::TileBuf;

/// Appends rows `idx` of `rows` (`m` values each, interleaved) to `out`.
pub(crate) fn gather_held(rows: &[f32], idx: &[u32], m: usize, out: &mut Vec<f32>) {
    match m {
        0 => {}
        1 => gather_rows::<1>(rows, idx, out),
        2 => gather_rows::<2>(rows, idx, out),
        3 => gather_rows::<3>(rows, idx, out),
        4 => gather_rows::<4>(rows, idx, out),
        5 => gather_rows::<5>(rows, idx, out),
        6 => gather_rows::<6>(rows, idx, out),
        7 => gather_rows::<7>(rows, idx, out),
        8 => gather_rows::<8>(rows, idx, out),
        _ => {
            for &i in idx {
                let at = i as usize * m;
                out.extend_from_slice(&rows[at..at + m]);
            }
        }
    }
}

/// Places the `count` samples `value(0..count)` of one tile at row-major pixels
/// `lut[0..count]` (the Z-order table, or the paper layout's pixels); the rest
/// stays NaN.
#[inline]
pub(crate) fn scatter_tile(lut: &[u32], count: usize, value: impl Fn(usize) -> f32) -> TileBuf {
    // A full tile writes every pixel (the table is a permutation): no NaN fill.
    let mut buf = TileBuf::for_points(count);
    for (i, &to) in lut[..count].iter().enumerate() {
        buf[to as usize] = value(i);
    }
    buf
}

/// [`scatter_tile`] for `lut` the tile's Z-order table (`tile_z_to_raster`): the
/// 256 samples of each aligned 16 × 16 block (consecutive on the curve) are
/// placed a row of 16 pixels at a time, a whole cache line, written around the
/// cache where the target has streaming stores (the tile goes to the disk, or to
/// the encoder, not back through this core's cache: read-for-ownership of cold
/// lines cost more than the placing); a partial last block goes pixel by pixel.
#[inline]
fn scatter_z_tile(lut: &[u32], count: usize, value: impl Fn(usize) -> f32) -> TileBuf {
    const W: usize = TILE_SIZE as usize;
    let mut buf = TileBuf::for_points(count);
    let blocks = count / 256;
    for b in 0..blocks {
        let i = 256 * b;
        let at = lut[i] as usize;
        for (r, zs) in BLOCK16.chunks_exact(16).enumerate() {
            let row: [f32; 16] = std::array::from_fn(|c| value(i + zs[c] as usize));
            store_line(&mut buf[at + r * W..at + r * W + 16], row);
        }
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of x86_64; orders the streaming stores above before
    // the tile is handed to another thread.
    unsafe {
        std::arch::x86_64::_mm_sfence()
    };
    for (i, &to) in lut[..count].iter().enumerate().skip(256 * blocks) {
        buf[to as usize] = value(i);
    }
    buf
}

/// The curve offset (Z-order within the block) of each pixel of a 16 × 16
/// block, in row-major order.
const BLOCK16: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut p = 0;
    while p < 256 {
        let (x, y) = (p % 16, p / 16);
        let mut z = 0;
        let mut bit = 0;
        while bit < 4 {
            z |= ((x >> bit) & 1) << (2 * bit) | ((y >> bit) & 1) << (2 * bit + 1);
            bit += 1;
        }
        t[p] = z as u8;
        p += 1;
    }
    t
};

/// Writes 16 samples to `dst` (a 64-byte aligned run of a tile), around the
/// cache where the target can.
#[inline(always)]
fn store_line(dst: &mut [f32], v: [f32; 16]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_loadu_ps, _mm_stream_ps};
        assert!(dst.len() == 16 && dst.as_ptr().align_offset(16) == 0);
        // SAFETY: SSE is part of x86_64; `dst` holds 16 samples, 16-byte aligned
        // (checked), so each of the four 4-sample stores is inside and aligned.
        unsafe {
            for k in 0..4 {
                _mm_stream_ps(
                    dst.as_mut_ptr().add(4 * k),
                    _mm_loadu_ps(v.as_ptr().add(4 * k)),
                );
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    dst.copy_from_slice(&v);
}

/// The parallel jobs of a level's tile `t` with `m` attributes: one per
/// coordinate band, and one for all attribute bands together (their values are
/// gathered a point at a time).
pub(crate) fn groups(m: usize) -> usize {
    3 + usize::from(m > 0)
}

/// The bands of job `group` (see [`groups`]) of one tile of the Hilbert layout
/// whose `count` points, in Z-order within the tile, are `pos(0..count)`, and
/// whose attribute rows are `gathered` (`m` values a point, in the same order;
/// only the attribute job reads them): (band, tile) pairs.
pub(crate) fn hilbert_bands(
    lut: &[u32],
    count: usize,
    group: usize,
    pos: impl Fn(usize) -> [f32; 3],
    gathered: &[f32],
    m: usize,
) -> Vec<(usize, TileBuf)> {
    if group < 3 {
        return vec![(group, scatter_z_tile(lut, count, |i| pos(i)[group]))];
    }
    (0..m)
        .map(|k| (3 + k, scatter_z_tile(lut, count, |i| gathered[i * m + k])))
        .collect()
}

/// Appends rows `idx` of `rows` (`M` values each) to `out`, prefetching ahead
/// (the rows are in input order, so nearly every one misses the cache).
#[inline]
fn gather_rows<const M: usize>(rows: &[f32], idx: &[u32], out: &mut Vec<f32>) {
    let rows: &[[f32; M]] = bytemuck::cast_slice(rows);
    for (k, &i) in idx.iter().enumerate() {
        if let Some(&ahead) = idx.get(k + bigvec::PREFETCH_AHEAD) {
            bigvec::prefetch(rows, ahead as usize);
        }
        out.extend_from_slice(&rows[i as usize]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec;
    use crate::tiff::zorder::tile_z_to_raster;

    /// The 4 × 4-block placement of a Z-ordered tile is the pixel-by-pixel one.
    #[test]
    fn z_tiles_are_placed_as_pixel_by_pixel() {
        let lut = tile_z_to_raster(spec::TILE_LOG2);
        for count in [spec::TILE_PIXELS, spec::TILE_PIXELS - 3, 1000, 33, 16, 5, 0] {
            let value = |i: usize| i as f32 * 0.5 - 7.0;
            let a = scatter_tile(&lut, count, value);
            let b = scatter_z_tile(&lut, count, value);
            let bits = |t: &TileBuf| t.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
            assert!(bits(&a) == bits(&b), "{count} samples");
        }
    }
}
