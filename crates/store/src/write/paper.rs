//! The paper's layout (Du & Li 2009), kept for comparison: points in input order,
//! row-major in the square image (point `i` at pixel `(i mod W, i div W)`), and
//! level `k` keeps pixel `(2^k·x, 2^k·y)` of level 0 (plain nearest-neighbour
//! down-sampling). Counts and per-tile bounds of the tile index come from what each
//! level actually holds; reading keeps the non-NaN pixels, row by row.

use crate::error::{Result, StoreError};
use crate::points::Bounds;
use crate::read::part::Part;
use crate::read::points::Points;
use crate::spec::TILE_SIZE;
use crate::tiff::metadata::{LevelIndex, TileEntry};
use crate::tiff::zorder::Geometry;
use rayon::prelude::*;

/// Index of the input point at pixel `(x, y)` of `level` (not checked against N).
#[inline]
fn source(width: u32, level: usize, x: u32, y: u32) -> u64 {
    ((y as u64) << level) * width as u64 + ((x as u64) << level)
}

/// Whether input point `i` of an image `width` wide is kept at `level`.
pub fn kept(i: u64, width: u32, level: usize) -> bool {
    let mask = (1u64 << level) - 1;
    (i % width as u64) & mask == 0 && (i / width as u64) & mask == 0
}

/// Indices of the input points kept at `level`, in row-major order of that level.
pub fn level_indices(points: u64, level: usize) -> Vec<u64> {
    let width = Geometry::for_points(points).size(0);
    let step = 1u64 << level;
    let row = width as u64;
    (0..points.div_ceil(row))
        .step_by(step as usize)
        .flat_map(|y| (y * row..((y + 1) * row).min(points)).step_by(step as usize))
        .collect()
}

/// Points held by row `y` (pixels `x0..x0 + TILE_SIZE`) of `level`.
fn row_points(g: Geometry, level: usize, x0: u32, y: u32) -> u32 {
    let w = g.size(0);
    let first = source(w, level, x0, y);
    if first >= g.points || x0 >= g.size(level) {
        return 0;
    }
    // Pixels x0 + j for j with first + j·2^k < N.
    (g.points - first)
        .div_ceil(1 << level)
        .min(TILE_SIZE as u64) as u32
}

/// Points held by the tile of raster index `t` of `level`.
pub fn tile_points(g: Geometry, level: usize, t: u32) -> u32 {
    let across = g.tiles_across(level);
    let (col, row) = (t % across, t / across);
    (0..TILE_SIZE)
        .map(|y| row_points(g, level, col * TILE_SIZE, row * TILE_SIZE + y))
        .sum()
}

/// The tile index: per level, every tile holding points, in raster order. A tile's
/// bounds are those of all level-0 points under it (the union of its four children).
pub(crate) fn tile_index(pos: &[[f32; 3]], origin: [f64; 3], g: Geometry) -> Vec<LevelIndex> {
    let w = g.size(0);
    let across0 = g.tiles_across(0);
    // Level 0: every tile's rows are contiguous runs of the input.
    let level0: Vec<Option<Bounds>> = (0..across0 * across0)
        .into_par_iter()
        .map(|t| {
            let (col, row) = (t % across0, t / across0);
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            let mut any = false;
            for y in 0..TILE_SIZE {
                let c = row_points(g, 0, col * TILE_SIZE, row * TILE_SIZE + y) as usize;
                if c == 0 {
                    break;
                }
                any = true;
                let s = source(w, 0, col * TILE_SIZE, row * TILE_SIZE + y) as usize;
                for p in &pos[s..s + c] {
                    for a in 0..3 {
                        lo[a] = lo[a].min(p[a]);
                        hi[a] = hi[a].max(p[a]);
                    }
                }
            }
            any.then(|| Bounds {
                min: [0, 1, 2].map(|a| origin[a] + lo[a] as f64),
                max: [0, 1, 2].map(|a| origin[a] + hi[a] as f64),
            })
        })
        .collect();
    let mut levels = Vec::with_capacity(g.levels());
    let mut below = level0;
    for level in 0..g.levels() {
        let across = g.tiles_across(level);
        let here: Vec<Option<Bounds>> = if level == 0 {
            below.clone()
        } else {
            (0..across * across)
                .map(|t| {
                    let (col, row) = (t % across, t / across);
                    let down = 2 * across;
                    [(0, 0), (1, 0), (0, 1), (1, 1)]
                        .iter()
                        .filter_map(|(dx, dy)| {
                            below[((2 * row + dy) * down + 2 * col + dx) as usize]
                        })
                        .reduce(|a, b| a.union(&b))
                })
                .collect()
        };
        let tiles = (0..across * across)
            .filter_map(|t| {
                let points = tile_points(g, level, t);
                (points > 0).then(|| TileEntry {
                    index: t,
                    points,
                    // A held pixel implies held level-0 points under the tile.
                    bounds: here[t as usize].unwrap_or(Bounds::EMPTY),
                })
            })
            .collect();
        levels.push(LevelIndex {
            size: g.size(level),
            tile_size: TILE_SIZE,
            tiles,
        });
        below = here;
    }
    levels
}

/// The pixels of the tile of raster index `t` of `level` for one band (`value(i)`:
/// the band's value for input point `i`), NaN where no point is held.
pub(crate) fn tile_pixels(
    value: impl Fn(usize) -> f32,
    g: Geometry,
    level: usize,
    t: u32,
) -> crate::write::out::TileBuf {
    let mut buf = crate::write::out::TileBuf::filled(f32::NAN);
    tile_sources(g, level, t, |pixel, i| buf[pixel] = value(i));
    buf
}

/// Calls `visit(pixel, i)` for every pixel of the tile of raster index `t` of
/// `level` that holds a point (row-major pixel index within the tile; `i`: the
/// input point there), in raster order, so in ascending `i`.
pub(crate) fn tile_sources(g: Geometry, level: usize, t: u32, mut visit: impl FnMut(usize, usize)) {
    let w = g.size(0);
    let across = g.tiles_across(level);
    let (x0, y0) = ((t % across) * TILE_SIZE, (t / across) * TILE_SIZE);
    for y in 0..TILE_SIZE {
        let c = row_points(g, level, x0, y0 + y) as usize;
        if c == 0 {
            break;
        }
        let s = source(w, level, x0, y0 + y) as usize;
        let row = (y * TILE_SIZE) as usize;
        for j in 0..c {
            visit(row + j, s + (j << level));
        }
    }
}

/// A decoded tile: one plane per band (x first), and the width of its rows.
type Planes = (Vec<Vec<f32>>, usize);

impl Part {
    /// Whether points are placed row-major (the paper's layout).
    pub(crate) fn row_major(&self) -> bool {
        self.meta.layout == crate::spec::layout::PAPER
    }

    /// Decodes tile `t` of `level` whole: per band of `[0] + bands`, every pixel in
    /// raster order (rows as wide as the tile's part of the image), and that width.
    fn tile_planes(
        &self,
        level: usize,
        t: u32,
        bands: &[usize],
    ) -> std::result::Result<Planes, String> {
        let l = &self.levels[level];
        let dec: Vec<usize> = std::iter::once(0).chain(bands.iter().copied()).collect();
        let src = self
            .chunks(l, &[t], &dec, false)
            .map_err(|e| e.to_string())?;
        let planes = self.read_tile(&src, l, t, Some(l.tile_width * l.tile_height), &dec)?;
        let w = l
            .tile_width
            .min(l.width - (t % l.tiles_across) * l.tile_width) as usize;
        Ok((planes, w))
    }

    fn check_request(&self, level: usize, tiles: &[u32], bands: &[usize]) -> Result<()> {
        let l = self.level(level)?;
        if let Some(&b) = bands.iter().find(|&&b| b >= self.bands.len()) {
            return Err(StoreError::new(
                &self.path,
                format!("has no band {b} ({} bands)", self.bands.len()),
            ));
        }
        let per_band = l.tiles_across * l.tiles_down;
        if let Some(&t) = tiles.iter().find(|&&t| t >= per_band) {
            return Err(StoreError::new(
                &self.path,
                format!("level {level} has no tile {t} ({per_band} tiles)"),
            ));
        }
        Ok(())
    }

    fn empty_points(&self, bands: &[usize]) -> Points {
        Points {
            bands: bands.iter().map(|&b| self.bands[b].name.clone()).collect(),
            offsets: bands.iter().map(|&b| self.bands[b].offset).collect(),
            columns: vec![Vec::new(); bands.len()],
            tile_points: Vec::new(),
        }
    }

    /// Reads a row-major level whole, in image row order (level 0: input order).
    pub(crate) fn read_level_row_major(&self, level: usize, bands: &[usize]) -> Result<Points> {
        self.check_request(level, &[], bands)?;
        let l = &self.levels[level];
        let fail = |m: String| StoreError::new(&self.path, format!("level {level}: {m}"));
        let mut out = self.empty_points(bands);
        for row in 0..l.tiles_down {
            let tiles: Vec<u32> = l
                .tiles
                .iter()
                .map(|t| t.index)
                .filter(|t| t / l.tiles_across == row)
                .collect();
            let mut decoded: Vec<(u32, Planes)> = tiles
                .par_iter()
                .map(|&t| self.tile_planes(level, t, bands).map(|p| (t, p)))
                .collect::<std::result::Result<_, String>>()
                .map_err(fail)?;
            decoded.sort_by_key(|d| d.0);
            let h = l.tile_height.min(l.height - row * l.tile_height) as usize;
            for y in 0..h {
                for (_, (planes, w)) in &decoded {
                    let xs = &planes[0][y * w..(y + 1) * w];
                    for (x, v) in xs.iter().enumerate() {
                        if !v.is_nan() {
                            for (c, p) in out.columns.iter_mut().zip(&planes[1..]) {
                                c.push(p[y * w + x]);
                            }
                        }
                    }
                }
            }
            if out.len() as u64 > self.meta.point_count {
                return Err(fail(format!(
                    "holds more points than the part's POINT_COUNT ({})",
                    self.meta.point_count
                )));
            }
        }
        // `tile_points` stays empty: the level was read in rows across tiles.
        Ok(out)
    }

    /// Reads tiles of a row-major level, each tile's points in its raster order.
    pub(crate) fn read_tiles_row_major(
        &self,
        level: usize,
        tiles: &[u32],
        bands: &[usize],
    ) -> Result<Points> {
        self.check_request(level, tiles, bands)?;
        let l = &self.levels[level];
        let fail = |m: String| StoreError::new(&self.path, format!("level {level}: {m}"));
        let mut out = self.empty_points(bands);
        for batch in tiles.chunks(8) {
            let got: Vec<Vec<Vec<f32>>> = batch
                .par_iter()
                .map(|&t| {
                    let (planes, _) = self.tile_planes(level, t, bands)?;
                    let keep: Vec<usize> = (0..planes[0].len())
                        .filter(|&p| !planes[0][p].is_nan())
                        .collect();
                    let known = l.tiles.iter().find(|i| i.index == t).and_then(|i| i.points);
                    if let Some(k) = known.filter(|&k| k as usize != keep.len()) {
                        return Err(format!(
                            "tile {t} holds {} points but the tile index says {k}",
                            keep.len()
                        ));
                    }
                    Ok(planes[1..]
                        .iter()
                        .map(|p| keep.iter().map(|&i| p[i]).collect())
                        .collect())
                })
                .collect::<std::result::Result<_, String>>()
                .map_err(fail)?;
            for cols in got {
                out.tile_points
                    .push(cols.first().map_or(0, Vec::len) as u32);
                for (c, v) in out.columns.iter_mut().zip(cols) {
                    c.extend_from_slice(&v);
                }
            }
            if out.len() as u64 > self.meta.point_count {
                return Err(fail(format!(
                    "holds more points than the part's POINT_COUNT ({})",
                    self.meta.point_count
                )));
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_match_the_strided_subset() {
        for n in [1u64, 255, 256, 257, 65_536, 70_001, 300_000] {
            let g = Geometry::for_points(n);
            for level in 0..g.levels() + 2 {
                let idx = level_indices(n, level);
                assert!(idx.iter().all(|&i| kept(i, g.size(0), level) && i < n));
                let all = (0..n).filter(|&i| kept(i, g.size(0), level)).count();
                assert_eq!(idx.len(), all, "n {n} level {level}");
                if level < g.levels() {
                    let across = g.tiles_across(level);
                    let sum: u64 = (0..across * across)
                        .map(|t| tile_points(g, level, t) as u64)
                        .sum();
                    assert_eq!(sum, all as u64, "n {n} level {level}");
                }
            }
        }
    }

    #[test]
    fn tile_pixels_follow_the_rule() {
        let n = 150_000u64;
        let g = Geometry::for_points(n);
        let src: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let w = g.size(0);
        for level in 0..g.levels() {
            let across = g.tiles_across(level);
            for t in 0..across * across {
                let px = tile_pixels(|i| src[i], g, level, t);
                for (p, &v) in px.iter().enumerate() {
                    let x = (t % across) * TILE_SIZE + p as u32 % TILE_SIZE;
                    let y = (t / across) * TILE_SIZE + p as u32 / TILE_SIZE;
                    let i = source(w, level, x, y);
                    if i < n {
                        assert_eq!(v, i as f32);
                    } else {
                        assert!(v.is_nan());
                    }
                }
            }
        }
    }
}
