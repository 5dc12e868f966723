//! One frame, from a request to pixels: the tiles a camera sees are selected
//! ([`lod::select_region`], culled by the filter's clip box too), loaded (all of
//! them before drawing, or those in memory while the rest stream in), coloured
//! (each tile's colours and filter cached for one style and one filter, so an
//! orbit recolours nothing), rasterized, picked at a pixel if asked, and the
//! overlays drawn over the result.
//!
//! `render`, `preview`, the turntable and the inspector all draw through
//! [`Pipeline::draw`]; they differ only in [`Loading`] and in where the colour
//! ranges come from ([`Pipeline::with_reference`]).

use crate::edl::EdlParams;
use crate::filter::Filter;
use crate::legend::{self, Legend};
use crate::lod::{self, LoadedTile, LodMode, Selection, TileCache, TileKey};
use crate::marks;
use crate::pick::{self, Hit};
use crate::scene::{ColorRanges, Style, band_range, colorize_style};
use crate::store::Dataset;
use crate::{Camera, Frame, PointBatch, Rasterizer, RenderError, RenderOptions, RendererChoice};
use std::collections::{HashMap, HashSet};
use std::sync::Arc;
use std::time::Instant;

/// How a frame gets its tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loading {
    /// Every selected tile is loaded before the frame is drawn (`render`).
    Wait,
    /// Tiles are asked for and the frame drawn from those in memory, coarser
    /// loaded tiles standing in for missing ones (the inspector redraws as the
    /// rest arrive).
    Stream,
}

/// What to draw, besides the dataset and the pipeline's loading.
#[derive(Debug, Clone)]
pub struct FrameRequest<'a> {
    pub camera: &'a Camera,
    pub width: u32,
    pub height: u32,
    pub style: &'a Style,
    pub filter: &'a Filter,
    /// Level selection; a view-dependent budget is used as given.
    pub mode: LodMode,
    /// Bytes of points a selection may take.
    pub memory: u64,
    pub point_size: u32,
    pub eye_dome_lighting: bool,
    pub edl: EdlParams,
    /// Find the point drawn nearest pixel `(x, y)`, searching `radius` pixels.
    pub pick: Option<(u32, u32, u32)>,
    pub overlays: Overlays<'a>,
}

/// What is drawn over the points, in this order: the picked points and the line
/// between two, the crosshair, the legend, the scale bar. For images without a
/// terminal (`render`, `preview`, a frame the inspector saves); the inspector's
/// view draws its overlays as terminal cells instead (`tui::overlay`).
#[derive(Debug, Clone, Default)]
pub struct Overlays<'a> {
    pub marks: &'a [[f64; 3]],
    /// A pixel of the frame.
    pub crosshair: Option<(u32, u32)>,
    pub legend: bool,
    pub scale_bar: bool,
}

/// What one frame took and held.
#[derive(Debug, Clone, Default)]
pub struct FrameReport {
    pub selection: Selection,
    /// Points of the tiles drawn (loaded; the filter may hide some).
    pub points: u64,
    /// Of those, the points the filter keeps (all of them without a filter).
    pub kept: u64,
    /// Finest and coarsest part level drawn (overview tiles not counted).
    pub levels: Option<(usize, usize)>,
    /// Selected tiles still loading ([`Loading::Stream`]).
    pub pending: usize,
    /// Selected tiles that could not be read.
    pub unreadable: usize,
    /// Selected tiles whose load failed for a reason that may pass: tried
    /// again in the background ([`crate::lod::TileCache::retries`]).
    pub retrying: usize,
    pub select_ms: f64,
    /// Waiting for tiles (for [`Loading::Stream`], since the frame that first
    /// found tiles missing).
    pub load_ms: f64,
    /// Colouring the loaded points and applying the filter.
    pub color_ms: f64,
    pub render_ms: f64,
    pub renderer: String,
}

/// One drawn frame and what it was drawn from.
pub struct Drawn {
    pub frame: Frame,
    /// The tiles drawn, in the order of the rasterizer's batches ([`Hit::batch`]).
    pub tiles: Vec<Arc<LoadedTile>>,
    pub ranges: ColorRanges,
    /// The legend for the request's style (whether or not it was drawn).
    pub legend: Option<Legend>,
    pub report: FrameReport,
    /// The answer to [`FrameRequest::pick`]: the point found, if any.
    pub pick: Option<Option<Hit>>,
}

impl Drawn {
    /// The tile a picked point belongs to.
    pub fn tile_of(&self, hit: &Hit) -> TileKey {
        self.tiles[hit.batch].key
    }
}

/// Why a frame could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    /// A tile could not be read (the error names the part, and what would put
    /// it right where the store knows).
    #[error("{0}")]
    Load(crate::store::StoreError),
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// Colours of loaded tiles for one style, and for one filter their heights with
/// hidden points NaN (`None`: none hidden) and the count it keeps.
#[derive(Default)]
struct ColorCache {
    style: Option<Style>,
    columns: HashMap<TileKey, Vec<u32>>,
    filter: Option<Filter>,
    hidden: HashMap<TileKey, (Option<Vec<f32>>, u64)>,
}

/// Draws frames of one dataset; keeps the tile cache, the rasterizer, the colour
/// ranges and the coloured tiles between frames.
pub struct Pipeline {
    ds: Arc<Dataset>,
    cache: TileCache,
    loading: Loading,
    choice: RendererChoice,
    renderer: Option<Box<dyn Rasterizer>>,
    /// The tiles colour ranges come from; `None`: each frame's own (the first
    /// frame's fix the ranges).
    reference: Option<Vec<Arc<LoadedTile>>>,
    ranges: Option<ColorRanges>,
    colors: ColorCache,
    loading_since: Option<Instant>,
}

impl Pipeline {
    /// A pipeline over `cache` (which names the bands loads read). The
    /// rasterizer is created on the first frame, on the thread that draws.
    pub fn new(
        ds: Arc<Dataset>,
        cache: TileCache,
        choice: RendererChoice,
        loading: Loading,
    ) -> Self {
        Pipeline {
            ds,
            cache,
            loading,
            choice,
            renderer: None,
            reference: None,
            ranges: None,
            colors: ColorCache::default(),
            loading_since: None,
        }
    }

    /// Colour ranges from `tiles` (for the whole session) rather than from the
    /// first frame's tiles.
    pub fn with_reference(mut self, tiles: Vec<Arc<LoadedTile>>) -> Self {
        self.ranges = Some(ColorRanges::from_tiles(&tiles, &self.ds.bounds()));
        self.reference = Some(tiles);
        self
    }

    pub fn dataset(&self) -> &Arc<Dataset> {
        &self.ds
    }

    pub fn cache(&self) -> &TileCache {
        &self.cache
    }

    /// Creates the rasterizer now (its errors are then the caller's first).
    pub fn renderer(&mut self) -> Result<&mut Box<dyn Rasterizer>, RenderError> {
        if self.renderer.is_none() {
            self.renderer = Some(crate::create(self.choice)?);
        }
        Ok(self.renderer.as_mut().expect("created above"))
    }

    /// Selects, loads, colours and rasterizes one frame, picks if asked and
    /// draws the overlays.
    pub fn draw(&mut self, req: &FrameRequest<'_>) -> Result<Drawn, DrawError> {
        let received = Instant::now();
        let (width, height) = (req.width, req.height);
        self.renderer()?;

        let t = Instant::now();
        let sel = lod::select_region(
            &self.ds,
            req.camera,
            width,
            height,
            req.mode,
            req.memory,
            &|b| req.filter.may_show(b),
        );
        let select_ms = ms(t);

        let t = Instant::now();
        let (tiles, pending, unreadable, retrying) = match self.loading {
            Loading::Wait => (
                self.cache.load_all(&sel.tiles).map_err(DrawError::Load)?,
                0,
                0,
                0,
            ),
            Loading::Stream => {
                self.cache.request(&sel.tiles);
                let mut tiles = self.cache.ready(&sel.tiles);
                let unreadable = self.cache.unreadable(&sel.tiles);
                let retrying = self.cache.retrying(&sel.tiles);
                // (Counted one after the other: a tile that arrived between
                // the counts is in none of them.)
                let pending = sel
                    .tiles
                    .len()
                    .saturating_sub(tiles.len() + unreadable + retrying);
                if tiles.len() < sel.tiles.len() {
                    // Coarser tiles already in memory stand in for those still missing.
                    let have: HashSet<TileKey> = tiles.iter().map(|t| t.key).collect();
                    let extra = self.cache.stand_ins(&sel.tiles);
                    tiles.extend(extra.into_iter().filter(|t| !have.contains(&t.key)));
                }
                (tiles, pending, unreadable, retrying)
            }
        };
        let load_ms = match self.loading {
            Loading::Wait => ms(t),
            // From the request that found tiles missing until all arrived.
            Loading::Stream if pending > 0 => ms(*self.loading_since.get_or_insert(received)),
            Loading::Stream => self.loading_since.take().map_or(0.0, ms),
        };

        let t = Instant::now();
        let ranges = self.colour(&tiles, req.style, req.filter);
        let batches = batches(&self.colors, &tiles);
        let color_ms = ms(t);

        let opts = options(req);
        let t = Instant::now();
        let renderer = self.renderer.as_mut().expect("created at the top");
        renderer.keep_ids(req.pick.is_some());
        let mut frame = renderer.render(req.camera, &batches, &opts)?;
        let render_ms = ms(t);
        let pick = match req.pick {
            Some((x, y, radius)) => Some(pick::pick_drawn(
                &**renderer,
                req.camera,
                &batches,
                &opts,
                x,
                y,
                radius,
            )?),
            None => None,
        };
        drop(batches);

        let legend = Legend::for_style(&self.ds, req.style, req.filter, &ranges);
        // The scale bar is labelled in the dataset's unit (its CRS parsed only then).
        let unit = if req.overlays.scale_bar {
            legend::dataset_unit(&self.ds)
        } else {
            String::new()
        };
        draw_overlays(
            &mut frame,
            req.camera,
            &req.overlays,
            legend.as_ref(),
            &unit,
        );

        let points = tiles.iter().map(|t| t.len() as u64).sum();
        let kept = tiles.iter().map(|t| self.colors.hidden[&t.key].1).sum();
        let levels = tiles
            .iter()
            .filter(|t| !self.ds.is_overview(t.key.part))
            .fold(None, |acc: Option<(usize, usize)>, t| {
                let l = t.key.level;
                Some(acc.map_or((l, l), |(lo, hi)| (lo.min(l), hi.max(l))))
            });
        Ok(Drawn {
            frame,
            tiles,
            ranges,
            legend,
            report: FrameReport {
                selection: sel,
                points,
                kept,
                levels,
                pending,
                unreadable,
                retrying,
                select_ms,
                load_ms,
                color_ms,
                render_ms,
                renderer: renderer.name(),
            },
            pick,
        })
    }

    /// The point nearest pixel `(x, y)` (within `radius`) of a frame of `req`
    /// drawn from `tiles` (an earlier [`Drawn::tiles`]), found by projecting
    /// them again ([`pick::pick`]) with their cached colours, without drawing a
    /// frame: the inspector picks over the frame it shows. `Hit::batch` indexes
    /// `tiles`.
    pub fn pick_in(
        &mut self,
        tiles: &[Arc<LoadedTile>],
        req: &FrameRequest<'_>,
        (x, y, radius): (u32, u32, u32),
    ) -> Result<Option<Hit>, DrawError> {
        self.colour(tiles, req.style, req.filter);
        let batches = batches(&self.colors, tiles);
        Ok(pick::pick(
            req.camera,
            &batches,
            &options(req),
            x,
            y,
            radius,
        )?)
    }

    /// Colours and filters `tiles` for `style` and `filter` (those not already
    /// done for them), fixing the colour ranges on first use; returns the ranges.
    fn colour(&mut self, tiles: &[Arc<LoadedTile>], style: &Style, filter: &Filter) -> ColorRanges {
        let bounds = self.ds.bounds();
        // Without reference tiles the first frame's serve, and are not kept: a
        // turntable's later frames reuse the ranges, not the points.
        let reference: &[Arc<LoadedTile>] = self.reference.as_deref().unwrap_or(tiles);
        let ranges = self
            .ranges
            .get_or_insert_with(|| ColorRanges::from_tiles(reference, &bounds));
        if self.colors.style.as_ref() != Some(style) {
            self.colors.columns.clear();
            if let crate::ColorMode::Band(b) = &style.mode {
                ranges.band = band_range(reference, b).unwrap_or((0.0, 1.0));
            }
            self.colors.style = Some(style.clone());
        }
        let ranges = *ranges;
        if self.colors.filter.as_ref() != Some(filter) {
            self.colors.hidden.clear();
            self.colors.filter = Some(filter.clone());
        }
        self.color_tiles(tiles, style, filter, &ranges);
        ranges
    }

    /// Colours (and filters) the tiles not yet coloured for this style and
    /// filter, in parallel; forgets the tiles no longer drawn.
    fn color_tiles(
        &mut self,
        tiles: &[Arc<LoadedTile>],
        style: &Style,
        filter: &Filter,
        ranges: &ColorRanges,
    ) {
        use rayon::prelude::*;
        let keep: HashSet<TileKey> = tiles.iter().map(|t| t.key).collect();
        let c = &mut self.colors;
        c.columns.retain(|k, _| keep.contains(k));
        c.hidden.retain(|k, _| keep.contains(k));
        let columns: Vec<_> = tiles
            .par_iter()
            .filter(|t| !c.columns.contains_key(&t.key))
            .map(|t| (t.key, colorize_style(t, style, ranges)))
            .collect();
        c.columns.extend(columns);
        let hidden: Vec<_> = tiles
            .par_iter()
            .filter(|t| !c.hidden.contains_key(&t.key))
            .map(|t| {
                let z = filter.hidden_z(t);
                let kept = z
                    .as_deref()
                    .map_or(t.len(), |z| z.iter().filter(|v| !v.is_nan()).count());
                (t.key, (z, kept as u64))
            })
            .collect();
        c.hidden.extend(hidden);
    }
}

/// The rasterizer's batches of `tiles` (coloured by [`Pipeline::colour`] into
/// `colors`): hidden points' heights NaN.
fn batches<'a>(colors: &'a ColorCache, tiles: &'a [Arc<LoadedTile>]) -> Vec<PointBatch<'a>> {
    tiles
        .iter()
        .map(|t| PointBatch {
            origin: t.origin,
            x: &t.x,
            y: &t.y,
            z: colors.hidden[&t.key].0.as_deref().unwrap_or(&t.z),
            color: &colors.columns[&t.key],
        })
        .collect()
}

/// The rasterizer's options for `req`.
fn options(req: &FrameRequest<'_>) -> RenderOptions {
    RenderOptions {
        width: req.width,
        height: req.height,
        point_size: req.point_size,
        eye_dome_lighting: req.eye_dome_lighting,
        edl: req.edl,
        background: [0, 0, 0],
    }
}

/// Draws `o` over `frame` (in the order [`Overlays`] gives).
pub fn draw_overlays(
    frame: &mut Frame,
    cam: &Camera,
    o: &Overlays<'_>,
    legend: Option<&Legend>,
    unit: &str,
) {
    if let [a, b] = o.marks[..] {
        marks::segment(frame, cam, a, b, MARK_COLOR);
    }
    for m in o.marks {
        marks::mark(frame, cam, *m, MARK_COLOR);
    }
    if let Some((x, y)) = o.crosshair {
        marks::crosshair(frame, x, y, (frame.height / 40).max(6));
    }
    if o.legend
        && let Some(l) = legend
    {
        legend::draw(frame, l);
    }
    if o.scale_bar {
        legend::draw_scale_bar(frame, cam, unit);
    }
}

/// Picked points and the line between them.
const MARK_COLOR: [u8; 3] = [255, 220, 0];

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
