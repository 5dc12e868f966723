//! Choosing tiles for a viewpoint.
//!
//! - `Distance` (the paper): the distance from the eye to the centre of the
//!   dataset's bounds picks one level for every part; thresholds double per level,
//!   starting at half the bounds' diagonal, so closer means finer, down to level 0.
//! - `View` (default): per part and per tile, tiles outside the frustum are culled
//!   by their stored bounds; starting from each part's coarsest level, the visible
//!   tile whose points are spread widest on screen is refined into its four children
//!   (which hold its points and three times more) until every tile's projected point
//!   spacing is below about a pixel or the point budget would be exceeded.
//! - `Fixed(k)`: level k (clamped per part) everywhere, culled by the frustum.
//!
//! A dataset with an overview (`store::index`) starts `View` at the overview's
//! root: a node's coarsest tile refines into its children's coarsest tiles (nodes
//! of the layer below, then parts), then into each part's own pyramid, so the
//! whole visible dataset is drawn under any budget. For `Distance` and `Fixed`
//! the overview's layers are the levels above the parts' own.
//!
//! A dataset's parts and a [`TileSource`] (COPC, EPT, a survey of COPC files)
//! are refined by one loop ([`refine`]) over a [`TileTree`]: roots, children,
//! and whether a refined tile stays drawn (a source's octree node) or gives
//! way to its children (a part's tile, an overview node).
//!
//! Every mode then respects a memory budget: tiles that do not fit are not loaded,
//! farthest first, and the selection says so (the paper: "it has to give up
//! loading").

use crate::camera::{Camera, Containment, Frustum};
use crate::points::Bounds;
use crate::store::{Dataset, SOURCE_PART, SourceTile, TileSource};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// How levels are chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LodMode {
    Distance,
    View { budget: u64 },
    Fixed(usize),
}

/// One tile to draw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TileRef {
    pub part: usize,
    pub level: usize,
    /// Raster index of the tile in its level.
    pub tile: u32,
    pub points: u64,
    pub bounds: Bounds,
}

/// The outcome of a selection.
#[derive(Debug, Clone, Default)]
pub struct Selection {
    pub tiles: Vec<TileRef>,
    pub points: u64,
    /// Tiles left out because they lie outside the view.
    pub culled: usize,
    /// Tiles (and their points) given up for the memory or the point budget.
    pub dropped_tiles: usize,
    pub dropped_points: u64,
    /// The finest and coarsest level of the parts drawn.
    pub levels: Option<(usize, usize)>,
    /// Tiles of overview nodes drawn.
    pub overview_tiles: usize,
}

/// The default cap on points drawn: 4K at two points a pixel.
pub const DEFAULT_BUDGET_CAP: u64 = 16_000_000;
/// Points a pixel the automatic budget allows.
pub(crate) const POINTS_PER_PIXEL: u64 = 2;

/// The point budget for a `width`×`height` frame: two points a pixel, at least
/// four tiles' worth (262,144), at most `cap`. Four tiles are what one
/// refinement needs (a tile's children, an overview node's children): with
/// less, a small view (text mode in a terminal pane) zoomed onto the line
/// where a node's children meet could never refine past that node.
pub fn budget_for_pixels(width: u32, height: u32, cap: u64) -> u64 {
    (POINTS_PER_PIXEL * width as u64 * height as u64)
        .max(4 * crate::store::spec::TILE_PIXELS as u64)
        .min(cap)
}

/// Bytes a point costs in memory when loaded (x, y, z and one colour source).
pub const BYTES_PER_LOADED_POINT: u64 = 4 * 4 + 4;

/// The paper's distance rule: level for the eye at `distance` from the centre of
/// bounds with diagonal `diag`, for a part with `levels` levels.
pub fn distance_level(distance: f64, diag: f64, levels: usize) -> usize {
    if levels == 0 {
        return 0;
    }
    let t0 = (0.5 * diag).max(1e-9);
    let mut level = 0;
    let mut t = t0;
    while distance >= t && level + 1 < levels {
        level += 1;
        t *= 2.0;
    }
    level
}

/// Points spacing in world units of a tile: points spread over its two largest
/// extents (scans sample surfaces).
fn spacing(b: &Bounds, points: u64) -> f64 {
    let mut e = b.extent();
    e.sort_by(|a, b| b.total_cmp(a));
    let area = (e[0] * e[1]).max(e[0] * e[0] * 1e-6).max(1e-12);
    (area / points.max(1) as f64).sqrt()
}

/// Distance from the eye to the nearest point of `b`.
fn distance_to_box(eye: [f64; 3], b: &Bounds) -> f64 {
    (0..3)
        .map(|a| {
            let d = (b.min[a] - eye[a]).max(eye[a] - b.max[a]).max(0.0);
            d * d
        })
        .sum::<f64>()
        .sqrt()
}

/// A tile waiting in the refinement queue, ordered by projected point spacing.
struct Candidate {
    key: f64,
    tile: TileRef,
}
impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.key == o.key
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    fn cmp(&self, o: &Self) -> Ordering {
        self.key.total_cmp(&o.key)
    }
}

/// Tile entries of a level: raster index → (points, bounds), in Z-rank order.
fn level_tiles(ds: &Dataset, part: usize, level: usize) -> Vec<TileRef> {
    let Some(p) = ds.part(part) else {
        return Vec::new();
    };
    let Some(l) = p.levels.get(level) else {
        return Vec::new();
    };
    // A node's tiles stand for all of its children's points.
    let cover = ds.cover(part);
    l.tiles
        .iter()
        .map(|t| TileRef {
            part,
            level,
            tile: t.index,
            points: t.points.map(|n| n as u64).unwrap_or_else(|| {
                l.points.unwrap_or(p.meta.point_count) / l.tiles.len().max(1) as u64
            }),
            bounds: cover.unwrap_or(t.bounds),
        })
        .collect()
}

/// The four children (one level finer) of a tile, when the level below has a tile
/// index with the same Z-order structure.
fn children(
    ds: &Dataset,
    t: &TileRef,
    visible: &dyn Fn(&TileRef) -> bool,
    culled: &mut usize,
) -> Option<Vec<TileRef>> {
    if ds.is_overview(t.part) {
        // Children the view cannot show are culled by the bounds their parent
        // records, before their index pages are read. (A child whose page
        // cannot be read: nothing finer.)
        let mut shown = Vec::new();
        for (c, b) in ds.children(t.part).ok()? {
            let probe = TileRef {
                part: c,
                level: 0,
                tile: 0,
                points: 0,
                bounds: b,
            };
            if visible(&probe) {
                shown.push(c);
            } else {
                *culled += 1;
            }
        }
        ds.prefetch(&shown);
        let mut tiles = Vec::new();
        for c in shown {
            ds.child(t.part, c).ok()?;
            tiles.extend(top_tiles(ds, c));
        }
        return Some(tiles);
    }
    if t.level == 0 {
        return None;
    }
    let p = ds.part(t.part)?;
    let (up, down) = (&p.levels[t.level], &p.levels[t.level - 1]);
    if !up.indexed || !down.indexed || down.tiles_across != 2 * up.tiles_across {
        return None;
    }
    let col = t.tile % up.tiles_across;
    let row = t.tile / up.tiles_across;
    let kids: Vec<u32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
        .iter()
        .map(|(dx, dy)| (2 * row + dy) * down.tiles_across + 2 * col + dx)
        .collect();
    Some(
        down.tiles
            .iter()
            .filter(|d| kids.contains(&d.index))
            .map(|d| TileRef {
                part: t.part,
                level: t.level - 1,
                tile: d.index,
                points: d.points.unwrap_or(0) as u64,
                bounds: d.bounds,
            })
            .collect(),
    )
}

/// The tiles of part `part`'s coarsest level.
fn top_tiles(ds: &Dataset, part: usize) -> Vec<TileRef> {
    let top = ds
        .part(part)
        .map_or(0, |p| p.levels.len().saturating_sub(1));
    level_tiles(ds, part, top)
}

/// Levels a `Fixed` or `Distance` selection counts: the parts' own, then one per
/// overview layer.
pub fn level_count(ds: &Dataset) -> usize {
    ds.own_levels() + ds.layer_count() as usize
}

/// The tiles of dataset level `level` (clamped per part; past the parts' own
/// levels, the overview layer's nodes).
fn tiles_at(ds: &Dataset, level: usize) -> Vec<TileRef> {
    // (A level over the whole dataset reads every page of a paged index; one
    // that cannot be read gives its entries' tiles up.)
    let own = ds.own_levels();
    if ds.has_overview() && level >= own {
        let layer = ((level - own + 1) as u32).min(ds.layer_count());
        return ds
            .layer_nodes(layer)
            .unwrap_or_default()
            .into_iter()
            .flat_map(|id| top_tiles(ds, id))
            .collect();
    }
    ds.part_ids()
        .unwrap_or_default()
        .into_iter()
        .flat_map(|pi| {
            let n = ds.part(pi).map_or(0, |p| p.levels.len());
            level_tiles(ds, pi, level.min(n.saturating_sub(1)))
        })
        .collect()
}

/// A source's tile as a tile reference.
fn source_ref(t: &SourceTile) -> TileRef {
    TileRef {
        part: SOURCE_PART,
        level: t.depth,
        tile: t.id,
        points: t.points,
        bounds: t.bounds,
    }
}

/// A hierarchy of tiles the view refines: a dataset's parts (their pyramids,
/// and the overview nodes above them) or a [`TileSource`] (a COPC or EPT
/// octree, a survey of COPC files). One refinement ([`refine`]) serves them
/// all; they differ only in their roots, each tile's children and whether a
/// refined tile stays drawn.
trait TileTree {
    /// The tiles refinement starts from.
    fn roots(&self) -> Vec<TileRef>;
    /// Tile `t`'s children (`None`: nothing finer), counting in `culled`
    /// those it leaves out before reading them (an overview node's children
    /// culled by the bounds it records).
    fn children(
        &self,
        t: &TileRef,
        visible: &dyn Fn(&TileRef) -> bool,
        culled: &mut usize,
    ) -> Option<Vec<TileRef>>;
    /// Whether `t` stays drawn with its children (a COPC node: its points are
    /// not repeated in them) or is replaced by them (a part's tile, whose
    /// children hold its points and three times more).
    fn additive(&self, t: &TileRef) -> bool;
}

/// A dataset's parts: from the overview's root (or every part's coarsest
/// level), a node's coarsest tile refines into its children's coarsest tiles,
/// then into each part's own pyramid.
struct PartTree<'a>(&'a Dataset);

impl TileTree for PartTree<'_> {
    fn roots(&self) -> Vec<TileRef> {
        let starts: Vec<usize> = match self.0.root() {
            Some(root) => vec![root],
            None => self.0.part_ids().unwrap_or_default(),
        };
        starts
            .into_iter()
            .flat_map(|pi| top_tiles(self.0, pi))
            .collect()
    }
    fn children(
        &self,
        t: &TileRef,
        visible: &dyn Fn(&TileRef) -> bool,
        culled: &mut usize,
    ) -> Option<Vec<TileRef>> {
        children(self.0, t, visible, culled)
    }
    fn additive(&self, _t: &TileRef) -> bool {
        false
    }
}

/// A [`TileSource`]'s tiles (read as the view reaches them).
struct SourceTree<'a>(&'a dyn TileSource);

impl TileTree for SourceTree<'_> {
    fn roots(&self) -> Vec<TileRef> {
        self.0.roots().iter().map(source_ref).collect()
    }
    fn children(
        &self,
        t: &TileRef,
        _visible: &dyn Fn(&TileRef) -> bool,
        _culled: &mut usize,
    ) -> Option<Vec<TileRef>> {
        // (A tile whose children cannot be read: nothing finer.)
        let kids = self.0.children(t.tile).ok()?;
        (!kids.is_empty()).then(|| kids.iter().map(source_ref).collect())
    }
    fn additive(&self, t: &TileRef) -> bool {
        self.0.additive(t.tile)
    }
}

/// What [`refine`] chose: the tiles to draw, and (refining `full`) those
/// replaced by their children.
struct Refined {
    chosen: Vec<TileRef>,
    replaced: Vec<TileRef>,
}

/// The view's refinement of `tree`: from its visible roots, the tile whose
/// points are spread widest on screen is refined first, until every tile's
/// projected spacing is below about a pixel or its children would pass
/// `budget` points (or, `full`, down to the finest tiles).
fn refine(
    tree: &dyn TileTree,
    camera: &Camera,
    height: u32,
    budget: u64,
    full: bool,
    visible: &dyn Fn(&TileRef) -> bool,
    sel: &mut Selection,
) -> Refined {
    let eye = camera.eye().to_array();
    let ppu = |b: &Bounds| camera.pixels_per_unit(distance_to_box(eye, b), height);
    let key = |t: &TileRef| spacing(&t.bounds, t.points) * ppu(&t.bounds);
    let mut out = Refined {
        chosen: Vec::new(),
        replaced: Vec::new(),
    };
    let mut heap = BinaryHeap::new();
    let mut total = 0u64;
    for t in tree.roots() {
        if !visible(&t) {
            sel.culled += 1;
            continue;
        }
        total += t.points;
        heap.push(Candidate {
            key: key(&t),
            tile: t,
        });
    }
    while let Some(c) = heap.pop() {
        // Fine enough, or nothing finer: keep it.
        let mut culled_early = 0;
        let kids = if full || c.key > 1.0 {
            tree.children(&c.tile, visible, &mut culled_early)
        } else {
            None
        };
        let Some(kids) = kids else {
            out.chosen.push(c.tile);
            continue;
        };
        let vis: Vec<TileRef> = kids.iter().copied().filter(|k| visible(k)).collect();
        let added: u64 = vis.iter().map(|k| k.points).sum();
        let additive = tree.additive(&c.tile);
        let after = if additive {
            total + added
        } else {
            total - c.tile.points + added
        };
        if after > budget {
            out.chosen.push(c.tile);
            continue;
        }
        total = after;
        sel.culled += kids.len() - vis.len() + culled_early;
        if additive {
            out.chosen.push(c.tile);
        } else if full {
            out.replaced.push(c.tile);
        }
        for k in vis {
            heap.push(Candidate {
                key: key(&k),
                tile: k,
            });
        }
    }
    out
}

/// The tiles of a [`TileSource`] for the view: [`refine`]d (`View`, and
/// `Distance`, which a source has no levels for); `Fixed(k)` draws every
/// visible tile but those of the `k` deepest depths (0 = all, as a part's
/// level 0 is its finest).
fn select_source(
    src: &dyn TileSource,
    camera: &Camera,
    height: u32,
    mode: LodMode,
    visible: &dyn Fn(&TileRef) -> bool,
    sel: &mut Selection,
) -> Vec<TileRef> {
    let budget = match mode {
        LodMode::View { budget } => budget,
        _ => u64::MAX,
    };
    let full = matches!(mode, LodMode::Fixed(_));
    let Refined {
        mut chosen,
        replaced,
    } = refine(&SourceTree(src), camera, height, budget, full, visible, sel);
    if let LodMode::Fixed(k) = mode {
        // Down to depth `deepest - k`: a replaced tile stands for its
        // children where they are left out.
        let deepest = chosen.iter().map(|t| t.level).max().unwrap_or(0);
        chosen.retain(|t| t.level + k <= deepest);
        chosen.extend(replaced.into_iter().filter(|t| t.level + k == deepest));
    }
    chosen
}

/// Selects the tiles to draw for `camera` on a `width`×`height` view.
pub fn select(
    ds: &Dataset,
    camera: &Camera,
    width: u32,
    height: u32,
    mode: LodMode,
    memory_budget: u64,
) -> Selection {
    select_clipped(ds, camera, width, height, mode, memory_budget, None)
}

/// [`select`] drawing only what lies in the box `clip`: tiles whose bounds miss
/// it are culled like those outside the view (a section loads only what it
/// shows), and refinement spends the budget on the tiles that touch it.
pub fn select_clipped(
    ds: &Dataset,
    camera: &Camera,
    width: u32,
    height: u32,
    mode: LodMode,
    memory_budget: u64,
    clip: Option<&Bounds>,
) -> Selection {
    let keep = |b: &Bounds| clip.is_none_or(|c| c.intersects(b));
    select_region(ds, camera, width, height, mode, memory_budget, &keep)
}

/// [`select`] drawing only what `may_show` lets through: tiles whose bounds it
/// refuses (a clip box, a slab) are culled like those outside the view.
pub fn select_region(
    ds: &Dataset,
    camera: &Camera,
    width: u32,
    height: u32,
    mode: LodMode,
    memory_budget: u64,
    may_show: &dyn Fn(&Bounds) -> bool,
) -> Selection {
    let aspect = width as f64 / height.max(1) as f64;
    let frustum: Frustum = camera.frustum(aspect);
    let eye = camera.eye().to_array();
    let mut sel = Selection::default();
    let mut chosen: Vec<TileRef> = Vec::new();
    let visible = |t: &TileRef| {
        may_show(&t.bounds) && frustum.contains_aabb(&t.bounds) != Containment::Outside
    };
    if let Some(src) = ds.source() {
        chosen = select_source(src.as_ref(), camera, height, mode, &visible, &mut sel);
    } else {
        match mode {
            LodMode::Distance | LodMode::Fixed(_) => {
                let total = ds.bounds();
                let diag = total.extent().iter().map(|e| e * e).sum::<f64>().sqrt();
                let d = camera.distance_to(total.center());
                let level = match mode {
                    LodMode::Fixed(k) => k,
                    _ => distance_level(d, diag, level_count(ds)),
                };
                for t in tiles_at(ds, level) {
                    if visible(&t) {
                        chosen.push(t);
                    } else {
                        sel.culled += 1;
                    }
                }
            }
            LodMode::View { budget } => {
                chosen = refine(
                    &PartTree(ds),
                    camera,
                    height,
                    budget,
                    false,
                    &visible,
                    &mut sel,
                )
                .chosen;
            }
        }
    }
    // The memory budget (and in view mode the point budget, which the coarsest
    // tiles of many parts could exceed on their own): nearest tiles first; give up
    // the rest.
    chosen.sort_by(|a, b| {
        distance_to_box(eye, &a.bounds).total_cmp(&distance_to_box(eye, &b.bounds))
    });
    let point_cap = match mode {
        LodMode::View { budget } => budget,
        _ => u64::MAX,
    };
    let mut bytes = 0u64;
    for t in chosen {
        let cost = t.points * BYTES_PER_LOADED_POINT;
        // The nearest tile is drawn even beyond the point budget: a budget below
        // the coarsest tile would otherwise draw nothing at all.
        let over_points = sel.points + t.points > point_cap && !sel.tiles.is_empty();
        if bytes + cost > memory_budget || over_points {
            sel.dropped_tiles += 1;
            sel.dropped_points += t.points;
            continue;
        }
        bytes += cost;
        sel.points += t.points;
        if ds.is_overview(t.part) {
            sel.overview_tiles += 1;
            sel.tiles.push(t);
            continue;
        }
        sel.levels = Some(match sel.levels {
            None => (t.level, t.level),
            Some((lo, hi)) => (lo.min(t.level), hi.max(t.level)),
        });
        sel.tiles.push(t);
    }
    sel
}
