//! Levels 1 and up of an uncompressed part in the Hilbert layout, written while
//! its points are arranged, as level 0 is: each arranged tile's level-1 points
//! (slots 0, 4, 8, …: position and attribute row) are kept, and once every tile
//! of an aligned group of `4^k` tiles is arranged, the group's tile of level `k`
//! is made from them and sent to the writer threads. The levels above a tile
//! only move whole groups ([`layout::group_tile_order`]), so a group makes the
//! same tile of level `k` wherever the tile order puts it: its bands go to the
//! group's own slot of the level's region of the file
//! (`crate::write::part::region_start`), and the
//! level's `TileOffsets` follow the tile order. So the disk writes the coarse
//! levels while the CPU arranges, instead of after it.

use crate::bigvec::{self, Shared};
use crate::spec::{TILE_BYTES, TILE_PIXELS};
use crate::tiff::zorder::Geometry;
use crate::write::layout;
use crate::write::out::TileBuf;
use crate::write::sink::TileSink;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The kept level-1 points of a part being arranged, and which groups of tiles
/// are complete.
pub(crate) struct Coarse {
    g: Geometry,
    n: usize,
    /// Attributes a point.
    m: usize,
    /// Where the file's tile data begins (the coarsest level's region).
    first: u64,
    /// Each tile's level-1 points, `TILE_PIXELS / 4` of `3 + m` values (x y z,
    /// then the row), written by the tile's own arranging thread.
    _leads: Vec<f32>,
    at: Shared<f32>,
    /// `done[k - 1][h]`: tiles of group `h` of level `k` arranged so far.
    done: Vec<Vec<AtomicUsize>>,
    lut: Vec<u32>,
}

// SAFETY: `at` points into `leads`, which lives as long as the `Coarse`; each
// tile's share is written by one thread only, and read only after the counters
// (acquire/release) say that tile is complete.
unsafe impl Sync for Coarse {}

impl Coarse {
    /// For the points of `g`, of `m` attributes, whose tile data starts at
    /// byte `first`.
    pub fn new(g: Geometry, m: usize, first: u64, lut: Vec<u32>) -> Coarse {
        let n = g.points as usize;
        let tiles = n.div_ceil(TILE_PIXELS);
        let mut leads: Vec<f32> = bigvec::with_capacity(tiles * TILE_PIXELS / 4 * (3 + m));
        let at = Shared(leads.as_mut_ptr());
        let done = (1..g.levels())
            .map(|k| {
                (0..tiles.div_ceil(1 << (2 * k)))
                    .map(|_| AtomicUsize::new(0))
                    .collect()
            })
            .collect();
        Coarse {
            g,
            n,
            m,
            first,
            _leads: leads,
            at,
            done,
            lut,
        }
    }

    /// Values kept a tile.
    fn share(&self) -> usize {
        TILE_PIXELS / 4 * (3 + self.m)
    }

    /// Tile `t` is arranged: `o` its points, `rows` their attribute rows (`m`
    /// values a point, slot order). Keeps its level-1 points; makes and sends
    /// every coarse tile whose group this tile completes. Called once a tile.
    pub(crate) fn tile_done(&self, t: usize, o: &[[f32; 3]], rows: &[f32], sink: &TileSink) {
        let (m, rec) = (self.m, 3 + self.m);
        // SAFETY: tile t's share lies inside the allocation (t < tiles) and only
        // this call writes it.
        let mine =
            unsafe { std::slice::from_raw_parts_mut(self.at.at(t * self.share()), self.share()) };
        for (j, (d, p)) in mine
            .chunks_exact_mut(rec)
            .zip(o.iter().step_by(4))
            .enumerate()
        {
            d[..3].copy_from_slice(p);
            d[3..].copy_from_slice(&rows[4 * j * m..4 * j * m + m]);
        }
        let tiles = self.n.div_ceil(TILE_PIXELS);
        for (k, done) in (1..).zip(&self.done) {
            let h = t >> (2 * k);
            let size = (1usize << (2 * k)).min(tiles - (h << (2 * k)));
            // AcqRel: the last tile of a group sees every other tile's share.
            if done[h].fetch_add(1, Ordering::AcqRel) + 1 == size {
                if sink.stopped() {
                    return;
                }
                let _ = sink.send(self.group_tile(k, h));
            }
        }
    }

    /// The level-`k` tile of group `h` (all its tiles arranged): its bands at
    /// their places in the file.
    fn group_tile(&self, k: usize, h: usize) -> Vec<(u64, TileBuf)> {
        let (m, rec, share) = (self.m, 3 + self.m, self.share());
        // SAFETY: every tile of the group wrote its share before the counter
        // that brought us here said so (acquire).
        let lead = |t: usize, j: usize| -> &[f32] {
            // SAFETY: see above: the share was written and published before this read.
            unsafe { std::slice::from_raw_parts(self.at.at(t * share + j * rec), rec) }
        };
        let order = layout::group_tile_order(self.n, k, h, |t| {
            let p = lead(t, 0);
            [p[0], p[1], p[2]]
        });
        let count = self.g.tile_points(k, h as u64) as usize;
        // Level-k point i: the (i mod per_tile)-th level-k point of the group's
        // (i / per_tile)-th tile, whose lead is `step` times further.
        let shift = TILE_PIXELS.trailing_zeros() as usize - 2 * k;
        let step = 2 * k - 2;
        let mut pos = Vec::with_capacity(count);
        let mut rows = Vec::with_capacity(count * m);
        for i in 0..count {
            let tile = order[i >> shift] as usize;
            let p = lead(tile, (i & ((1 << shift) - 1)) << step);
            pos.push([p[0], p[1], p[2]]);
            rows.extend_from_slice(&p[3..]);
        }
        let nb = 3 + m;
        let start = crate::write::part::region_start(
            |l| self.g.filled_tiles(l),
            nb,
            self.first,
            self.g.levels(),
            k,
        );
        (0..crate::tiff::tiles::groups(m))
            .flat_map(|group| {
                crate::tiff::tiles::hilbert_bands(&self.lut, count, group, |i| pos[i], &rows, m)
            })
            .map(|(b, buf)| (start + (h * nb + b) as u64 * TILE_BYTES, buf))
            .collect()
    }
}
