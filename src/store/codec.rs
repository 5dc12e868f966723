//! Tile payloads: Float32 samples to bytes and back, with optional Deflate or Zstd
//! compression and TIFF's floating-point predictor (3).

use super::spec::{compression as comp, predictor as pred};
use std::io::{Read, Write};

/// Compression of a part's tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Compression {
    /// Fastest to load: tiles are read straight out of the memory map.
    #[default]
    None,
    Deflate,
    Zstd,
}

impl Compression {
    pub fn tiff_code(self) -> u16 {
        match self {
            Compression::None => comp::NONE,
            Compression::Deflate => comp::ADOBE_DEFLATE,
            Compression::Zstd => comp::ZSTD,
        }
    }

    pub fn predictor(self) -> u16 {
        match self {
            Compression::None => pred::NONE,
            _ => pred::FLOATING_POINT,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Deflate => "deflate",
            Compression::Zstd => "zstd",
        }
    }

    pub fn parse(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "none" => Ok(Compression::None),
            "deflate" | "zip" => Ok(Compression::Deflate),
            "zstd" => Ok(Compression::Zstd),
            _ => Err(format!(
                "unknown compression '{s}' (expected none, deflate or zstd)"
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
        5 => "lzw".into(),
        c => format!("code {c}"),
    }
}

/// Encodes one tile of one band (`width` samples per row, native byte order).
pub fn encode(values: &[f32], width: usize, c: Compression) -> Vec<u8> {
    match c {
        Compression::None => bytemuck::cast_slice(values).to_vec(),
        Compression::Deflate => {
            let raw = predict_float(values, width);
            let mut e = flate2::write::ZlibEncoder::new(
                Vec::with_capacity(raw.len() / 2),
                flate2::Compression::new(6),
            );
            // Writing into a Vec cannot fail.
            let _ = e.write_all(&raw);
            e.finish().unwrap_or_default()
        }
        Compression::Zstd => {
            let raw = predict_float(values, width);
            zstd::bulk::compress(&raw, 3).unwrap_or_default()
        }
    }
}

/// TIFF floating-point predictor on rows of one sample per pixel: bytes of each row
/// regrouped most significant first, then differenced.
fn predict_float(values: &[f32], width: usize) -> Vec<u8> {
    let mut out = vec![0u8; values.len() * 4];
    for (row, dst) in values.chunks(width).zip(out.chunks_mut(width * 4)) {
        let w = row.len();
        for (i, v) in row.iter().enumerate() {
            let b = v.to_be_bytes();
            for k in 0..4 {
                dst[k * w + i] = b[k];
            }
        }
        for i in (1..dst.len()).rev() {
            dst[i] = dst[i].wrapping_sub(dst[i - 1]);
        }
    }
    out
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
}

impl TileCodec {
    pub fn check(&self) -> Result<(), String> {
        match self.compression {
            comp::NONE | comp::ADOBE_DEFLATE | comp::DEFLATE | comp::ZSTD => {}
            c => {
                return Err(format!(
                    "tiles use compression {} which pcimg does not read (none, deflate or zstd)",
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
        let owned;
        let raw: &[u8] = match self.compression {
            comp::NONE => stored,
            comp::ADOBE_DEFLATE | comp::DEFLATE => {
                let mut v = Vec::with_capacity(nbytes);
                flate2::read::ZlibDecoder::new(stored)
                    .take(nbytes as u64)
                    .read_to_end(&mut v)
                    .map_err(|e| format!("deflate stream is corrupt: {e}"))?;
                owned = v;
                &owned
            }
            comp::ZSTD => {
                owned = zstd::bulk::decompress(stored, nbytes)
                    .map_err(|e| format!("zstd stream is corrupt: {e}"))?;
                &owned
            }
            c => {
                return Err(format!(
                    "compression {} is not supported",
                    compression_name(c)
                ));
            }
        };
        if raw.len() < nbytes {
            return Err(format!(
                "tile holds {} bytes, {} expected",
                raw.len(),
                nbytes
            ));
        }
        let raw = &raw[..nbytes];
        if self.predictor == pred::FLOATING_POINT {
            return Ok(unpredict_float(
                raw,
                self.width * self.samples,
                self.samples,
            ));
        }
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

/// Undoes the floating-point predictor: rows of `row_samples` samples, differenced
/// with a stride of `stride` bytes.
fn unpredict_float(raw: &[u8], row_samples: usize, stride: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(raw.len() / 4);
    let mut row = vec![0u8; row_samples * 4];
    for src in raw.chunks(row_samples * 4) {
        let n = src.len();
        row[..n].copy_from_slice(src);
        for i in stride..n {
            row[i] = row[i].wrapping_add(row[i - stride]);
        }
        let w = n / 4;
        for i in 0..w {
            out.push(f32::from_be_bytes([
                row[i],
                row[w + i],
                row[2 * w + i],
                row[3 * w + i],
            ]));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

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
        for c in [Compression::None, Compression::Deflate, Compression::Zstd] {
            let bytes = encode(&v, 256, c);
            let codec = TileCodec {
                compression: c.tiff_code(),
                predictor: c.predictor(),
                little_endian: cfg!(target_endian = "little"),
                width: 256,
                samples: 1,
            };
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
        };
        assert!(codec.decode(b"not deflate", 16).is_err());
        let good = encode(&[1.0; 16], 4, Compression::Deflate);
        assert!(codec.decode(&good[..good.len() / 2], 16).is_err());
    }
}
