//! Reading points out of an opened part: a level, or chosen tiles, for chosen bands
//! into `f32` columns. Uncompressed tiles are read straight out of the memory map;
//! compressed ones are decoded in parallel.

use crate::bigvec;
use crate::error::{Result, StoreError};
use crate::read::part::{Level, Part};
use crate::read::source::Chunks;
use crate::spec;
use crate::tiff::codec::TileCodec;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::mem::MaybeUninit;

impl Level {
    pub(crate) fn codec(&self, little_endian: bool, samples: usize) -> TileCodec {
        TileCodec {
            compression: self.compression,
            predictor: self.predictor,
            little_endian,
            width: self.tile_width as usize,
            samples,
            lerc_extra: self.lerc_extra,
        }
    }
}

/// Points read from a part: columns in the order of the requested bands.
#[derive(Debug, Clone, Default)]
pub struct Points {
    /// Names of the columns.
    pub bands: Vec<String>,
    /// Offset of each column: true value = offset + stored value.
    pub offsets: Vec<f64>,
    pub columns: Vec<Vec<f32>>,
    /// Points per requested tile, in order.
    pub tile_points: Vec<u32>,
}

impl Points {
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The column of band `name`, if it was read.
    pub fn column(&self, name: &str) -> Option<&[f32]> {
        let i = self.bands.iter().position(|b| b == name)?;
        Some(&self.columns[i])
    }
}

impl Part {
    /// Reads every point of `level` for `bands` (a paper-layout part: in image row
    /// order, so level 0 comes back in input order).
    pub fn read_level(&self, level: usize, bands: &[usize]) -> Result<Points> {
        if let Some(p) = self.opened()? {
            return p.read_level(level, bands);
        }
        if self.row_major() {
            return self.read_level_row_major(level, bands);
        }
        let l = self.level(level)?;
        let tiles: Vec<u32> = l.tiles.iter().map(|t| t.index).collect();
        self.read_tiles(level, &tiles, bands)
    }

    pub(crate) fn level(&self, level: usize) -> Result<&Level> {
        self.levels.get(level).ok_or_else(|| {
            StoreError::new(
                &self.path,
                format!("has no level {level} (levels 0..{})", self.levels.len()),
            )
        })
    }

    /// Reads the points of the tiles `tiles` (raster indices) of `level` for `bands`,
    /// tile after tile in the order given.
    pub fn read_tiles(&self, level: usize, tiles: &[u32], bands: &[usize]) -> Result<Points> {
        if let Some(p) = self.opened()? {
            return p.read_tiles(level, tiles, bands);
        }
        if self.row_major() {
            return self.read_tiles_row_major(level, tiles, bands);
        }
        let l = self.level(level)?;
        if let Some(&b) = bands.iter().find(|&&b| b >= self.bands.len()) {
            return Err(StoreError::new(
                &self.path,
                format!("has no band {b} ({} bands)", self.bands.len()),
            ));
        }
        let per_band = (l.tiles_across * l.tiles_down) as usize;
        if let Some(&t) = tiles.iter().find(|&&t| t as usize >= per_band) {
            return Err(StoreError::new(
                &self.path,
                format!("level {level} has no tile {t} ({per_band} tiles)"),
            ));
        }
        let known: BTreeMap<u32, Option<u32>> =
            l.tiles.iter().map(|t| (t.index, t.points)).collect();
        let counts: Option<Vec<usize>> = tiles
            .iter()
            .map(|t| known.get(t).copied().flatten().map(|c| c as usize))
            .collect();
        let fail = |m: String| StoreError::new(&self.path, format!("level {level}: {m}"));
        // The stored bytes: the map, or for a remote part exactly these chunks,
        // fetched now (x too where counts are unknown: it finds the points).
        let src = self
            .chunks(l, tiles, bands, counts.is_none())
            .map_err(|e| self.fetch_failed(level, e))?;
        if let Some(counts) = counts {
            // Every count is known: fill disjoint slices of the output in parallel.
            let total: usize = counts.iter().sum();
            // Columns are filled in place without being zeroed first (every slot is
            // written by exactly one tile), in huge-page-backed memory.
            let mut columns: Vec<Vec<f32>> =
                bands.iter().map(|_| bigvec::with_capacity(total)).collect();
            let mut outs: Vec<Vec<&mut [MaybeUninit<f32>]>> = (0..tiles.len())
                .map(|_| Vec::with_capacity(bands.len()))
                .collect();
            for col in columns.iter_mut() {
                let mut rest = &mut col.spare_capacity_mut()[..total];
                for (k, &c) in counts.iter().enumerate() {
                    let (head, tail) = rest.split_at_mut(c);
                    outs[k].push(head);
                    rest = tail;
                }
            }
            outs.into_par_iter()
                .zip(tiles.par_iter())
                .try_for_each(|(o, &t)| self.fill_tile(&src, l, t, bands, o))
                .map_err(fail)?;
            for col in columns.iter_mut() {
                // SAFETY: fill_tile succeeded for every tile, and the tiles' slices
                // (sized by their counts) cover the first `total` slots exactly.
                unsafe { col.set_len(total) };
            }
            return Ok(Points {
                bands: bands.iter().map(|&b| self.bands[b].name.clone()).collect(),
                offsets: bands.iter().map(|&b| self.bands[b].offset).collect(),
                columns,
                tile_points: counts.iter().map(|&c| c as u32).collect(),
            });
        }
        // Without counts, tiles are decoded in parallel batches and the total is
        // checked against POINT_COUNT, so a corrupt file cannot make us hold more.
        let mut per_tile: Vec<Vec<Vec<f32>>> = Vec::with_capacity(tiles.len());
        let mut held = 0u64;
        for batch in tiles.chunks(8) {
            let got: Vec<Vec<Vec<f32>>> = batch
                .par_iter()
                .map(|&t| self.read_tile(&src, l, t, known.get(&t).copied().flatten(), bands))
                .collect::<std::result::Result<_, String>>()
                .map_err(fail)?;
            held += got
                .iter()
                .map(|c| c.first().map_or(0, Vec::len) as u64)
                .sum::<u64>();
            if held > self.meta.point_count {
                return Err(fail(format!(
                    "holds more points than the part's POINT_COUNT ({})",
                    self.meta.point_count
                )));
            }
            per_tile.extend(got);
        }
        let total: usize = per_tile.iter().map(|c| c.first().map_or(0, Vec::len)).sum();
        let mut columns: Vec<Vec<f32>> = bands.iter().map(|_| Vec::with_capacity(total)).collect();
        let mut tile_points = Vec::with_capacity(tiles.len());
        for t in &per_tile {
            tile_points.push(t.first().map_or(0, Vec::len) as u32);
            for (c, v) in columns.iter_mut().zip(t) {
                c.extend_from_slice(v);
            }
        }
        Ok(Points {
            bands: bands.iter().map(|&b| self.bands[b].name.clone()).collect(),
            offsets: bands.iter().map(|&b| self.bands[b].offset).collect(),
            columns,
            tile_points,
        })
    }

    /// Fills `outs` (one slice per requested band, all of the tile's point count)
    /// with the tile's first points in reading order. Uncompressed native-order
    /// planes are gathered straight from the memory map.
    fn fill_tile(
        &self,
        src: &Chunks,
        l: &Level,
        t: u32,
        bands: &[usize],
        outs: Vec<&mut [MaybeUninit<f32>]>,
    ) -> std::result::Result<(), String> {
        let n = outs.first().map_or(0, |o| o.len());
        let per_band = (l.tiles_across * l.tiles_down) as usize;
        let pixels = (l.tile_width * l.tile_height) as usize;
        let Some(lut) = l.z_lut.as_deref().filter(|lut| lut.len() >= n) else {
            // No Z-order tiles: take the general path.
            let cols = self.read_tile(src, l, t, Some(n as u32), bands)?;
            for (o, c) in outs.into_iter().zip(cols) {
                if c.len() != o.len() {
                    return Err(format!("tile {t} holds fewer points than its index says"));
                }
                for (d, v) in o.iter_mut().zip(c) {
                    d.write(v);
                }
            }
            return Ok(());
        };
        let native = self.little_endian == cfg!(target_endian = "little");
        if !l.planar_separate {
            let cols = self.read_tile(src, l, t, Some(n as u32), bands)?;
            for (o, c) in outs.into_iter().zip(cols) {
                if c.len() < o.len() {
                    return Err(format!("tile {t} holds fewer points than its index says"));
                }
                for (d, &v) in o.iter_mut().zip(&c) {
                    d.write(v);
                }
            }
            return Ok(());
        }
        for &b in bands {
            let c = b * per_band + t as usize;
            if let (Some(&o), Some(&n)) = (l.offsets.get(c), l.counts.get(c)) {
                src.will_need(o, n);
            }
        }
        for (o, &b) in outs.into_iter().zip(bands) {
            let c = b * per_band + t as usize;
            let (off, len) = (l.offsets[c] as usize, l.counts[c] as usize);
            if len == 0 {
                return Err(format!(
                    "tile {t} band {} is empty but its index says {n} points",
                    b + 1
                ));
            }
            let stored = src.get(off as u64, len as u64)?;
            let raw = (l.compression == spec::compression::NONE && native && len >= pixels * 4)
                .then(|| bytemuck::try_cast_slice::<u8, f32>(&stored[..pixels * 4]).ok())
                .flatten();
            let map = self.bands[b].stored_map();
            match raw {
                Some(plane) => place(o, plane, &lut[..n], map),
                None if l.row_order
                    && l.codec(self.little_endian, 1)
                        .decode_rows_into(stored, pixels, o, map)
                        .map_err(|m| format!("tile {t} band {}: {m}", b + 1))? => {}
                None if map.is_none()
                    && l.tile_width == l.tile_height
                    && l.codec(self.little_endian, 1)
                        .decode_lerc_z(stored, o)
                        .map_err(|m| format!("tile {t} band {}: {m}", b + 1))? => {}
                None => {
                    let plane = l
                        .codec(self.little_endian, 1)
                        .decode(stored, pixels)
                        .map_err(|m| format!("tile {t} band {}: {m}", b + 1))?;
                    place(o, &plane, &lut[..n], map);
                }
            }
        }
        Ok(())
    }

    /// Decodes one tile: per requested band, the tile's points in reading order.
    pub(crate) fn read_tile(
        &self,
        src: &Chunks,
        l: &Level,
        t: u32,
        points: Option<u32>,
        bands: &[usize],
    ) -> std::result::Result<Vec<Vec<f32>>, String> {
        let per_band = (l.tiles_across * l.tiles_down) as usize;
        let pixels = (l.tile_width * l.tile_height) as usize;
        // Pixels of this tile inside the image, in reading order.
        let col = t % l.tiles_across;
        let row = t / l.tiles_across;
        let order: Vec<u32>;
        let read_order: &[u32] = match &l.z_lut {
            Some(lut) => lut,
            None => {
                let w = l.tile_width.min(l.width - col * l.tile_width);
                let h = l.tile_height.min(l.height - row * l.tile_height);
                order = (0..h)
                    .flat_map(|y| (0..w).map(move |x| y * l.tile_width + x))
                    .collect();
                &order
            }
        };
        let chunk = |b: usize| {
            if l.planar_separate {
                b * per_band + t as usize
            } else {
                t as usize
            }
        };
        let stored = |c: usize| -> std::result::Result<&[u8], String> {
            src.get(l.offsets[c], l.counts[c])
                .map_err(|m| format!("tile {t}: {m}"))
        };
        // The bands to decode: the requested ones, plus x to find valid pixels
        // when the tile index does not give the count.
        let mut decode: Vec<usize> = bands.to_vec();
        if points.is_none() && !decode.contains(&0) {
            decode.push(0);
        }
        // The map reads nothing ahead (`Bytes::random`): ask for exactly this
        // tile's chunks, all at once.
        for c in decode.iter().map(|&b| chunk(b)) {
            if let (Some(&o), Some(&n)) = (l.offsets.get(c), l.counts.get(c)) {
                src.will_need(o, n);
            }
        }
        let raw_native = l.compression == spec::compression::NONE
            && l.planar_separate
            && self.little_endian == cfg!(target_endian = "little");
        let mut planes: Vec<Vec<f32>> = Vec::with_capacity(decode.len());
        // Planes read straight from the stored bytes (uncompressed, native order).
        let mut raw: Vec<&[u8]> = vec![&[]; decode.len()];
        if l.planar_separate {
            for (k, &b) in decode.iter().enumerate() {
                let bytes = stored(chunk(b))?;
                if bytes.is_empty() {
                    planes.push(vec![f32::NAN; pixels]);
                } else if raw_native && bytes.len() >= pixels * 4 {
                    raw[k] = &bytes[..pixels * 4];
                    planes.push(Vec::new()); // read straight from the bytes below
                } else {
                    let codec = l.codec(self.little_endian, 1);
                    planes.push(
                        codec
                            .decode(bytes, pixels)
                            .map_err(|m| format!("tile {t} band {}: {m}", b + 1))?,
                    );
                }
            }
        } else {
            let bytes = stored(chunk(0))?;
            let all = if bytes.is_empty() {
                vec![f32::NAN; pixels * self.samples]
            } else {
                l.codec(self.little_endian, self.samples)
                    .decode(bytes, pixels * self.samples)
                    .map_err(|m| format!("tile {t}: {m}"))?
            };
            for &b in &decode {
                planes.push(all.iter().skip(b).step_by(self.samples).copied().collect());
            }
        }
        let sample = |k: usize, p: usize| -> f32 {
            if planes[k].is_empty() {
                let (o, d) = (p * 4, raw[k]);
                f32::from_le_bytes([d[o], d[o + 1], d[o + 2], d[o + 3]])
            } else {
                planes[k][p]
            }
        };
        let selected: Vec<u32> = match points {
            Some(n) => read_order[..(n as usize).min(read_order.len())].to_vec(),
            None => {
                let xk = decode.iter().position(|&b| b == 0).unwrap_or(0);
                read_order
                    .iter()
                    .copied()
                    .filter(|&p| !sample(xk, p as usize).is_nan())
                    .collect()
            }
        };
        Ok((0..bands.len())
            .map(|k| {
                if let Some((step, shift)) = self.bands[bands[k]].stored_map() {
                    return selected
                        .iter()
                        .map(|&p| (sample(k, p as usize) as f64 * step + shift) as f32)
                        .collect();
                }
                if planes[k].is_empty() {
                    let bytes = raw[k];
                    selected
                        .iter()
                        .map(|&p| {
                            let o = p as usize * 4;
                            f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]])
                        })
                        .collect()
                } else {
                    selected.iter().map(|&p| planes[k][p as usize]).collect()
                }
            })
            .collect())
    }
}

/// Writes `plane[lut[i]]` to `out[i]`: a tile's samples in reading order, mapped
/// from whole numbers on a lattice (`map`: step and shift) where the band has one.
#[inline]
fn place(out: &mut [MaybeUninit<f32>], plane: &[f32], lut: &[u32], map: Option<(f64, f64)>) {
    match map {
        None => {
            for (v, &p) in out.iter_mut().zip(lut) {
                v.write(plane[p as usize]);
            }
        }
        Some((step, shift)) => {
            for (v, &p) in out.iter_mut().zip(lut) {
                v.write((plane[p as usize] as f64 * step + shift) as f32);
            }
        }
    }
}
