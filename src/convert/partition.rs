//! Spatial partitioning out of core: a coarse 3D count grid from a first pass, then
//! a k-d split of the grid into boxes that each fit the budget, so parts hold
//! spatially compact, non-overlapping regions and a viewer can cull whole parts.

use crate::points::Bounds;

/// A grid of point counts over the input's bounds.
#[derive(Debug, Clone)]
pub struct CountGrid {
    pub bounds: Bounds,
    pub dims: [usize; 3],
    pub counts: Vec<u64>,
    /// Cells per world unit on each axis (0 on a flat axis): a multiplication
    /// per axis where a division cost a tenth of the distributing pass.
    scale: [f64; 3],
}

/// Cells in the grid (about 2 M: 16 MiB of counts).
const GRID_CELLS: f64 = (1u64 << 21) as f64;

impl CountGrid {
    /// A grid whose cells are about cubic and number about 2 M.
    pub fn new(bounds: Bounds) -> CountGrid {
        let e = bounds.extent();
        let vol: f64 = e.iter().map(|v| v.max(1e-9)).product();
        let cell = (vol / GRID_CELLS).cbrt();
        let dims = [0, 1, 2].map(|a| ((e[a] / cell).ceil() as usize).clamp(1, 4096));
        // Keep the total bounded whatever the shape.
        let mut dims = dims;
        while dims.iter().product::<usize>() > (GRID_CELLS as usize) * 4 {
            let a = (0..3).max_by_key(|&a| dims[a]).unwrap_or(0);
            dims[a] = dims[a].div_ceil(2);
        }
        let scale = [0, 1, 2].map(|a| {
            let e = bounds.max[a] - bounds.min[a];
            if e > 0.0 { dims[a] as f64 / e } else { 0.0 }
        });
        CountGrid {
            bounds,
            dims,
            counts: vec![0; dims.iter().product()],
            scale,
        }
    }

    /// Cell coordinates of a point.
    #[inline]
    pub fn cell(&self, p: [f64; 3]) -> [usize; 3] {
        // (`as` saturates: points below the bounds, and NaN, land in cell 0.)
        // Written out: `[0, 1, 2].map` was not inlined here (3% of a text
        // conversion within 256 MiB went to its call).
        let c = |a: usize| {
            (((p[a] - self.bounds.min[a]) * self.scale[a]) as usize).min(self.dims[a] - 1)
        };
        [c(0), c(1), c(2)]
    }

    #[inline]
    pub fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    pub fn add(&mut self, p: [f64; 3]) {
        let i = self.index(self.cell(p));
        self.counts[i] += 1;
    }

    /// Adds another grid's counts (same bounds and dims).
    pub fn merge(&mut self, o: &CountGrid) {
        for (a, b) in self.counts.iter_mut().zip(&o.counts) {
            *a += b;
        }
    }

    fn count_box(&self, lo: [usize; 3], hi: [usize; 3]) -> u64 {
        let mut n = 0;
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                let row = self.index([0, y, z]);
                n += self.counts[row + lo[0]..row + hi[0]].iter().sum::<u64>();
            }
        }
        n
    }

    /// Counts along axis `a` of a box, one per slab.
    fn slabs(&self, lo: [usize; 3], hi: [usize; 3], a: usize) -> Vec<u64> {
        let mut s = vec![0u64; hi[a] - lo[a]];
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                for x in lo[0]..hi[0] {
                    let c = [x, y, z];
                    s[c[a] - lo[a]] += self.counts[self.index(c)];
                }
            }
        }
        s
    }
}

/// A region of the grid: cells `lo..hi` on each axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Region {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
    pub points: u64,
}

impl Region {
    pub fn contains(&self, c: [usize; 3]) -> bool {
        (0..3).all(|a| self.lo[a] <= c[a] && c[a] < self.hi[a])
    }

    /// The centre of the region's box of cells in `grid`, in world units.
    pub fn centre(&self, grid: &CountGrid) -> [f64; 3] {
        let b = &grid.bounds;
        [0, 1, 2].map(|a| {
            let cell = (b.max[a] - b.min[a]) / grid.dims[a] as f64;
            b.min[a] + cell * (self.lo[a] + self.hi[a]) as f64 / 2.0
        })
    }
}

/// Splits the grid into regions of at most `max_points` each (where cells allow):
/// recursively along the box's longest populated axis, at the slab that leaves
/// each side a whole number of parts' worth of points. A region whose occupied
/// cells span `max_extent[a]` or more (world units) on axis `a` is halved there
/// too, whatever its count, so every part's points lie within `max_extent / 2`
/// of their centre (f32's 1 mm reach, or the reach of the input's lattice; see
/// [`occupied`] for that centre). Empty regions are dropped.
pub fn split(grid: &CountGrid, max_points: u64, max_extent: [f64; 3]) -> Vec<Region> {
    let mut out = Vec::new();
    let mut stack = vec![Region {
        lo: [0; 3],
        hi: grid.dims,
        points: grid.counts.iter().sum(),
    }];
    while let Some(r) = stack.pop() {
        if r.points == 0 {
            continue;
        }
        let e = grid.bounds.extent();
        if let Some((a, cut)) = too_wide(grid, &r, max_extent) {
            let (mut left, mut right) = (r, r);
            left.hi[a] = cut;
            right.lo[a] = cut;
            left.points = grid.count_box(left.lo, left.hi);
            right.points = r.points - left.points;
            stack.push(right);
            stack.push(left);
            continue;
        }
        if r.points <= max_points {
            out.push(r);
            continue;
        }
        // Longest axis in world units that is more than one cell thick.
        let axis = (0..3).filter(|&a| r.hi[a] - r.lo[a] > 1).max_by(|&a, &b| {
            let la = (r.hi[a] - r.lo[a]) as f64 * e[a] / grid.dims[a] as f64;
            let lb = (r.hi[b] - r.lo[b]) as f64 * e[b] / grid.dims[b] as f64;
            la.total_cmp(&lb)
        });
        let Some(a) = axis else {
            // One cell holds more than the budget: it stays one region; the
            // converter splits it by input order.
            out.push(r);
            continue;
        };
        let slabs = grid.slabs(r.lo, r.hi, a);
        // Cut so that both sides need whole numbers of parts: with k parts needed,
        // the left side takes floor(k/2)/k of the points (the minimum part count,
        // not a power of two).
        let k = r.points.div_ceil(max_points.max(1));
        let half = (r.points as u128 * (k / 2) as u128 / k as u128) as u64;
        let mut acc = 0;
        let mut cut = 1;
        for (i, s) in slabs.iter().enumerate() {
            acc += s;
            if acc >= half {
                cut = (i + 1).clamp(1, slabs.len() - 1);
                break;
            }
        }
        let mut left = r;
        let mut right = r;
        left.hi[a] = r.lo[a] + cut;
        right.lo[a] = r.lo[a] + cut;
        left.points = grid.count_box(left.lo, left.hi);
        right.points = r.points - left.points;
        stack.push(right);
        stack.push(left);
    }
    out.sort_by_key(|r| (r.lo[2], r.lo[1], r.lo[0]));
    out
}

/// `r` shrunk to the cells that hold its points: the box whose centre a part's
/// origin should be (a region's own box may reach far past its points).
pub fn occupied(grid: &CountGrid, mut r: Region) -> Region {
    for a in 0..3 {
        if let Some((first, last)) = occupied_slabs(grid, &r, a) {
            r.hi[a] = r.lo[a] + last + 1;
            r.lo[a] += first;
        }
    }
    r
}

/// The first and last slab of `r` along axis `a` that hold points (offsets from
/// `r.lo[a]`), if any does.
fn occupied_slabs(grid: &CountGrid, r: &Region, a: usize) -> Option<(usize, usize)> {
    let slabs = grid.slabs(r.lo, r.hi, a);
    let first = slabs.iter().position(|&c| c > 0)?;
    let last = slabs.iter().rposition(|&c| c > 0)?;
    Some((first, last))
}

/// The axis on which `r`'s occupied cells span its `max_extent` or more (world
/// units) and the cell to cut at (the middle of the occupied span), if any axis
/// does and its span is more than one cell.
fn too_wide(grid: &CountGrid, r: &Region, max_extent: [f64; 3]) -> Option<(usize, usize)> {
    let e = grid.bounds.extent();
    (0..3).find_map(|a| {
        let cell = e[a] / grid.dims[a] as f64;
        if (r.hi[a] - r.lo[a]) as f64 * cell < max_extent[a] {
            return None;
        }
        let (first, last) = occupied_slabs(grid, r, a)?;
        let span = (last + 1 - first) as f64 * cell;
        (span >= max_extent[a] && last > first).then(|| (a, r.lo[a] + (first + last).div_ceil(2)))
    })
}

/// For each cell, the index of its region (`u32::MAX` for cells of no region).
pub fn cell_regions(grid: &CountGrid, regions: &[Region]) -> Vec<u32> {
    let mut map = vec![u32::MAX; grid.counts.len()];
    for (i, r) in regions.iter().enumerate() {
        for z in r.lo[2]..r.hi[2] {
            for y in r.lo[1]..r.hi[1] {
                for x in r.lo[0]..r.hi[0] {
                    map[grid.index([x, y, z])] = i as u32;
                }
            }
        }
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_cover_all_points_within_budget() {
        let b = Bounds {
            min: [0.0; 3],
            max: [100.0, 50.0, 10.0],
        };
        let mut g = CountGrid::new(b);
        let mut r = crate::synth::Rng::new(1);
        let n = 200_000;
        for _ in 0..n {
            // Clustered: most points in one corner.
            let s = if r.f64() < 0.7 { 0.2 } else { 1.0 };
            g.add([r.f64() * 100.0 * s, r.f64() * 50.0 * s, r.f64() * 10.0]);
        }
        let regions = split(&g, 30_000, [f64::INFINITY; 3]);
        assert_eq!(regions.iter().map(|r| r.points).sum::<u64>(), n);
        assert!(regions.iter().all(|r| r.points <= 30_000));
        assert!(
            regions.len() >= 7 && regions.len() <= 32,
            "{}",
            regions.len()
        );
        let map = cell_regions(&g, &regions);
        for (i, &c) in g.counts.iter().enumerate() {
            if c > 0 {
                assert_ne!(map[i], u32::MAX);
            }
        }
        // Regions do not overlap.
        for (i, a) in regions.iter().enumerate() {
            for b in &regions[i + 1..] {
                assert!((0..3).any(|k| a.hi[k] <= b.lo[k] || b.hi[k] <= a.lo[k]));
            }
        }
    }

    #[test]
    fn regions_wider_than_the_limit_are_halved_whatever_their_count() {
        // Two clusters 100 units apart: one region by count, two by extent.
        let b = Bounds {
            min: [0.0; 3],
            max: [100.0, 1.0, 1.0],
        };
        let mut g = CountGrid::new(b);
        for i in 0..1000 {
            let x = if i % 2 == 0 { 0.5 } else { 99.5 };
            g.add([x, 0.5, 0.5]);
        }
        assert_eq!(split(&g, 10_000, [f64::INFINITY; 3]).len(), 1);
        let regions = split(&g, 10_000, [40.0; 3]);
        assert_eq!(regions.len(), 2);
        assert_eq!(regions.iter().map(|r| r.points).sum::<u64>(), 1000);
        let cell = 100.0 / g.dims[0] as f64;
        for r in &regions {
            let (first, last) = occupied_slabs(&g, r, 0).unwrap();
            assert!(((last + 1 - first) as f64) * cell < 40.0);
        }
    }

    #[test]
    fn flat_and_degenerate_bounds() {
        let b = Bounds {
            min: [5.0; 3],
            max: [5.0; 3],
        };
        let mut g = CountGrid::new(b);
        for _ in 0..10 {
            g.add([5.0; 3]);
        }
        let regions = split(&g, 3, [f64::INFINITY; 3]);
        assert_eq!(regions.len(), 1);
        assert_eq!(regions[0].points, 10);
    }
}
