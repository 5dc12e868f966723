//! Rendering off the event loop: a worker thread receives (camera, settings, pane
//! size) requests through a channel, keeps only the newest, selects tiles, asks
//! the tile cache for them (loading happens on the cache's own threads), draws
//! what is loaded, encodes the frame for the terminal and sends it back. While
//! tiles are still arriving it redraws as they come. While tiles wait to be
//! tried again (the server did not answer) it looks every
//! [`REDRAW_WHILE_LOADING`] for tiles that loaded at last, or for a change in
//! what the status line says of the tries, and redraws then: the view recovers
//! by itself when the server returns, without a key press. The event loop never
//! waits on it: it polls [`RenderWorker::try_recv`] between key presses.

use super::app::{FrameStatus, RetryStatus, Settings};
use super::protocol::{self, PaneImage};
use crate::camera::Camera;
use crate::lod::point::{PointRecord, point_record};
use crate::lod::{self, LoadedTile, LodMode, TileCache, TileKey, TileRef};
use crate::render::legend::{self, Legend};
use crate::render::pipeline::{FrameRequest, Loading, Overlays, Pipeline};
use crate::render::{self, Frame, RendererChoice};
use crate::store::Dataset;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, TryRecvError, channel};
use std::time::{Duration, Instant};

/// What to draw.
#[derive(Debug, Clone)]
pub struct Request {
    /// Increases with every request; frames carry the number they answer.
    pub seq: u64,
    pub camera: Camera,
    pub settings: Settings,
    /// The crosshair, as fractions of the view across and down (where a pick
    /// looks; the crosshair itself is drawn as cells, `overlay`).
    pub cursor: Option<(f64, f64)>,
    /// Whether to pick the point under the crosshair in this frame.
    pub pick: bool,
    /// The view pane in cells.
    pub cells: (u16, u16),
    /// Pixels per cell for the protocol in use.
    pub cell_pixels: (u32, u32),
    /// 1 for a full frame; n renders 1/n of the pixels each way (while the camera
    /// moves, over a slow link), scaled up by the terminal or by us.
    pub scale: u32,
    /// The most bytes a full frame should cost (the link is slow): sent in
    /// fewer colours to fit ([`protocol::encode_within`]); `None` sends it
    /// exact (a fast or unmeasured link, or the exact frame after a reduced one).
    pub allowance: Option<usize>,
    /// Where the terminal takes an image away when a cell over it is written
    /// (`Encoding::overlays_in_pixels`): the picks and the unit, drawn with
    /// the scale bar and the crosshair (`cursor`) into the frame's pixels.
    pub pixel_marks: Option<(Vec<[f64; 3]>, String)>,
}

/// A drawn and encoded frame.
pub struct FrameReady {
    pub seq: u64,
    /// Ready for the terminal; drawing it only copies cells.
    pub image: PaneImage,
    pub frame: Arc<Frame>,
    /// Cells the image covers.
    pub cells: (u16, u16),
    pub status: FrameStatus,
    /// When the request this frame answers was received by the worker.
    pub requested: Instant,
    /// The answer to a pick: the point under the crosshair, if any.
    pub pick: Option<Option<PointRecord>>,
}

impl Request {
    /// Whether `self` asks for the same picture as `other` (the crosshair, the
    /// pick and the sequence number aside).
    pub fn same_frame(&self, other: &Request) -> bool {
        self.camera == other.camera
            && self.settings == other.settings
            && self.cells == other.cells
            && self.cell_pixels == other.cell_pixels
            && self.scale == other.scale
            && self.pixel_marks == other.pixel_marks
            // Overlays in pixels: the crosshair is part of the picture.
            && (self.pixel_marks.is_none() || self.cursor == other.cursor)
    }
}

/// What the worker sends back.
pub enum Report {
    Frame(Box<FrameReady>),
    /// The answer to a pick over the frame last sent (a request for the same
    /// picture with a pick): the point under the crosshair, if any. No frame
    /// is drawn for it.
    Pick(Option<PointRecord>),
    Error(String),
}

/// How long the worker waits for more tiles before drawing what arrived.
const REDRAW_WHILE_LOADING: Duration = Duration::from_millis(60);
/// Points of the overview's top layers loaded before the first frame.
const OVERVIEW_FIRST_POINTS: u64 = 1_000_000;

/// The render worker thread and its two channels.
pub struct RenderWorker {
    requests: Option<Sender<Request>>,
    reports: Receiver<Report>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// How the worker is set up.
#[derive(Debug, Clone)]
pub struct WorkerOptions {
    pub encoding: protocol::Encoding,
    /// Bands loaded besides the colour bands (classification, bands filtered on).
    pub extra_bands: Vec<String>,
    pub renderer: RendererChoice,
    /// Bytes of loaded tiles kept.
    pub memory: u64,
    /// Tile loading threads.
    pub load_threads: usize,
}

impl RenderWorker {
    pub fn spawn(ds: Arc<Dataset>, opts: WorkerOptions) -> RenderWorker {
        let (req_tx, req_rx) = channel::<Request>();
        let (rep_tx, rep_rx) = channel::<Report>();
        let thread = std::thread::Builder::new()
            .name("pcimg-render".into())
            .spawn(move || run(ds, opts, req_rx, rep_tx))
            .expect("cannot start the render thread");
        RenderWorker {
            requests: Some(req_tx),
            reports: rep_rx,
            thread: Some(thread),
        }
    }

    /// Asks for a frame; returns at once. Older requests not yet started are dropped.
    pub fn request(&self, r: Request) {
        if let Some(tx) = &self.requests {
            let _ = tx.send(r);
        }
    }

    /// A report, if one is waiting; an error when the worker has stopped (it
    /// panicked: the panic hook has already restored the terminal).
    pub fn try_recv(&self) -> anyhow::Result<Option<Report>> {
        match self.reports.try_recv() {
            Ok(r) => Ok(Some(r)),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(anyhow::anyhow!("the render thread stopped")),
        }
    }

    /// Waits up to `timeout` for a report (for tests and measurements).
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Report> {
        self.reports.recv_timeout(timeout).ok()
    }
}

impl Drop for RenderWorker {
    fn drop(&mut self) {
        // Closing the request channel ends the thread after its current frame;
        // nobody waits for that.
        self.requests = None;
        drop(self.thread.take());
    }
}

struct Worker {
    opts: WorkerOptions,
    pipeline: Pipeline,
    /// The last frame drawn: its request and tiles (picks over it need no new one).
    last: Option<(Request, Vec<Arc<LoadedTile>>)>,
    /// Bytes of the last exact full frame, and the colours the last full frame
    /// reduced for a slow link was sent in ([`protocol::encode_within`]).
    slow: (Option<usize>, Option<usize>),
    /// The legend's histogram and what it was counted over (the tiles, the
    /// band and its range): a frame over the same tiles reuses it instead of
    /// counting every point again.
    histogram: Option<Counted>,
}

/// A legend histogram and what it counted: the tiles, the band, its range.
type Counted = (Vec<TileKey>, String, f64, f64, Vec<u32>);

fn run(
    ds: Arc<Dataset>,
    opts: WorkerOptions,
    requests: Receiver<Request>,
    reports: Sender<Report>,
) {
    let cache = TileCache::with_bands(
        ds.clone(),
        opts.memory,
        opts.load_threads.max(1),
        opts.extra_bands.clone(),
    );
    let first = first_tiles(&ds, &cache);
    let pipeline = Pipeline::new(ds, cache, opts.renderer, Loading::Stream).with_reference(first);
    let mut w = Worker {
        opts,
        pipeline,
        last: None,
        slow: (None, None),
        histogram: None,
    };
    let mut current: Option<(Request, Instant)> = None;
    let mut pending = 0usize;
    // What the last frame's status line said of tiles waiting to be retried.
    let mut told: Option<(usize, bool, String)> = None;
    loop {
        let mut dirty = false;
        let mut incoming = None;
        let got = if pending > 0 || told.is_some() {
            requests.recv_timeout(REDRAW_WHILE_LOADING)
        } else {
            requests.recv().map_err(|_| RecvTimeoutError::Disconnected)
        };
        match got {
            Ok(r) => incoming = Some(r),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return,
        }
        // Only the newest request matters.
        while let Ok(r) = requests.try_recv() {
            incoming = Some(r);
        }
        if let Some(r) = incoming {
            if r.pick && w.last.as_ref().is_some_and(|(l, _)| l.same_frame(&r)) {
                // A pick over the frame already sent: answered without a new one.
                // Redraws as tiles arrive answer it too (the loop drops older ones).
                if let Some((c, _)) = current.as_mut() {
                    c.seq = r.seq;
                }
                let report = match w.pick_only(&r) {
                    Ok(p) => Report::Pick(p),
                    Err(e) => Report::Error(crate::advice::message(&e)),
                };
                if reports.send(report).is_err() {
                    return;
                }
            } else {
                current = Some((r, Instant::now()));
                dirty = true;
            }
        }
        if w.pipeline.cache().arrivals.try_iter().count() > 0 {
            dirty = true;
        }
        // Retries going on: redrawn when the status line would say otherwise.
        if told.is_some() && told != retry_status(w.pipeline.cache()).as_ref().map(shown) {
            dirty = true;
        }
        let Some((req, received)) = current.as_mut() else {
            continue;
        };
        if !dirty {
            continue;
        }
        let result = w.frame(req, *received);
        // A pick is answered once; redraws as tiles arrive do not pick again.
        req.pick = false;
        match result {
            Ok(f) => {
                pending = f.status.pending;
                told = f.status.retry.as_ref().map(shown);
                if reports.send(Report::Frame(Box::new(f))).is_err() {
                    return;
                }
            }
            Err(e) => {
                pending = 0;
                told = None;
                if reports
                    .send(Report::Error(crate::advice::message(&e)))
                    .is_err()
                {
                    return;
                }
            }
        }
        for e in w.pipeline.cache().take_errors() {
            let _ = reports.send(Report::Error(crate::advice::store(&e)));
        }
    }
}

/// The tiles the view wants that wait to be tried again, for the status line
/// (`None`: none).
fn retry_status(cache: &TileCache) -> Option<RetryStatus> {
    let r = cache.retries();
    (r.tiles > 0).then(|| RetryStatus {
        tiles: r.tiles,
        attempts: r.attempts,
        failing_for: r.failing_for,
        error: r
            .last_error
            .as_ref()
            .map(crate::advice::retrying)
            .unwrap_or_default(),
    })
}

/// What of a [`RetryStatus`] the status line shows: a change redraws.
fn shown(r: &RetryStatus) -> (usize, bool, String) {
    let tell = r.tell();
    (
        r.tiles,
        tell,
        if tell { r.error.clone() } else { String::new() },
    )
}

/// The tiles colour ranges come from: the overview's top layers, loaded first
/// (they cover the whole dataset), or without an overview every part's coarsest
/// level (small, and fixed for the session so colours do not flicker as tiles
/// stream in).
fn first_tiles(ds: &Dataset, cache: &TileCache) -> Vec<Arc<LoadedTile>> {
    // With an overview, its top stands for the whole dataset: no part is read.
    let first: Vec<TileRef> = ds
        .overview_first(OVERVIEW_FIRST_POINTS)
        .into_iter()
        .map(|(part, level, tile, points)| TileRef {
            part,
            level,
            tile,
            points,
            bounds: ds.bounds(),
        })
        .collect();
    let refs: Vec<TileRef> = if !first.is_empty() {
        first
    } else {
        ds.part_ids()
            .unwrap_or_default()
            .into_iter()
            .filter_map(|pi| ds.part(pi).map(|p| (pi, p)))
            .filter_map(|(pi, p)| p.levels.last().map(|l| (pi, l)))
            .flat_map(|(pi, l)| {
                l.tiles.iter().map(move |t| TileRef {
                    part: pi,
                    level: l.index,
                    tile: t.index,
                    points: t.points.unwrap_or(0) as u64,
                    bounds: t.bounds,
                })
            })
            .collect()
    };
    cache.load_all(&refs).unwrap_or_default()
}

impl Worker {
    /// The point under the crosshair of `req` in the last frame drawn (which
    /// `req` asks for again), found without drawing one.
    fn pick_only(&mut self, req: &Request) -> anyhow::Result<Option<PointRecord>> {
        let Some((_, tiles)) = &self.last else {
            return Ok(None);
        };
        let s = Sizes::of(req);
        let hit = match s.pick(req) {
            Some(at) => self.pipeline.pick_in(tiles, &s.frame_request(req), at)?,
            None => None,
        };
        let ds = self.pipeline.dataset();
        let record = match hit {
            Some(h) => {
                Some(point_record(ds, tiles[h.batch].key, h.index).map_err(anyhow::Error::msg)?)
            }
            None => None,
        };
        Ok(record)
    }

    fn frame(&mut self, req: &Request, received: Instant) -> anyhow::Result<FrameReady> {
        let sizes = Sizes::of(req);
        let Sizes {
            cols,
            rows,
            full,
            width,
            height,
            scale,
        } = sizes;
        let mode = sizes.frame_request(req).mode;
        let d = self.pipeline.draw(&FrameRequest {
            pick: sizes.pick(req),
            ..sizes.frame_request(req)
        })?;
        self.last = Some((req.clone(), d.tiles.clone()));
        let ds = self.pipeline.dataset();
        let pick = match d.pick {
            Some(Some(h)) => Some(Some(
                point_record(ds, d.tile_of(&h), h.index).map_err(anyhow::Error::msg)?,
            )),
            Some(None) => Some(None),
            None => None,
        };

        let t = Instant::now();
        let view = super::overlay::FrameView {
            camera: req.camera,
            width,
            height,
        };
        // Overlays drawn into the pixels where cells would take the image away.
        let frame = match &req.pixel_marks {
            Some((picks, unit)) => {
                let marks = super::overlay::Marks {
                    cursor: req.cursor,
                    picks,
                    unit,
                };
                super::overlay::onto_pixels(&d.frame, &view, &marks)
            }
            None => d.frame,
        };
        // On a link known to be too slow for the exact frame (the last one was
        // bigger than this allowance), start where the last reduced one fit.
        let start = match (req.allowance, self.slow) {
            (Some(a), (Some(exact), colors)) if exact > a => {
                Some(colors.unwrap_or(protocol::SLOW_COLORS[0]))
            }
            _ => None,
        };
        let (image, colors) = protocol::encode_within(
            self.opts.encoding,
            &frame,
            (cols, rows),
            full,
            req.allowance,
            start,
        )?;
        if scale == 1 {
            match colors {
                Some(c) => self.slow.1 = Some(c),
                None => self.slow.0 = Some(image.bytes()),
            }
        }
        // A reduced frame that did not need the exact one's size measured:
        // the exact bytes seen when that was tried.
        if scale == 1 && colors.is_some() && start.is_none() {
            self.slow.0 = self.slow.0.max(req.allowance.map(|a| a + 1));
        }
        let encode_ms = ms(t);
        // The legend's ramp with the drawn points' values under it.
        let s = &req.settings;
        let ramp =
            s.style.mode.uses_ramp().then(|| {
                Legend::for_style(self.pipeline.dataset(), &s.style, &s.filter, &d.ranges)
            });
        let histogram = match ramp.flatten() {
            Some(Legend::Ramp { title, lo, hi, .. }) => {
                let keys: Vec<TileKey> = d.tiles.iter().map(|t| t.key).collect();
                match &self.histogram {
                    Some((k, b, l, h, counts))
                        if *k == keys && *b == title && *l == lo && *h == hi =>
                    {
                        counts.clone()
                    }
                    _ => {
                        let counts =
                            legend::histogram(&d.tiles, &title, lo, hi, super::panels::RAMP_CELLS);
                        self.histogram = Some((keys, title, lo, hi, counts.clone()));
                        counts
                    }
                }
            }
            _ => Vec::new(),
        };

        let cache = self.pipeline.cache();
        let mut loaded: BTreeMap<(usize, usize), usize> = BTreeMap::new();
        for k in cache.loaded() {
            *loaded.entry((k.part, k.level)).or_default() += 1;
        }
        let r = d.report;
        let status = FrameStatus {
            levels: r.levels,
            points: r.points,
            tiles: d.tiles.len(),
            pending: r.pending,
            unreadable: r.unreadable,
            retry: retry_status(cache),
            dropped: r.selection.dropped_tiles,
            overview_tiles: r.selection.overview_tiles,
            budget: match mode {
                LodMode::View { budget } => budget,
                _ => 0,
            },
            select_ms: r.select_ms,
            load_ms: r.load_ms,
            render_ms: r.render_ms,
            encode_ms,
            renderer: r.renderer,
            cache_bytes: cache.stats().bytes,
            loaded: loaded.into_iter().collect(),
            bytes: image.bytes(),
            scale,
            colors,
            ranges: d.ranges,
            units_per_pixel: 1.0 / req.camera.pixels_per_unit(req.camera.distance, height),
            histogram,
            view: Some(view),
        };
        Ok(FrameReady {
            seq: req.seq,
            image,
            frame: Arc::new(frame),
            cells: (cols, rows),
            status,
            requested: received,
            pick,
        })
    }
}

/// A request's sizes: the pane in cells, its full size in pixels, and the
/// frame's (1/`scale` of it each way).
#[derive(Debug, Clone, Copy)]
struct Sizes {
    cols: u16,
    rows: u16,
    full: (u32, u32),
    width: u32,
    height: u32,
    scale: u32,
}

impl Sizes {
    fn of(req: &Request) -> Sizes {
        let (cols, rows) = (req.cells.0.max(1), req.cells.1.max(1));
        let scale = req.scale.max(1);
        let full = (
            (cols as u32 * req.cell_pixels.0).clamp(1, render::MAX_FRAME_SIDE),
            (rows as u32 * req.cell_pixels.1).clamp(1, render::MAX_FRAME_SIDE),
        );
        let (width, height) = ((full.0 / scale).max(1), (full.1 / scale).max(1));
        Sizes {
            cols,
            rows,
            full,
            width,
            height,
            scale,
        }
    }

    /// The pipeline's request for `req`'s frame, without a pick.
    fn frame_request<'a>(&self, req: &'a Request) -> FrameRequest<'a> {
        let s = &req.settings;
        let mode = match s.lod_mode() {
            LodMode::View { budget } => LodMode::View {
                budget: lod::budget_for_pixels(self.width, self.height, budget),
            },
            m => m,
        };
        FrameRequest {
            camera: &req.camera,
            width: self.width,
            height: self.height,
            style: &s.style,
            filter: &s.filter,
            mode,
            memory: s.memory,
            point_size: s.point_size,
            eye_dome_lighting: s.edl,
            edl: s.edl_params,
            pick: None,
            // The scale bar, crosshair and picks are drawn as cells over the
            // picture (`overlay`), the legend in the tool panel.
            overlays: Overlays::default(),
        }
    }

    /// The pixel under the crosshair and the radius searched, when `req` picks.
    fn pick(&self, req: &Request) -> Option<(u32, u32, u32)> {
        let (x, y) = req.cursor.filter(|_| req.pick)?;
        Some((
            ((x * self.width as f64) as u32).min(self.width - 1),
            ((y * self.height as f64) as u32).min(self.height - 1),
            req_pick_radius(self.width),
        ))
    }
}

/// Pixels around the crosshair a pick searches: about half a terminal cell.
fn req_pick_radius(width: u32) -> u32 {
    (width / 200).clamp(2, 8)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
