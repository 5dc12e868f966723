//! The order in which a part's points are laid out in its image: after the 3D
//! Hilbert sort (`hilbert.rs`, re-exported here), representatives moved to the
//! first slot of every block up the pyramid (a voxel-like choice at level 1, the
//! centroid rule above), so that every down-sampled level is a spatially even
//! sample (`docs/notes/lod-layout.md` and `benches/lod_quality.rs` for the
//! measurements behind this); where the positions come from ([`Positions`]).

use crate::bigvec;
use crate::points::RowSource;
use crate::spec::TILE_PIXELS;
use rayon::prelude::*;

pub use crate::write::hilbert::{
    KEY_BITS, hilbert_key, hilbert_key_top, hilbert_order, sort_indexed,
};

/// How points are placed along the image's Z-order curve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Layout {
    /// Hilbert order with centroid representatives (the default).
    #[default]
    Hilbert,
    /// The paper's layout: input order, row-major image, plain nearest-neighbour
    /// pyramid (`crate::write::paper`).
    Paper,
}

impl Layout {
    /// The value of the `LAYOUT` metadata item.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Hilbert => crate::spec::layout::HILBERT,
            Layout::Paper => crate::spec::layout::PAPER,
        }
    }
}

/// Where a part's positions come from for its sort and arrangement: held (`f32`
/// relative to the part's origin), or given again by the reader's source
/// ([`RowSource::positions`], the same values), so the part need not hold them.
#[derive(Clone, Copy)]
pub enum Positions<'a> {
    Held(&'a [[f32; 3]]),
    /// The source and the part's origin; with `rows`, each tile's attribute rows
    /// are read with its positions (each point read once) and handed to `on_tile`
    /// ([`TileRows`]).
    Source {
        src: &'a dyn RowSource,
        origin: [f64; 3],
        rows: bool,
    },
}

impl<'a> Positions<'a> {
    pub fn len(&self) -> usize {
        match self {
            Positions::Held(p) => p.len(),
            Positions::Source { src, .. } => src.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The positions of the points `range`: a slice of the held ones, or
    /// `scratch` filled from the source.
    pub fn slice<'s>(
        &self,
        range: std::ops::Range<usize>,
        scratch: &'s mut Vec<[f32; 3]>,
    ) -> &'s [[f32; 3]]
    where
        'a: 's,
    {
        match *self {
            Positions::Held(p) => &p[range],
            Positions::Source { src, origin, .. } => {
                scratch.clear();
                let len = range.len();
                src.positions_in(range, origin, scratch);
                // A source that gives fewer never makes a slice too short.
                scratch.resize(len, [f32::NAN; 3]);
                scratch
            }
        }
    }

    /// All the positions, in order, held.
    pub fn to_vec(&self) -> Vec<[f32; 3]> {
        const PIECE: usize = 1 << 14;
        let n = self.len();
        let mut pos: Vec<[f32; 3]> = bigvec::with_capacity(n);
        pos.spare_capacity_mut()[..n]
            .par_chunks_mut(PIECE)
            .enumerate()
            .for_each_init(Vec::new, |scratch, (k, d)| {
                let got = self.slice(k * PIECE..k * PIECE + d.len(), scratch);
                for (d, &v) in d.iter_mut().zip(got) {
                    d.write(v);
                }
            });
        // SAFETY: every piece wrote each of its slots (`slice` gives as many).
        unsafe { pos.set_len(n) };
        pos
    }

    /// Appends the positions of points `idx` to `out`, and their attribute rows
    /// to `rows` when so asked (`Source` with `rows`): then true.
    fn gather(&self, idx: &[u32], out: &mut Vec<[f32; 3]>, rows: &mut Vec<f32>) -> bool {
        match *self {
            Positions::Held(p) => {
                out.extend(idx.iter().map(|&k| p[k as usize]));
                false
            }
            Positions::Source {
                src,
                origin,
                rows: with_rows,
            } => {
                let want = out.len() + idx.len();
                let want_rows = rows.len() + idx.len() * src.width();
                if with_rows {
                    src.positions_and_rows(idx, origin, out, rows);
                    rows.resize(want_rows, f32::NAN);
                } else {
                    src.positions(idx, origin, out);
                }
                // A source that gives fewer never leaves a tile short.
                out.resize(want, [f32::NAN; 3]);
                with_rows
            }
        }
    }
}

/// A tile's attribute rows read with its positions ([`Positions::Source`]): `rows`
/// holds them in curve order (the source's `width` values a point), and arranged
/// slot `k` holds the point of row `local[k]`.
pub struct TileRows<'a> {
    pub rows: &'a [f32],
    pub local: &'a [u32],
}

/// Levels over which [`gather_representatives`] runs for `n` points: every level
/// whose blocks can hold more than one sub-block, beyond the stored pyramid too, so
/// any stride-`4^k` subset of a stored level (of its last tile, say) is even as well.
pub fn representative_levels(n: usize) -> usize {
    let mut levels = 1;
    while (1u128 << (2 * (levels - 1))) < n as u128 {
        levels += 1;
    }
    levels
}

/// Which arranged positions [`gather_representatives`] returns.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Keep {
    /// Every point's, in image order.
    All,
    /// Only each tile's first point (tile `t`'s at `t`): for a caller that took
    /// every level from `on_tile`.
    Firsts,
}

impl Keep {
    /// Slots per kept position.
    pub fn every(self) -> usize {
        match self {
            Keep::All => 1,
            Keep::Firsts => TILE_PIXELS,
        }
    }
}

/// What [`gather_representatives`] calls with each arranged tile: its number,
/// its points, their source indices and, when read with them, their rows.
pub(crate) type OnTile<'a> = dyn Fn(usize, &[[f32; 3]], &[u32], Option<TileRows<'_>>) + Sync + 'a;

/// Gathers the points `src[perm[..]]` (`perm`: indices of `src` in Hilbert order)
/// and arranges them so that for every level `k` in `1..levels` the first slots
/// of the aligned blocks of `4^k` slots hold an even sample of the points;
/// `perm` is rearranged the same way.
///
/// Level 1 is chosen like a voxel grid (`select`), so sparse parts (vegetation,
/// walls, a single flight line) keep as many neighbours as dense ones; each chosen
/// point then leads a block of four with the next three unchosen ones along the
/// curve. This happens inside each level-0 tile, so every tile still holds the same
/// run of the Hilbert curve. Coarser levels move whole sub-blocks: the one whose
/// first point is nearest the block's centroid comes first (measured as good as any
/// density rule there, once level 1 has evened the density out). The pyramid stays
/// nested and the filled slots a prefix.
/// `lo`, `hi`: the bounds of the points (the writer has them; the grid is built
/// from them rather than from another pass over the points).
///
/// Each tile is gathered into scratch, arranged there (levels up to the tile's
/// own block size, all in cache) and written once; `on_tile(t, points, indices)`
/// then sees tile `t` as it will be stored (the writer encodes and writes level 0
/// from it while it is in cache). The levels above a tile only reorder whole
/// tiles: they are not moved but returned as the tile order (the `t`-th tile of
/// the final order is tile `order[t]` of the result; the partial last tile, if
/// any, stays last). `keep` says whether the result holds every arranged
/// position or only level 1's.
pub fn gather_representatives(
    src: Positions<'_>,
    perm: &mut [u32],
    levels: usize,
    lo: [f32; 3],
    hi: [f32; 3],
    on_tile: &OnTile<'_>,
    keep: Keep,
) -> (Vec<[f32; 3]>, Vec<u32>) {
    let n = perm.len();
    let every = keep.every();
    let kept = n.div_ceil(every);
    let mut out: Vec<[f32; 3]> = crate::bigvec::with_capacity(kept);
    let grid = Grid::new(lo, hi);
    out.spare_capacity_mut()[..kept]
        .par_chunks_mut(TILE_PIXELS / every)
        .zip(perm.par_chunks_mut(TILE_PIXELS))
        .enumerate()
        .for_each_init(
            || {
                (
                    Scratch::default(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                )
            },
            |(sc, rows, local, from, whole), (t, (kept, i))| {
                sc.pos.clear();
                rows.clear();
                let with_rows = src.gather(i, &mut sc.pos, rows);
                let o: &mut [[f32; 3]] = if every == 1 {
                    // SAFETY: `[f32; 3]` has no invalid bit patterns to fear and
                    // `arrange_tile` writes every slot of `o` before anything
                    // reads it.
                    unsafe {
                        &mut *(kept as *mut [std::mem::MaybeUninit<[f32; 3]>] as *mut [[f32; 3]])
                    }
                } else {
                    whole.resize(i.len(), [0.0; 3]);
                    whole
                };
                if !with_rows {
                    arrange_tile(sc, o, i, &grid, levels);
                    on_tile(t, o, i, None);
                } else {
                    arrange_with_rows(sc, o, i, (local, from), &grid, levels);
                    on_tile(t, o, i, Some(TileRows { rows, local }));
                }
                if every > 1 {
                    for (k, &p) in kept.iter_mut().zip(o.iter().step_by(every)) {
                        k.write(p);
                    }
                }
            },
        );
    // SAFETY: every tile's chunk of the kept slots was written above.
    unsafe { out.set_len(kept) };
    let order = tile_order(n, |t| out[t * TILE_PIXELS / every], levels);
    (out, order)
}

/// [`arrange_tile`] of a tile whose rows were read with its positions: arranged as
/// the tile's own slots (`local`), so that the rows, in curve order, are found
/// again; then the source indices `idx` follow. `from` is scratch.
fn arrange_with_rows(
    sc: &mut Scratch,
    o: &mut [[f32; 3]],
    idx: &mut [u32],
    (local, from): (&mut Vec<u32>, &mut Vec<u32>),
    grid: &Grid,
    levels: usize,
) {
    local.clear();
    local.extend(0..idx.len() as u32);
    arrange_tile(sc, o, local, grid, levels);
    from.clear();
    from.extend_from_slice(idx);
    for (d, &l) in idx.iter_mut().zip(local.iter()) {
        *d = from[l as usize];
    }
}

/// Levels whose blocks fit in one tile (block 4^k ≤ tile pixels): arranged tile by
/// tile, in cache.
const TILE_LEVELS: usize = (TILE_PIXELS.trailing_zeros() / 2) as usize;

/// Per-thread working memory of [`arrange_tile`].
#[derive(Default)]
struct Scratch {
    /// The tile's points in curve order (input).
    pos: Vec<[f32; 3]>,
    idx: Vec<u32>,
}

/// Arranges one tile: `sc.pos` holds its points in curve order and `idx` their
/// indices; `out` receives the points in arranged order and `idx` is rearranged
/// the same way. Level 1 by [`select`], levels 2..=TILE_LEVELS by the centroid rule.
fn arrange_tile(
    sc: &mut Scratch,
    out: &mut [[f32; 3]],
    idx: &mut [u32],
    grid: &Grid,
    levels: usize,
) {
    let len = out.len();
    if len < 2 || levels < 2 {
        out.copy_from_slice(&sc.pos);
        return;
    }
    let p = &sc.pos;
    let domain = len / 4 * 4;
    if domain > 0 {
        let chosen = select(&p[..domain], domain / 4, grid);
        sc.idx.clear();
        sc.idx.extend_from_slice(&idx[..domain]);
        // Chosen points go to slots 4j, the others fill the slots between in turn.
        let (mut lead, mut rest) = (0, 1);
        for (i, &c) in chosen.iter().enumerate() {
            let k = if c {
                lead += 4;
                lead - 4
            } else {
                let k = rest;
                rest += if rest % 4 == 3 { 2 } else { 1 };
                k
            };
            out[k] = p[i];
            idx[k] = sc.idx[i];
        }
    }
    // A partial last block (last tile only) keeps its points and leads with the
    // one nearest its centroid.
    if domain < len {
        out[domain..].copy_from_slice(&p[domain..]);
        let best = nearest_centroid(out, domain..len);
        out.swap(domain, best);
        idx.swap(domain, best);
    }
    for level in 2..levels.min(TILE_LEVELS + 1) {
        centroid_level(out, idx, level);
    }
}

/// The quantization of `hilbert_order` (21 bits per axis over a cube), so runs of
/// points sharing a cell are the curve's own cells.
struct Grid {
    lo: [f32; 3],
    scale: f64,
}

impl Grid {
    /// The grid over `lo`, `hi`, the bounds of the points (the cube of the largest
    /// extent, as the Hilbert keys use).
    fn new(lo: [f32; 3], hi: [f32; 3]) -> Grid {
        let side = (0..3).map(|a| hi[a] - lo[a]).fold(0f32, f32::max) as f64;
        let max = ((1u32 << KEY_BITS) - 1) as f64;
        Grid {
            lo,
            scale: if side > 0.0 { max / side } else { 0.0 },
        }
    }

    fn cell(&self, p: &[f32; 3]) -> [u32; 3] {
        let max = (1u32 << KEY_BITS) - 1;
        let q = |a: usize| (((p[a] - self.lo[a]) as f64 * self.scale) as u32).min(max);
        [q(0), q(1), q(2)]
    }
}

/// Depth (0..=KEY_BITS) of the smallest grid cell holding both points.
fn common_depth(a: [u32; 3], b: [u32; 3]) -> usize {
    let x = (a[0] ^ b[0]) | (a[1] ^ b[1]) | (a[2] ^ b[2]);
    (x.leading_zeros() as usize).saturating_sub(32 - KEY_BITS as usize)
}

/// Index (within `pts`) of the point of `range` nearest the range's centroid.
fn nearest_centroid(pts: &[[f32; 3]], range: std::ops::Range<usize>) -> usize {
    let run = &pts[range.clone()];
    if run.len() == 1 {
        return range.start;
    }
    let mut c = [0f32; 3];
    for p in run {
        c[0] += p[0];
        c[1] += p[1];
        c[2] += p[2];
    }
    let c = c.map(|v| v / run.len() as f32);
    let mut best = (0, f32::INFINITY);
    for (i, p) in run.iter().enumerate() {
        let d = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2);
        if d < best.1 {
            best = (i, d);
        }
    }
    range.start + best.0
}

/// Splits `total` equally among children of `sizes` points, none above its size
/// (water-filling: child `i` gets `min(sizes[i], L)` for the level `L` that adds up
/// to `total`), into `out`; `order` is scratch.
fn share(total: f64, sizes: &[usize], out: &mut Vec<f64>, order: &mut Vec<usize>) {
    out.clear();
    let all: usize = sizes.iter().sum();
    if total >= all as f64 {
        out.extend(sizes.iter().map(|&n| n as f64));
        return;
    }
    // Common case: no child is below the even share.
    let even = total / sizes.len() as f64;
    if sizes.iter().all(|&n| n as f64 > even) {
        out.resize(sizes.len(), even);
        return;
    }
    // The level: walk the distinct sizes in increasing order, capping while the
    // even share of what is left reaches them.
    let mut left = total;
    let mut open = sizes.len();
    let mut level = None;
    let mut visit = |v: usize, c: usize| -> bool {
        if left / open as f64 >= v as f64 {
            left -= (v * c) as f64;
            open -= c;
            false
        } else {
            level = Some(left / open as f64);
            true
        }
    };
    order.clear();
    const SMALL: usize = 64;
    if sizes.len() > 4 * SMALL {
        // Thousands of cells of a few points: a histogram for the small sizes.
        let mut hist = [0usize; SMALL];
        for &n in sizes {
            if n < SMALL {
                hist[n] += 1;
            } else {
                order.push(n);
            }
        }
        order.sort_unstable();
        let done = hist
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c > 0)
            .any(|(v, &c)| visit(v, c));
        if !done {
            order.iter().any(|&v| visit(v, 1));
        }
    } else {
        order.extend_from_slice(sizes);
        order.sort_unstable();
        order.iter().any(|&v| visit(v, 1));
    }
    let level = level.unwrap_or(f64::INFINITY);
    out.extend(sizes.iter().map(|&n| (n as f64).min(level)));
}

/// Cuts the curve into runs of weight one as weights arrive in curve order; each
/// finished run marks its point nearest its centroid.
struct Runs {
    quota: usize,
    /// First point of the open run.
    start: usize,
    /// Where the next run begins on the weight scale (`run + 1`; infinite for
    /// the last run).
    next: f64,
    /// Weight before the next point.
    cum: f64,
}

impl Runs {
    fn new(quota: usize) -> Runs {
        Runs {
            quota,
            start: 0,
            next: if quota > 1 { 1.0 } else { f64::INFINITY },
            cum: 0.0,
        }
    }

    /// Points `range`, each of weight `u`. A point belongs to the run where the
    /// middle of its weight falls (weights never exceed one, so every run gets at
    /// least one point). The middles only grow, so a run ends where a middle
    /// reaches `next`.
    #[inline]
    fn add(
        &mut self,
        pts: &[[f32; 3]],
        chosen: &mut [bool],
        range: std::ops::Range<usize>,
        u: f64,
    ) {
        let half = u / 2.0;
        for i in range {
            let mid = self.cum + half;
            self.cum += u;
            if mid >= self.next {
                let r = (mid as usize).min(self.quota - 1);
                chosen[nearest_centroid(pts, self.start..i)] = true;
                self.start = i;
                self.next = if r + 1 < self.quota {
                    (r + 1) as f64
                } else {
                    f64::INFINITY
                };
            }
        }
    }
}

/// Chooses exactly `quota` of `pts` (in curve order) as an even sample, like a
/// voxel grid. Each point gets a weight: every cell of the finest grid depth with at
/// most `quota` occupied cells (cells are runs of the curve) gets the same share of
/// `quota`, and a cell's share is split equally among its occupied sub-cells, down to
/// cells of weight one or less, which share it evenly among their points; no point
/// weighs more than one. The curve is then cut into `quota` runs of weight one, and
/// each run keeps its point nearest its centroid. With equal weights this is the
/// plain rule (runs of four, nearest the centroid); sparse cells get more.
fn select(pts: &[[f32; 3]], quota: usize, grid: &Grid) -> Vec<bool> {
    let m = pts.len();
    let mut chosen = vec![false; m];
    if quota == 0 {
        return chosen;
    }
    // cd[i]: depth of the smallest cell holding points i - 1 and i.
    // (Cells first, in a loop of their own that vectorizes.)
    let cells: Vec<[u32; 3]> = pts.iter().map(|p| grid.cell(p)).collect();
    let mut cd = vec![0u8; m];
    for (d, w) in cd[1..].iter_mut().zip(cells.windows(2)) {
        *d = common_depth(w[0], w[1]) as u8;
    }
    drop(cells);
    let mut hist = [0usize; KEY_BITS as usize + 1];
    for &d in &cd[1..] {
        hist[d as usize] += 1;
    }
    // occupied(d) = 1 + #{i : cd[i] < d}
    let mut depth = 0;
    let mut occupied = 1;
    while depth < KEY_BITS as usize && occupied + hist[depth] <= quota {
        occupied += hist[depth];
        depth += 1;
    }
    let mut top = Children::default();
    top.starts.push(0);
    top.starts
        .extend((1..m).filter(|&i| (cd[i] as usize) < depth));
    top.starts.push(m);
    let mut d = Descent {
        pts,
        cd: &cd,
        runs: Runs::new(quota),
        chosen: &mut chosen,
        below: Vec::new(),
        order: Vec::new(),
    };
    top.share(quota as f64, &mut d.order);
    d.children(&top, 0);
    let start = d.runs.start;
    chosen[nearest_centroid(pts, start..m)] = true;
    chosen
}

/// The children of one cell of [`select`]'s descent: where each starts (and, last,
/// where the cell ends), their sizes and their shares of the cell's weight.
#[derive(Default)]
struct Children {
    starts: Vec<usize>,
    sizes: Vec<usize>,
    shares: Vec<f64>,
}

impl Children {
    /// Shares `total` among the children ([`share`]).
    fn share(&mut self, total: f64, order: &mut Vec<usize>) {
        self.sizes.clear();
        self.sizes
            .extend(self.starts.windows(2).map(|w| w[1] - w[0]));
        share(total, &self.sizes, &mut self.shares, order);
    }
}

/// [`select`]'s walk down the cells: each cell of weight above one (and below its
/// point count) is split into its sub-cells, which share its weight; the points of
/// the others get their weights, in curve order.
struct Descent<'a> {
    pts: &'a [[f32; 3]],
    cd: &'a [u8],
    runs: Runs,
    chosen: &'a mut [bool],
    /// The children of the cells being split, one entry per depth of the descent
    /// (kept for the next cell at that depth).
    below: Vec<Children>,
    order: Vec<usize>,
}

impl Descent<'_> {
    /// The points `s..e`, one cell of weight `w`, `depth` splits below the top cells.
    fn cell(&mut self, s: usize, e: usize, w: f64, depth: usize) {
        let n = e - s;
        if w <= 1.0 || w >= n as f64 {
            self.runs
                .add(self.pts, self.chosen, s..e, w.min(n as f64) / n as f64);
            return;
        }
        if self.below.len() <= depth {
            self.below.resize_with(depth + 1, Children::default);
        }
        let mut ch = std::mem::take(&mut self.below[depth]);
        // The sub-cells: runs split where the common depth is least (found in
        // one pass: a lesser depth drops the splits found so far).
        ch.starts.clear();
        ch.starts.push(s);
        let mut split = u8::MAX;
        for (i, &d) in self.cd[s + 1..e].iter().enumerate() {
            if d <= split {
                if d < split {
                    split = d;
                    ch.starts.truncate(1);
                }
                ch.starts.push(s + 1 + i);
            }
        }
        if split as u32 >= KEY_BITS {
            // Closer than the grid resolves: even shares.
            self.runs.add(self.pts, self.chosen, s..e, w / n as f64);
        } else {
            ch.starts.push(e);
            ch.share(w, &mut self.order);
            self.children(&ch, depth + 1);
        }
        self.below[depth] = ch;
    }

    /// The cells `ch`, `depth` splits below the top cells, in curve order, so the
    /// weights arrive in order and the runs are cut on the fly (depth first).
    fn children(&mut self, ch: &Children, depth: usize) {
        for c in 0..ch.shares.len() {
            self.cell(ch.starts[c], ch.starts[c + 1], ch.shares[c], depth);
        }
    }
}

/// Levels `TILE_LEVELS + 1..levels`, whose sub-blocks are whole tiles, by the
/// centroid rule ([`leading_sub_block`]) on the tiles' order rather than on their
/// points: of `n` points in arranged tiles, `first_of(t)` is tile `t`'s first
/// point, and the result is the order in which they are stored (see
/// [`gather_representatives`]).
fn tile_order(n: usize, first_of: impl Fn(usize) -> [f32; 3], levels: usize) -> Vec<u32> {
    let mut order: Vec<u32> = (0..n.div_ceil(TILE_PIXELS) as u32).collect();
    order_tiles(&mut order, 0, n, first_of, TILE_LEVELS + 1..levels);
    order
}

/// The order [`gather_representatives`] gives the tiles of one aligned group of
/// `4^k` tiles (group `g`; the last group may hold fewer) of `n` points: the
/// centroid rule of the `k` levels whose sub-blocks are tiles within the group,
/// `first_of(t)` being tile `t`'s first point. Whole groups of `4^k` tiles keep
/// this order in the tile order (the levels above only move whole groups), so
/// the group makes the same tile of level `k` wherever it ends up; the last
/// group stays last.
pub fn group_tile_order(
    n: usize,
    k: usize,
    g: usize,
    first_of: impl Fn(usize) -> [f32; 3],
) -> Vec<u32> {
    let tiles = n.div_ceil(TILE_PIXELS);
    let first = g << (2 * k);
    let mut order: Vec<u32> = (first..tiles.min(first + (1 << (2 * k))))
        .map(|t| t as u32)
        .collect();
    order_tiles(
        &mut order,
        first,
        n,
        first_of,
        TILE_LEVELS + 1..TILE_LEVELS + 1 + k,
    );
    order
}

/// Applies the centroid rule of `levels` (all above [`TILE_LEVELS`]) to `order`,
/// the tiles `first..` of `n` points (`first` aligned to the largest block).
fn order_tiles(
    order: &mut [u32],
    first: usize,
    n: usize,
    first_of: impl Fn(usize) -> [f32; 3],
    levels: std::ops::Range<usize>,
) {
    for level in levels {
        // Tiles per sub-block, and points per sub-block.
        let sub = 1usize << (2 * (level - 1 - TILE_LEVELS));
        let sub_points = sub * TILE_PIXELS;
        for (b, block) in order.chunks_mut(4 * sub).enumerate() {
            let len = (n - (first + b * 4 * sub) * TILE_PIXELS).min(4 * sub_points);
            let count = len.div_ceil(sub_points);
            if count < 2 {
                continue;
            }
            let full = (len / sub_points).max(1);
            let lead = |j: usize| first_of(block[j * sub] as usize);
            let best = leading_sub_block(count, full, lead);
            if best > 0 {
                let (head, tail) = block.split_at_mut(best * sub);
                head[..sub].swap_with_slice(&mut tail[..sub]);
            }
        }
    }
}

/// One level of the centroid rule over a run of whole blocks (a tile).
fn centroid_level(pos: &mut [[f32; 3]], perm: &mut [u32], level: usize) {
    let block = 1usize << (2 * level);
    for (chunk, idx) in pos.chunks_mut(block).zip(perm.chunks_mut(block)) {
        centroid_block(chunk, idx, level);
    }
}

/// The centroid rule in one block of `4^level` slots (or the partial last one).
#[inline]
fn centroid_block(chunk: &mut [[f32; 3]], idx: &mut [u32], level: usize) {
    let sub = 1usize << (2 * (level - 1));
    let count = chunk.len().div_ceil(sub);
    if count < 2 {
        return;
    }
    let full = (chunk.len() / sub).max(1);
    let best = leading_sub_block(count, full, |j| chunk[j * sub]);
    if best > 0 {
        let (head, tail) = chunk.split_at_mut(best * sub);
        head[..sub].swap_with_slice(&mut tail[..sub]);
        let (head, tail) = idx.split_at_mut(best * sub);
        head[..sub].swap_with_slice(&mut tail[..sub]);
    }
}

/// The centroid rule: of a block's `count` sub-blocks, whose first points
/// (representatives) are `first(0..count)`, the one whose representative is
/// nearest the centroid of the representatives leads the block. (The centroid of
/// the representatives, not of all points: after level 1 a block's other points
/// need not sit around its representative.) Only the `full` first sub-blocks may
/// move (sub-block 0 is where they go).
#[inline]
fn leading_sub_block(count: usize, full: usize, first: impl Fn(usize) -> [f32; 3]) -> usize {
    let mut c = [0f32; 3];
    for j in 0..count {
        for a in 0..3 {
            c[a] += first(j)[a];
        }
    }
    let c = c.map(|v| v / count as f32);
    let d = |p: [f32; 3]| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2);
    (0..full)
        .min_by(|&i, &j| d(first(i)).total_cmp(&d(first(j))))
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`gather_representatives`] of points already in curve order (`pos`, with
    /// source indices `perm`), the bounds taken from the points, and the tiles
    /// put in their order.
    fn representatives(pos: &mut [[f32; 3]], perm: &mut [u32], levels: usize) {
        let lo = [0, 1, 2].map(|a| pos.iter().map(|p| p[a]).fold(f32::INFINITY, f32::min));
        let hi = [0, 1, 2].map(|a| pos.iter().map(|p| p[a]).fold(f32::NEG_INFINITY, f32::max));
        let src = pos.to_vec();
        let mut local: Vec<u32> = (0..pos.len() as u32).collect();
        let (out, order) = gather_representatives(
            Positions::Held(&src),
            &mut local,
            levels,
            lo,
            hi,
            &|_, _, _, _| {},
            Keep::All,
        );
        pos.copy_from_slice(&in_tile_order(&out, &order));
        let moved: Vec<u32> = in_tile_order(&local, &order)
            .iter()
            .map(|&k| perm[k as usize])
            .collect();
        perm.copy_from_slice(&moved);
    }

    /// The tiles of `v` (runs of [`TILE_PIXELS`]) in `order`.
    fn in_tile_order<T: Copy>(v: &[T], order: &[u32]) -> Vec<T> {
        let tiles: Vec<&[T]> = v.chunks(TILE_PIXELS).collect();
        order
            .iter()
            .flat_map(|&t| tiles[t as usize])
            .copied()
            .collect()
    }

    #[test]
    fn representative_is_nearest_centroid_and_prefix_kept() {
        // 4 points of a block: the one at the centroid moves to slot 0.
        let mut pos = vec![
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            [5.0, 0.1, 0.0],
            [5.0, 9.0, 0.0],
        ];
        let mut order = vec![0u32, 1, 2, 3];
        representatives(&mut pos, &mut order, 2);
        assert_eq!(order[0], 2);
        assert_eq!(pos[0], [5.0, 0.1, 0.0]);
        // A partial last block never moves a partial sub-block forward.
        let mut pos: Vec<[f32; 3]> = (0..22).map(|i| [i as f32, 0.0, 0.0]).collect();
        let mut order: Vec<u32> = (0..22).collect();
        representatives(&mut pos, &mut order, 3);
        for (p, &i) in pos.iter().zip(&order) {
            assert_eq!(p[0], i as f32, "positions move with their indices");
        }
        let mut sorted = order.clone();
        sorted.sort();
        assert_eq!(sorted, (0..22).collect::<Vec<_>>());
        // The last block of level 1 (slots 20, 21) is partial: its points stay there.
        let mut last = order[20..].to_vec();
        last.sort();
        assert_eq!(last, [20, 21]);
    }
    #[test]
    fn share_fills_water_levels() {
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        share(9.0, &[1, 5, 10], &mut out, &mut scratch);
        assert_eq!(out, [1.0, 4.0, 4.0]);
        share(100.0, &[1, 5, 10], &mut out, &mut scratch);
        assert_eq!(out, [1.0, 5.0, 10.0]);
        // Many children (the histogram path): equal shares, small ones capped.
        let sizes: Vec<usize> = (0..1000)
            .map(|i| if i % 2 == 0 { 1 } else { 100 })
            .collect();
        share(2000.0, &sizes, &mut out, &mut scratch);
        assert!((out.iter().sum::<f64>() - 2000.0).abs() < 1e-6);
        assert_eq!((out[0], out[1]), (1.0, 3.0));
    }

    #[test]
    fn level_one_keeps_sparse_points() {
        // A dense patch (one corner) and isolated points spread over the rest.
        let mut r = crate::rng::Rng::new(5);
        let mut pos: Vec<[f32; 3]> = (0..20_000)
            .map(|_| [r.f64() as f32, r.f64() as f32, 0.0])
            .collect();
        let sparse: Vec<[f32; 3]> = (0..400)
            .map(|i| {
                [
                    10.0 + (i % 20) as f32 * 5.0,
                    10.0 + (i / 20) as f32 * 5.0,
                    0.0,
                ]
            })
            .collect();
        pos.extend(&sparse);
        let order = hilbert_order(Positions::Held(&pos), [0.0; 3], [110.0, 110.0, 0.0]);
        let mut sorted: Vec<[f32; 3]> = order.iter().map(|&i| pos[i as usize]).collect();
        let mut perm = order.clone();
        representatives(&mut sorted, &mut perm, 3);
        let kept: Vec<u32> = perm.iter().step_by(4).copied().collect();
        assert_eq!(kept.len(), pos.len().div_ceil(4));
        let sparse_kept = kept.iter().filter(|&&i| i >= 20_000).count();
        // The plain rule would keep about a quarter of them.
        assert!(
            sparse_kept >= 380,
            "kept {sparse_kept} of 400 isolated points"
        );
        for (p, &i) in sorted.iter().zip(&perm) {
            assert_eq!(*p, pos[i as usize], "positions move with their indices");
        }
    }

    /// The tile order that `gather_representatives` returns is the centroid rule
    /// applied by moving whole tiles level by level, as `centroid_block` does
    /// within a tile (checked against that, with a partial last tile); and
    /// `on_tile` saw every tile once, as it was stored.
    #[test]
    fn tile_order_is_the_centroid_rule_on_whole_tiles() {
        let mut r = crate::rng::Rng::new(3);
        // Levels 9..=11 reorder tiles: blocks of 4 and of 16 tiles.
        let n = 21 * TILE_PIXELS + 777;
        let pos: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                [
                    r.f64() as f32 * 100.0,
                    r.f64().powi(2) as f32 * 100.0,
                    r.f64() as f32 * 5.0,
                ]
            })
            .collect();
        let (lo, hi) = ([0.0; 3], [100.0, 100.0, 5.0]);
        let mut perm = hilbert_order(Positions::Held(&pos), lo, hi);
        let levels = representative_levels(n);
        assert!(levels > TILE_LEVELS + 2, "{levels}");
        let seen = std::sync::Mutex::new(Vec::new());
        let on_tile = |t: usize, p: &[[f32; 3]], i: &[u32], _: Option<TileRows<'_>>| {
            seen.lock().unwrap().push((t, p.to_vec(), i.to_vec()));
        };
        let sorted = perm.clone();
        let (out, order) = gather_representatives(
            Positions::Held(&pos),
            &mut perm,
            levels,
            lo,
            hi,
            &on_tile,
            Keep::All,
        );
        // Each tile's first point only: the same arrangement and order.
        let mut perm1 = sorted;
        let (firsts, order1) = gather_representatives(
            Positions::Held(&pos),
            &mut perm1,
            levels,
            lo,
            hi,
            &|_, _, _, _| {},
            Keep::Firsts,
        );
        let first_of_each: Vec<[f32; 3]> = out.iter().step_by(TILE_PIXELS).copied().collect();
        assert_eq!((&perm1, &order1), (&perm, &order));
        assert!(firsts == first_of_each);
        // Every aligned group of 4^k tiles keeps its own order within the tile
        // order, as a whole (the last, partial group last).
        let tiles = order.len();
        for k in 1..=levels - 1 - TILE_LEVELS {
            let size = 1usize << (2 * k);
            for (at, block) in order.chunks(size).enumerate() {
                let g = block[0] as usize / size;
                let own = group_tile_order(n, k, g, |t| out[t * TILE_PIXELS]);
                assert_eq!(block, &own[..], "level {k}, block {at}");
                if (g + 1) * size >= tiles {
                    assert_eq!(at, tiles.div_ceil(size) - 1, "the last group moved");
                }
            }
        }
        let (mut want, mut want_perm) = (out.clone(), perm.clone());
        for level in TILE_LEVELS + 1..levels {
            let block = 1usize << (2 * level);
            for (c, i) in want.chunks_mut(block).zip(want_perm.chunks_mut(block)) {
                centroid_block(c, i, level);
            }
        }
        let identity: Vec<u32> = (0..n.div_ceil(TILE_PIXELS) as u32).collect();
        assert_ne!(order, identity, "no tile moved");
        assert!(in_tile_order(&out, &order) == want);
        assert!(in_tile_order(&perm, &order) == want_perm);
        let mut seen = seen.into_inner().unwrap();
        seen.sort_by_key(|s| s.0);
        assert_eq!(seen.len(), identity.len());
        for ((t, p, i), (o, k)) in seen
            .iter()
            .zip(out.chunks(TILE_PIXELS).zip(perm.chunks(TILE_PIXELS)))
        {
            assert!(p == o && i == k, "tile {t}");
        }
    }

    #[test]
    fn points_stay_in_their_tile() {
        let mut r = crate::rng::Rng::new(8);
        let n = 2 * crate::spec::TILE_PIXELS + 12_345;
        let pos: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                [
                    r.f64() as f32 * 50.0,
                    r.f64().powi(3) as f32 * 50.0,
                    r.f64() as f32,
                ]
            })
            .collect();
        let order = hilbert_order(Positions::Held(&pos), [0.0; 3], [50.0, 50.0, 1.0]);
        let mut sorted: Vec<[f32; 3]> = order.iter().map(|&i| pos[i as usize]).collect();
        let mut perm = order.clone();
        representatives(&mut sorted, &mut perm, representative_levels(n));
        // Tiles hold the same runs of the curve (coarse levels may reorder tiles).
        let tiles = |v: &[u32]| {
            let mut t: Vec<Vec<u32>> = v
                .chunks(crate::spec::TILE_PIXELS)
                .map(|c| {
                    let mut c = c.to_vec();
                    c.sort();
                    c
                })
                .collect();
            t.sort();
            t
        };
        assert_eq!(tiles(&order), tiles(&perm));
    }
}
