//! Writing one part: order the points, lay them out along the image's Z-order curve,
//! build the nearest-neighbour pyramid and write a tiled, band-separate Float32 TIFF
//! with internal overviews, atomically (temporary name, then rename).

use crate::clock::{Span, Stamp};
use crate::error::{Result, StoreError};
use crate::points::{Bounds, PointColumns, RowSource};
use crate::spec::{self, TILE_BYTES, TILE_PIXELS, TILE_SIZE, key, tag};
use crate::tiff::codec::{self, Compression};
use crate::tiff::ifd::{Dir, Head, Value};
use crate::tiff::metadata::{self, Item, LevelIndex, TileEntry};
use crate::tiff::tiles::{gather_held, groups, hilbert_bands, scatter_tile};
use crate::tiff::zorder::{Geometry, tile_z_to_raster};
use crate::write::builder::PartBuilder;
use crate::write::coarse::Coarse;
use crate::write::layout::{self, Layout};
use crate::write::out::{self, TileBuf, TileIo, TileWriter};
use crate::write::paper;
use crate::write::sink::{self, TileSink};
use rayon::prelude::*;
use std::fs::File;
use std::io::{Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// How to write a part.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    pub compression: Compression,
    /// The LERC codecs: the largest error allowed in each coordinate band
    /// (`x y z`, source units; 0: lossless). Attributes are always lossless.
    /// A LAS input's is half its scale factors: the coordinates were whole
    /// multiples of them, and come back on that lattice.
    pub coord_max_error: [f64; 3],
    pub layout: Layout,
    /// The input's file name, recorded in the metadata.
    pub source: Option<String>,
    /// Coordinate reference system (WKT or `EPSG:n`), recorded in the metadata.
    pub crs: Option<String>,
    /// Items the source gives about itself (`key::FROM_SOURCE`), recorded in
    /// the metadata.
    pub from_source: Vec<(String, String)>,
    /// Write BigTIFF even when classic TIFF would do.
    pub force_bigtiff: bool,
    /// When set (Ctrl-C), the write stops at the next tile batch or phase with an
    /// error, and its temporary file is removed.
    pub cancel: Option<Arc<AtomicBool>>,
    /// How uncompressed tile data is written (`out::TileWriter`).
    pub io: TileIo,
    /// Hands the allocator's pooled blocks back to the kernel once the points are
    /// arranged (`alloc::release_pool`): for the last part of a conversion, whose
    /// tiles need no large buffers and after which nothing would reuse them.
    pub release_pool: bool,
    /// The input's coordinate lattice (LAS scale factors and offsets). With a
    /// lossless predictor codec (`zstd`, `deflate`) the part stores each
    /// coordinate's whole number on it, GDAL's band scale and offset giving the
    /// coordinate back ([`StoredLattice`]); a part some point of which is not on
    /// it is stored as without one.
    pub lattice: Option<crate::points::Lattice>,
    /// A part of a dataset of many (`convert` writing several): small parts
    /// get levels down to a quarter tile, so that the overview above them
    /// holds less ([`Geometry::for_part`]).
    pub shallow_coarsest: bool,
    /// Round every coordinate to [`WriteOptions::lattice`] (`--precision`)
    /// instead of keeping the lattice only where every point lies on it; the
    /// part's `MAX_QUANTIZATION_ERROR` grows by half the step.
    pub lattice_round: bool,
    /// Zstd's level for `zstd` tiles; `None`: [`codec::ZSTD_FAST`]. A
    /// conversion of a small input takes [`codec::ZSTD_SMALL`], smaller
    /// tiles at a cost in time that is small there.
    pub zstd_level: Option<i32>,
}

impl WriteOptions {
    /// The widest a part's points may spread on each axis for its coordinates
    /// to be kept on [`Self::lattice`], when the codec and layout keep one: a
    /// part stores whole numbers of steps within 2^23 of the lattice point
    /// nearest its origin (see `StoredLattice`), so with the origin at the
    /// points' centre they may span 2^24 steps less one (1 % kept to spare).
    /// 168 km at 1 cm, 16.8 km at 1 mm, 1.68 km at 0.1 mm.
    pub fn lattice_extent(&self) -> Option<[f64; 3]> {
        if self.layout != Layout::Hilbert || !self.compression.row_ordered() {
            return None;
        }
        lattice_extent(&self.lattice?)
    }

    /// The Zstd level `zstd` tiles are written with: [`Self::zstd_level`], or
    /// [`codec::ZSTD_FAST`] where none is set.
    pub fn zstd_level_used(&self) -> i32 {
        self.zstd_level.unwrap_or(codec::ZSTD_FAST)
    }

    fn cancelled(&self) -> bool {
        self.cancel
            .as_ref()
            .is_some_and(|c| c.load(Ordering::Relaxed))
    }
}

/// The message of a write stopped by [`WriteOptions::cancel`].
pub const INTERRUPTED: &str = "interrupted";

/// What was written.
#[derive(Debug, Clone)]
pub struct PartSummary {
    pub path: PathBuf,
    pub points: u64,
    pub level_points: Vec<u64>,
    pub bytes: u64,
    /// Bytes at the head of the file holding every directory, tile index and the
    /// metadata; the tiles follow.
    pub head: u64,
    pub bounds: Bounds,
    pub origin: [f64; 3],
    /// Largest difference between a source coordinate and its stored value.
    pub max_quantization_error: f64,
    pub bigtiff: bool,
    /// Whether the tile data went to the disk around the page cache (`TileIo`), at
    /// the end of the write.
    pub direct: bool,
    /// Whether the attribute rows were read from the input ([`RowSource`]) rather
    /// than from a copy the part held.
    pub rows_from_input: bool,
    /// Wall and CPU time of each phase of the write, in order.
    pub phases: Vec<(&'static str, Span)>,
    /// The input's lattice, where the part keeps its coordinates as whole
    /// numbers on it (format version 2).
    pub lattice: Option<crate::points::Lattice>,
}

/// Records the wall and CPU time of consecutive phases.
struct Phases {
    last: Stamp,
    list: Vec<(&'static str, Span)>,
}

impl Phases {
    fn new() -> Self {
        Phases {
            last: Stamp::now(),
            list: Vec::new(),
        }
    }
    fn mark(&mut self, name: &'static str) {
        self.list.push((name, self.last.elapsed()));
        self.last = Stamp::now();
    }
}

/// An upper bound of |stored - source| for any coordinate inside `bounds`: half an
/// f32 ulp at the largest offset from the origin, plus the f64 rounding of the
/// subtraction and of the reader's re-addition.
pub(crate) fn quantization_bound(bounds: &Bounds, origin: [f64; 3]) -> f64 {
    if bounds.is_empty() {
        return 0.0;
    }
    (0..3)
        .map(|a| {
            let rel = (bounds.max[a] - origin[a])
                .abs()
                .max((bounds.min[a] - origin[a]).abs());
            let mag = bounds.max[a].abs().max(bounds.min[a].abs());
            let half_ulp = if rel > 0.0 {
                2f64.powi(rel.log2().floor() as i32 - 24)
            } else {
                0.0
            };
            half_ulp + 4.0 * f64::EPSILON * mag
        })
        .fold(0.0, f64::max)
}

/// The codec's error bound of each coordinate band (0 for lossless codecs).
fn codec_bound(opts: &WriteOptions) -> [f64; 3] {
    if opts.compression.is_lerc() {
        opts.coord_max_error.map(|e| e.max(0.0))
    } else {
        [0.0; 3]
    }
}

/// A part's attribute rows: held (interleaved, in input order), or given again by
/// the reader a tile at a time.
enum Rows {
    Held(Vec<f32>),
    Source(Arc<dyn RowSource>),
}

impl Rows {
    /// Appends the rows (`m` values each) of points `idx` to `out`.
    fn gather(&self, idx: &[u32], m: usize, out: &mut Vec<f32>) {
        match self {
            Rows::Source(src) => src.gather(idx, out),
            Rows::Held(rows) => gather_held(rows, idx, m, out),
        }
    }

    /// The rows (`m` values each) of points `idx` as columns: value `k` of
    /// point `idx[i]` into `cols[k][i]`.
    fn gather_columns(&self, idx: &[u32], m: usize, cols: &mut [&mut [f32]]) {
        match self {
            Rows::Source(src) => src.gather_columns(idx, cols),
            Rows::Held(rows) => {
                let mut out = Vec::with_capacity(idx.len() * m);
                gather_held(rows, idx, m, &mut out);
                pcimg_core::points::columns_of_rows(&out, m, cols);
            }
        }
    }
}

/// A part in image order, ready to be tiled. Positions stay interleaved (`x y z`
/// bands 0–2 are read straight out of them by the tile encoder, which saves a
/// pass over every point); attributes stay in input order as rows (`m` values a
/// point), which the encoder gathers through `perm` a tile at a time.
struct Arranged {
    geometry: Geometry,
    layout: Layout,
    /// Positions, whole level-0 tiles in stored order (see `tile_order`); when
    /// every level was written while arranging, only each tile's first.
    pos: Vec<[f32; 3]>,
    /// Source index of each slot of `pos` (empty for the paper layout, whose
    /// order is the input's).
    perm: Vec<u32>,
    /// The image order of the tiles of `pos` and `perm`: image tile `t` (Z-rank,
    /// level 0) is their tile `tile_order[t]` (empty: the same order). See
    /// [`Arranged::slot`].
    tile_order: Vec<u32>,
    /// Bounds of the stored coordinates of each tile of `pos` (as stored, before
    /// `tile_order`), found while arranging (empty for the paper layout).
    tile_bounds: Vec<Option<[[f32; 3]; 2]>>,
    /// Whether every level's tiles were written while the points were arranged
    /// (level 0: tile `tile_order[t]`'s bands from its region's start on; level `k`:
    /// group `tile_order[t · 4^k] / 4^k`'s in the level's region, see
    /// [`coarse`]), band-interleaved as `encode` lays them out.
    levels_written: bool,
    /// Bands 3 and up, interleaved, in input order.
    rows: Rows,
    m: usize,
    /// Each attribute's smallest and largest value.
    ranges: Vec<(f32, f32)>,
    names: Vec<String>,
    offsets: Vec<f64>,
    origin: [f64; 3],
    bounds: Bounds,
    max_error: f64,
    /// Tiles in row order, each tile's points in the order [`tile_order`] chose
    /// (version 2: lossless predictor codecs of the Hilbert layout).
    rows_order: bool,
    /// Coordinates stored as whole numbers on the input's lattice.
    lattice: Option<StoredLattice>,
    /// Row-ordered parts: the attributes (bands 3 and up) whose values are all
    /// whole numbers, stored plus `spec::WHOLE_BIAS`.
    whole: Vec<bool>,
    /// Points per classification code ([`attribute_pass`]).
    class_counts: Option<Vec<(u8, u64)>>,
}

/// The widest points may spread on each axis for a part to keep them on `l`
/// ([`WriteOptions::lattice_extent`]); `None` for a lattice with a zero or
/// non-finite step.
pub fn lattice_extent(l: &crate::points::Lattice) -> Option<[f64; 3]> {
    let ok = l.step.iter().all(|s| s.is_finite() && *s != 0.0);
    ok.then(|| {
        l.step
            .map(|s| s.abs() * (2.0 * spec::WHOLE_BIAS - 1.0) * 0.99)
    })
}

/// Coordinates kept as whole numbers: a stored `k` on axis `a` stands for
/// `base[a] + step[a] · k`, stored as `k + 2^23` (`spec::WHOLE_BIAS`; GDAL's
/// band scale is the step, its offset `base - step · 2^23`). `base` is the
/// source lattice's point nearest the part's origin, so `|k|` stays below
/// 2^23 for parts up to 2^24 steps wide (168 km at 1 cm).
#[derive(Debug, Clone, Copy)]
pub(crate) struct StoredLattice {
    pub step: [f64; 3],
    pub base: [f64; 3],
    pub source: crate::points::Lattice,
}

impl StoredLattice {
    /// The lattice of `source` rebased near `origin`.
    fn new(source: crate::points::Lattice, origin: [f64; 3]) -> Option<Self> {
        let mut base = [0.0; 3];
        for a in 0..3 {
            let s = source.step[a];
            if !(s.is_finite() && s != 0.0 && source.origin[a].is_finite()) {
                return None;
            }
            base[a] = source.origin[a] + s * ((origin[a] - source.origin[a]) / s).round();
        }
        Some(StoredLattice {
            step: source.step,
            base,
            source,
        })
    }

    /// For a point on the lattice, its stored value is the nearest whole
    /// number to `v · inv + shift` (`v` relative to `origin`): `(inv, shift)`.
    fn stored_map(&self, a: usize, origin: f64) -> (f64, f64) {
        let inv = 1.0 / self.step[a];
        (inv, (origin - self.base[a]) * inv + spec::WHOLE_BIAS)
    }

    /// Whether every position of `pos` (relative to `origin`) lies on this
    /// lattice: its stored value, the nearest whole number to `v · inv +
    /// shift`, lies within 2^23 steps of `base` and, without `round`, gives
    /// `v` back to `f32`'s rounding (the next `f32` either way) or to f64's
    /// rounding of coordinates as large as the origin's. (Near the origin an
    /// `f32` is finer than the f64 sums both sides come from: at a northing of
    /// 4,000,500 m, `offset + scale · X` and `base + step · k` each round by up
    /// to 4.7e-10 m, while 0.0035 m has f32 neighbours 2.3e-10 m apart.) With
    /// `round` only the numbers must fit.
    fn holds(&self, origin: [f64; 3], pos: &[[f32; 3]], round: bool) -> bool {
        // Each axis's map and slack worked out once: a few f64 roundings at the
        // size of the coordinates, far below any step (7e-9 m at 4e6 m).
        let maps = [0, 1, 2].map(|a| self.stored_map(a, origin[a]));
        let slack = [0, 1, 2].map(|a| 8.0 * f64::EPSILON * (origin[a].abs() + self.base[a].abs()));
        let fits = |a: usize, v: f32| -> bool {
            let s = round_half(v as f64 * maps[a].0 + maps[a].1);
            if !(0.0..2.0 * spec::WHOLE_BIAS).contains(&s) {
                return false;
            }
            if round {
                return true;
            }
            let back = (self.base[a] + self.step[a] * (s - spec::WHOLE_BIAS)) - origin[a];
            let b32 = back as f32;
            b32 == v
                || b32.next_up() == v
                || b32.next_down() == v
                || (back - v as f64).abs() <= slack[a]
        };
        pos.iter()
            .all(|p| (0..3).all(|a| p[a].is_nan() || fits(a, p[a])))
    }
}

/// The input's lattice checked tile by tile while the points are arranged
/// (each tile then in cache), for a part whose codec keeps coordinates on it:
/// the candidate, and whether some tile's point lay off it.
struct LatticeCheck {
    lattice: StoredLattice,
    round: bool,
    off: AtomicBool,
}

impl LatticeCheck {
    fn new(opts: &WriteOptions, layout: Layout, origin: [f64; 3]) -> Option<Self> {
        if layout != Layout::Hilbert || !opts.compression.row_ordered() {
            return None;
        }
        Some(LatticeCheck {
            lattice: StoredLattice::new(opts.lattice?, origin)?,
            round: opts.lattice_round,
            off: AtomicBool::new(false),
        })
    }

    /// Checks one arranged tile's positions.
    fn tile(&self, origin: [f64; 3], pos: &[[f32; 3]]) {
        if !self.off.load(Ordering::Relaxed) && !self.lattice.holds(origin, pos, self.round) {
            self.off.store(true, Ordering::Relaxed);
        }
    }

    /// The lattice, if every tile lay on it.
    fn result(self) -> Option<StoredLattice> {
        (!self.off.into_inner()).then_some(self.lattice)
    }
}

impl Arranged {
    /// What Zstd does with band `b`'s tiles at its fast level
    /// ([`codec::Fast`]): coordinates keep raw literals; whole-number bands
    /// that span fewer than 256 values (one byte plane of differences) are
    /// coded as runs.
    fn fast(&self, b: usize) -> codec::Fast {
        let Some(k) = b.checked_sub(3) else {
            return codec::Fast::RawLiterals;
        };
        let small = self.ranges.get(k).is_some_and(|&(lo, hi)| hi - lo < 256.0);
        if self.whole.get(k) == Some(&true) && small {
            codec::Fast::Runs
        } else {
            codec::Fast::Zstd
        }
    }

    /// The tile of `pos` and `perm` that holds level 0's image tile `t` (Z-rank).
    #[inline]
    fn stored_tile(&self, t: usize) -> usize {
        self.tile_order.get(t).map_or(t, |&s| s as usize)
    }

    /// The index in `pos` and `perm` of image slot `s` (level 0, Z-order).
    #[inline]
    fn slot(&self, s: usize) -> usize {
        self.stored_tile(s / TILE_PIXELS) * TILE_PIXELS + s % TILE_PIXELS
    }
}

/// Where level `level`'s tile data begins in an uncompressed file of `levels`
/// levels whose tiles start at `first`: the coarsest level's tiles first, level
/// 0's last (as a Cloud Optimized GeoTIFF orders them), the `filled(k)` tiles
/// holding points of level `k` in slots of `bands` band tiles (tile `s`'s band
/// `b` at slot `s · bands + b`). `level == levels` gives the end of level 0's.
pub(crate) fn region_start(
    filled: impl Fn(usize) -> u64,
    bands: usize,
    first: u64,
    levels: usize,
    level: usize,
) -> u64 {
    // (Level 0's region ends where the data ends: after every level's.)
    let above = if level >= levels { 0 } else { level + 1 };
    first
        + (above..levels)
            .map(|k| filled(k) * bands as u64 * TILE_BYTES)
            .sum::<u64>()
}

fn band_name(raw: &str) -> String {
    let s: String = raw
        .trim()
        .chars()
        .map(|c| {
            if c.is_whitespace() || c.is_control() {
                '_'
            } else {
                c
            }
        })
        .collect();
    if s.is_empty() { "band".into() } else { s }
}

/// The bounds of the chunks' points, axis by axis over contiguous slices
/// (vectorizes). `min`/`max` pass over NaN, which the builder then refuses as
/// not finite; an infinity shows in the bounds themselves and is an error.
fn scan_bounds(path: &Path, chunks: &[PointColumns]) -> Result<Bounds> {
    let stats: Vec<(f64, f64)> = (0..3)
        .into_par_iter()
        .map(|axis| {
            chunks
                .par_iter()
                .flat_map(|c| [&c.x, &c.y, &c.z][axis].par_chunks(1 << 16))
                .map(|c| {
                    let lo = c.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    (lo, hi)
                })
                .reduce(
                    || (f64::INFINITY, f64::NEG_INFINITY),
                    |a, b| (a.0.min(b.0), a.1.max(b.1)),
                )
        })
        .collect();
    if stats.iter().any(|s| s.0.is_infinite() || s.1.is_infinite()) {
        let mut base = 0;
        for c in chunks {
            let finite = |i: usize| c.x[i].is_finite() && c.y[i].is_finite() && c.z[i].is_finite();
            if let Some(i) = (0..c.len()).find(|&i| !finite(i)) {
                return Err(StoreError::new(
                    path,
                    format!(
                        "point {} has a coordinate that is not a finite number ({}, {}, {})",
                        base + i,
                        c.x[i],
                        c.y[i],
                        c.z[i]
                    ),
                ));
            }
            base += c.len();
        }
    }
    Ok(Bounds {
        min: [stats[0].0, stats[1].0, stats[2].0],
        max: [stats[0].1, stats[1].1, stats[2].1],
    })
}

/// Sorts and arranges `part`'s points for `layout`. Given `level0` (Hilbert
/// layout, uncompressed), each tile's level-0 bands are encoded as soon as the
/// tile is arranged, in cache, and sent to level 0's region of the file (whose
/// tile data begins at `tiles_at`, the first disk block after the largest head
/// the part can have),
/// so the disk writes most of the file while the rest is still being arranged.
fn arrange(
    path: &Path,
    part: PartBuilder,
    opts: &WriteOptions,
    ph: &mut Phases,
    level0: Option<&TileSink>,
    tiles_at: u64,
) -> Result<Arranged> {
    let from_source = part.positions_from_source();
    let PartBuilder {
        origin,
        pos,
        count: n,
        rows,
        source,
        attributes,
        ranges,
        bounds,
        ..
    } = part;
    let rows = match source {
        None => Rows::Held(rows),
        Some(src) if src.len() != n || src.width() != attributes.len() => {
            return Err(StoreError::new(
                path,
                format!(
                    "the reader's attribute rows ({} points of {} values) do not match the \
                     part ({n} points of {} values)",
                    src.len(),
                    src.width(),
                    attributes.len()
                ),
            ));
        }
        Some(src) => Rows::Source(src),
    };
    // Positions the source gives again are read from it, the same values; with
    // them the rows level 0's tiles want (each point read once).
    let positions = match &rows {
        Rows::Source(src) if from_source => layout::Positions::Source {
            src: &**src,
            origin,
            rows: level0.is_some() && !attributes.is_empty(),
        },
        _ => layout::Positions::Held(&pos),
    };
    let mut names: Vec<String> = spec::COORDINATE_BANDS
        .iter()
        .map(|s| s.to_string())
        .collect();
    for (a, _) in &attributes {
        let name = band_name(a);
        if names.contains(&name) {
            return Err(StoreError::new(
                path,
                format!("two bands are named '{name}'"),
            ));
        }
        names.push(name);
    }
    let (bounds, origin) = if n == 0 {
        (Bounds::EMPTY, [0.0; 3])
    } else {
        (bounds, origin)
    };
    let max_error = quantization_bound(&bounds, origin);
    let layout = opts.layout;
    let geometry = Geometry::for_part(n as u64, opts.shallow_coarsest);
    ph.mark("validate+origin");
    // Points in image order, tile by tile (the tiles themselves in the order
    // `tile_order` gives): positions and their source indices.
    let m = attributes.len();
    let mut tile_bounds = Vec::new();
    let mut lattice = None;
    let (pos, perm, tile_order) = match layout {
        Layout::Hilbert => {
            let lo = [0, 1, 2].map(|a| (bounds.min[a] - origin[a]) as f32);
            let hi = [0, 1, 2].map(|a| (bounds.max[a] - origin[a]) as f32);
            let mut perm = layout::hilbert_order(positions, lo, hi);
            ph.mark("hilbert sort");
            let lut = tile_z_to_raster(spec::TILE_LOG2);
            let nb = 3 + m;
            // The bounds of arranged tile t and (when `level0`) its level-0 bands
            // as `encode` would write them, while the tile is in cache.
            let found: Vec<std::sync::OnceLock<[[f32; 3]; 2]>> = (0..n.div_ceil(TILE_PIXELS))
                .map(|_| Default::default())
                .collect();
            // Levels 1 and up from the tiles' level-1 points, each coarse tile
            // written as soon as the tiles below it are arranged.
            let coarse = level0.map(|_| Coarse::new(geometry, m, tiles_at, lut.clone()));
            // The lattice checked while each tile is in cache.
            let check = LatticeCheck::new(opts, layout, origin);
            let filled = |l| geometry.filled_tiles(l);
            let level0_at = region_start(filled, nb, tiles_at, geometry.levels(), 0);
            let on_tile = |t: usize, o: &[[f32; 3]], i: &[u32], tile: Option<layout::TileRows>| {
                if let Some(c) = &check {
                    c.tile(origin, o);
                }
                let mut b = [[f32::INFINITY; 3], [f32::NEG_INFINITY; 3]];
                for p in o {
                    for ax in 0..3 {
                        b[0][ax] = b[0][ax].min(p[ax]);
                        b[1][ax] = b[1][ax].max(p[ax]);
                    }
                }
                let _ = found[t].set(b);
                let (Some(sink), Some(coarse)) = (level0.filter(|s| !s.stopped()), &coarse) else {
                    return;
                };
                let at = |b: usize| level0_at + (t * nb + b) as u64 * TILE_BYTES;
                // The attribute rows in slot order: read with the positions, or
                // gathered now.
                let mut slot_rows = Vec::with_capacity(o.len() * m);
                match &tile {
                    Some(tr) => gather_held(tr.rows, tr.local, m, &mut slot_rows),
                    None => rows.gather(i, m, &mut slot_rows),
                }
                let batch = (0..groups(m))
                    .flat_map(|group| hilbert_bands(&lut, o.len(), group, |k| o[k], &slot_rows, m))
                    .map(|(b, buf)| (at(b), buf))
                    .collect();
                // A refusal (cancelled, a failed write) is kept by the sink.
                let _ = sink.send(batch);
                coarse.tile_done(t, o, &slot_rows, sink);
            };
            let levels = layout::representative_levels(n);
            // Every level written from `on_tile`: the tile order wants each
            // tile's first point only.
            let keep = if level0.is_some() {
                layout::Keep::Firsts
            } else {
                layout::Keep::All
            };
            let (sorted, order) = layout::gather_representatives(
                positions, &mut perm, levels, lo, hi, &on_tile, keep,
            );
            drop(pos);
            drop(coarse);
            tile_bounds = found.into_iter().map(|b| b.into_inner()).collect();
            lattice = check.and_then(LatticeCheck::result);
            ph.mark(if level0.is_some() {
                "gather+representatives+levels"
            } else {
                "gather+representatives"
            });
            (sorted, perm, order)
        }
        Layout::Paper if from_source => (positions.to_vec(), Vec::new(), Vec::new()),
        Layout::Paper => (pos, Vec::new(), Vec::new()),
    };
    let mut offsets = origin.to_vec();
    offsets.extend(attributes.iter().map(|(_, o)| *o));
    Ok(Arranged {
        geometry,
        layout,
        pos,
        perm,
        tile_order,
        tile_bounds,
        levels_written: level0.is_some(),
        rows,
        m,
        ranges,
        names,
        offsets,
        origin,
        bounds,
        max_error,
        rows_order: false,
        lattice,
        whole: Vec::new(),
        class_counts: None,
    })
}

/// Bounds per tile for every level: level 0 from the stored coordinates, each
/// coarser tile the union of the four tiles below it.
fn tile_index(a: &Arranged) -> Vec<LevelIndex> {
    let g = a.geometry;
    if a.layout == Layout::Paper {
        return paper::tile_index(&a.pos, a.origin, g);
    }
    let o = a.origin;
    let mut levels: Vec<LevelIndex> = Vec::with_capacity(g.levels());
    // Level 0 from the bounds found while arranging, taken in image order.
    let level0: Vec<Bounds> = (0..g.filled_tiles(0) as usize)
        .map(
            |t| match a.tile_bounds.get(a.stored_tile(t)).copied().flatten() {
                Some([lo, hi]) => Bounds {
                    min: [0, 1, 2].map(|ax| o[ax] + lo[ax] as f64),
                    max: [0, 1, 2].map(|ax| o[ax] + hi[ax] as f64),
                },
                None => Bounds::EMPTY,
            },
        )
        .collect();
    let mut prev = level0;
    for level in 0..g.levels() {
        if level > 0 {
            prev = (0..g.filled_tiles(level) as usize)
                .map(|t| {
                    prev[4 * t..(4 * t + 4).min(prev.len())]
                        .iter()
                        .fold(Bounds::EMPTY, |b, c| b.union(c))
                })
                .collect();
        }
        levels.push(LevelIndex {
            size: g.size(level),
            tile_size: TILE_SIZE,
            tiles: prev
                .iter()
                .enumerate()
                .map(|(t, b)| TileEntry {
                    index: g.tile_raster_index(level, t as u64),
                    points: g.tile_points(level, t as u64),
                    bounds: *b,
                })
                .collect(),
        });
    }
    levels
}

/// Minimum and maximum of each band's stored values (NaN ignored; `lo > hi` for a
/// band with no finite value): x y z from the bounds, the rest as the builder
/// found them.
/// Whether each band holds whole numbers stored plus `spec::WHOLE_BIAS`.
fn whole_bands(a: &Arranged) -> Vec<bool> {
    (0..a.names.len())
        .map(|b| {
            if b < 3 {
                a.lattice.is_some()
            } else {
                a.whole.get(b - 3).copied().unwrap_or(false)
            }
        })
        .collect()
}

fn stored_ranges(a: &Arranged) -> Vec<(f64, f64)> {
    let mut r: Vec<(f64, f64)> = (0..3)
        .map(|k| {
            let (lo, hi) = (a.bounds.min[k], a.bounds.max[k]);
            match &a.lattice {
                // (Whole numbers: the bounds are points of the lattice.)
                Some(l) => (
                    ((lo - l.base[k]) / l.step[k]).round() + spec::WHOLE_BIAS,
                    ((hi - l.base[k]) / l.step[k]).round() + spec::WHOLE_BIAS,
                ),
                None => (
                    (lo - a.origin[k]) as f32 as f64,
                    (hi - a.origin[k]) as f32 as f64,
                ),
            }
        })
        .map(|(lo, hi)| if lo <= hi { (lo, hi) } else { (hi, lo) })
        .collect();
    let whole = whole_bands(a);
    r.extend(a.ranges.iter().enumerate().map(|(k, &(lo, hi))| {
        let bias = if whole[3 + k] { spec::WHOLE_BIAS } else { 0.0 };
        (lo as f64 + bias, hi as f64 + bias)
    }));
    r
}

/// Points per classification code when the part has a `classification` band
/// (values that are not whole codes 0..=255 are not counted). Held rows are
/// counted in place; rows the reader gives again are asked for in blocks.
/// One pass over the attribute rows: the points per classification code when
/// the part has a `classification` band (values that are not whole codes
/// 0..=255 are not counted), and when `whole` is asked (row-ordered parts),
/// whether each attribute's values are all whole numbers in `[-2^23, 2^23)`
/// (NaN aside), which such a part stores plus 2^23. Held rows are read in
/// place; rows the reader gives again are asked for in blocks.
fn attribute_pass(a: &Arranged, whole: bool) -> (Option<Vec<(u8, u64)>>, Vec<bool>) {
    let (m, n) = (a.m, a.geometry.points as usize);
    let class = a
        .names
        .iter()
        .position(|n| n == "classification")
        .and_then(|b| b.checked_sub(3));
    let bias = spec::WHOLE_BIAS as f32;
    let mut candidates: Vec<bool> = (0..m)
        .map(|k| {
            let (lo, hi) = a.ranges[k];
            whole && (lo > hi || (lo >= -bias && hi < bias))
        })
        .collect();
    if m == 0 || (class.is_none() && !candidates.iter().any(|&w| w)) {
        return (None, candidates);
    }
    // Per block: the class histogram and each attribute's wholeness.
    type Seen = (Vec<u64>, Vec<bool>);
    let look = |rows: &[f32]| -> Seen {
        let mut hist = vec![0u64; if class.is_some() { 256 } else { 0 }];
        let mut w = candidates.clone();
        for row in rows.chunks_exact(m) {
            if let Some(c) = class.and_then(|j| crate::points::class_code(row[j])) {
                hist[c as usize] += 1;
            }
            for (k, v) in row.iter().enumerate() {
                // (A whole number below 2^23 is its own nearest, which the
                // magic-number rounding finds without a call.)
                w[k] &= v.is_nan() || (*v as f64) == round_half(*v as f64);
            }
        }
        (hist, w)
    };
    let merge = |x: Seen, y: Seen| -> Seen {
        (
            x.0.iter().zip(&y.0).map(|(p, q)| p + q).collect(),
            x.1.iter().zip(&y.1).map(|(p, q)| *p && *q).collect(),
        )
    };
    let empty = || -> Seen {
        (
            vec![0u64; if class.is_some() { 256 } else { 0 }],
            candidates.clone(),
        )
    };
    const BLOCK: usize = 1 << 16;
    let (hist, seen) = match &a.rows {
        Rows::Held(rows) => rows.par_chunks(m * BLOCK).map(look).reduce(empty, merge),
        Rows::Source(src) => (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|blk| {
                let idx: Vec<u32> = (blk * BLOCK..((blk + 1) * BLOCK).min(n))
                    .map(|i| i as u32)
                    .collect();
                let mut out = Vec::with_capacity(idx.len() * m);
                src.gather(&idx, &mut out);
                look(&out)
            })
            .reduce(empty, merge),
    };
    for (w, s) in candidates.iter_mut().zip(seen) {
        *w &= s;
    }
    let counts = class.map(|_| {
        hist.iter()
            .enumerate()
            .filter(|p| *p.1 > 0)
            .map(|(c, &k)| (c as u8, k))
            .collect()
    });
    (counts, candidates)
}

fn metadata_xml(a: &Arranged, opts: &WriteOptions, index: &[LevelIndex]) -> String {
    let g = a.geometry;
    let version = if a.rows_order || a.lattice.is_some() {
        spec::COMPACT_VERSION
    } else {
        spec::FIRST_VERSION
    };
    let mut items = vec![
        Item::dataset(key::FORMAT, version.to_string()),
        Item::dataset(key::POINT_COUNT, g.points.to_string()),
        Item::dataset(key::ORIGIN, metadata::f64s(&a.origin)),
        Item::dataset(key::BOUNDS_MIN, metadata::f64s(&a.bounds.min)),
        Item::dataset(key::BOUNDS_MAX, metadata::f64s(&a.bounds.max)),
        Item::dataset(
            key::LEVEL_POINTS,
            level_points(index)
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(" "),
        ),
        Item::dataset(key::LAYOUT, opts.layout.name()),
        Item::dataset(key::BANDS, a.names.join(" ")),
        Item::dataset(key::MAX_QUANTIZATION_ERROR, format!("{:e}", a.max_error)),
    ];
    if a.rows_order {
        items.push(Item::dataset(key::TILE_ORDER, spec::tile_order::ROWS));
        // (Filled in once the tiles are encoded: `level_bytes_item`.)
        items.push(Item::dataset(
            key::LEVEL_BYTES,
            level_bytes_item(&vec![0; g.levels()]),
        ));
    }
    if let Some(l) = &a.lattice {
        let mut v = l.source.step.to_vec();
        v.extend_from_slice(&l.source.origin);
        items.push(Item::dataset(key::LATTICE, metadata::f64s(&v)));
        if opts.lattice_round {
            items.push(Item::dataset(key::LATTICE_ROUNDED, "1".to_string()));
        }
    }
    let whole = whole_bands(a);
    if whole.iter().any(|&w| w) {
        let list: Vec<String> = (0..whole.len())
            .filter(|&b| whole[b])
            .map(|b| (b + 1).to_string())
            .collect();
        items.push(Item::dataset(key::WHOLE_BANDS, list.join(" ")));
    }
    if opts.compression.is_lerc() {
        items.push(Item::dataset(
            key::CODEC_MAX_ERROR,
            metadata::f64s(&codec_bound(opts)),
        ));
    }
    if let Some(s) = &opts.source {
        items.push(Item::dataset(key::SOURCE, s.clone()));
    }
    if let Some(c) = &opts.crs {
        items.push(Item::dataset(key::CRS, c.clone()));
    }
    if let Some(counts) = &a.class_counts {
        items.push(Item::dataset(
            key::CLASS_COUNTS,
            metadata::class_counts(counts),
        ));
    }
    for (k, v) in &opts.from_source {
        items.push(Item::dataset(k, v.clone()));
    }
    for (b, (lo, hi)) in stored_ranges(a).into_iter().enumerate() {
        if lo <= hi {
            items.push(Item::band_stat(
                key::STATISTICS_MINIMUM,
                b,
                format!("{lo:?}"),
            ));
            items.push(Item::band_stat(
                key::STATISTICS_MAXIMUM,
                b,
                format!("{hi:?}"),
            ));
        }
    }
    for (b, name) in a.names.iter().enumerate() {
        items.push(Item::band("DESCRIPTION", b, "description", name.clone()));
        if let Some(l) = a.lattice.as_ref().filter(|_| b < 3) {
            let zero = l.base[b] - l.step[b] * spec::WHOLE_BIAS;
            items.push(Item::band("OFFSET", b, "offset", format!("{zero:?}")));
            items.push(Item::band("SCALE", b, "scale", format!("{:?}", l.step[b])));
        } else if whole[b] {
            let zero = a.offsets[b] - spec::WHOLE_BIAS;
            items.push(Item::band("OFFSET", b, "offset", format!("{zero:?}")));
            items.push(Item::band("SCALE", b, "scale", "1"));
        } else if a.offsets[b] != 0.0 {
            items.push(Item::band(
                "OFFSET",
                b,
                "offset",
                format!("{:?}", a.offsets[b]),
            ));
            items.push(Item::band("SCALE", b, "scale", "1"));
        }
    }
    items.push(Item {
        domain: Some(key::TILE_INDEX_DOMAIN.into()),
        ..Item::dataset(key::TILE_INDEX, metadata::encode_tile_index(index))
    });
    metadata::to_xml(&items)
}

/// The [`key::LEVEL_BYTES`] item's value: fixed-width numbers, so the head's
/// length is known before the tiles are encoded and the item is filled in after.
fn level_bytes_item(bytes: &[u64]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:020}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Points per level, from the tile index.
fn level_points(index: &[LevelIndex]) -> Vec<u64> {
    index
        .iter()
        .map(|l| l.tiles.iter().map(|t| t.points as u64).sum())
        .collect()
}

/// Upper bound of the file size, to choose between classic TIFF and BigTIFF.
fn size_estimate(a: &Arranged, xml: &str) -> u64 {
    let g = a.geometry;
    let per_tile = TILE_BYTES * a.names.len() as u64;
    // Compressed tiles can exceed raw size slightly: allow 1%.
    let data: u64 = (0..g.levels())
        .map(|l| g.filled_tiles(l) * per_tile)
        .sum::<u64>()
        * 101
        / 100;
    let tags: u64 = (0..g.levels())
        .map(|l| (g.tiles_across(l) as u64).pow(2) * a.names.len() as u64 * 16 + 4096)
        .sum();
    data + tags + xml.len() as u64
}

/// `e`, with what is known of the file system holding `path` when it is full
/// (see [`pcimg_core::disk::full_note`]).
#[cfg(unix)]
pub(crate) fn full_note(e: std::io::Error, path: &Path, needed: Option<u64>) -> std::io::Error {
    pcimg_core::disk::with_full_note(e, path, needed)
}

#[cfg(not(unix))]
pub(crate) fn full_note(e: std::io::Error, _path: &Path, _needed: Option<u64>) -> std::io::Error {
    e
}

/// Removes the temporary file unless the write completed.
struct TempFile {
    path: PathBuf,
    done: bool,
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Writes `pts` as one part at `path` (replacing an existing file atomically).
pub fn write_part(path: &Path, pts: &PointColumns, opts: &WriteOptions) -> Result<PartSummary> {
    write_part_chunks(path, std::slice::from_ref(pts), opts)
}

/// Writes the points of consecutive `chunks` (a reader's windows, as read: no
/// copy into one set of columns) as one part at `path`. The chunks must have the
/// same attributes with the same offsets.
pub fn write_part_chunks(
    path: &Path,
    chunks: &[PointColumns],
    opts: &WriteOptions,
) -> Result<PartSummary> {
    let ph = Phases::new();
    let bounds = scan_bounds(path, chunks)?;
    let n = chunks.iter().map(|c| c.len()).sum();
    let mut part = PartBuilder::new(bounds.center(), None, n);
    for c in chunks {
        part.push(path, c)?;
    }
    write(path, part, ph, opts)
}

/// [`write_part_chunks`] taking the chunks: each is freed as soon as it is
/// converted, which lowers the peak memory and gives that memory to the sort
/// (reused pages are cheaper than fresh ones). `bounds`, when the caller has
/// them, save a pass over the coordinates; every point must lie inside them (it
/// is checked, and an error otherwise).
pub fn write_part_owned(
    path: &Path,
    chunks: Vec<PointColumns>,
    bounds: Option<Bounds>,
    opts: &WriteOptions,
) -> Result<PartSummary> {
    let ph = Phases::new();
    let expect = match bounds {
        Some(b) => b,
        None => scan_bounds(path, &chunks)?,
    };
    let n = chunks.iter().map(|c| c.len()).sum();
    let mut part = PartBuilder::new(expect.center(), bounds, n);
    part.push_all(path, chunks)?;
    write(path, part, ph, opts)
}

/// Writes the points collected in `part` as one part at `path` (replacing an
/// existing file atomically). `part`'s origin should be near the centre of its
/// points: f32 keeps 1 mm up to 32.7 km from it.
pub fn write_part_built(
    path: &Path,
    part: PartBuilder,
    opts: &WriteOptions,
) -> Result<PartSummary> {
    write(path, part, Phases::new(), opts)
}

fn write(
    path: &Path,
    part: PartBuilder,
    mut ph: Phases,
    opts: &WriteOptions,
) -> Result<PartSummary> {
    let stop = || {
        if opts.cancelled() {
            Err(StoreError::new(path, INTERRUPTED))
        } else {
            Ok(())
        }
    };
    // A write that failed because it was cancelled is reported as interrupted.
    // A full disk names its file system, and the part's size where it is known
    // (uncompressed: the tiles' bytes).
    let write_failed = |e: std::io::Error, needed: Option<u64>| {
        if opts.cancelled() {
            StoreError::new(path, INTERRUPTED)
        } else {
            let needed = needed.filter(|_| opts.compression == Compression::None);
            StoreError::new(
                path,
                format!("write failed: {}", full_note(e, path, needed)),
            )
        }
    };
    stop()?;
    let file_name = path
        .file_name()
        .ok_or_else(|| StoreError::new(path, "output path has no file name"))?;
    let tmp_path = path.with_file_name(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let mut tmp = TempFile {
        path: tmp_path.clone(),
        done: false,
    };
    let file = File::create(&tmp_path).map_err(|e| {
        StoreError::new(
            path,
            format!(
                "cannot create {}: {}",
                tmp_path.display(),
                full_note(e, path, None)
            ),
        )
    })?;
    let tiles = TileWriter::new(&file, &tmp_path, opts.io);
    // Uncompressed tiles of the Hilbert layout have their place in the file
    // before the rest is known: level 0 (three quarters of the file) is written
    // while the points are arranged, so the disk works while the CPU does.
    // They begin at the first disk block after the largest head the part can
    // have (its exact length waits for the metadata).
    let names: Vec<&str> = spec::COORDINATE_BANDS
        .iter()
        .copied()
        .chain(part.attributes.iter().map(|(a, _)| a.as_str()))
        .collect();
    let tiles_at = align_up(
        head_bound(part.count, &names, opts),
        out::DIRECT_ALIGN as u64,
    );
    if let Some(e) = opts
        .coord_max_error
        .iter()
        .find(|e| !e.is_finite() || **e < 0.0)
    {
        return Err(StoreError::new(
            path,
            format!("the coordinates' error bound {e} is not a finite number >= 0"),
        ));
    }
    let part_bytes = part.count as u64 * names.len() as u64 * 4;
    let mut a = if opts.layout == Layout::Hilbert && opts.compression == Compression::None {
        let cancelled = || opts.cancelled();
        let (a, written) = sink::with_sink(&tiles, &cancelled, |sink| {
            arrange(path, part, opts, &mut ph, Some(sink), tiles_at)
        });
        let a = a?;
        // (Level 0 and the coarser levels, a third more: the tiles' bytes.)
        let rough = tiles_at + part_bytes * 4 / 3;
        written.map_err(|e| write_failed(e, Some(rough)))?;
        ph.mark("levels written");
        a
    } else {
        arrange(path, part, opts, &mut ph, None, tiles_at)?
    };
    // Lossless predictor codecs store tiles in row order, and coordinates on
    // the input's lattice where every point lies on it (format version 2;
    // `arrange` checked each tile against it).
    if a.layout == Layout::Hilbert && opts.compression.row_ordered() {
        a.rows_order = true;
        if let Some(l) = a.lattice.filter(|_| opts.lattice_round) {
            let half = l.step.iter().map(|s| s.abs() / 2.0).fold(0.0, f64::max);
            a.max_error += half;
        }
    }
    // A lossy codec adds its bound, and the f32 rounding of what it gives back,
    // to f32's.
    let lossy = codec_bound(opts).into_iter().fold(0.0, f64::max);
    if lossy > 0.0 {
        a.max_error = 2.0 * a.max_error + lossy;
    }
    stop()?;
    if opts.release_pool {
        crate::alloc::release_pool();
    }
    (a.class_counts, a.whole) = attribute_pass(&a, a.rows_order);
    ph.mark("attributes");
    let index = tile_index(&a);
    let xml = metadata_xml(&a, opts, &index);
    ph.mark("tile index");
    let bigtiff = opts.force_bigtiff || size_estimate(&a, &xml) >= u32::MAX as u64 - (64 << 20);
    let (bytes, head) = encode(&file, &tiles, &a, opts, &xml, &index, bigtiff, tiles_at)
        .map_err(|e| write_failed(e, Some(size_estimate(&a, &xml))))?;
    let direct = tiles.is_direct();
    drop(tiles);
    drop(file);
    ph.mark("tiles+write");
    stop()?;
    std::fs::rename(&tmp_path, path).map_err(|e| {
        StoreError::new(
            path,
            format!("cannot rename the finished file into place: {e}"),
        )
    })?;
    tmp.done = true;
    ph.mark("rename");
    let g = a.geometry;
    Ok(PartSummary {
        path: path.to_path_buf(),
        points: g.points,
        level_points: level_points(&index),
        bytes,
        head,
        bounds: a.bounds,
        origin: a.origin,
        max_quantization_error: a.max_error,
        bigtiff,
        direct,
        rows_from_input: matches!(a.rows, Rows::Source(_)),
        lattice: a.lattice.map(|l| l.source),
        phases: ph.list,
    })
}

/// A tile ready to be written: raw samples (native order) or encoded bytes, or
/// why it could not be encoded.
enum Encoded {
    Raw(TileBuf),
    Bytes(Vec<u8>),
    Failed(String),
}

/// Tiles encoded per parallel batch (bounds memory: about three batches of
/// batch × bands × 256 KiB are alive at once).
const BATCH_TILES: usize = 8;

/// Encodes job `group` (see [`groups`]) of tile `t` (Z-rank; `raster`: its raster
/// index) at `level`: its bands and their tiles.
#[allow(clippy::too_many_arguments)]
fn encode_job(
    a: &Arranged,
    lut: &[u32],
    level: usize,
    (t, raster): (usize, u32),
    group: usize,
    compression: Compression,
    coord_max_error: [f64; 3],
    zstd_level: i32,
) -> Vec<(usize, Encoded)> {
    let g = a.geometry;
    let count = g.tile_points(level, t as u64) as usize;
    let stride = 1usize << (2 * level);
    let base = t * TILE_PIXELS;
    let m = a.m;
    let done = |b: usize, buf: TileBuf| match compression {
        Compression::None => Encoded::Raw(buf),
        c => {
            let e = coord_max_error.get(b).copied().unwrap_or(0.0);
            match codec::encode(&buf, TILE_SIZE as usize, c, e, zstd_level, a.fast(b)) {
                Ok(v) => Encoded::Bytes(v),
                Err(m) => Encoded::Failed(format!("level {level} tile {t} band {}: {m}", b + 1)),
            }
        }
    };
    if a.layout == Layout::Paper {
        // The paper's layout: input order, row-major (`paper.rs`).
        if group < 3 {
            let buf = paper::tile_pixels(|i| a.pos[i][group], g, level, raster);
            return vec![(group, done(group, buf))];
        }
        // The tile's rows (runs of neighbouring points, in input order), then
        // each band placed from them.
        let (mut pixels, mut idx) = (Vec::new(), Vec::new());
        paper::tile_sources(g, level, raster, |px, i| {
            pixels.push(px as u32);
            idx.push(i as u32);
        });
        let mut rows = Vec::with_capacity(idx.len() * m);
        a.rows.gather(&idx, m, &mut rows);
        return (0..m)
            .map(|k| {
                let buf = scatter_tile(&pixels, pixels.len(), |j| rows[j * m + k]);
                (3 + k, done(3 + k, buf))
            })
            .collect();
    }
    let at = |i: usize| a.slot((base + i) * stride);
    let (pos, perm) = (&a.pos, &a.perm);
    let mut rows = Vec::new();
    if group >= 3 {
        rows.reserve(count * m);
        let idx: Vec<u32> = (0..count).map(|i| perm[at(i)]).collect();
        a.rows.gather(&idx, m, &mut rows);
    }
    hilbert_bands(lut, count, group, |i| pos[at(i)], &rows, m)
        .into_iter()
        .map(|(b, buf)| (b, done(b, buf)))
        .collect()
}

/// Encodes tile `t` (Z-rank) of `level` in row order (format version 2): its
/// points in the order [`tile_order`] chooses, row-major from the first pixel,
/// coordinates as whole numbers where the part has a lattice; every band.
fn rows_tile(
    a: &Arranged,
    level: usize,
    t: usize,
    compression: Compression,
    zstd_level: i32,
) -> Vec<(usize, Encoded)> {
    let g = a.geometry;
    let count = g.tile_points(level, t as u64) as usize;
    let stride = 1usize << (2 * level);
    let first = t * TILE_PIXELS;
    let m = a.m;
    let slots: Vec<usize> = (0..count).map(|i| a.slot((first + i) * stride)).collect();
    let idx: Vec<u32> = slots.iter().map(|&s| a.perm[s]).collect();
    // The tile's positions in level order, read once from the part's (the
    // order's steps and the coordinate bands then read this copy).
    let pos: Vec<[f32; 3]> = slots.iter().map(|&s| a.pos[s]).collect();
    drop(slots);
    let order = tile_order(&idx, &pos);
    let mut bufs: Vec<TileBuf> = (0..3 + m).map(|_| TileBuf::for_points(count)).collect();
    let (xyz, attrs) = bufs.split_at_mut(3);
    // The attribute bands gathered in the tile's order, straight into their
    // tiles: in input order, that reads the reader's rows (a LAS file's
    // records) nearly in sequence.
    if m > 0 {
        let at: Vec<u32> = order.iter().map(|&i| idx[i as usize]).collect();
        let mut cols: Vec<&mut [f32]> = attrs.iter_mut().map(|b| &mut b[..count]).collect();
        a.rows.gather_columns(&at, m, &mut cols);
    }
    let maps = a
        .lattice
        .map(|l| [0, 1, 2].map(|b| l.stored_map(b, a.origin[b])));
    for (j, &i) in order.iter().enumerate() {
        let p = pos[i as usize];
        for b in 0..3 {
            xyz[b][j] = match &maps {
                // (`fit` checked that every point lies on the lattice, so
                // its nearest lattice point is its own.)
                Some(mp) => round_half(p[b] as f64 * mp[b].0 + mp[b].1) as f32,
                None => p[b],
            };
        }
    }
    for (k, buf) in attrs.iter_mut().enumerate() {
        // The coarser levels keep GPS time to its Float32 (`gps_time`): the
        // whole numbers that make it exact are NaN there (in their order they
        // would cost four bytes a point; `pcimg_core::time`).
        if level > 0 && pcimg_core::time::is_exact_band(&a.names[3 + k]) {
            buf.fill(f32::NAN);
        } else if a.whole[k] {
            let bias = spec::WHOLE_BIAS as f32;
            for v in &mut buf[..count] {
                *v += bias;
            }
        }
    }
    bufs.into_par_iter()
        .enumerate()
        .map(|(b, buf)| {
            let fast = a.fast(b);
            let e =
                match codec::encode(&buf, TILE_SIZE as usize, compression, 0.0, zstd_level, fast) {
                    Ok(v) => Encoded::Bytes(v),
                    Err(msg) => {
                        Encoded::Failed(format!("level {level} tile {t} band {}: {msg}", b + 1))
                    }
                };
            (b, e)
        })
        .collect()
}

/// The whole number nearest `v` (`|v|` below 2^51), ties to even, by adding
/// and taking away 1.5 · 2^52 (no call to `round`, which x86-64's baseline
/// has no instruction for).
#[inline(always)]
fn round_half(v: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    (v + MAGIC) - MAGIC
}

/// The order in which a row-ordered tile keeps its points (indices into the
/// tile's points, which come in level order: `pos` their positions, `idx`
/// their input indices). Each row is differenced by the TIFF
/// predictor, so the order should make neighbours alike: the input's order
/// (a scanner's: points recorded one after another lie close, and their times,
/// colours and intensities change little) unless it takes more than twice the
/// steps between consecutive points that the level order takes (an input in
/// no useful order: tens of times more), else the level order. Twice, not
/// once: a coarser level's points in input order take about 1.5 times the
/// level order's steps (a scan line's end jumps back across the tile), yet
/// their times, returns and flags change so much less that the tile is
/// smaller (on `autzen_trim`, level 1 took 3.3 % less; bench/RESULTS.md,
/// "Compact storage").
fn tile_order(idx: &[u32], pos: &[[f32; 3]]) -> Vec<u32> {
    let input = radix_order(idx);
    let level = steps(pos, pos.len(), |j| j);
    if steps(pos, input.len(), |j| input[j] as usize) < 2.0 * level {
        input
    } else {
        (0..pos.len() as u32).collect()
    }
}

/// The sum of the steps (|dx| + |dy| + |dz|) between consecutive points of
/// `pos` taken in the order `at(0), at(1), ...at(n - 1)`.
fn steps(pos: &[[f32; 3]], n: usize, at: impl Fn(usize) -> usize) -> f64 {
    let mut sum = 0.0f64;
    if n == 0 {
        return sum;
    }
    let mut q = pos[at(0)];
    for i in 1..n {
        let p = pos[at(i)];
        sum += ((p[0] - q[0]).abs() + (p[1] - q[1]).abs() + (p[2] - q[2]).abs()) as f64;
        q = p;
    }
    sum
}

/// The stable order of `keys` ascending (indices into it), by a least
/// significant digit radix sort of 11-bit digits of each key less the least,
/// carried with its index in one `u64` (read in sequence, where sorting
/// indices by their keys read the keys at random): a tile's 65,536 input
/// indices span a few million at most, two or three passes after one that
/// counts every digit, where a comparison sort took about ten times as long.
fn radix_order(keys: &[u32]) -> Vec<u32> {
    const BITS: u32 = 11;
    const DIGITS: usize = 3; // 33 bits: any u32
    let n = keys.len();
    let least = keys.iter().copied().min().unwrap_or(0);
    let mut count = vec![[0u32; 1 << BITS]; DIGITS];
    for &k in keys {
        let k = k - least;
        for (d, c) in count.iter_mut().enumerate() {
            c[((k >> (BITS * d as u32)) & ((1 << BITS) - 1)) as usize] += 1;
        }
    }
    let mut a: Vec<u64> = keys
        .iter()
        .enumerate()
        .map(|(i, &k)| (u64::from(k - least) << 32) | i as u64)
        .collect();
    let mut b = vec![0u64; n];
    for (d, c) in count.iter().enumerate() {
        // A pass whose digit is the same for every key moves nothing.
        if c.iter().any(|&x| x as usize == n) {
            continue;
        }
        let mut at = vec![0u32; 1 << BITS];
        let mut sum = 0u32;
        for (s, &x) in at.iter_mut().zip(c) {
            *s = sum;
            sum += x;
        }
        let shift = 32 + BITS * d as u32;
        for &v in &a {
            let digit = ((v >> shift) & ((1 << BITS) - 1)) as usize;
            b[at[digit] as usize] = v;
            at[digit] += 1;
        }
        std::mem::swap(&mut a, &mut b);
    }
    a.into_iter().map(|v| v as u32).collect()
}

/// The directory of `level`, its tile offsets and byte counts given.
#[allow(clippy::too_many_arguments)]
fn directory(
    a: &Arranged,
    opts: &WriteOptions,
    xml: &str,
    software: &str,
    level: usize,
    offsets: &[u64],
    counts: &[u64],
    big: bool,
) -> Dir {
    let nb = a.names.len();
    let size = a.geometry.size(level);
    let mut d: Dir = vec![
        (tag::IMAGE_WIDTH, Value::Long(vec![size])),
        (tag::IMAGE_LENGTH, Value::Long(vec![size])),
        (tag::BITS_PER_SAMPLE, Value::Short(vec![32; nb])),
        (
            tag::COMPRESSION,
            Value::Short(vec![opts.compression.tiff_code()]),
        ),
        (tag::PHOTOMETRIC, Value::Short(vec![1])),
        (tag::SAMPLES_PER_PIXEL, Value::Short(vec![nb as u16])),
        (tag::PLANAR_CONFIGURATION, Value::Short(vec![2])),
        (tag::SOFTWARE, Value::Ascii(software.into())),
        (tag::TILE_WIDTH, Value::Long(vec![TILE_SIZE])),
        (tag::TILE_LENGTH, Value::Long(vec![TILE_SIZE])),
        (tag::SAMPLE_FORMAT, Value::Short(vec![3; nb])),
        (tag::GDAL_NODATA, Value::Ascii("nan".into())),
    ];
    if big {
        d.push((tag::TILE_OFFSETS, Value::Long8(offsets.to_vec())));
        d.push((tag::TILE_BYTE_COUNTS, Value::Long8(counts.to_vec())));
    } else {
        let long = |v: &[u64]| Value::Long(v.iter().map(|&x| x as u32).collect());
        d.push((tag::TILE_OFFSETS, long(offsets)));
        d.push((tag::TILE_BYTE_COUNTS, long(counts)));
    }
    if level > 0 {
        d.push((tag::NEW_SUBFILE_TYPE, Value::Long(vec![1])));
    }
    if opts.compression.predictor() != spec::predictor::NONE {
        d.push((
            tag::PREDICTOR,
            Value::Short(vec![opts.compression.predictor()]),
        ));
    }
    if let Some(p) = opts.compression.lerc_parameters() {
        d.push((tag::LERC_PARAMETERS, Value::Long(p.to_vec())));
    }
    if nb > 1 {
        d.push((tag::EXTRA_SAMPLES, Value::Short(vec![0; nb - 1])));
    }
    if level == 0 {
        d.push((tag::GDAL_METADATA, Value::Ascii(xml.into())));
    }
    d
}

/// The `Software` tag's text.
fn software() -> String {
    format!("{} {}", spec::SOFTWARE_PREFIX, env!("CARGO_PKG_VERSION"))
}

/// An upper bound of the head's length (BigTIFF, the largest) for a part of
/// `n` points whose bands are named `names`, before the points are arranged:
/// uncompressed tiles are written from the next disk block on while they are.
/// Every tag's count is known; the metadata's length is bounded from what it
/// holds (the tile index exactly, the rest generously).
fn head_bound(n: usize, names: &[&str], opts: &WriteOptions) -> u64 {
    let g = Geometry::for_part(n as u64, opts.shallow_coarsest);
    let nb = names.len();
    // The tile index: a header, per level a header and 56 bytes a tile, base64.
    let index: u64 = 12
        + (0..g.levels())
            .map(|l| 12 + 56 * g.filled_tiles(l))
            .sum::<u64>();
    // Text values are escaped twice (`&` becomes `&amp;amp;`): at most 10 bytes
    // a byte.
    let text: u64 = [&opts.source, &opts.crs]
        .iter()
        .filter_map(|s| s.as_ref().map(|s| s.len() as u64))
        .chain(
            opts.from_source
                .iter()
                .map(|(k, v)| (k.len() + v.len()) as u64 + 100),
        )
        .sum::<u64>()
        * 10;
    let bands: u64 = names.iter().map(|s| 700 + 10 * s.len() as u64).sum();
    // Classification counts: at most 256 `code:count` pairs.
    let classes = 256 * 26;
    let xml = 16384 + index.div_ceil(3) * 4 + text + bands + classes;
    let dirs: Vec<Dir> = (0..g.levels())
        .map(|level| {
            let across = g.tiles_across(level) as usize;
            let zeros = vec![0u64; across * across * nb];
            let mut d = vec![
                (tag::TILE_OFFSETS, Value::Long8(zeros.clone())),
                (tag::TILE_BYTE_COUNTS, Value::Long8(zeros)),
                (tag::BITS_PER_SAMPLE, Value::Short(vec![32; nb])),
                (tag::SAMPLE_FORMAT, Value::Short(vec![3; nb])),
                (tag::EXTRA_SAMPLES, Value::Short(vec![0; nb])),
                (tag::SOFTWARE, Value::Ascii(software())),
                (tag::GDAL_NODATA, Value::Ascii("nan".into())),
            ];
            // The other tags are inline: 12 of them at most.
            for t in 0..12 {
                d.push((t, Value::Short(vec![0])));
            }
            if level == 0 {
                d.push((tag::GDAL_METADATA, Value::Ascii("x".repeat(xml as usize))));
            }
            d
        })
        .collect();
    Head { big: true, dirs }.len()
}

fn align_up(v: u64, to: u64) -> u64 {
    v.div_ceil(to) * to
}

/// Writes every level's tiles after the head, then the head (every directory,
/// tile offsets and byte counts and the metadata) at the start of the file.
/// Uncompressed tiles begin at `tiles_at` when they were written while the
/// points were arranged, else at the first disk block after the head;
/// compressed ones right after it. Returns the file's length and the head's.
#[allow(clippy::too_many_arguments)]
fn encode(
    file: &File,
    tile_writer: &TileWriter,
    a: &Arranged,
    opts: &WriteOptions,
    xml: &str,
    index: &[LevelIndex],
    big: bool,
    tiles_at: u64,
) -> std::io::Result<(u64, u64)> {
    let g = a.geometry;
    let nb = a.names.len();
    let lut = tile_z_to_raster(spec::TILE_LOG2);
    let software = software();
    let per_band = |level: usize| (g.tiles_across(level) as usize).pow(2);
    let mut offsets: Vec<Vec<u64>> = (0..g.levels())
        .map(|l| vec![0u64; per_band(l) * nb])
        .collect();
    let mut counts = offsets.clone();
    let head_of = |xml: &str, offsets: &[Vec<u64>], counts: &[Vec<u64>]| Head {
        big,
        dirs: (0..g.levels())
            .map(|l| directory(a, opts, xml, &software, l, &offsets[l], &counts[l], big))
            .collect(),
    };
    // The head's length depends only on the counts of its values.
    let head_len = head_of(xml, &offsets, &counts).len();
    let level_tiles = |k: usize| index[k].tiles.len() as u64;
    let end = if opts.compression == Compression::None {
        // Every tile is TILE_PIXELS samples: every level's tile data lies in one
        // region, the coarsest first ([`region_start`]: tile t's band b at slot
        // t * nb + b of its level's region), encoded and written by the rayon
        // pool. They may have been written already, while the points were
        // arranged: the slot of level k's image tile t is then
        // tile_order[t * 4^k] / 4^k.
        let first = if a.levels_written {
            tiles_at
        } else {
            align_up(head_len, out::DIRECT_ALIGN as u64)
        };
        if head_len > first {
            return Err(std::io::Error::other(format!(
                "the head ({head_len} bytes) outgrew the {first} bytes reserved for it"
            )));
        }
        for level in 0..g.levels() {
            let tiles = &index[level].tiles;
            let filled = tiles.len();
            let start = region_start(level_tiles, nb, first, g.levels(), level);
            let written = a.levels_written;
            let per_tile = groups(a.m);
            let cancelled = || opts.cancelled();
            let jobs = if written { 0 } else { filled * per_tile };
            sink::write_tiles(
                tile_writer,
                &cancelled,
                (0..jobs).into_par_iter().map(|j| {
                    let (t, group) = (j / per_tile, j % per_tile);
                    let tile = (t, tiles[t].index);
                    encode_job(
                        a,
                        &lut,
                        level,
                        tile,
                        group,
                        Compression::None,
                        [0.0; 3],
                        codec::ZSTD_FAST,
                    )
                    .into_iter()
                    .map(move |(b, e)| {
                        let Encoded::Raw(v) = e else {
                            unreachable!("uncompressed tiles are raw")
                        };
                        (start + (t * nb + b) as u64 * TILE_BYTES, v)
                    })
                    .collect::<Vec<_>>()
                }),
            )?;
            let pb = per_band(level);
            for (t, tile) in tiles.iter().enumerate() {
                let slot = if written {
                    a.stored_tile(t << (2 * level)) >> (2 * level)
                } else {
                    t
                };
                for b in 0..nb {
                    let r = tile.index as usize;
                    offsets[level][b * pb + r] = start + (slot * nb + b) as u64 * TILE_BYTES;
                    counts[level][b * pb + r] = TILE_BYTES;
                }
            }
        }
        region_start(level_tiles, nb, first, g.levels(), g.levels())
    } else {
        // Compressed tiles (sizes known once encoded) follow the head, the
        // coarsest level's first, each level's aligned to 8 bytes so readers can
        // view planes in place.
        let mut w = out::StreamOut::new(file, tile_writer, head_len)?;
        for level in (0..g.levels()).rev() {
            let at = w.stream_position()?;
            if at % 8 != 0 {
                w.write_all(&[0u8; 8][..(8 - at % 8) as usize])?;
            }
            encode_batches(
                &mut w,
                opts,
                a,
                &lut,
                level,
                &index[level].tiles,
                opts.compression,
                &mut offsets[level],
                &mut counts[level],
            )?;
        }
        w.finish()?
    };
    if !big && end > u32::MAX as u64 {
        return Err(std::io::Error::other(
            "the file outgrew classic TIFF's 4 GiB (BigTIFF was not chosen)",
        ));
    }
    // Row-ordered parts record each level's stored bytes, now known (the
    // item's width is fixed: the head keeps its length).
    let xml = if a.rows_order {
        let was = format!(">{}<", level_bytes_item(&vec![0; g.levels()]));
        let now = format!(
            ">{}<",
            level_bytes_item(&counts.iter().map(|c| c.iter().sum()).collect::<Vec<u64>>())
        );
        xml.replacen(&was, &now, 1)
    } else {
        xml.to_string()
    };
    let head = head_of(&xml, &offsets, &counts).to_bytes();
    debug_assert_eq!(head.len() as u64, head_len);
    out::write_all_at(file, &head, 0)?;
    file.set_len(end)?;
    Ok((end, head_len))
}

/// Compressed tiles (sizes known only once encoded): encoded in batches on the
/// rayon pool by a producer thread while this thread writes the previous batch,
/// so encoding and the writes (into the page cache or around it) overlap.
#[allow(clippy::too_many_arguments)]
fn encode_batches(
    w: &mut out::StreamOut,
    opts: &WriteOptions,
    a: &Arranged,
    lut: &[u32],
    level: usize,
    tiles: &[TileEntry],
    compression: Compression,
    offsets: &mut [u64],
    counts: &mut [u64],
) -> std::io::Result<()> {
    let nb = a.names.len();
    let per_band = offsets.len() / nb;
    let filled = tiles.len();
    let zstd_level = opts.zstd_level_used();
    let encode = |start: usize| -> Vec<(usize, usize, Encoded)> {
        let end = (start + BATCH_TILES).min(filled);
        if a.rows_order {
            let encoded: Vec<Vec<(usize, usize, Encoded)>> = (start..end)
                .into_par_iter()
                .map(|t| {
                    rows_tile(a, level, t, compression, zstd_level)
                        .into_iter()
                        .map(|(b, e)| (t, b, e))
                        .collect()
                })
                .collect();
            return encoded.into_iter().flatten().collect();
        }
        let per_tile = groups(a.m);
        let jobs: Vec<(usize, usize)> = (start..end)
            .flat_map(|t| (0..per_tile).map(move |g| (t, g)))
            .collect();
        let encoded: Vec<Vec<(usize, usize, Encoded)>> = jobs
            .into_par_iter()
            .map(|(t, group)| {
                let tile = (t, tiles[t].index);
                encode_job(
                    a,
                    lut,
                    level,
                    tile,
                    group,
                    compression,
                    opts.coord_max_error,
                    zstd_level,
                )
                .into_iter()
                .map(|(b, e)| (t, b, e))
                .collect()
            })
            .collect();
        encoded.into_iter().flatten().collect()
    };
    let mut write = |batch: Vec<(usize, usize, Encoded)>| -> std::io::Result<()> {
        if opts.cancelled() {
            return Err(std::io::Error::from(std::io::ErrorKind::Interrupted));
        }
        for (t, b, e) in &batch {
            let bytes: &[u8] = match e {
                Encoded::Raw(v) => bytemuck::cast_slice(&v[..]),
                Encoded::Bytes(v) => v,
                Encoded::Failed(m) => return Err(std::io::Error::other(m.clone())),
            };
            let r = tiles[*t].index as usize;
            offsets[b * per_band + r] = w.stream_position()?;
            w.write_all(bytes)?;
            counts[b * per_band + r] = bytes.len() as u64;
        }
        Ok(())
    };
    // On a rayon worker (parts or overview nodes written in parallel), the
    // worker must not block on a channel fed by jobs queued on its own pool:
    // with every worker so blocked, nothing would run them. There the batches
    // are encoded in turn (the encoding itself still spreads over the pool).
    if rayon::current_thread_index().is_some() {
        for start in (0..filled).step_by(BATCH_TILES) {
            write(encode(start))?;
        }
        return Ok(());
    }
    std::thread::scope(|scope| -> std::io::Result<()> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<(usize, usize, Encoded)>>(1);
        scope.spawn(move || {
            for start in (0..filled).step_by(BATCH_TILES) {
                if tx.send(encode(start)).is_err() {
                    return; // the writer failed and stopped listening
                }
            }
        });
        for batch in rx {
            write(batch)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radix order is the stable sort's, for keys alike in some digits.
    #[test]
    fn radix_order_is_the_stable_sort() {
        let mut rng = crate::rng::Rng::new(7);
        for n in [0usize, 1, 2, 1000, 65_536] {
            for spread in [1u32, 256, 1 << 20, u32::MAX] {
                let keys: Vec<u32> = (0..n)
                    .map(|_| (rng.next_u64() as u32) % spread.max(1))
                    .collect();
                let mut want: Vec<u32> = (0..n as u32).collect();
                want.sort_by_key(|&i| keys[i as usize]);
                assert_eq!(radix_order(&keys), want, "{n} keys below {spread}");
            }
        }
    }

    /// Rows kept in a `Vec`, given again on demand.
    struct VecRows(Vec<f32>, usize);

    impl RowSource for VecRows {
        fn len(&self) -> usize {
            self.0.len() / self.1
        }
        fn width(&self) -> usize {
            self.1
        }
        fn gather(&self, idx: &[u32], out: &mut Vec<f32>) {
            for &i in idx {
                let r = i as usize * self.1;
                out.extend_from_slice(&self.0[r..r + self.1]);
            }
        }
    }

    /// Rows and positions given again from `f64` coordinates, as a LAS file's map
    /// gives them.
    struct PosRows(VecRows, [Vec<f64>; 3]);

    impl RowSource for PosRows {
        fn len(&self) -> usize {
            self.0.len()
        }
        fn width(&self) -> usize {
            self.0.width()
        }
        fn gather(&self, idx: &[u32], out: &mut Vec<f32>) {
            self.0.gather(idx, out)
        }
        fn has_positions(&self) -> bool {
            true
        }
        fn positions(&self, idx: &[u32], origin: [f64; 3], out: &mut Vec<[f32; 3]>) {
            let c = &self.1;
            out.extend(idx.iter().map(|&i| {
                let i = i as usize;
                [0, 1, 2].map(|a| (c[a][i] - origin[a]) as f32)
            }));
        }
        fn positions_in(
            &self,
            range: std::ops::Range<usize>,
            origin: [f64; 3],
            out: &mut Vec<[f32; 3]>,
        ) {
            let idx: Vec<u32> = range.map(|i| i as u32).collect();
            self.positions(&idx, origin, out);
        }
    }

    /// Rows that raise a cancel flag once the writer starts gathering them: for
    /// a Hilbert part, while level 0 is written during the arrangement.
    struct CancellingRows(VecRows, Arc<AtomicBool>);

    impl RowSource for CancellingRows {
        fn len(&self) -> usize {
            self.0.len()
        }
        fn width(&self) -> usize {
            self.0.width()
        }
        fn gather(&self, idx: &[u32], out: &mut Vec<f32>) {
            self.1.store(true, Ordering::Relaxed);
            self.0.gather(idx, out)
        }
    }

    /// The lattice is kept only where every point of every tile lies on it:
    /// one point of a part of several tiles a third of a step off, and the
    /// part stores its coordinates as without one; `lattice_round` keeps it,
    /// that point within half a step. Either way the points come back.
    #[test]
    fn one_point_off_the_lattice_drops_it() {
        let dir = tempfile::tempdir().unwrap();
        let n = 3 * TILE_PIXELS + 7;
        let mut r = crate::rng::Rng::new(8);
        let mut c = PointColumns::default();
        for _ in 0..n {
            c.x.push(1000.0 + (r.f64() * 10_000.0).round() * 0.01);
            c.y.push(2000.0 + (r.f64() * 10_000.0).round() * 0.01);
            c.z.push((r.f64() * 1000.0).round() * 0.01);
        }
        let lattice = crate::points::Lattice {
            step: [0.01; 3],
            origin: [0.0; 3],
        };
        let write = |c: &PointColumns, round: bool, name: &str| {
            let opts = WriteOptions {
                compression: Compression::Zstd,
                lattice: Some(lattice),
                lattice_round: round,
                ..WriteOptions::default()
            };
            let path = dir.path().join(name);
            (write_part(&path, c, &opts).unwrap(), path)
        };
        let (on, _) = write(&c, false, "on.tif");
        assert!(on.lattice.is_some());
        let mut off = c.clone();
        off.x[n - 1] += 0.0033;
        let (dropped, path) = write(&off, false, "off.tif");
        assert!(dropped.lattice.is_none(), "a point off the lattice kept it");
        let (rounded, rpath) = write(&off, true, "round.tif");
        assert!(rounded.lattice.is_some());
        for (p, err) in [(path, 1e-3), (rpath, 0.005 + 1e-3)] {
            let part = crate::Part::open(&p).unwrap();
            let got = part.read_level(0, &[0]).unwrap();
            let x0 = got.offsets[0];
            let mut xs: Vec<f64> = got.columns[0].iter().map(|&v| x0 + v as f64).collect();
            let mut want = off.x.clone();
            xs.sort_by(f64::total_cmp);
            want.sort_by(f64::total_cmp);
            for (a, b) in xs.iter().zip(&want) {
                assert!((a - b).abs() <= err, "{a} against {b}");
            }
        }
    }

    /// Points at UTM-sized coordinates on a 1 mm lattice keep it, those within
    /// a few millimetres of the part's origin too: there the source's f64 sums
    /// (`offset + scale · X`) round by more than an f32's spacing (the check
    /// allowed only the latter, and dropped the lattice of such a part).
    #[test]
    fn points_near_the_origin_at_utm_coordinates_keep_a_fine_lattice() {
        let dir = tempfile::tempdir().unwrap();
        let lattice = crate::points::Lattice {
            step: [0.001; 3],
            origin: [500_000.0, 4_000_000.0, 0.0],
        };
        let at = |k: [i64; 3]| -> [f64; 3] {
            [0, 1, 2].map(|a| lattice.origin[a] + lattice.step[a] * k[a] as f64)
        };
        let mut r = crate::rng::Rng::new(5);
        let mut c = PointColumns::default();
        let mut push = |k: [i64; 3]| {
            let p = at(k);
            c.x.push(p[0]);
            c.y.push(p[1]);
            c.z.push(p[2]);
        };
        // The bounds, so that their centre (the part's origin) is half a step
        // off the lattice on every axis: 4,000,500.0015 m in y.
        let (lo, hi) = (
            [201_500_000, 499_500, 49_950],
            [201_620_003, 500_503, 50_051],
        );
        push(lo);
        push(hi);
        // Points within 0.5 to 3.5 mm of the origin, and more around them.
        for i in 0..64i64 {
            let d = (i % 8) - 4 + 1;
            push(
                [0, 1, 2]
                    .map(|a| (lo[a] + hi[a] + 1) / 2 + if i / 8 % 3 == a as i64 { d } else { 0 }),
            );
        }
        for _ in 0..20_000 {
            push([0, 1, 2].map(|a| lo[a] + (r.f64() * (hi[a] - lo[a]) as f64) as i64));
        }
        let opts = WriteOptions {
            compression: Compression::Zstd,
            lattice: Some(lattice),
            ..WriteOptions::default()
        };
        let path = dir.path().join("utm.tif");
        let s = write_part(&path, &c, &opts).unwrap();
        assert!(s.lattice.is_some(), "a part on a 1 mm lattice lost it");
        // Every point comes back on the lattice: the nearest lattice point to
        // what is read is the source's.
        let part = crate::Part::open(&path).unwrap();
        let got = part.read_level(0, &[0, 1, 2]).unwrap();
        let mut back: Vec<[i64; 3]> = (0..got.len())
            .map(|i| {
                [0, 1, 2].map(|a| {
                    let v = got.offsets[a] + got.columns[a][i] as f64;
                    ((v - lattice.origin[a]) / lattice.step[a]).round() as i64
                })
            })
            .collect();
        let mut want: Vec<[i64; 3]> = (0..c.len())
            .map(|i| {
                let p = [c.x[i], c.y[i], c.z[i]];
                [0, 1, 2].map(|a| ((p[a] - lattice.origin[a]) / lattice.step[a]).round() as i64)
            })
            .collect();
        back.sort_unstable();
        want.sort_unstable();
        assert_eq!(back, want);
    }

    /// Ctrl-C while level 0 is being written (the points still being arranged)
    /// stops the write as interrupted and leaves no file, temporary or final.
    #[test]
    fn a_write_cancelled_while_arranging_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let n = 5 * TILE_PIXELS + 99;
        let mut r = crate::rng::Rng::new(4);
        let mut c = PointColumns::default();
        for _ in 0..n {
            c.x.push(r.f64() * 100.0);
            c.y.push(r.f64() * 100.0);
            c.z.push(r.f64());
        }
        c.attributes
            .push(crate::points::Attribute::new("intensity", vec![1.0; n]));
        let cancel = Arc::new(AtomicBool::new(false));
        let opts = WriteOptions {
            cancel: Some(cancel.clone()),
            ..WriteOptions::default()
        };
        let path = dir.path().join("part.tif");
        let mut b = PartBuilder::new([50.0, 50.0, 0.5], None, n);
        b.rows_from(Arc::new(CancellingRows(
            VecRows(vec![1.0; n], 1),
            cancel.clone(),
        )));
        b.push(&path, &c).unwrap();
        let e = write_part_built(&path, b, &opts).unwrap_err();
        assert!(e.to_string().contains(INTERRUPTED), "{e}");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert!(left.is_empty(), "{left:?}");
    }

    /// A part whose rows come from a [`RowSource`] is the same file, byte for
    /// byte, as one holding them, in either layout; a source of another length is
    /// an error naming the part.
    #[test]
    fn rows_from_a_source_write_the_same_file() {
        let dir = tempfile::tempdir().unwrap();
        let n = 70_000;
        let mut r = crate::rng::Rng::new(5);
        let mut c = PointColumns {
            x: (0..n).map(|_| 1000.0 + r.f64() * 50.0).collect(),
            y: (0..n).map(|_| 2000.0 + r.f64() * 50.0).collect(),
            z: (0..n).map(|_| r.f64() * 10.0).collect(),
            attributes: Vec::new(),
        };
        for (k, name) in ["intensity", "gps_time"].iter().enumerate() {
            let mut a = crate::points::Attribute::new(
                *name,
                (0..n).map(|i| (i * (k + 3) % 977) as f32).collect(),
            );
            a.offset = k as f64 * 1e6;
            c.attributes.push(a);
        }
        let rows: Vec<f32> = (0..n)
            .flat_map(|i| c.attributes.iter().map(move |a| a.values[i]))
            .collect();
        for layout in [Layout::Hilbert, Layout::Paper] {
            let opts = WriteOptions {
                layout,
                ..WriteOptions::default()
            };
            let write = |name: &str, src: Option<VecRows>| {
                let path = dir.path().join(name);
                let mut b = PartBuilder::new([1025.0, 2025.0, 5.0], None, n);
                if let Some(s) = src {
                    b.rows_from(Arc::new(s));
                }
                for k in 0..7 {
                    let (from, to) = (k * n / 7, (k + 1) * n / 7);
                    let mut part = c.empty_like();
                    part.append_range(&c, from, to);
                    b.push(&path, &part).unwrap();
                }
                write_part_built(&path, b, &opts).map(|s| (s, std::fs::read(&path).unwrap()))
            };
            let (held, a) = write("held.tif", None).unwrap();
            let (mapped, b) = write("mapped.tif", Some(VecRows(rows.clone(), 2))).unwrap();
            assert!(!held.rows_from_input);
            assert!(mapped.rows_from_input, "{layout:?}: rows were copied");
            assert!(a == b, "{layout:?}: the files differ");
            let e = write(
                "short.tif",
                Some(VecRows(rows[..rows.len() - 2].to_vec(), 2)),
            )
            .expect_err("a short source is an error");
            assert!(e.to_string().contains("short.tif"), "{e}");
            assert!(!dir.path().join("short.tif").exists());
        }
        // A source that gives the positions too: the part holds none, and the
        // file is the same, byte for byte (level 0 written while arranging, with
        // each tile's rows read with its positions; or compressed afterwards).
        for (layout, compression) in [
            (Layout::Hilbert, Compression::None),
            (Layout::Hilbert, Compression::Zstd),
            (Layout::Paper, Compression::None),
        ] {
            let opts = WriteOptions {
                layout,
                compression,
                ..WriteOptions::default()
            };
            let write = |name: &str, src: Option<PosRows>| {
                let path = dir.path().join(name);
                let mut b = PartBuilder::new([1025.0, 2025.0, 5.0], None, n);
                if let Some(s) = src {
                    b.rows_from(Arc::new(s));
                    assert!(b.positions_from_source());
                }
                for k in 0..7 {
                    let (from, to) = (k * n / 7, (k + 1) * n / 7);
                    let mut part = c.empty_like();
                    part.append_range(&c, from, to);
                    b.push(&path, &part).unwrap();
                }
                assert_eq!(b.pos.is_empty(), b.positions_from_source());
                write_part_built(&path, b, &opts).unwrap();
                std::fs::read(&path).unwrap()
            };
            let held = write("held.tif", None);
            let coords = [c.x.clone(), c.y.clone(), c.z.clone()];
            let src = || PosRows(VecRows(rows.clone(), 2), coords.clone());
            let given = write("given.tif", Some(src()));
            assert!(
                held == given,
                "{layout:?} {compression:?}: the files differ"
            );
            // Told to hold them, the builder keeps the positions all the same.
            let mut b = PartBuilder::new([1025.0, 2025.0, 5.0], None, n);
            b.rows_from(Arc::new(src()));
            b.hold_positions();
            b.push(Path::new("p.tif"), &c).unwrap();
            assert!(!b.positions_from_source() && b.pos.len() == n);
            // Not held, they are checked all the same.
            let mut b = PartBuilder::new([1025.0, 2025.0, 5.0], None, n);
            b.rows_from(Arc::new(src()));
            let mut bad = c.clone();
            bad.z[n - 2] = f64::NAN;
            let e = b.push(Path::new("p.tif"), &bad).unwrap_err().to_string();
            assert!(e.contains(&format!("point {} ", n - 2)), "{e}");
            assert!(b.is_empty());
        }
    }
}
