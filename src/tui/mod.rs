//! `pcimg inspect`, the terminal inspector: panels describing a dataset beside a
//! live view of it, driven by the keyboard, over SSH and without a GPU.
//!
//! One concern per file: [`app`] (state machine, key commands → state changes),
//! [`keys`] (the key map and help), [`ui`] (layout), [`overlay`] (the scale bar,
//! crosshair and picks as cells over the picture), [`worker`] (select → load →
//! render → encode on a worker thread), [`protocol`] (which terminal image
//! protocol, and encoding for it), `terminal` (entering and restoring the
//! terminal). This file holds the event loop, which never waits on loading or
//! rendering: it sends requests and polls for finished frames between key presses.

pub mod app;
pub mod clipbox;
pub mod keys;
pub mod overlay;
pub mod panels;
pub mod protocol;
pub mod section;
mod terminal;
pub mod ui;
pub mod worker;

use crate::camera::Camera;
use crate::render::{Frame, RendererChoice};
use crate::store::Dataset;
use app::{App, Effect, Settings};
use protocol::PaneImage;
use ratatui::layout::Rect;
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::{Duration, Instant};
use worker::{RenderWorker, Report, Request, WorkerOptions};

/// How the inspector starts.
#[derive(Debug, Clone)]
pub struct InspectOptions {
    /// `--protocol`.
    pub protocol: crate::term::Protocol,
    /// `--symbols`: the text protocol's symbols, when given.
    pub symbols: Option<crate::term::symbols::SymbolSet>,
    pub renderer: RendererChoice,
    pub camera: Camera,
    pub settings: Settings,
    /// Bands tiles load besides the colour bands (classification, filtered bands).
    pub extra_bands: Vec<String>,
    /// Tile loading threads.
    pub load_threads: usize,
    /// A temporary directory to remove should the process have to be ended by
    /// force (a terminal gone while reading it): `demo`'s dataset.
    pub temporary: Option<PathBuf>,
}

/// Set by SIGTERM / SIGHUP: the loop ends and the terminal is restored.
static STOP: AtomicBool = AtomicBool::new(false);
/// Set when the event loop has returned (the signal handler's watchdog stands down).
static LOOP_ENDED: AtomicBool = AtomicBool::new(false);
/// Whether the inspector's loop runs now (for [`on_signal`]'s callers).
static RUNNING: AtomicBool = AtomicBool::new(false);
/// [`InspectOptions::temporary`], for the forced exit.
static TEMPORARY: std::sync::Mutex<Option<PathBuf>> = std::sync::Mutex::new(None);

/// How long the loop waits for a key before looking for finished frames.
const POLL: Duration = Duration::from_millis(8);

/// Runs the inspector on `ds` until the user quits (the terminal is restored on
/// every exit path); returns the camera it ended with.
pub fn run(ds: Arc<Dataset>, opts: InspectOptions) -> anyhow::Result<Camera> {
    // Ask the terminal (or the tmux server) once, before raw mode and the loop.
    let mut found = crate::term::detect(opts.protocol, crate::term::probe::CAP);
    if let Some(set) = opts.symbols {
        found.use_symbols(set);
    }
    found.prepare();
    let graphics = found.choice.graphics;
    let encoding = protocol::Encoding {
        graphics,
        passthrough: found.choice.passthrough,
        placeholders: found.choice.kitty_placeholders,
        text: (found.choice.text.set, found.choice.text.depth),
        overlays_in_pixels: found.choice.text_erases_images,
    };
    let cell_pixels = found.cell_pixels;
    // Termination signals end the loop (the first handler of the process wins;
    // a command that installs its own first forwards to [`on_signal`]).
    let _ = ctrlc::set_handler(on_signal);
    RUNNING.store(true, Ordering::SeqCst);

    if let Ok(mut t) = TEMPORARY.lock() {
        t.clone_from(&opts.temporary);
    }
    let worker = RenderWorker::spawn(
        ds.clone(),
        WorkerOptions {
            encoding,
            extra_bands: opts.extra_bands.clone(),
            renderer: opts.renderer,
            memory: opts.settings.memory,
            load_threads: opts.load_threads,
        },
    );
    let mut app = App::new(ds, opts.camera, opts.settings);
    app.protocol = graphics.name().into();
    app.overlays_in_pixels = encoding.overlays_in_pixels;
    app.terminal_note = crate::advice::protocol_note(&found.choice).unwrap_or_default();
    let typed = crate::term::typed::key_events(found.typed());
    let mut session = terminal::Session::enter(encoding)?;
    let result = event_loop(
        &mut session,
        &mut app,
        &worker,
        Pane {
            graphics,
            encoding,
            cell_pixels,
        },
        typed,
    );
    LOOP_ENDED.store(true, Ordering::SeqCst);
    RUNNING.store(false, Ordering::SeqCst);
    drop(session);
    result.map(|()| app.camera)
}

/// Whether the inspector runs now: a signal handler installed by a command
/// before it (`demo`) passes termination signals on to [`on_signal`] then.
pub fn running() -> bool {
    RUNNING.load(Ordering::SeqCst)
}

/// SIGINT, SIGTERM, SIGHUP while the inspector runs: the loop ends and the
/// terminal is restored. Should the loop not get there within a second (stuck in
/// a read from a terminal that is gone), the terminal is restored, the temporary
/// directory removed, and the process ends.
pub fn on_signal() {
    STOP.store(true, Ordering::SeqCst);
    std::thread::sleep(Duration::from_secs(1));
    if !LOOP_ENDED.load(Ordering::SeqCst) {
        terminal::restore();
        if let Some(dir) = TEMPORARY.lock().ok().and_then(|mut t| t.take()) {
            let _ = std::fs::remove_dir_all(dir);
        }
        std::process::exit(130);
    }
}

/// What the view pane shows now.
#[derive(Default)]
struct Shown {
    image: Option<PaneImage>,
    /// The image arrived since the last draw (the next draw sends it).
    unsent: bool,
    frame: Option<Arc<Frame>>,
    arrivals: VecDeque<Instant>,
}

/// How the view pane is drawn: the protocol and a cell's size in pixels.
#[derive(Debug, Clone, Copy)]
struct Pane {
    graphics: protocol::Graphics,
    encoding: protocol::Encoding,
    cell_pixels: (u32, u32),
}

/// After the last key that moved the camera, how long before the full-resolution
/// frame is asked for (frames while keys keep coming are reduced). Longer than
/// a keyboard's auto-repeat interval (25–40 ms), so held keys stay "moving".
const SETTLE: Duration = Duration::from_millis(60);

/// Most bytes a frame may cost while the camera moves.
const MOVING_BYTES: usize = 150_000;
/// Most time a moving frame may take to reach the terminal, at the measured rate
/// (a held key repeats every 25-40 ms; frames should keep up with a few).
const MOVING_TRANSFER: f64 = 0.06;

/// Most time the full frame after the camera stops may take to reach the
/// terminal at the measured rate: with the settle time, rendering and a moving
/// frame still on its way, the picture is whole within ~0.3 s of the last key.
/// A full frame that would take longer is sent in fewer colours first
/// ([`protocol::encode_within`]), the exact one after [`REFINE_AFTER`].
const FULL_TRANSFER: f64 = 0.12;

/// How long after a full frame reduced for a slow link, with no key since,
/// the exact frame is asked for.
const REFINE_AFTER: Duration = Duration::from_millis(250);

/// What the event loop knows of how fast the terminal takes our output, and the
/// reduction moving frames get.
#[derive(Debug)]
struct Link {
    /// Bytes per second, smoothed, from draws that took long enough to measure.
    rate: Option<f64>,
    /// 1/n of the pane's pixels each way for moving frames.
    scale: u32,
}

impl Default for Link {
    fn default() -> Link {
        Link {
            rate: None,
            scale: 2,
        }
    }
}

impl Link {
    /// Records a draw of `bytes` that took `took`.
    fn record(&mut self, bytes: usize, took: Duration) {
        // Short writes measure the kernel's buffer, not the link.
        if bytes < 32 * 1024 || took < Duration::from_millis(4) {
            return;
        }
        let r = bytes as f64 / took.as_secs_f64();
        self.rate = Some(self.rate.map_or(r, |old| 0.5 * old + 0.5 * r));
    }

    /// The most bytes a full frame should cost on this link: what it carries
    /// in [`FULL_TRANSFER`]. `None` while the rate is unknown (nothing large
    /// has been drawn yet): full frames are sent exact then. On a fast link
    /// (a local terminal, 100 Mbit/s) the allowance is above any frame's
    /// bytes, so nothing changes there.
    fn full_allowance(&self) -> Option<usize> {
        self.rate.map(|r| (r * FULL_TRANSFER).round() as usize)
    }

    /// A moving frame of `bytes` at 1/`scale` arrived: the next ones are
    /// reduced more when it cost more than [`MOVING_BYTES`] or would take more
    /// than [`MOVING_TRANSFER`] on this link, less when it cost under a third.
    fn moving_frame(&mut self, bytes: usize, scale: u32) {
        let slow = self
            .rate
            .is_some_and(|r| bytes as f64 / r > MOVING_TRANSFER);
        if bytes > MOVING_BYTES || slow {
            self.scale = (scale + 1).min(MAX_SCALE);
        } else if bytes < MOVING_BYTES / 3 && scale > 2 {
            self.scale = scale - 1;
        }
    }
}

/// The most a moving frame is reduced (1/4 of the pixels each way).
const MAX_SCALE: u32 = 4;

fn event_loop(
    session: &mut terminal::Session,
    app: &mut App,
    worker: &RenderWorker,
    pane: Pane,
    typed: Vec<crossterm::event::KeyEvent>,
) -> anyhow::Result<()> {
    use crossterm::event::{self, Event};
    let mut shown = Shown::default();
    let (msg_tx, msg_rx): (Sender<String>, Receiver<String>) = channel();
    let mut typed: VecDeque<_> = typed.into();
    let mut seq = 0u64;
    let mut want_frame = true;
    let mut requested_cells = (0u16, 0u16);
    let mut dirty = true;
    let mut saved = 0u32;
    let mut help_shown = false;
    // Frames asked for while keys come are reduced; the full one follows.
    let mut last_move: Option<Instant> = None;
    let mut moving = false;
    let mut full_owed = false;
    // A full frame went out reduced for a slow link: the exact one is owed,
    // asked for once no key has come for [`REFINE_AFTER`] since it was drawn.
    let mut refine_owed = false;
    let mut exact_next = false;
    let mut last_image_draw = Instant::now();
    let mut link = Link::default();
    // The overlay cells drawn last (`overlay`).
    let mut drawn_marks: Vec<overlay::Mark> = Vec::new();
    let scalable = pane.graphics != protocol::Graphics::Halfblocks;
    // Overlays in pixels: the marks the last frame asked for was drawn with
    // (a change to them needs a new frame).
    let pixel_marks = |app: &App| {
        app.overlays_in_pixels.then(|| {
            let picks: Vec<[f64; 3]> = app.picks.iter().map(|p| p.position).collect();
            (picks, app.unit.clone())
        })
    };
    let mut requested_marks = None;
    loop {
        if STOP.load(Ordering::SeqCst) {
            return Ok(());
        }
        let size = session.terminal.size()?;
        let view = ui::areas(Rect::new(0, 0, size.width, size.height), app).view_inner;
        let cells = (view.width, view.height);
        if cells != requested_cells {
            want_frame = true;
        }
        if app.overlays_in_pixels
            && requested_marks != Some((pixel_marks(app), app.picking.then_some(app.cursor)))
        {
            want_frame = true;
        }
        if full_owed && !want_frame && last_move.is_some_and(|t| t.elapsed() >= SETTLE) {
            moving = false;
            want_frame = true;
        }
        if refine_owed
            && !want_frame
            && !full_owed
            && !shown.unsent
            && last_image_draw.elapsed() >= REFINE_AFTER
            && last_move.is_none_or(|t| t.elapsed() >= REFINE_AFTER)
        {
            refine_owed = false;
            exact_next = true;
            want_frame = true;
        }
        if want_frame && cells.0 > 0 && cells.1 > 0 {
            seq += 1;
            let scale = if moving && scalable { link.scale } else { 1 };
            full_owed = scale > 1;
            let allowance = if scale == 1 && !std::mem::take(&mut exact_next) {
                link.full_allowance()
            } else {
                None
            };
            worker.request(Request {
                seq,
                camera: app.camera,
                settings: app.settings.clone(),
                cursor: app.picking.then_some(app.cursor),
                pick: std::mem::take(&mut app.pick_pending),
                cells,
                cell_pixels: pane.cell_pixels,
                scale,
                allowance,
                pixel_marks: pixel_marks(app),
            });
            requested_marks = Some((pixel_marks(app), app.picking.then_some(app.cursor)));
            requested_cells = cells;
            want_frame = false;
        }
        if !help_shown && app.show_help && protocol::image_above_text(pane.encoding) {
            // A kitty image placed directly would stay above the help's text:
            // taken off now, placed again by the redraw when the help closes.
            use std::io::Write as _;
            let out = session.terminal.backend_mut();
            out.write_all(protocol::kitty_delete_sequence(pane.encoding.passthrough).as_bytes())?;
            out.flush()?;
        }
        if help_shown && !app.show_help && protocol::image_in_one_cell(pane.encoding) {
            // The help was drawn over the image's skipped cells; ratatui would not
            // send those again, so its text would stay. Redraw everything once.
            session.terminal.clear()?;
            dirty = true;
        }
        help_shown = app.show_help;
        // Frames per second over the last two seconds: 0 (shown as idle) once
        // frames stop coming.
        let now = Instant::now();
        while shown
            .arrivals
            .front()
            .is_some_and(|t| now - *t > Duration::from_secs(2))
        {
            shown.arrivals.pop_front();
        }
        let rate = fps(&shown.arrivals);
        if rate != app.fps {
            app.fps = rate;
            dirty = true;
        }
        if dirty {
            let t = Instant::now();
            // A kitty image placed directly would cover the help: not drawn while
            // it shows (taken off when it opened, above).
            let covered = app.show_help && protocol::image_above_text(pane.encoding);
            let image = shown.image.as_ref().filter(|_| !covered);
            // Only a draw that sends a new image says how fast the link is.
            let image_bytes = if shown.unsent {
                image.map_or(0, |i| i.bytes())
            } else {
                0
            };
            let marks = image.map_or_else(Vec::new, |i| overlay::of_app(app, view, i));
            let done = session.terminal.draw(|f| ui::draw(f, app, image))?;
            // Overlay cells over an image sent from the pane's first cell are
            // written again where the image went over them (or left them).
            let patch = |(x, y, n): (u16, u16, u16)| {
                let (frame, image) = (shown.frame.as_ref()?, image?);
                let at = (x.checked_sub(view.x)?, y.checked_sub(view.y)?, n);
                protocol::patch(pane.encoding, frame, image.cells(), pane.cell_pixels, at)
            };
            let again = match image {
                Some(_) if !app.show_help => overlay::rewrite(
                    done.buffer,
                    pane.encoding,
                    shown.unsent,
                    (&drawn_marks, &marks),
                    (view.x, view.y),
                    &patch,
                ),
                _ => Vec::new(),
            };
            if !again.is_empty() {
                use ratatui::backend::Backend as _;
                let out = session.terminal.backend_mut();
                out.draw(again.iter().map(|(x, y, c)| (*x, *y, c)))?;
                ratatui::backend::Backend::flush(out)?;
            }
            drawn_marks = marks;
            shown.unsent &= covered;
            link.record(image_bytes, t.elapsed());
            if image_bytes > 0 {
                last_image_draw = Instant::now();
            }
            app.link_rate = link.rate;
            dirty = false;
        }
        if terminal::hung_up() {
            // The terminal went away: nothing to restore, nobody to show frames to.
            return Ok(());
        }
        // Keys typed while the terminal was probed come first. Every key already
        // waiting is taken before the next frame is asked for: after a slow
        // draw, a burst of orbit keys makes one frame, not one each.
        let mut events = Vec::new();
        if let Some(k) = typed.pop_front() {
            events.push(Event::Key(k));
        } else if event::poll(POLL)? {
            events.push(event::read()?);
            while events.len() < 256 && event::poll(Duration::ZERO)? {
                events.push(event::read()?);
            }
        }
        for ev in events {
            match ev {
                Event::Key(k) => {
                    let Some(cmd) = keys::command_for(k) else {
                        continue;
                    };
                    let effect = app.apply(cmd);
                    if effect != Effect::None {
                        app.message.clear();
                    }
                    match effect {
                        Effect::Quit => return Ok(()),
                        Effect::Render => {
                            want_frame = true;
                            moving = true;
                            refine_owed = false;
                            last_move = Some(Instant::now());
                        }
                        // The frame stays as it is; its request carries the pick.
                        Effect::Pick => want_frame = true,
                        Effect::Save => {
                            saved += 1;
                            let picks = app.picks.iter().map(|p| p.position).collect();
                            let marks =
                                (picks, app.picking.then_some(app.cursor), app.unit.clone());
                            save_frame(
                                shown.frame.clone(),
                                app.frame.view.map(|v| (v, marks)),
                                saved,
                                msg_tx.clone(),
                            );
                            app.message = "saving the frame…".into();
                        }
                        Effect::Suspend => {
                            session.suspend()?;
                            want_frame = true;
                        }
                        Effect::Repaint => {
                            session.terminal.clear()?;
                            want_frame = true;
                        }
                        Effect::Redraw | Effect::None => {}
                    }
                    dirty = true;
                }
                Event::Mouse(m) => {
                    use crossterm::event::{MouseButton, MouseEventKind};
                    let v = ui::areas(Rect::new(0, 0, size.width, size.height), app).view_inner;
                    let inside = m.column >= v.x
                        && m.row >= v.y
                        && m.column < v.x + v.width
                        && m.row < v.y + v.height;
                    // A click on a class row of the legend shows or hides the class.
                    let tools = ui::areas(Rect::new(0, 0, size.width, size.height), app).tools;
                    if m.kind == MouseEventKind::Down(MouseButton::Left)
                        && m.column > tools.x
                        && m.column + 1 < tools.x + tools.width
                        && m.row > tools.y
                        && m.row + 1 < tools.y + tools.height
                    {
                        let row = (m.row - tools.y - 1) as usize;
                        if app.apply(keys::Command::ToggleClassRow(row)) == Effect::Render {
                            want_frame = true;
                        }
                        dirty = true;
                    }
                    if m.kind == MouseEventKind::Down(MouseButton::Left) && inside {
                        // The middle of the clicked cell, as fractions of the view.
                        let fx = (m.column - v.x) as f32 + 0.5;
                        let fy = (m.row - v.y) as f32 + 0.5;
                        let cmd = keys::Command::PickAt(fx / v.width as f32, fy / v.height as f32);
                        if app.apply(cmd) == Effect::Pick {
                            want_frame = true;
                        }
                        dirty = true;
                    }
                }
                Event::Resize(..) => dirty = true,
                _ => {}
            }
        }
        // Only the newest finished frame is drawn: older ones are dropped, so
        // nothing queues behind a slow terminal.
        loop {
            match worker.try_recv() {
                Ok(Some(Report::Frame(f))) => {
                    // A pick is kept whatever the frame: it answers the click.
                    if let Some(p) = f.pick {
                        // Its mark is drawn over the frame (`overlay`).
                        app.add_pick(p);
                    }
                    // A frame for a request already superseded is stale: sending
                    // it would only delay the newer one on a slow terminal.
                    if f.seq < seq && shown.image.is_some() {
                        continue;
                    }
                    shown.arrivals.push_back(Instant::now());
                    if f.status.scale > 1 {
                        link.moving_frame(f.status.bytes, f.status.scale);
                    }
                    refine_owed = f.status.colors.is_some();
                    app.frame = f.status;
                    shown.image = Some(f.image);
                    shown.unsent = true;
                    shown.frame = Some(f.frame);
                    dirty = true;
                }
                Ok(Some(Report::Pick(p))) => {
                    app.add_pick(p);
                    dirty = true;
                }
                Ok(Some(Report::Error(e))) => {
                    app.message = crate::text::sanitize(&e);
                    dirty = true;
                }
                Ok(None) => break,
                Err(e) => return Err(e),
            }
        }
        while let Ok(m) = msg_rx.try_recv() {
            app.message = crate::text::sanitize(&m);
            dirty = true;
        }
    }
}

/// Frames per second over the arrivals of the last two seconds.
fn fps(arrivals: &VecDeque<Instant>) -> f64 {
    match (arrivals.front(), arrivals.back()) {
        (Some(a), Some(b)) if arrivals.len() > 1 && b > a => {
            (arrivals.len() - 1) as f64 / (*b - *a).as_secs_f64()
        }
        _ => 0.0,
    }
}

/// What a saved frame shows over the points: how it was drawn, the picks, the
/// crosshair and the unit.
type SavedMarks = (
    overlay::FrameView,
    (Vec<[f64; 3]>, Option<(f64, f64)>, String),
);

/// Saves a frame as `pcimg-frame-NNN.png` in the working directory, with the
/// view's overlays drawn into its pixels, on a thread; the outcome comes back
/// as a message.
fn save_frame(frame: Option<Arc<Frame>>, marks: Option<SavedMarks>, n: u32, done: Sender<String>) {
    std::thread::spawn(move || {
        let msg = match frame {
            None => "no frame to save yet".to_string(),
            Some(f) => {
                let f = match &marks {
                    Some((view, (picks, cursor, unit))) => {
                        let m = overlay::Marks {
                            cursor: *cursor,
                            picks,
                            unit,
                        };
                        Arc::new(overlay::onto_pixels(&f, view, &m))
                    }
                    None => f,
                };
                let mut path = PathBuf::from(format!("pcimg-frame-{n:03}.png"));
                let mut k = n;
                while path.exists() {
                    k += 1;
                    path = PathBuf::from(format!("pcimg-frame-{k:03}.png"));
                }
                match f.save_png(&path) {
                    Ok(()) => format!("saved {} ({}×{} px)", path.display(), f.width, f.height),
                    Err(e) => format!("could not save: {e}"),
                }
            }
        };
        let _ = done.send(msg);
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_frames_are_reduced_until_they_fit_the_budget_and_the_link() {
        let mut link = Link::default();
        assert_eq!(link.scale, 2);
        link.moving_frame(200_000, 2);
        assert_eq!(link.scale, 3);
        link.moving_frame(100_000, 3);
        assert_eq!(link.scale, 3, "within the budget: kept");
        link.moving_frame(20_000, 3);
        assert_eq!(link.scale, 2, "far under it: less reduced");
        // A 1.25 MB/s link (10 Mbit/s): 100 KB takes 80 ms, over the 60 ms allowed.
        link.record(500_000, Duration::from_millis(400));
        link.moving_frame(100_000, 2);
        assert_eq!(link.scale, 3);
        for _ in 0..5 {
            link.moving_frame(900_000, link.scale);
        }
        assert_eq!(link.scale, MAX_SCALE);
        // 10 Mbit/s: a full frame may cost 150 KB (0.12 s of it).
        assert_eq!(link.full_allowance(), Some(150_000));
        // Short writes say nothing about the link.
        let mut fresh = Link::default();
        fresh.record(10_000, Duration::from_millis(50));
        fresh.record(100_000, Duration::from_millis(1));
        assert_eq!(fresh.rate, None);
        assert_eq!(fresh.full_allowance(), None, "unknown: exact frames");
        // 100 Mbit/s: 1.5 MB, more than any full frame (~320 K sixel, ~520 K kitty).
        fresh.record(1_250_000, Duration::from_millis(100));
        assert_eq!(fresh.full_allowance(), Some(1_500_000));
    }
}
