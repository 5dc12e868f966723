//! Tile payloads: Float32 samples to bytes and back, with optional Deflate or Zstd
//! compression and TIFF's floating-point predictor (3), or LERC (limited-error
//! raster compression, as GDAL and libtiff write it in TIFF: one LERC blob per
//! band tile, optionally Deflate- or Zstd-compressed again; the `lerc-rs` crate).

use crate::spec::{self, compression as comp, predictor as pred};
use std::io::{Read, Write};

/// Compression of a part's tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Compression {
    /// Fastest to load: tiles are read straight out of the memory map.
    #[default]
    None,
    Deflate,
    Zstd,
    /// LERC: each band tile within its own error bound (`TileError`).
    Lerc,
    /// LERC, the blob Deflate-compressed again (GDAL's `LERC_DEFLATE`).
    LercDeflate,
    /// LERC, the blob Zstd-compressed again (GDAL's `LERC_ZSTD`).
    LercZstd,
}

impl Compression {
    /// Every codec, fastest to read first.
    pub const ALL: [Compression; 6] = [
        Compression::None,
        Compression::Deflate,
        Compression::Zstd,
        Compression::Lerc,
        Compression::LercDeflate,
        Compression::LercZstd,
    ];

    pub(crate) fn tiff_code(self) -> u16 {
        match self {
            Compression::None => comp::NONE,
            Compression::Deflate => comp::ADOBE_DEFLATE,
            Compression::Zstd => comp::ZSTD,
            _ => comp::LERC,
        }
    }

    pub fn predictor(self) -> u16 {
        match self {
            Compression::Deflate | Compression::Zstd => pred::FLOATING_POINT,
            _ => pred::NONE,
        }
    }

    /// The LERC codes (`LercParameters`: version, additional compression), for
    /// the LERC codecs.
    pub(crate) fn lerc_parameters(self) -> Option<[u32; 2]> {
        let extra = match self {
            Compression::Lerc => spec::lerc::ADD_NONE,
            Compression::LercDeflate => spec::lerc::ADD_DEFLATE,
            Compression::LercZstd => spec::lerc::ADD_ZSTD,
            _ => return None,
        };
        Some([spec::lerc::VERSION, extra])
    }

    /// The codec a part was written with, from its first level's TIFF codes.
    pub(crate) fn from_codes(compression: u16, lerc_extra: u32) -> Option<Self> {
        Some(match (compression, lerc_extra) {
            (comp::NONE, _) => Compression::None,
            (comp::ADOBE_DEFLATE | comp::DEFLATE, _) => Compression::Deflate,
            (comp::ZSTD, _) => Compression::Zstd,
            (comp::LERC, spec::lerc::ADD_NONE) => Compression::Lerc,
            (comp::LERC, spec::lerc::ADD_DEFLATE) => Compression::LercDeflate,
            (comp::LERC, spec::lerc::ADD_ZSTD) => Compression::LercZstd,
            _ => return None,
        })
    }

    /// The codec written when none is named: for local output, the one read
    /// fastest from the page cache; for output to object storage, where bytes
    /// are time, the smallest that reads fast enough (bench/RESULTS.md, issue
    /// 30).
    pub fn default_for(_remote: bool) -> Self {
        Compression::Zstd
    }

    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Deflate => "deflate",
            Compression::Zstd => "zstd",
            Compression::Lerc => "lerc",
            Compression::LercDeflate => "lerc_deflate",
            Compression::LercZstd => "lerc_zstd",
        }
    }

    /// Whether parts are written with row-ordered tiles and lattice coordinates
    /// (format version 2): the lossless codecs whose TIFF predictor differences
    /// each row, so the order of a row's points decides the size.
    pub fn row_ordered(self) -> bool {
        matches!(self, Compression::Zstd | Compression::Deflate)
    }

    pub fn is_lerc(self) -> bool {
        self.lerc_parameters().is_some()
    }

    pub fn parse(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().replace('-', "_").as_str() {
            "none" => Ok(Compression::None),
            "deflate" | "zip" => Ok(Compression::Deflate),
            "zstd" => Ok(Compression::Zstd),
            "lerc" => Ok(Compression::Lerc),
            "lerc_deflate" => Ok(Compression::LercDeflate),
            "lerc_zstd" => Ok(Compression::LercZstd),
            _ => Err(format!(
                "unknown compression '{s}' (expected none, deflate, zstd, lerc, lerc_deflate \
                 or lerc_zstd)"
            )),
        }
    }
}

/// Name of a TIFF compression code for messages and `info`.
pub fn compression_name(code: u16) -> String {
    match code {
        comp::NONE => "none".into(),
        comp::ADOBE_DEFLATE | comp::DEFLATE => "deflate".into(),
        comp::ZSTD => "zstd".into(),
        comp::LERC => "lerc".into(),
        5 => "lzw".into(),
        c => format!("code {c}"),
    }
}

/// Name of a level's codec: [`compression_name`], LERC's with its additional
/// compression (`lerc_zstd`).
pub fn level_codec_name(code: u16, lerc_extra: u32) -> String {
    match Compression::from_codes(code, lerc_extra) {
        Some(c) if c.is_lerc() => c.name().into(),
        _ => compression_name(code),
    }
}

/// Zstd's level for the tiles of `zstd` parts by default: on row-ordered
/// tiles within 0.2 % of level 3's size at about twice its speed
/// (bench/RESULTS.md, "Compact storage").
pub const ZSTD_FAST: i32 = 1;

/// Zstd's level for small inputs ([`crate::WriteOptions::zstd_level`]): on
/// `autzen_trim` 6.7 % smaller than level 1, and the lowest level near that
/// (4: 3.8 %, 5: 4.6 %, 7: 6.3 %), at 1.2× the conversion's time there and
/// 1.3–1.6× on 47.7 M points (history 48).
pub const ZSTD_SMALL: i32 = 6;

/// The shortest match Zstd looks for, at levels up to
/// [`ZSTD_LONG_MATCHES_UP_TO`] (theirs: 6 at level 1, 5 at level 6). A tile
/// row's byte planes, once differenced, are runs of zeros and noise: shorter
/// matches inside the noise cost a sequence each and save little. On the
/// 47.7 M points at level 1: 0.7 % smaller, read 1.03× faster, no slower to
/// write; at level 6, 0.7 % smaller (history 49).
const ZSTD_MIN_MATCH: u32 = 7;

/// The highest level that takes [`ZSTD_MIN_MATCH`]; above it Zstd's optimal
/// parsers choose matches by their cost and keep their own.
const ZSTD_LONG_MATCHES_UP_TO: i32 = 9;

/// What Zstd does with a band's tiles at [`ZSTD_FAST`] (other levels always
/// take [`Fast::Zstd`]: they were chosen for size).
///
/// - The coordinate bands take [`Fast::RawLiterals`]: Zstd's own matches, the
///   literals (the bytes no match covers) stored as they are. Coordinates are
///   what every reader decodes (each frame, pick and export), and their
///   literals, the noisy low bytes of each sample, cost about a third of a
///   read to Huffman-decode: on the 47.7 M points x y z read level 0 at 1.45×
///   the speed for 6.7 % more bytes (x 1.71 → 2.00, y 1.95 → 2.17, z 1.87 →
///   2.12 B/pt; history 51).
/// - Whole-number bands spanning fewer than 256 values take [`Fast::Runs`]
///   ([`super::runs`]): matches only where a byte repeats, found by our scan,
///   where the runs leave at most [`RUNS_MAX_LITERALS`] of the tile as
///   literals; otherwise Zstd's own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fast {
    Zstd,
    RawLiterals,
    Runs,
}

/// The most of a tile (a fraction of its bytes) that [`Fast::Runs`] leaves as
/// literals; past it the tile is Zstd's.
pub const RUNS_MAX_LITERALS: f64 = 0.15;

/// Encodes one tile of one band (`width` samples per row, native byte order).
/// `max_error` bounds |decoded - value| for the LERC codecs (0: lossless); the
/// other codecs are lossless. `zstd_level`: Zstd's level for [`Compression::Zstd`]
/// ([`ZSTD_FAST`] unless the writer chose another); `fast`: what Zstd does
/// with the tile at that level ([`Fast`]).
pub fn encode(
    values: &[f32],
    width: usize,
    c: Compression,
    max_error: f64,
    zstd_level: i32,
    fast: Fast,
) -> Result<Vec<u8>, String> {
    Ok(match c {
        Compression::None => bytemuck::cast_slice(values).to_vec(),
        Compression::Deflate => deflate(&predict_float(values, width)),
        Compression::Zstd => {
            // A tile of one value (a constant band, the NaN of a coarser
            // level's `gps_time_lo`): level 1 leaves it at 1.2 KB where level
            // 3 makes 50 bytes, and every such tile of a width encodes alike,
            // so each thread keeps the last few.
            if let Some(&first) = values.first()
                && values.iter().all(|v| v.to_bits() == first.to_bits())
            {
                return constant_tile(first, values.len(), width);
            }
            PREDICTED
                .with(|raw| {
                    let mut raw = raw.borrow_mut();
                    predict_float_into(values, width, &mut raw);
                    if fast == Fast::Runs && zstd_level == ZSTD_FAST {
                        let most = (raw.len() as f64 * RUNS_MAX_LITERALS) as usize;
                        let runs = SQUEEZED.with_borrow_mut(|out| {
                            super::runs::compress_runs(&raw, zstd_level, most, out)
                                .map(|done| done.then(|| out.to_vec()))
                        })?;
                        if let Some(v) = runs {
                            return Ok(v);
                        }
                    }
                    // A tile level 1 leaves under 4 KB (one value and the NaN
                    // past the last point) is squeezed again at level 3, which
                    // costs little at that ratio.
                    let once = zstd_compress(&raw, zstd_level, fast == Fast::RawLiterals)?;
                    if zstd_level < 3 && once.len() < 4096 {
                        let again = zstd_compress(&raw, 3, false)?;
                        if again.len() < once.len() {
                            return Ok(again);
                        }
                    }
                    Ok(once)
                })
                .map_err(|e: std::io::Error| format!("zstd: {e}"))?
        }
        Compression::Lerc => encode_lerc(values, width, max_error)?,
        Compression::LercDeflate => deflate(&encode_lerc(values, width, max_error)?),
        Compression::LercZstd => {
            // GDAL's default level for LERC_ZSTD: the blobs are small.
            zstd_compress(&encode_lerc(values, width, max_error)?, 9, false)
                .map_err(|e| format!("zstd: {e}"))?
        }
    })
}

/// The Zstd tile (predicted, level 3) of `len` samples all `v`, `width` to
/// a row: from this thread's last few, else made and kept.
fn constant_tile(v: f32, len: usize, width: usize) -> Result<Vec<u8>, String> {
    /// A tile's value (bits), samples and width, and its encoding.
    type Made = Vec<((u32, usize, usize), Vec<u8>)>;
    thread_local! {
        static MADE: std::cell::RefCell<Made> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let key = (v.to_bits(), len, width);
    if let Some(hit) = MADE.with_borrow(|m| m.iter().find(|e| e.0 == key).map(|e| e.1.clone())) {
        return Ok(hit);
    }
    let tile = PREDICTED
        .with(|raw| {
            let mut raw = raw.borrow_mut();
            predict_float_into(&vec![v; len], width, &mut raw);
            zstd_compress(&raw, 3, false)
        })
        .map_err(|e| format!("zstd: {e}"))?;
    MADE.with_borrow_mut(|m| {
        if m.len() >= 8 {
            m.remove(0);
        }
        m.push((key, tile.clone()));
    });
    Ok(tile)
}

fn deflate(raw: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(raw.len() / 2),
        flate2::Compression::new(6),
    );
    // Writing into a Vec cannot fail.
    let _ = e.write_all(raw);
    e.finish().unwrap_or_default()
}

/// Largest integer an `f32` holds exactly with all smaller ones (2^24).
const F32_EXACT_INTEGERS: f32 = 16_777_216.0;

/// One LERC blob (Lerc2, Float32, one band, one depth) of a band's tile: NaN
/// samples (pixels without a point) are left out by the blob's validity mask
/// and read back as NaN. A tile of whole numbers (classes, returns, colours,
/// intensities) is coded with LERC's error 0.5, which gives every whole number
/// back exactly; other tiles within `max_error` (0: bit-exact, LERC's
/// floating-point lossless coding).
pub(crate) fn encode_lerc(values: &[f32], width: usize, max_error: f64) -> Result<Vec<u8>, String> {
    use lerc::bitmask::BitMask;
    let n = values.len();
    if width == 0 || !n.is_multiple_of(width) {
        return Err(format!("a LERC tile of {n} samples is not rows of {width}"));
    }
    let mut invalid = 0usize;
    let mut whole = true;
    let mut finite = true;
    for &v in values {
        if v.is_nan() {
            invalid += 1;
        } else {
            finite &= v.is_finite();
            whole &= v.trunc() == v && v.abs() <= F32_EXACT_INTEGERS;
        }
    }
    let mask = if invalid == 0 {
        BitMask::all_valid(n)
    } else {
        let mut m = BitMask::new(n);
        for (i, v) in values.iter().enumerate() {
            if !v.is_nan() {
                m.set_valid(i);
            }
        }
        m
    };
    // An infinity has no place in a limited-error range: such tiles are coded
    // losslessly.
    let error = if !finite {
        0.0
    } else if whole && max_error < 0.5 {
        0.5
    } else {
        max_error.max(0.0)
    };
    // (The bound as an f32 no larger than asked.)
    let precision = if error > 0.0 {
        let e = error as f32;
        lerc::Precision::Tolerance(if e as f64 > error { e.next_down() } else { e })
    } else {
        lerc::Precision::Lossless
    };
    let (w, h) = (width as u32, (n / width) as u32);
    let blob = lerc::encode_borrowed(w, h, 1, 1, values, &[mask], None, precision)
        .map_err(|e| format!("LERC encoding failed: {e}"))?;
    Ok(lerc_v3_as_v4(&blob).unwrap_or(blob))
}

/// A Lerc2 version 3 blob of Float32 samples, one depth, as version 4 (the
/// version libtiff expects in TIFF, `spec::lerc::VERSION`; it warns at every
/// other): the same tiles, the header with its depth (1), and the value range
/// after the mask. `lerc-rs` writes the lowest version a blob needs: 3 for
/// limited-error tiles, 6 for floating-point lossless ones (left as they are).
/// `None` for any other blob.
fn lerc_v3_as_v4(b: &[u8]) -> Option<Vec<u8>> {
    let i32_at = |o: usize| Some(i32::from_le_bytes(b.get(o..o + 4)?.try_into().ok()?));
    let f64_at = |o: usize| Some(f64::from_le_bytes(b.get(o..o + 8)?.try_into().ok()?));
    // Version 3: magic, version, checksum, rows, columns, valid pixels, micro
    // block size, blob size, data type, max error, min, max; then the mask's
    // byte count and bytes.
    const HEAD3: usize = 62;
    const FLOAT: i32 = 6;
    if b.get(..6)? != b"Lerc2 " || i32_at(6)? != 3 || i32_at(34)? != FLOAT {
        return None;
    }
    if i32_at(30)? as usize != b.len() {
        return None;
    }
    let valid = i32_at(22)?;
    let (lo, hi) = (f64_at(46)?, f64_at(54)?);
    let mask_end = HEAD3 + 4 + usize::try_from(i32_at(HEAD3)?).ok()?;
    let rest = b.get(mask_end..)?;
    let mut v = Vec::with_capacity(b.len() + 12);
    v.extend_from_slice(&b[..22]);
    v.extend_from_slice(&1i32.to_le_bytes());
    v.extend_from_slice(&b[22..mask_end]);
    // Version 4 keeps each depth's range where the values are not all one.
    if valid > 0 && lo != hi {
        v.extend_from_slice(&(lo as f32).to_le_bytes());
        v.extend_from_slice(&(hi as f32).to_le_bytes());
    }
    v.extend_from_slice(rest);
    let len = i32::try_from(v.len()).ok()?;
    v[6..10].copy_from_slice(&4i32.to_le_bytes());
    v[34..38].copy_from_slice(&len.to_le_bytes());
    let sum = lerc::checksum::fletcher32(&v[14..]);
    v[10..14].copy_from_slice(&sum.to_le_bytes());
    Some(v)
}

/// TIFF floating-point predictor on rows of one sample per pixel: bytes of each row
/// regrouped most significant first, then differenced.
fn predict_float(values: &[f32], width: usize) -> Vec<u8> {
    let mut out = Vec::new();
    predict_float_into(values, width, &mut out);
    out
}

thread_local! {
    /// Each thread's buffer for a tile's predicted bytes, and for Zstd's
    /// output: reused from tile to tile (fresh buffers of a tile's size were
    /// new pages, zeroed by the kernel, every time).
    static PREDICTED: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
    static SQUEEZED: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// [`predict_float`] into `out` (its allocation reused).
fn predict_float_into(values: &[f32], width: usize, out: &mut Vec<u8>) {
    // Every byte is written below: a buffer already as long is not zeroed
    // first (for a band of 4-byte samples that is its size again in stores).
    out.resize(values.len() * 4, 0);
    let mut planes = [0u8; 4 * spec::TILE_SIZE as usize];
    let mut heap = Vec::new();
    let planes: &mut [u8] = if width <= spec::TILE_SIZE as usize {
        &mut planes[..]
    } else {
        heap.resize(width * 4, 0);
        &mut heap
    };
    for (row, dst) in values.chunks(width).zip(out.chunks_mut(width * 4)) {
        let w = row.len();
        if predict_row_sse2(row, dst) {
            continue;
        }
        let planes = &mut planes[..w * 4];
        // One plane at a time (each loop a vectorisable narrowing).
        for (k, plane) in planes.chunks_exact_mut(w).enumerate() {
            let shift = 24 - 8 * k as u32;
            for (p, v) in plane.iter_mut().zip(row) {
                *p = (v.to_bits() >> shift) as u8;
            }
        }
        dst[0] = planes[0];
        for ((d, &b), &a) in dst[1..].iter_mut().zip(&planes[1..]).zip(planes.iter()) {
            *d = b.wrapping_sub(a);
        }
    }
}

/// One row of [`predict_float_into`] (`dst`: `4 · row.len()` bytes) in one
/// pass, 16 samples a step, where the row is a whole number of steps (every
/// tile row is): each byte plane taken out of the samples by shifts and packs,
/// and differenced against the plane bytes before it, straight into `dst`.
/// 1.85× the separate passes' speed (11 against 6 GB/s of samples, a 4 MiB
/// band of whole numbers, rustc -O3, the VM). `false` where it does nothing.
#[inline]
fn predict_row_sse2(row: &[f32], dst: &mut [u8]) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        let w = row.len();
        if w == 0 || !w.is_multiple_of(16) || dst.len() != 4 * w {
            return false;
        }
        // SAFETY: SSE2 is part of every x86-64 CPU. Loads read 4 samples at
        // `j + 4q < w` of `row`; stores write 16 bytes at `k · w + j`, inside
        // `dst` (4 · w long, checked above).
        unsafe {
            let mask = _mm_set1_epi32(0xff);
            let src = row.as_ptr() as *const __m128i;
            let out = dst.as_mut_ptr() as *mut __m128i;
            let mut prev = _mm_setzero_si128();
            for k in 0..4 {
                let shift = _mm_cvtsi32_si128(24 - 8 * k as i32);
                let byte = |q: usize| {
                    _mm_and_si128(_mm_srl_epi32(_mm_loadu_si128(src.add(q)), shift), mask)
                };
                for j in (0..w).step_by(16) {
                    let q = j / 4;
                    let lo = _mm_packs_epi32(byte(q), byte(q + 1));
                    let hi = _mm_packs_epi32(byte(q + 2), byte(q + 3));
                    let plane = _mm_packus_epi16(lo, hi);
                    let before = _mm_or_si128(_mm_slli_si128(plane, 1), _mm_srli_si128(prev, 15));
                    _mm_storeu_si128(out.add((k * w + j) / 16), _mm_sub_epi8(plane, before));
                    prev = plane;
                }
            }
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (row, dst);
        false
    }
}

/// How a stored tile is to be decoded.
#[derive(Debug, Clone, Copy)]
pub struct TileCodec {
    pub compression: u16,
    pub predictor: u16,
    pub little_endian: bool,
    /// Pixels per row of the tile.
    pub width: usize,
    /// Samples per pixel in this chunk (1 for separate planes).
    pub samples: usize,
    /// LERC tiles: the additional compression of each blob (`spec::lerc`).
    pub lerc_extra: u32,
}

impl TileCodec {
    pub fn check(&self) -> Result<(), String> {
        match self.compression {
            comp::NONE | comp::ADOBE_DEFLATE | comp::DEFLATE | comp::ZSTD => {}
            comp::LERC => {
                if self.lerc_extra > spec::lerc::ADD_ZSTD {
                    return Err(format!(
                        "LERC tiles use additional compression {}, which pcimg does not read \
                         (0 none, 1 deflate, 2 zstd)",
                        self.lerc_extra
                    ));
                }
                if self.samples != 1 {
                    return Err(
                        "LERC tiles of several samples a pixel (pixel-interleaved) are not read \
                         by pcimg: rewrite the part with -co INTERLEAVE=BAND"
                            .into(),
                    );
                }
            }
            c => {
                return Err(format!(
                    "tiles use compression {} which pcimg does not read (none, deflate, zstd or \
                     lerc)",
                    compression_name(c)
                ));
            }
        }
        match self.predictor {
            pred::NONE | pred::FLOATING_POINT => Ok(()),
            p => Err(format!(
                "tiles use predictor {p}, which is not valid for Float32 (expected 1 or 3)"
            )),
        }
    }

    /// Decodes a stored tile into `count` samples (pixel-interleaved if `samples > 1`).
    pub fn decode(&self, stored: &[u8], count: usize) -> Result<Vec<f32>, String> {
        let nbytes = count * 4;
        if self.compression == comp::LERC {
            return self.decode_lerc(stored, count);
        }
        let mut owned = match self.compression {
            comp::NONE => None,
            comp::ADOBE_DEFLATE | comp::DEFLATE | comp::ZSTD => {
                let mut v = Vec::new();
                self.inflate_into(stored, nbytes, &mut v)?;
                Some(v)
            }
            c => {
                return Err(format!(
                    "compression {} is not supported",
                    compression_name(c)
                ));
            }
        };
        let have = owned.as_ref().map_or(stored.len(), Vec::len);
        if have < nbytes {
            return Err(format!("tile holds {have} bytes, {nbytes} expected"));
        }
        if self.predictor == pred::FLOATING_POINT {
            let raw = match &mut owned {
                Some(v) => &mut v[..nbytes],
                None => owned.insert(stored[..nbytes].to_vec()),
            };
            return Ok(unpredict_float(
                raw,
                self.width * self.samples,
                self.samples,
            ));
        }
        let raw = &owned.as_deref().unwrap_or(stored)[..nbytes];
        Ok(if self.little_endian {
            raw.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        } else {
            raw.chunks_exact(4)
                .map(|b| f32::from_be_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        })
    }
}

thread_local! {
    /// Each thread's Zstd decompression context, kept between tiles.
    static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

thread_local! {
    /// Each thread's Zstd compression contexts and their levels, kept between
    /// tiles (a fresh context a tile cost its set-up every time).
    static ZSTD_OUT: std::cell::RefCell<Vec<((i32, bool), zstd::bulk::Compressor<'static>)>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Compresses `raw` as one Zstd frame at `level` with this thread's context.
fn zstd_compress(raw: &[u8], level: i32, raw_literals: bool) -> std::io::Result<Vec<u8>> {
    ZSTD_OUT.with(|z| {
        let mut z = z.borrow_mut();
        let raw_literals = raw_literals && level == ZSTD_FAST;
        let key = (level, raw_literals);
        let at = match z.iter().position(|(k, _)| *k == key) {
            Some(at) => at,
            None => {
                let mut c = zstd::bulk::Compressor::new(level)?;
                if level <= ZSTD_LONG_MATCHES_UP_TO {
                    c.set_parameter(zstd::stream::raw::CParameter::MinMatch(ZSTD_MIN_MATCH))?;
                }
                if raw_literals {
                    // Zstd's fast strategy takes a target length above 0 as
                    // its "acceleration", which at 1 keeps level 1's search
                    // step (2) and turns off literal compression
                    // (`ZSTD_literalsCompressionIsDisabled`): the same
                    // matches, the literals stored as they are.
                    c.set_parameter(zstd::stream::raw::CParameter::TargetLength(1))?;
                }
                z.push((key, c));
                z.len() - 1
            }
        };
        let c = &mut z[at].1;
        SQUEEZED.with(|out| {
            let mut out = out.borrow_mut();
            out.clear();
            out.reserve(zstd::zstd_safe::compress_bound(raw.len()));
            let n = c.compress_to_buffer(raw, &mut *out)?;
            Ok(out[..n].to_vec())
        })
    })
}

/// Decompresses a Zstd frame of at most `capacity` bytes with this thread's
/// context.
fn zstd_decompress(stored: &[u8], capacity: usize) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::new();
    zstd_decompress_into(stored, capacity, &mut out)?;
    Ok(out)
}

/// [`zstd_decompress`] into `out` (cleared first, its allocation reused).
fn zstd_decompress_into(stored: &[u8], capacity: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
    out.clear();
    out.reserve(capacity);
    ZSTD.with(|z| {
        let mut z = z.borrow_mut();
        let d = match &mut *z {
            Some(d) => d,
            None => z.insert(zstd::bulk::Decompressor::new()?),
        };
        d.decompress_to_buffer(stored, out).map(|_| ())
    })
}

thread_local! {
    /// Each thread's buffer for a LERC blob unwrapped from Deflate or Zstd.
    static BLOB: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl TileCodec {
    /// A LERC tile of a Z-ordered part straight into its points: `out[z]` gets
    /// the sample at Z-index `z` of the square tile (`crate::tiff::lerc_z`). `Ok(false)`
    /// when this is not a LERC tile or its blob is of a kind only `lerc-rs`
    /// decodes (then nothing is written: use [`TileCodec::decode`]).
    pub(crate) fn decode_lerc_z(
        &self,
        stored: &[u8],
        out: &mut [std::mem::MaybeUninit<f32>],
    ) -> Result<bool, String> {
        if self.compression != comp::LERC || self.samples != 1 {
            return Ok(false);
        }
        let side = self.width;
        if self.lerc_extra == spec::lerc::ADD_NONE {
            return crate::tiff::lerc_z::decode(stored, side, out);
        }
        let limit = side * side * 8 + 65_536;
        BLOB.with(|b| {
            let mut blob = b.borrow_mut();
            blob.clear();
            match self.lerc_extra {
                spec::lerc::ADD_DEFLATE => {
                    flate2::read::ZlibDecoder::new(stored)
                        .take(limit as u64)
                        .read_to_end(&mut blob)
                        .map_err(|e| {
                            format!("deflate stream around the LERC blob is corrupt: {e}")
                        })?;
                }
                spec::lerc::ADD_ZSTD => {
                    zstd_decompress_into(stored, limit, &mut blob)
                        .map_err(|e| format!("zstd stream around the LERC blob is corrupt: {e}"))?;
                }
                _ => return Ok(false),
            }
            crate::tiff::lerc_z::decode(&blob, side, out)
        })
    }

    /// A LERC tile: the blob (decompressed first where the part says so), one
    /// band of `count` Float32 samples, rows of `width`; masked pixels as NaN.
    fn decode_lerc(&self, stored: &[u8], count: usize) -> Result<Vec<f32>, String> {
        // A blob is at most about the raw samples plus its mask and headers.
        let limit = count * 8 + 65_536;
        let owned;
        let blob: &[u8] = match self.lerc_extra {
            spec::lerc::ADD_NONE => stored,
            spec::lerc::ADD_DEFLATE => {
                let mut v = Vec::with_capacity(count * 2);
                flate2::read::ZlibDecoder::new(stored)
                    .take(limit as u64)
                    .read_to_end(&mut v)
                    .map_err(|e| format!("deflate stream around the LERC blob is corrupt: {e}"))?;
                owned = v;
                &owned
            }
            spec::lerc::ADD_ZSTD => {
                owned = zstd_decompress(stored, limit)
                    .map_err(|e| format!("zstd stream around the LERC blob is corrupt: {e}"))?;
                &owned
            }
            e => return Err(format!("LERC additional compression {e} is not supported")),
        };
        let info = lerc::decode_info(blob).map_err(|e| format!("LERC blob is corrupt: {e}"))?;
        let want_rows = count / self.width.max(1);
        if info.width as usize != self.width
            || info.height as usize != want_rows
            || info.bands != 1
            || info.depth != 1
        {
            return Err(format!(
                "LERC blob is {}x{} with {} band(s) of depth {}; a {}x{} tile of one band expected",
                info.width, info.height, info.bands, info.depth, self.width, want_rows
            ));
        }
        if info.data_type != lerc::DataType::Float {
            return Err(format!(
                "LERC blob holds {:?} samples; Float32 expected",
                info.data_type
            ));
        }
        let mut out = vec![0f32; count];
        lerc::decode_into_with_nodata(blob, &mut out, f32::NAN)
            .map_err(|e| format!("LERC blob is corrupt: {e}"))?;
        Ok(out)
    }
}

/// Undoes the floating-point predictor in place: rows of `row_samples`
/// samples, differenced with a stride of `stride` bytes, each row's bytes
/// regrouped most significant first.
fn unpredict_float(raw: &mut [u8], row_samples: usize, stride: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(raw.len() / 4);
    for row in raw.chunks_mut(row_samples * 4) {
        if stride == 1 {
            running_sum(row);
        } else {
            for i in stride..row.len() {
                row[i] = row[i].wrapping_add(row[i - stride]);
            }
        }
        let w = row.len() / 4;
        let (b0, rest) = row.split_at(w);
        let (b1, rest) = rest.split_at(w);
        let (b2, b3) = rest.split_at(w);
        out.extend(
            b0.iter()
                .zip(b1)
                .zip(b2)
                .zip(&b3[..w])
                .map(|(((&a, &b), &c), &d)| f32::from_be_bytes([a, b, c, d])),
        );
    }
    out
}

thread_local! {
    /// Each thread's buffer for a tile decompressed before its predictor is undone.
    static RAW: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl TileCodec {
    /// A Deflate or Zstd tile's bytes (at most `nbytes`) into `out` (cleared
    /// first, its allocation reused).
    fn inflate_into(&self, stored: &[u8], nbytes: usize, out: &mut Vec<u8>) -> Result<(), String> {
        if self.compression == comp::ZSTD {
            return zstd_decompress_into(stored, nbytes, out)
                .map_err(|e| format!("zstd stream is corrupt: {e}"));
        }
        out.clear();
        out.reserve(nbytes);
        flate2::read::ZlibDecoder::new(stored)
            .take(nbytes as u64)
            .read_to_end(out)
            .map(|_| ())
            .map_err(|e| format!("deflate stream is corrupt: {e}"))
    }

    /// A Deflate or Zstd tile with the floating-point predictor, one sample a
    /// pixel, straight into its first `out.len()` samples in row order (a
    /// row-ordered part's points), each mapped by `map` (`step`, `shift`:
    /// `stored · step + shift`) where given: no tile-sized allocation, and only
    /// the rows that hold points undone. `Ok(false)` for any other tile
    /// (nothing written: use [`TileCodec::decode`]).
    pub(crate) fn decode_rows_into(
        &self,
        stored: &[u8],
        pixels: usize,
        out: &mut [std::mem::MaybeUninit<f32>],
        map: Option<(f64, f64)>,
    ) -> Result<bool, String> {
        let n = out.len();
        let w = self.width;
        if self.samples != 1
            || self.predictor != pred::FLOATING_POINT
            || w == 0
            || n > pixels
            || !matches!(
                self.compression,
                comp::ZSTD | comp::ADOBE_DEFLATE | comp::DEFLATE
            )
        {
            return Ok(false);
        }
        let nbytes = pixels * 4;
        RAW.with(|raw| -> Result<bool, String> {
            let mut raw = raw.borrow_mut();
            self.inflate_into(stored, nbytes, &mut raw)?;
            if raw.len() < nbytes {
                return Err(format!("tile holds {} bytes, {nbytes} expected", raw.len()));
            }
            let avx2 = has_avx2();
            for (row, dst) in raw[..n.div_ceil(w) * w * 4]
                .chunks_exact_mut(w * 4)
                .zip(out.chunks_mut(w))
            {
                // AVX2 where the CPU has it: the row's sum and its planes
                // joined and mapped in one call, the same values.
                #[cfg(target_arch = "x86_64")]
                if avx2 && w.is_multiple_of(16) && dst.len() == w {
                    // SAFETY: the CPU has AVX2 (checked above).
                    unsafe { undo_row_avx2(row, dst, map) };
                    continue;
                }
                running_sum(row);
                let (b0, rest) = row.split_at(w);
                let (b1, rest) = rest.split_at(w);
                let (b2, b3) = rest.split_at(w);
                let done = join_planes([b0, b1, b2, b3], dst, map);
                let value = |j: usize| f32::from_be_bytes([b0[j], b1[j], b2[j], b3[j]]);
                match map {
                    None => {
                        for (j, d) in dst.iter_mut().enumerate().skip(done) {
                            d.write(value(j));
                        }
                    }
                    Some((step, shift)) => {
                        for (j, d) in dst.iter_mut().enumerate().skip(done) {
                            d.write((value(j) as f64 * step + shift) as f32);
                        }
                    }
                }
            }
            Ok(true)
        })
    }
}

/// The first samples of `dst` (16 at a time; returns how many) from the byte
/// planes of a row (most significant first, as the floating-point predictor
/// leaves them once undone), each mapped by `map` (`stored · step + shift`,
/// in `f64`) where given. On x86-64, SSE2: the planes interleaved by unpacking,
/// the map two samples at a time; elsewhere none (the caller's loop does all).
#[inline]
fn join_planes(
    planes: [&[u8]; 4],
    dst: &mut [std::mem::MaybeUninit<f32>],
    map: Option<(f64, f64)>,
) -> usize {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        let n = dst.len() / 16 * 16;
        assert!(planes.iter().all(|p| p.len() >= n));
        // SAFETY: SSE2 is part of every x86-64 CPU. Each load reads 16 bytes at
        // `j < n` of a plane at least `n` long (checked above); each store
        // writes 4 samples inside `dst[..n]`.
        unsafe {
            let out = dst.as_mut_ptr() as *mut f32;
            let (step, shift) = map.unwrap_or((1.0, 0.0));
            let (vstep, vshift) = (_mm_set1_pd(step), _mm_set1_pd(shift));
            for j in (0..n).step_by(16) {
                for (q, f) in join16([planes[0], planes[1], planes[2], planes[3]], j)
                    .into_iter()
                    .enumerate()
                {
                    let r = if map.is_some() {
                        let a = _mm_cvtps_pd(f);
                        let b = _mm_cvtps_pd(_mm_movehl_ps(f, f));
                        let a = _mm_cvtpd_ps(_mm_add_pd(_mm_mul_pd(a, vstep), vshift));
                        let b = _mm_cvtpd_ps(_mm_add_pd(_mm_mul_pd(b, vstep), vshift));
                        _mm_movelh_ps(a, b)
                    } else {
                        f
                    };
                    _mm_storeu_ps(out.add(j + 4 * q), r);
                }
            }
            n
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (planes, dst, map);
        0
    }
}

/// Samples `j..j + 16` of a row's byte planes (most significant first, the
/// predictor undone) as four vectors of four `f32`, by unpacking (SSE2):
/// [`join_planes`]' and [`undo_row_avx2`]'s step.
///
/// # Safety
/// Every plane must hold at least `j + 16` bytes.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn join16(planes: [&[u8]; 4], j: usize) -> [std::arch::x86_64::__m128; 4] {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of every x86-64 CPU; each load reads the 16 bytes
    // at `j` of a plane, which the caller guarantees are there.
    unsafe {
        let ld = |k: usize| _mm_loadu_si128(planes[k].as_ptr().add(j) as *const __m128i);
        let (x0, x1, x2, x3) = (ld(0), ld(1), ld(2), ld(3));
        let lo = [_mm_unpacklo_epi8(x3, x2), _mm_unpackhi_epi8(x3, x2)];
        let hi = [_mm_unpacklo_epi8(x1, x0), _mm_unpackhi_epi8(x1, x0)];
        [
            _mm_castsi128_ps(_mm_unpacklo_epi16(lo[0], hi[0])),
            _mm_castsi128_ps(_mm_unpackhi_epi16(lo[0], hi[0])),
            _mm_castsi128_ps(_mm_unpacklo_epi16(lo[1], hi[1])),
            _mm_castsi128_ps(_mm_unpackhi_epi16(lo[1], hi[1])),
        ]
    }
}

/// Whether the CPU has AVX2 ([`undo_row_avx2`]); false off x86-64.
#[inline]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// One row of a floating-point-predictor tile undone (the running byte sum over
/// its four planes, [`running_sum`]) and its samples joined into `dst`, each
/// mapped by `map` as [`join_planes`] does: the same values, 32 bytes a step in
/// the sum and the map four samples at a time in `f64` (SSE2 takes two). The
/// row's width (`dst.len()`) must be a multiple of 16 and `row` its four planes.
/// `read_speed` (x y z of the 47.7 M points, level 0, 2 cores): see
/// bench/history/51.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn undo_row_avx2(
    row: &mut [u8],
    dst: &mut [std::mem::MaybeUninit<f32>],
    map: Option<(f64, f64)>,
) {
    use std::arch::x86_64::*;
    let w = dst.len();
    assert!(w.is_multiple_of(16) && row.len() == 4 * w);
    // The running sum, 32 bytes a step (4w is a multiple of 64). Each block's
    // sums within its lanes, then the low lane's total added to the high lane;
    // the running total's only chain from block to block is one add.
    let mut total = _mm256_setzero_si256();
    let fifteen = _mm256_set1_epi8(15);
    for c in row.chunks_exact_mut(32) {
        let p = c.as_mut_ptr() as *mut __m256i;
        // SAFETY: the load and store cover exactly the 32 bytes of `c`.
        let mut x = unsafe { _mm256_loadu_si256(p) };
        x = _mm256_add_epi8(x, _mm256_slli_si256::<1>(x));
        x = _mm256_add_epi8(x, _mm256_slli_si256::<2>(x));
        x = _mm256_add_epi8(x, _mm256_slli_si256::<4>(x));
        x = _mm256_add_epi8(x, _mm256_slli_si256::<8>(x));
        // Each lane's last byte in all of that lane's bytes.
        let ends = _mm256_shuffle_epi8(x, fifteen);
        // The low lane's total into the high lane (the low lane gets zero).
        x = _mm256_add_epi8(x, _mm256_permute2x128_si256::<0x08>(ends, ends));
        // SAFETY: as the load.
        unsafe { _mm256_storeu_si256(p, _mm256_add_epi8(x, total)) };
        // The block's total (its byte 31) in every byte.
        let last = _mm256_permute4x64_epi64::<0xFF>(_mm256_shuffle_epi8(x, fifteen));
        total = _mm256_add_epi8(total, last);
    }
    let (b0, rest) = row.split_at(w);
    let (b1, rest) = rest.split_at(w);
    let (b2, b3) = rest.split_at(w);
    let out = dst.as_mut_ptr() as *mut f32;
    let (step, shift) = map.unwrap_or((1.0, 0.0));
    let (vstep, vshift) = (_mm256_set1_pd(step), _mm256_set1_pd(shift));
    for j in (0..w).step_by(16) {
        // SAFETY: each load reads the 16 bytes at `j < w` of a plane `w` long;
        // each store writes 4 samples inside `dst[..w]`.
        unsafe {
            for (q, f) in join16([b0, b1, b2, b3], j).into_iter().enumerate() {
                let r = if map.is_some() {
                    // A product, then a sum, each rounded (no fused
                    // multiply-add): [`join_planes`]' values exactly.
                    let d = _mm256_mul_pd(_mm256_cvtps_pd(f), vstep);
                    _mm256_cvtpd_ps(_mm256_add_pd(d, vshift))
                } else {
                    f
                };
                _mm_storeu_ps(out.add(j + 4 * q), r);
            }
        }
    }
}

/// Running (wrapping) sum of `bytes` in place: the horizontal differencing of
/// one byte a sample undone. On x86-64, 16 bytes at a time (SSE2: log-step
/// sums within a vector, then the previous vector's last byte added).
fn running_sum(bytes: &mut [u8]) {
    #[cfg(not(target_arch = "x86_64"))]
    let mut carry = 0u8;
    #[cfg(target_arch = "x86_64")]
    let mut carry;
    #[cfg(target_arch = "x86_64")]
    let bytes = {
        use std::arch::x86_64::*;
        let mut chunks = bytes.chunks_exact_mut(16);
        // The running total so far in every byte, kept in a register. Each
        // block's own sums (and their last byte, broadcast by shuffles) do not
        // depend on it, so the only chain from block to block is one add: the
        // block's sum broadcast is added to the total, not taken from the
        // totalled block (that chain, an add and three shuffles, took 1.13×
        // as long over 2,048-byte rows; history 49).
        // SAFETY: SSE2 is part of every x86-64 CPU.
        let mut total = unsafe { _mm_setzero_si128() };
        for c in &mut chunks {
            // SAFETY: the unaligned load and store cover exactly the 16 bytes
            // of `c`.
            unsafe {
                let p = c.as_mut_ptr() as *mut __m128i;
                let mut x = _mm_loadu_si128(p);
                x = _mm_add_epi8(x, _mm_slli_si128::<1>(x));
                x = _mm_add_epi8(x, _mm_slli_si128::<2>(x));
                x = _mm_add_epi8(x, _mm_slli_si128::<4>(x));
                x = _mm_add_epi8(x, _mm_slli_si128::<8>(x));
                let t = _mm_unpackhi_epi8(x, x);
                let last = _mm_shuffle_epi32::<0xFF>(_mm_shufflehi_epi16::<0xFF>(t));
                _mm_storeu_si128(p, _mm_add_epi8(x, total));
                total = _mm_add_epi8(total, last);
            }
        }
        // SAFETY: SSE2 is part of every x86-64 CPU.
        carry = unsafe { (_mm_cvtsi128_si32(total) & 0xFF) as u8 };
        chunks.into_remainder()
    };
    for b in bytes {
        carry = carry.wrapping_add(*b);
        *b = carry;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The predictor's bytes are the TIFF floating-point predictor's, as
    /// written out here (byte planes most significant first, then each byte
    /// less the one before it in the row), for rows the 16-sample path takes
    /// and rows it leaves to the plain loops, several rows a call.
    #[test]
    fn predicted_rows_are_the_tiff_float_predictor() {
        let mut rng = crate::rng::Rng::new(11);
        for width in [1usize, 5, 16, 17, 48, 256] {
            let values: Vec<f32> = (0..width * 3)
                .map(|i| match i % 3 {
                    0 => f32::from_bits(rng.next_u64() as u32),
                    1 => (8_388_608 + (rng.next_u64() % 1000)) as f32,
                    _ => f32::NAN,
                })
                .collect();
            let mut want = Vec::new();
            for row in values.chunks(width) {
                let mut planes = Vec::new();
                for k in 0..4 {
                    planes.extend(row.iter().map(|v| v.to_be_bytes()[k]));
                }
                want.push(planes[0]);
                want.extend(planes.windows(2).map(|p| p[1].wrapping_sub(p[0])));
            }
            assert_eq!(predict_float(&values, width), want, "width {width}");
        }
    }

    const ALL: [Compression; 6] = Compression::ALL;

    fn codec_of(c: Compression, width: usize) -> TileCodec {
        TileCodec {
            compression: c.tiff_code(),
            predictor: c.predictor(),
            little_endian: cfg!(target_endian = "little"),
            width,
            samples: 1,
            lerc_extra: c.lerc_parameters().map_or(0, |p| p[1]),
        }
    }

    /// LERC within a bound: coordinates on a LAS lattice (integers times 0.01,
    /// relative to an origin off the lattice) come back within the bound and,
    /// at half the lattice step, on the lattice to f32 rounding; whole numbers
    /// exactly whatever the bound; NaN (no point) as NaN; infinities exactly.
    #[test]
    fn lerc_keeps_its_bound_and_whole_numbers() {
        let mut r = crate::rng::Rng::new(9);
        let n = 256 * 256;
        let lattice: Vec<f32> = (0..n)
            .map(|i| {
                if i > n - 300 {
                    f32::NAN
                } else {
                    ((r.f64() * 60000.0).round() * 0.01 - 299.993) as f32
                }
            })
            .collect();
        let whole: Vec<f32> = (0..n).map(|i| ((i * 7919) % 65536) as f32).collect();
        let mut odd = whole.clone();
        odd[5] = f32::INFINITY;
        odd[9] = f32::NAN;
        for c in [
            Compression::Lerc,
            Compression::LercDeflate,
            Compression::LercZstd,
        ] {
            let codec = codec_of(c, 256);
            for (v, e) in [
                (&lattice, 0.005),
                (&lattice, 0.0),
                (&whole, 0.0),
                (&odd, 0.0),
            ] {
                let bytes = encode(v, 256, c, e, ZSTD_FAST, Fast::Zstd).unwrap();
                let back = codec.decode(&bytes, n).unwrap();
                let mut worst = 0f64;
                for (a, b) in v.iter().zip(&back) {
                    if a.is_nan() || !a.is_finite() || e == 0.0 {
                        assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
                    } else {
                        worst = worst.max((*a as f64 - *b as f64).abs());
                    }
                }
                // Within the bound, and in fact on the lattice (f32 rounding of
                // values up to 300: 2^-15).
                assert!(worst <= 4e-5, "{c:?} {e}: {worst}");
            }
            // Within a bound: smaller than lossless (random values, no
            // neighbour alike: a third smaller).
            let lossy = encode(&lattice, 256, c, 0.005, ZSTD_FAST, Fast::Zstd)
                .unwrap()
                .len();
            let exact = encode(&lattice, 256, c, 0.0, ZSTD_FAST, Fast::Zstd)
                .unwrap()
                .len();
            assert!(lossy * 4 < exact * 3, "{c:?}: {lossy} vs {exact}");
        }
    }

    /// Limited-error blobs are written as Lerc2 version 4 (what libtiff
    /// expects), lossless floating-point ones as version 6; both decode to what
    /// the version-3 blob gives, for tiles full, partly empty, empty and flat.
    #[test]
    fn lerc_blobs_are_version_4_where_they_can_be() {
        let n = 64 * 64;
        let ramp: Vec<f32> = (0..n).map(|i| (i % 97) as f32 * 0.013).collect();
        let mut holes = ramp.clone();
        for v in holes.iter_mut().skip(1000) {
            *v = f32::NAN;
        }
        let flat = vec![2.5f32; n];
        let empty = vec![f32::NAN; n];
        for (v, e) in [
            (&ramp, 0.001),
            (&holes, 0.001),
            (&flat, 0.001),
            (&empty, 0.001),
        ] {
            let blob = encode_lerc(v, 64, e).unwrap();
            assert_eq!(lerc::decode_info(&blob).unwrap().version, 4);
            let codec = codec_of(Compression::Lerc, 64);
            let back = codec.decode(&blob, n).unwrap();
            if v.iter().all(|x| !x.is_nan()) {
                let mut plain = vec![0f32; n];
                let v3 = lerc::encode_borrowed(
                    64,
                    64,
                    1,
                    1,
                    v,
                    &[lerc::bitmask::BitMask::all_valid(n)],
                    None,
                    lerc::Precision::Tolerance((e as f32).next_down()),
                );
                lerc::decode_into(&v3.unwrap(), &mut plain).unwrap();
                assert!(back == plain, "version 4 decodes otherwise than version 3");
            }
            for (a, b) in v.iter().zip(&back) {
                // The bound, plus the f32 rounding of what LERC gives back.
                assert!(a.is_nan() && b.is_nan() || (a - b).abs() <= 0.001 + 1e-6);
            }
        }
        let lossless = encode_lerc(&ramp, 64, 0.0).unwrap();
        assert_eq!(lerc::decode_info(&lossless).unwrap().version, 6);
    }

    /// The vector running sum is the byte-by-byte one, at every length.
    #[test]
    fn running_sum_matches_the_plain_loop() {
        let mut r = crate::rng::Rng::new(3);
        for len in [0, 1, 15, 16, 17, 31, 32, 33, 1000, 1024] {
            let v: Vec<u8> = (0..len).map(|_| r.next_u64() as u8).collect();
            let mut fast = v.clone();
            running_sum(&mut fast);
            let mut acc = 0u8;
            let plain: Vec<u8> = v
                .iter()
                .map(|b| {
                    acc = acc.wrapping_add(*b);
                    acc
                })
                .collect();
            assert_eq!(fast, plain, "length {len}");
        }
    }

    /// The AVX2 row (sum, join and map in one) gives the plain path's samples,
    /// bit for bit, with and without a map, for every width it takes.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_rows_are_the_plain_rows() {
        if !has_avx2() {
            eprintln!("skipped: this CPU has no AVX2");
            return;
        }
        let mut r = crate::rng::Rng::new(5);
        for w in [16usize, 32, 48, 256] {
            for map in [None, Some((0.01, -1234.5678)), Some((0.001, 83_886.07))] {
                let row: Vec<u8> = (0..4 * w).map(|_| r.next_u64() as u8).collect();
                let mut plain = row.clone();
                running_sum(&mut plain);
                let (b0, rest) = plain.split_at(w);
                let (b1, rest) = rest.split_at(w);
                let (b2, b3) = rest.split_at(w);
                let want: Vec<u32> = (0..w)
                    .map(|j| {
                        let v = f32::from_be_bytes([b0[j], b1[j], b2[j], b3[j]]);
                        match map {
                            None => v.to_bits(),
                            Some((step, shift)) => ((v as f64 * step + shift) as f32).to_bits(),
                        }
                    })
                    .collect();
                let mut fast = row.clone();
                let mut out = vec![std::mem::MaybeUninit::<f32>::uninit(); w];
                // SAFETY: the CPU has AVX2 (checked above).
                unsafe { undo_row_avx2(&mut fast, &mut out, map) };
                assert_eq!(fast, plain, "width {w}: the running sum");
                // SAFETY: `undo_row_avx2` writes all `w` samples.
                let got: Vec<u32> = out
                    .iter()
                    .map(|v| unsafe { v.assume_init() }.to_bits())
                    .collect();
                assert_eq!(got, want, "width {w}, map {map:?}");
            }
        }
    }

    /// The type of the literals of a Zstd frame's first compressed block
    /// (RFC 8878: 0 raw, 1 RLE, 2 Huffman-coded, 3 with the previous table).
    fn first_literals_type(frame: &[u8]) -> Option<u8> {
        let fhd = frame[4];
        let single = fhd & 0x20 != 0;
        let dict = [0, 1, 2, 4][(fhd & 3) as usize];
        let fcs = match fhd >> 6 {
            0 => usize::from(single),
            1 => 2,
            2 => 4,
            _ => 8,
        };
        let mut at = 5 + usize::from(!single) + dict + fcs;
        loop {
            let h = u32::from_le_bytes([frame[at], frame[at + 1], frame[at + 2], 0]);
            let (last, kind, size) = (h & 1 != 0, (h >> 1) & 3, (h >> 3) as usize);
            at += 3;
            match kind {
                2 => return Some(frame[at] & 3),
                1 => at += 1,
                _ => at += size,
            }
            if last {
                return None;
            }
        }
    }

    /// Coordinate tiles at the fast level keep their literals raw; every other
    /// band and level Huffman-codes them; all decode to the same values.
    #[test]
    fn coordinates_keep_raw_literals_at_the_fast_level() {
        let mut r = crate::rng::Rng::new(9);
        let mut k = 1_000_000i64;
        // Whole numbers on a lattice as stored (biased by 2^23), a random walk
        // along the curve: noisy low bytes.
        let v: Vec<f32> = (0..256 * 256)
            .map(|_| {
                k += (r.next_u64() % 41) as i64 - 20;
                (k + (1 << 23)) as f32
            })
            .collect();
        let codec = codec_of(Compression::Zstd, 256);
        for (level, literals, want) in [
            (ZSTD_FAST, Fast::RawLiterals, 0),
            (ZSTD_FAST, Fast::Zstd, 2),
            (ZSTD_SMALL, Fast::RawLiterals, 2),
        ] {
            let frame = encode(&v, 256, Compression::Zstd, 0.0, level, literals).unwrap();
            assert_eq!(
                first_literals_type(&frame),
                Some(want),
                "level {level}, {literals:?}"
            );
            assert_eq!(codec.decode(&frame, v.len()).unwrap(), v);
        }
    }

    #[test]
    fn corrupt_lerc_is_an_error() {
        let v: Vec<f32> = (0..64).map(|i| i as f32 * 0.5).collect();
        for c in [Compression::Lerc, Compression::LercZstd] {
            let good = encode(&v, 8, c, 0.0, ZSTD_FAST, Fast::Zstd).unwrap();
            let codec = codec_of(c, 8);
            assert_eq!(codec.decode(&good, 64).unwrap(), v);
            assert!(codec.decode(&good[..good.len() / 2], 64).is_err());
            // A blob of another size than the tile's.
            assert!(codec_of(c, 16).decode(&good, 256).is_err());
            let mut bad = good.clone();
            let k = bad.len() - 3;
            bad[k] ^= 0x5a;
            assert!(codec.decode(&bad, 64).is_err() || c == Compression::LercZstd);
        }
    }

    #[test]
    fn zstd_levels_decode_alike_and_the_small_level_is_smaller() {
        // A scan-like band: a slow walk with a repeating jitter, the kind of
        // row Zstd's lazier levels find longer matches in.
        let v: Vec<f32> = (0..512 * 64)
            .map(|i| (i / 3) as f32 + [0.0, 2.0, 1.0, 5.0, 3.0][i % 5])
            .collect();
        let fast = encode(&v, 512, Compression::Zstd, 0.0, ZSTD_FAST, Fast::Zstd).unwrap();
        let small = encode(&v, 512, Compression::Zstd, 0.0, ZSTD_SMALL, Fast::Zstd).unwrap();
        assert!(
            small.len() < fast.len(),
            "{} vs {}",
            small.len(),
            fast.len()
        );
        let codec = codec_of(Compression::Zstd, 512);
        for bytes in [&fast, &small] {
            let back = codec.decode(bytes, v.len()).unwrap();
            assert!(v.iter().zip(&back).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }

    #[test]
    fn round_trip_every_compression() {
        let v: Vec<f32> = (0..256 * 4)
            .map(|i| {
                if i % 7 == 0 {
                    f32::NAN
                } else {
                    i as f32 * 0.37 - 50.0
                }
            })
            .collect();
        for c in ALL {
            let bytes = encode(&v, 256, c, 0.0, ZSTD_FAST, Fast::Zstd).unwrap();
            let codec = codec_of(c, 256);
            let back = codec.decode(&bytes, v.len()).unwrap();
            assert_eq!(back.len(), v.len());
            for (a, b) in v.iter().zip(&back) {
                assert!(a.to_bits() == b.to_bits(), "{c:?}");
            }
        }
    }

    #[test]
    fn corrupt_streams_are_errors() {
        let codec = TileCodec {
            compression: comp::ADOBE_DEFLATE,
            predictor: 3,
            little_endian: true,
            width: 4,
            samples: 1,
            lerc_extra: 0,
        };
        assert!(codec.decode(b"not deflate", 16).is_err());
        let good = encode(
            &[1.0; 16],
            4,
            Compression::Deflate,
            0.0,
            ZSTD_FAST,
            Fast::Zstd,
        )
        .unwrap();
        assert!(codec.decode(&good[..good.len() / 2], 16).is_err());
    }
}
