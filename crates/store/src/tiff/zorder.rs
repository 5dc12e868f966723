//! Image geometry of a part: the square power-of-two image whose pixels follow one
//! 2D Z-order (Morton) curve, its pyramid levels, and the maps between a point's
//! rank on the curve and its pixel or tile.
//!
//! Point `i` of level 0 sits at Z-index `i`; level `k` keeps Z-indices `j * 4^k`, so
//! every level is a prefix of its own curve and every tile but the last is full.

use crate::spec::{TILE_LOG2, TILE_PIXELS};

/// Spreads the low 16 bits of `v` to the even bit positions.
#[inline]
pub fn spread2(v: u32) -> u64 {
    let mut x = v as u64 & 0xffff_ffff;
    x = (x | (x << 16)) & 0x0000_ffff_0000_ffff;
    x = (x | (x << 8)) & 0x00ff_00ff_00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    x = (x | (x << 1)) & 0x5555_5555_5555_5555;
    x
}

/// Gathers the even bits of `v` (inverse of [`spread2`]).
#[inline]
pub(crate) fn compact2(v: u64) -> u32 {
    let mut x = v & 0x5555_5555_5555_5555;
    x = (x | (x >> 1)) & 0x3333_3333_3333_3333;
    x = (x | (x >> 2)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | (x >> 4)) & 0x00ff_00ff_00ff_00ff;
    x = (x | (x >> 8)) & 0x0000_ffff_0000_ffff;
    x = (x | (x >> 16)) & 0x0000_0000_ffff_ffff;
    x as u32
}

/// Z-index of pixel (x, y): x on the even bits, y on the odd bits.
#[inline]
pub(crate) fn z_index(x: u32, y: u32) -> u64 {
    spread2(x) | (spread2(y) << 1)
}

/// Pixel (x, y) of a Z-index.
#[inline]
pub fn z_pixel(z: u64) -> (u32, u32) {
    (compact2(z), compact2(z >> 1))
}

/// For a square tile of `2^log2` pixels a side: raster offset (`y * w + x`) of each
/// Z-index inside the tile.
pub fn tile_z_to_raster(log2: u32) -> Vec<u32> {
    let w = 1u32 << log2;
    (0..(w as u64 * w as u64))
        .map(|z| {
            let (x, y) = z_pixel(z);
            y * w + x
        })
        .collect()
}

/// A table of a `2^log2 × 2^log2` tile made once per size and kind for the
/// whole process (every part opened uses the same few; a 256-pixel tile's is
/// 64 K entries): `rows` the identity, else [`tile_z_to_raster`].
fn shared_table(log2: u32, rows: bool) -> std::sync::Arc<Vec<u32>> {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};
    type Tables = Mutex<HashMap<(u32, bool), Arc<Vec<u32>>>>;
    static MADE: OnceLock<Tables> = OnceLock::new();
    let mut made = MADE
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner());
    made.entry((log2, rows))
        .or_insert_with(|| {
            Arc::new(if rows {
                (0..1u32 << (2 * log2)).collect()
            } else {
                tile_z_to_raster(log2)
            })
        })
        .clone()
}

/// [`tile_z_to_raster`], shared ([`shared_table`]).
pub fn shared_tile_z_to_raster(log2: u32) -> std::sync::Arc<Vec<u32>> {
    shared_table(log2, false)
}

/// The identity table of a `2^log2 × 2^log2` tile (row-ordered tiles: point `i`
/// at pixel `i`), shared ([`shared_table`]).
pub fn shared_rows(log2: u32) -> std::sync::Arc<Vec<u32>> {
    shared_table(log2, true)
}

/// The most points a small part's coarsest level holds ([`Geometry::for_points`]).
pub const COARSEST_MOST: u64 = TILE_PIXELS as u64 / 4;

/// The pyramid of one part: a `2^log2 × 2^log2` image at level 0 holding `points`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Geometry {
    pub points: u64,
    pub log2: u32,
}

impl Geometry {
    /// The smallest square power-of-two image, at least one tile, that holds
    /// `points`.
    pub fn for_points(points: u64) -> Geometry {
        Geometry::for_part(points, false)
    }

    /// [`Geometry::for_points`], or with `shallow` for a part of a dataset of
    /// many: a part of more than a quarter tile and at most four gets an image
    /// wide enough that its coarsest level holds at most a quarter tile
    /// ([`COARSEST_MOST`]), one or two levels more of its own. They are written
    /// from points already arranged, and the overview above the parts, which
    /// `pcimg index` reads back and writes again, then holds a quarter or a
    /// sixteenth of what it held (issue 44: 17.1 M of 92 M points, parts of up
    /// to 110,000 points, 11.1% of the conversion's time; 4.3 M and 4.2%).
    /// A part alone has no overview to spare: the levels would only add to it
    /// (8.8% to `autzen_trim`). Larger parts are as before: their heads would
    /// grow with the image, and their coarsest levels are a small share.
    pub fn for_part(points: u64, shallow: bool) -> Geometry {
        let mut log2 = TILE_LOG2;
        let pixels = |log2: u32| 1u128 << (2 * log2);
        while pixels(log2) < points as u128
            || (shallow && pixels(log2) < 4 * points as u128 && log2 < TILE_LOG2 + 2)
        {
            log2 += 1;
        }
        Geometry { points, log2 }
    }

    /// Number of levels: level 0 down to the single-tile level.
    pub fn levels(&self) -> usize {
        (self.log2 - TILE_LOG2 + 1) as usize
    }

    /// Image edge in pixels at `level`.
    pub fn size(&self, level: usize) -> u32 {
        1 << (self.log2 - level as u32)
    }

    /// Tiles along one edge at `level`.
    pub fn tiles_across(&self, level: usize) -> u32 {
        self.size(level) >> TILE_LOG2
    }

    /// Points kept at `level`: one per aligned `2^level` block, `ceil(n / 4^level)`.
    pub fn level_points(&self, level: usize) -> u64 {
        let block = 1u64 << (2 * level);
        self.points.div_ceil(block)
    }

    /// Tiles holding points at `level`; they are the first tiles in Z-order.
    pub(crate) fn filled_tiles(&self, level: usize) -> u64 {
        self.level_points(level).div_ceil(TILE_PIXELS as u64)
    }

    /// Points in the tile of Z-rank `t` at `level`.
    pub fn tile_points(&self, level: usize, t: u64) -> u32 {
        let n = self.level_points(level);
        let start = t * TILE_PIXELS as u64;
        n.saturating_sub(start).min(TILE_PIXELS as u64) as u32
    }

    /// Raster index (`row * across + col`, as TIFF numbers tiles) of the tile of
    /// Z-rank `t` at `level`.
    pub(crate) fn tile_raster_index(&self, level: usize, t: u64) -> u32 {
        let (col, row) = z_pixel(t);
        row * self.tiles_across(level) + col
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_round_trip() {
        for x in [0u32, 1, 2, 255, 256, 4095, 65535] {
            for y in [0u32, 3, 77, 65535] {
                assert_eq!(z_pixel(z_index(x, y)), (x, y));
            }
        }
    }

    #[test]
    fn blocks_are_consecutive() {
        // Every aligned 2x2 block of pixels holds 4 consecutive Z-indices.
        for y in (0..16).step_by(2) {
            for x in (0..16).step_by(2) {
                let z0 = z_index(x, y);
                assert_eq!(z0 % 4, 0);
                let mut zs = [
                    z_index(x, y),
                    z_index(x + 1, y),
                    z_index(x, y + 1),
                    z_index(x + 1, y + 1),
                ];
                zs.sort();
                assert_eq!(zs, [z0, z0 + 1, z0 + 2, z0 + 3]);
            }
        }
    }

    #[test]
    fn geometry_sizes() {
        let g = Geometry::for_points(0);
        assert_eq!((g.log2, g.levels()), (8, 1));
        let g = Geometry::for_points(65_537);
        assert_eq!((g.size(0), g.levels(), g.filled_tiles(0)), (512, 2, 2));
        assert_eq!(g.level_points(1), 16_385);
        let g = Geometry::for_part(65_537, true);
        assert_eq!((g.size(0), g.levels(), g.filled_tiles(0)), (1024, 3, 2));
        assert_eq!(g.level_points(1), 16_385);
        assert_eq!(g.level_points(2), 4_097);
        assert_eq!(g.tile_points(0, 1), 1);
        // Small parts: their coarsest level holds at most a quarter tile, up
        // to parts of four tiles; larger ones as many levels as before.
        for (n, size, levels) in [
            (16_384, 256, 1),
            (16_385, 512, 2),
            (65_536, 512, 2),
            (262_144, 1024, 3),
            (262_145, 1024, 3),
            (1_048_576, 1024, 3),
            (1_048_577, 2048, 4),
        ] {
            let g = Geometry::for_part(n, true);
            assert_eq!((g.size(0), g.levels()), (size, levels), "{n}");
            if n <= 4 * TILE_PIXELS as u64 && n > COARSEST_MOST {
                assert!(g.level_points(levels - 1) <= COARSEST_MOST, "{n}");
            }
        }
        let g = Geometry::for_points(10_000_000);
        assert_eq!(g.size(0), 4096);
        assert_eq!(g.levels(), 5);
        assert_eq!(g.filled_tiles(0), 153);
        let lut = tile_z_to_raster(2);
        assert_eq!(&lut[..4], &[0, 1, 4, 5]);
    }
}
