//! The inspector's state machine: the dataset, the selected part, the camera, the
//! level-of-detail choice, colour, point size, eye-dome lighting, point budget and
//! the status of the last frame. [`App::apply`] turns a [`Command`] into a state
//! change and says what the event loop must do next; nothing here touches a
//! terminal, a thread or a file, so every key can be tested on its own.

pub use super::clipbox::ClipBox;
use super::keys::Command;
pub use super::overlay::FrameView;
pub use super::section::Section;
use crate::camera::Camera;
use crate::lod::LodMode;
use crate::lod::point::PointRecord;
use crate::render::color::ColorMode;
use crate::render::edl::EdlParams;
use crate::render::filter::Filter;
use crate::render::legend::{ClassEntry, Legend};
use crate::render::scene::{ColorRanges, Style};
use crate::store::Dataset;
use std::sync::Arc;
use std::time::Duration;

/// How pyramid levels are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LodChoice {
    /// View-dependent, per tile, under the point budget.
    View,
    /// The paper's distance rule: one level for all parts.
    Distance,
    /// One level everywhere (clamped per part).
    Pinned(usize),
}

impl LodChoice {
    /// Short name for the status line.
    pub fn label(&self) -> String {
        match self {
            LodChoice::View => "auto (view-dependent)".into(),
            LodChoice::Distance => "auto (distance rule)".into(),
            LodChoice::Pinned(k) => format!("pinned level {k}"),
        }
    }
}

/// Everything that decides what a frame shows, apart from the camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub lod: LodChoice,
    /// The colour mode, and the ramp and range of ramp modes.
    pub style: Style,
    /// Which points are drawn (classes, band ranges, the clip box).
    pub filter: Filter,
    /// Splat side in pixels, 1..=3.
    pub point_size: u32,
    pub edl: bool,
    pub edl_params: EdlParams,
    /// Points drawn at most in view-dependent mode.
    pub budget: u64,
    /// Bytes of loaded tiles kept in memory.
    pub memory: u64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            lod: LodChoice::View,
            style: Style::of(ColorMode::Rgb),
            filter: Filter::default(),
            point_size: 1,
            edl: false,
            edl_params: EdlParams::default(),
            budget: DEFAULT_BUDGET,
            memory: 2 << 30,
        }
    }
}

impl Settings {
    /// The level selection mode for `lod::select`.
    pub fn lod_mode(&self) -> LodMode {
        match self.lod {
            LodChoice::View => LodMode::View {
                budget: self.budget,
            },
            LodChoice::Distance => LodMode::Distance,
            LodChoice::Pinned(k) => LodMode::Fixed(k),
        }
    }
}

/// The default point budget (a cap: a frame draws about two points a pixel).
pub const DEFAULT_BUDGET: u64 = crate::lod::DEFAULT_BUDGET_CAP;
/// Point budgets `b` and `B` stay within.
pub const BUDGET_RANGE: (u64, u64) = (15_625, 256_000_000);
/// Radians per orbit step.
const ORBIT_STEP: f64 = 10.0 * std::f64::consts::PI / 180.0;
/// Share of the orbit distance per pan step.
const PAN_STEP: f64 = 0.1;
/// Distance factor per zoom-in step.
const ZOOM_STEP: f64 = 0.8;

/// The order `c` cycles through (classification only where the data has it;
/// a `band:NAME` given on the command line is left for the next in the cycle).
pub const COLOR_CYCLE: [ColorMode; 6] = [
    ColorMode::Rgb,
    ColorMode::Intensity,
    ColorMode::Height,
    ColorMode::Classification,
    ColorMode::Level,
    ColorMode::Part,
];

/// Crosshair steps across the view per key press (shift: coarser).
const CURSOR_STEP: f64 = 1.0 / 64.0;
/// EDL strength factor per `<` / `>`, and its limits.
const EDL_STEP: f32 = 1.5;
const EDL_STRENGTH: (f32, f32) = (0.1, 10.0);

/// What the event loop does after a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Effect {
    /// Nothing changed.
    None,
    /// Only the panels changed: redraw.
    Redraw,
    /// The frame is out of date: ask the worker for a new one.
    Render,
    /// Pick the point under the crosshair (the frame itself is up to date).
    Pick,
    /// Save the current frame.
    Save,
    /// Stop until the shell continues the process (Ctrl-Z).
    Suspend,
    /// Clear and draw everything again.
    Repaint,
    Quit,
}

/// `x y z` as a panel shows them (millimetres).
pub fn format_xyz(p: [f64; 3]) -> String {
    format!("{:.3} {:.3} {:.3}", p[0], p[1], p[2])
}

/// What the last frame was, as the worker reported it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameStatus {
    /// Finest and coarsest level drawn.
    pub levels: Option<(usize, usize)>,
    pub points: u64,
    pub tiles: usize,
    /// Tiles of the selection still loading (coarser cached tiles stand in).
    pub pending: usize,
    /// Tiles of the selection that cannot be read.
    pub unreadable: usize,
    /// Tiles whose loads failed for a reason that may pass (the server did not
    /// answer), tried again in the background.
    pub retry: Option<RetryStatus>,
    /// Tiles in view given up for the point or memory budget.
    pub dropped: usize,
    /// Tiles of overview nodes drawn.
    pub overview_tiles: usize,
    /// The point budget the frame was selected under (view mode: the pixels'
    /// share of the budget setting), 0 in other modes.
    pub budget: u64,
    pub select_ms: f64,
    pub load_ms: f64,
    pub render_ms: f64,
    pub encode_ms: f64,
    pub renderer: String,
    /// Bytes of loaded tiles in the cache.
    pub cache_bytes: u64,
    /// Loaded tiles per (part, level).
    pub loaded: Vec<((usize, usize), usize)>,
    /// Bytes of escape sequences the frame costs the terminal.
    pub bytes: usize,
    /// 1: full resolution; n: 1/n of the pane's pixels each way (while moving).
    pub scale: u32,
    /// The colours a full frame was reduced to for a slow link (the exact
    /// frame follows once the link is idle); `None`: as the protocol sends it.
    pub colors: Option<usize>,
    /// The colour ranges the frame was coloured with (the legend's values).
    pub ranges: ColorRanges,
    /// Ground units a pixel of the frame spans at the orbit target.
    pub units_per_pixel: f64,
    /// Points of the drawn tiles per cell of the legend's ramp (its values
    /// from low to high), when colouring through one.
    pub histogram: Vec<u32>,
    /// The camera and pixel size the frame was drawn with (the overlays
    /// project with them); `None` before the first frame.
    pub view: Option<FrameView>,
}

/// Tiles the view wants that wait to be tried again, as the status line tells
/// them.
#[derive(Debug, Clone, PartialEq)]
pub struct RetryStatus {
    /// How many.
    pub tiles: usize,
    /// The most failed tries in a row of any of them.
    pub attempts: u32,
    /// Since the first failure of the one failing longest.
    pub failing_for: Duration,
    /// The latest failure with what to do about it (`advice`).
    pub error: String,
}

impl RetryStatus {
    /// Failed tries in a row after which the status line says what failed.
    pub const TELL_AFTER_ATTEMPTS: u32 = 3;
    /// Or failing this long.
    pub const TELL_AFTER: Duration = Duration::from_secs(5);

    /// Whether the tries have failed long enough to say what failed (at first
    /// only that requests are retried: a brief hiccup should not alarm).
    pub fn tell(&self) -> bool {
        self.attempts >= Self::TELL_AFTER_ATTEMPTS || self.failing_for >= Self::TELL_AFTER
    }

    /// The status line's words for it.
    pub fn describe(&self) -> String {
        let n = self.tiles;
        let what = if n == 1 { "request" } else { "requests" };
        if self.tell() {
            format!("retrying {n} {what}: {}", self.error)
        } else {
            format!("retrying {n} {what}")
        }
    }
}

/// The inspector's state.
pub struct App {
    pub dataset: Arc<Dataset>,
    /// Index of the part the panels describe.
    pub part: usize,
    pub camera: Camera,
    /// The camera `r` returns to.
    pub home: Camera,
    pub settings: Settings,
    pub show_help: bool,
    /// A message for the user (saved frames, errors), already sanitized.
    pub message: String,
    pub frame: FrameStatus,
    /// Frames shown per second, measured by the event loop.
    pub fps: f64,
    /// Name of the image protocol in use.
    pub protocol: String,
    /// The overlays are drawn into the frame's pixels by the worker, not as
    /// cells (`protocol::Encoding::overlays_in_pixels`).
    pub overlays_in_pixels: bool,
    /// Why the terminal gets no images, or that it did not answer (from
    /// detection), kept in the status line.
    pub terminal_note: String,
    /// Bytes per second the terminal took our output at, when measured.
    pub link_rate: Option<f64>,
    /// Pick mode: the crosshair is shown and the arrows move it.
    pub picking: bool,
    /// The crosshair, as a fraction of the view (0..1 across, 0..1 down).
    pub cursor: (f64, f64),
    /// A pick the next frame request carries (the crosshair's position).
    pub pick_pending: bool,
    /// The last two picked points, oldest first.
    pub picks: Vec<PointRecord>,
    /// The symbol of the dataset's unit of length (`m`, `ft`; `units` when its
    /// CRS does not say), for the scale bar and distances.
    pub unit: String,
    /// The legend row selected for `space` (classification colour).
    pub legend_row: usize,
    /// The section (a slab seen from the side), while one is shown.
    pub section: Option<Section>,
    /// The clip box the keys move and size, while one is on (mirrored in the
    /// filter's clip).
    pub clip: Option<ClipBox>,
    /// The last clip box, shown again by `o`.
    pub clip_hidden: Option<ClipBox>,
}

impl App {
    pub fn new(dataset: Arc<Dataset>, camera: Camera, settings: Settings) -> App {
        let settings_clip = settings
            .filter
            .clip
            .map(|c| ClipBox::start(&dataset.bounds(), Some(c)));
        App {
            unit: crate::render::legend::dataset_unit(&dataset),
            dataset,
            part: 0,
            home: camera,
            camera,
            settings,
            show_help: false,
            message: String::new(),
            frame: FrameStatus::default(),
            fps: 0.0,
            protocol: String::new(),
            overlays_in_pixels: false,
            terminal_note: String::new(),
            link_rate: None,
            picking: false,
            cursor: (0.5, 0.5),
            pick_pending: false,
            picks: Vec::new(),
            legend_row: 0,
            section: None,
            clip: settings_clip,
            clip_hidden: None,
        }
    }

    /// Whether some part has a `classification` band.
    /// The bands `v` cycles through: every band some part has, z first, x and
    /// y left out.
    pub fn band_names(&self) -> Vec<String> {
        let mut names: Vec<String> = vec!["z".into()];
        for b in self.dataset.totals().shown_bands() {
            if !names.contains(b) && !["x", "y", "z"].contains(&b.as_str()) {
                names.push(b.clone());
            }
        }
        names
    }

    pub fn has_classes(&self) -> bool {
        self.dataset
            .totals()
            .bands
            .iter()
            .any(|b| b == "classification")
    }

    /// The parts the panels list: every part, but for a paged index those of
    /// the pages the views have reached so far.
    pub fn part_ids(&self) -> Vec<usize> {
        self.dataset.loaded_part_ids()
    }

    /// The id and the part of the parts panel's selection.
    pub fn current_part(&self) -> Option<(usize, &crate::store::Part)> {
        let id = *self.part_ids().get(self.part)?;
        Some((id, self.dataset.part(id)?))
    }

    /// The classes present with their counts and whether each is shown.
    pub fn legend(&self) -> Option<Legend> {
        Legend::for_style(
            &self.dataset,
            &self.settings.style,
            &self.settings.filter,
            &self.frame.ranges,
        )
    }

    /// The legend's class rows (none unless colouring by class).
    pub fn class_rows(&self) -> Vec<ClassEntry> {
        match self.legend() {
            Some(Legend::Classes(rows)) => rows,
            _ => Vec::new(),
        }
    }

    /// Records a picked point (keeps the last two: a measurement).
    pub fn add_pick(&mut self, p: Option<PointRecord>) {
        match p {
            Some(p) => {
                self.message = format!("picked {}", crate::text::sanitize(&format_xyz(p.position)));
                self.picks.push(p);
                if self.picks.len() > 2 {
                    self.picks.remove(0);
                }
            }
            None => self.message = "no point under the crosshair".into(),
        }
    }

    /// The finest-to-coarsest level count of the deepest part.
    pub fn max_levels(&self) -> usize {
        self.dataset.own_levels()
    }

    /// Applies one command.
    pub fn apply(&mut self, cmd: Command) -> Effect {
        use Command::*;
        let top = self.max_levels() - 1;
        match cmd {
            Interrupt => return Effect::Quit,
            Suspend => return Effect::Suspend,
            Repaint => return Effect::Repaint,
            Quit if self.show_help => {
                self.show_help = false;
                return Effect::Redraw;
            }
            Quit if self.picking => {
                self.picking = false;
                return Effect::Redraw;
            }
            Quit => return Effect::Quit,
            ToggleHelp => {
                self.show_help = !self.show_help;
                return Effect::Redraw;
            }
            SaveFrame => return Effect::Save,
            NextPart => {
                self.part = (self.part + 1) % self.part_ids().len().max(1);
                return Effect::Redraw;
            }
            PreviousPart => {
                let n = self.part_ids().len().max(1);
                self.part = (self.part + n - 1) % n;
                return Effect::Redraw;
            }
            Pan(dr, du) => {
                let step = self.camera.distance * PAN_STEP;
                self.camera
                    .translate(dr as f64 * step, du as f64 * step, 0.0);
            }
            Zoom(d) => self.camera.zoom(ZOOM_STEP.powi(d as i32)),
            ResetView => self.camera = self.home,
            PinLevel(k) => self.settings.lod = LodChoice::Pinned(k.min(top)),
            Automatic => self.settings.lod = LodChoice::View,
            Coarser | Finer => {
                let current = match self.settings.lod {
                    LodChoice::Pinned(k) => k,
                    // From an automatic choice, step from the finest level drawn.
                    _ => self.frame.levels.map_or(top, |l| l.0),
                };
                let next = if cmd == Coarser {
                    (current + 1).min(top)
                } else {
                    current.saturating_sub(1)
                };
                self.settings.lod = LodChoice::Pinned(next);
            }
            ToggleDistanceRule => {
                self.settings.lod = match self.settings.lod {
                    LodChoice::Distance => LodChoice::View,
                    _ => LodChoice::Distance,
                }
            }
            // The crosshair is drawn over the frame: no new frame.
            Orbit(dx, dy) if self.picking => {
                let (x, y) = self.cursor;
                self.cursor = (
                    (x + dx as f64 * CURSOR_STEP).clamp(0.0, 1.0),
                    (y - dy as f64 * CURSOR_STEP).clamp(0.0, 1.0),
                );
                return Effect::Redraw;
            }
            Orbit(dy, dp) => self
                .camera
                .rotate(dy as f64 * ORBIT_STEP, dp as f64 * ORBIT_STEP),
            CycleColor => {
                let has_classes = self.has_classes();
                let i = COLOR_CYCLE
                    .iter()
                    .position(|c| *c == self.settings.style.mode)
                    .unwrap_or(COLOR_CYCLE.len() - 1);
                let mut next = (i + 1) % COLOR_CYCLE.len();
                if COLOR_CYCLE[next] == ColorMode::Classification && !has_classes {
                    next = (next + 1) % COLOR_CYCLE.len();
                }
                self.settings.style.mode = COLOR_CYCLE[next].clone();
                // A ramp or range from the command line was for the mode it named.
                self.settings.style.ramp = None;
                self.settings.style.range = None;
            }
            ColorClasses => {
                if !self.has_classes() {
                    self.message = "the data has no classification band".into();
                    return Effect::Redraw;
                }
                self.settings.style.mode = ColorMode::Classification;
            }
            TogglePick => {
                self.picking = !self.picking;
                return Effect::Redraw;
            }
            Pick => {
                self.picking = true;
                self.pick_pending = true;
                return Effect::Pick;
            }
            PickAt(x, y) => {
                self.picking = true;
                self.cursor = ((x as f64).clamp(0.0, 1.0), (y as f64).clamp(0.0, 1.0));
                self.pick_pending = true;
                return Effect::Pick;
            }
            ClearPicks => {
                self.picks.clear();
                return Effect::Redraw;
            }
            LegendRow(d) => {
                let n = self.class_rows().len();
                if n == 0 {
                    return Effect::None;
                }
                self.legend_row = (self.legend_row as i64 + d as i64).rem_euclid(n as i64) as usize;
                return Effect::Redraw;
            }
            ToggleClassRow(row) => {
                if self.settings.style.mode != ColorMode::Classification
                    || row >= self.class_rows().len()
                {
                    return Effect::None;
                }
                self.legend_row = row;
                return self.apply(ToggleClass);
            }
            ToggleClass => {
                let entries = self.class_rows();
                let Some(e) = entries.get(self.legend_row.min(entries.len().saturating_sub(1)))
                else {
                    self.message = "no classes to show or hide".into();
                    return Effect::Redraw;
                };
                self.settings.filter.classes.set(e.code, !e.shown);
            }
            ToggleSection => {
                if let Some(s) = self.section.take() {
                    self.settings.filter.slab = s.saved_slab;
                    self.camera = s.saved_camera;
                } else {
                    let picks: Vec<[f64; 3]> = self.picks.iter().map(|p| p.position).collect();
                    let s = Section::through(
                        &self.dataset.bounds(),
                        &self.camera,
                        &picks,
                        &self.settings.filter,
                    );
                    self.settings.filter.slab = Some(s.slab);
                    self.camera = s.profile_camera(&self.dataset.bounds(), &self.camera);
                    self.section = Some(s);
                }
            }
            ToggleClip => {
                if let Some(c) = self.clip.take() {
                    self.clip_hidden = Some(c);
                } else {
                    let c = self
                        .clip_hidden
                        .take()
                        .unwrap_or_else(|| ClipBox::start(&self.dataset.bounds(), None));
                    self.clip = Some(c);
                }
                self.settings.filter.clip = self.clip.map(|c| c.bounds);
            }
            SlabWidth(d) | SlabMove(d) | SlabTurn(d) if self.section.is_none() => {
                let Some(c) = self.clip.as_mut() else {
                    self.message = "no section or clip box: z shows a section, o a clip box".into();
                    return Effect::Redraw;
                };
                match cmd {
                    SlabWidth(_) => c.resize(d),
                    SlabMove(_) => c.shift(d),
                    _ => {
                        c.next_axis(d);
                        return Effect::Redraw;
                    }
                }
                self.settings.filter.clip = Some(c.bounds);
            }
            SlabWidth(d) | SlabMove(d) | SlabTurn(d) => {
                let Some(s) = self.section.as_mut() else {
                    return Effect::None;
                };
                match cmd {
                    SlabWidth(_) => s.resize(d),
                    SlabMove(_) => s.shift(d),
                    _ => {
                        s.turn(d);
                        self.camera = s.profile_camera(&self.dataset.bounds(), &self.camera);
                    }
                }
                self.settings.filter.slab = Some(s.slab);
            }
            CycleBand => {
                let bands = self.band_names();
                if bands.is_empty() {
                    self.message = "the data has no bands besides x y z".into();
                    return Effect::Redraw;
                }
                let next = match &self.settings.style.mode {
                    ColorMode::Band(b) => bands
                        .iter()
                        .position(|n| n == b)
                        .map_or(0, |i| (i + 1) % bands.len()),
                    _ => 0,
                };
                self.settings.style.mode = ColorMode::Band(bands[next].clone());
                self.settings.style.ramp = None;
                self.settings.style.range = None;
            }
            EdlStrength(d) => {
                let p = &mut self.settings.edl_params;
                p.strength =
                    (p.strength * EDL_STEP.powi(d as i32)).clamp(EDL_STRENGTH.0, EDL_STRENGTH.1);
                self.settings.edl = true;
            }
            EdlRadius => {
                let p = &mut self.settings.edl_params;
                p.radius = p.radius % 4 + 1;
                self.settings.edl = true;
            }
            CyclePointSize => self.settings.point_size = self.settings.point_size % 3 + 1,
            ToggleEdl => self.settings.edl = !self.settings.edl,
            BudgetDown => {
                self.settings.budget = (self.settings.budget / 2).max(BUDGET_RANGE.0);
            }
            BudgetUp => {
                self.settings.budget = (self.settings.budget * 2).min(BUDGET_RANGE.1);
            }
        }
        self.camera.set_clip_from_bounds(&self.dataset.bounds());
        Effect::Render
    }

    /// The status line: level mode, levels shown, points drawn against the budget,
    /// colour, point size, eye-dome lighting, tiles still loading. Tiles waiting
    /// to be retried come first (the line is cut at the terminal's width, and
    /// what failed matters most then).
    pub fn status_line(&self) -> String {
        match &self.frame.retry {
            Some(r) => format!(
                "{} | {}",
                crate::text::sanitize(&r.describe()),
                self.view_status()
            ),
            None => self.view_status(),
        }
    }

    /// The status line but for retries.
    fn view_status(&self) -> String {
        let f = &self.frame;
        let mut levels = match f.levels {
            Some((lo, hi)) if lo == hi => format!("level {lo}"),
            Some((lo, hi)) => format!("levels {lo}-{hi}"),
            None if f.overview_tiles > 0 => "overview".into(),
            None if f.renderer.is_empty() => "no frame yet".into(),
            None => "nothing drawn".into(),
        };
        if f.levels.is_some() && f.overview_tiles > 0 {
            levels.push_str(" + overview");
        }
        let mut s = format!(
            "{} | {levels} | {} pts / {} | {} | size {}{}",
            self.settings.lod.label(),
            crate::text::count(f.points),
            crate::text::count(if f.budget > 0 {
                f.budget
            } else {
                self.settings.budget
            }),
            self.settings.style.mode.name(),
            self.settings.point_size,
            if self.settings.edl {
                let p = self.settings.edl_params;
                format!(" | edl {:.2}/{}", p.strength, p.radius)
            } else {
                String::new()
            },
        );
        if !self.settings.filter.is_empty() {
            s.push_str(" | filtered");
        }
        if let Some(sec) = &self.section {
            let n = sec.slab.normal;
            s.push_str(&format!(
                " | section {}° {} thick",
                (n[1].atan2(n[0]).to_degrees().rem_euclid(180.0)).round(),
                crate::text::sanitize(&format!("{:.3}", 2.0 * sec.slab.half))
            ));
        }
        if let Some(c) = &self.clip {
            s.push_str(" | ");
            s.push_str(&crate::text::sanitize(&c.describe()));
        }
        if self.picking {
            s.push_str(" | pick: arrows move, Enter picks");
        }
        if f.pending > 0 {
            s.push_str(&format!(" | loading {} tiles", f.pending));
        }
        if f.dropped > 0 {
            s.push_str(&format!(
                " | {} tiles given up for the point or memory budget",
                f.dropped
            ));
        }
        if f.unreadable > 0 {
            s.push_str(&format!(" | {} tiles unreadable", f.unreadable));
        }
        // A dataset in object storage: requests in flight, bytes received, failures
        // (counters only: the loading worker does the waiting).
        let net = crate::remote::stats();
        if net.requests > 0 {
            s.push_str(&format!(
                " | net {} in flight, {:.1} MB{}",
                net.in_flight,
                net.bytes as f64 / 1e6,
                if net.failed > 0 {
                    format!(", {} failed", net.failed)
                } else {
                    String::new()
                }
            ));
        }
        if !self.terminal_note.is_empty() {
            s.push_str(&format!(" | {}", self.terminal_note));
        }
        s
    }

    /// The second status line: where the last frame's time went, frames per
    /// second, and the renderer.
    pub fn timing_line(&self) -> String {
        let f = &self.frame;
        let mut frame = crate::text::bytes(f.bytes as u64);
        if f.scale > 1 {
            frame.push_str(&format!(" at 1/{}", f.scale));
        }
        if let Some(c) = f.colors {
            frame.push_str(&format!(" in {c} colours: slow link"));
        }
        if let Some(r) = self.link_rate {
            frame.push_str(&format!(" · link {}/s", crate::text::bytes(r as u64)));
        }
        format!(
            "load {:.0} · render {:.0} · encode {:.0} ms | {frame} | {} | {}",
            f.load_ms,
            f.render_ms,
            f.encode_ms,
            if self.fps > 0.0 {
                format!("{:.1} fps", self.fps)
            } else {
                "idle".to_string()
            },
            // "wgpu Vulkan: llvmpipe (LLVM 15.0.6, 256 bits) (Mesa …)" → "wgpu Vulkan: llvmpipe".
            crate::text::sanitize(match f.renderer.split_once(" (") {
                Some((short, _)) if f.renderer.starts_with("wgpu") => short,
                _ => &f.renderer,
            }),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::Bounds;
    use crate::store::{self, WriteOptions};

    fn app() -> (tempfile::TempDir, App) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.tif");
        store::write_part(
            &path,
            &crate::synth::scene(300_000, 3),
            &WriteOptions::default(),
        )
        .unwrap();
        let ds = Arc::new(Dataset::open(&path).unwrap());
        let cam = Camera::fit(&ds.bounds());
        (dir, App::new(ds, cam, Settings::default()))
    }

    #[test]
    fn the_terminals_note_and_the_frames_cost_are_shown() {
        let (_d, mut a) = app();
        a.terminal_note = "half-blocks: the terminal did not answer within 1000 ms".into();
        assert!(
            a.status_line()
                .ends_with("| half-blocks: the terminal did not answer within 1000 ms")
        );
        a.frame.bytes = 120 * 1024;
        a.frame.scale = 2;
        a.link_rate = Some(1.25e6);
        let t = a.timing_line();
        assert!(t.contains("| 120.0 KiB at 1/2 · link 1.2 MiB/s |"), "{t}");
        // A full frame reduced for a slow link says so.
        a.frame.scale = 1;
        a.frame.colors = Some(16);
        let t = a.timing_line();
        assert!(
            t.contains("| 120.0 KiB in 16 colours: slow link · link 1.2 MiB/s |"),
            "{t}"
        );
    }

    #[test]
    fn levels_pin_step_and_return_to_automatic() {
        let (_d, mut a) = app();
        let top = a.max_levels() - 1;
        assert!(top >= 2, "a 300 k point part has three levels");
        assert_eq!(a.apply(Command::PinLevel(1)), Effect::Render);
        assert_eq!(a.settings.lod, LodChoice::Pinned(1));
        a.apply(Command::Coarser);
        assert_eq!(a.settings.lod, LodChoice::Pinned(2));
        a.apply(Command::Finer);
        a.apply(Command::Finer);
        a.apply(Command::Finer);
        assert_eq!(a.settings.lod, LodChoice::Pinned(0));
        a.apply(Command::PinLevel(9));
        assert_eq!(a.settings.lod, LodChoice::Pinned(top), "clamped");
        a.apply(Command::ToggleDistanceRule);
        assert_eq!(a.settings.lod, LodChoice::Distance);
        a.apply(Command::ToggleDistanceRule);
        assert_eq!(a.settings.lod, LodChoice::View);
        a.apply(Command::PinLevel(0));
        a.apply(Command::Automatic);
        assert_eq!(a.settings.lod, LodChoice::View);
    }

    #[test]
    fn the_status_line_says_retrying_then_what_failed() {
        let (_d, mut a) = app();
        let mut r = RetryStatus {
            tiles: 4,
            attempts: 1,
            failing_for: Duration::from_millis(600),
            error: "http://h:1/d/p.tif: connection refused; nothing answers at h:1".into(),
        };
        a.frame = FrameStatus {
            renderer: "cpu".into(),
            retry: Some(r.clone()),
            ..Default::default()
        };
        let s = a.status_line();
        assert!(s.starts_with("retrying 4 requests | "), "{s}");
        assert!(!s.contains("refused"), "not at the first failure: {s}");
        // Failing again and again: what failed, and what to do.
        r.attempts = RetryStatus::TELL_AFTER_ATTEMPTS;
        a.frame.retry = Some(r.clone());
        let s = a.status_line();
        assert!(
            s.starts_with(
                "retrying 4 requests: http://h:1/d/p.tif: connection refused; nothing answers at h:1 | "
            ),
            "{s}"
        );
        // Or failing for long.
        r.attempts = 1;
        r.failing_for = RetryStatus::TELL_AFTER;
        r.tiles = 1;
        a.frame.retry = Some(r);
        assert!(
            a.status_line()
                .starts_with("retrying 1 request: http://h:1"),
            "{}",
            a.status_line()
        );
    }

    #[test]
    fn the_status_line_says_why_nothing_is_drawn() {
        let (_d, mut a) = app();
        assert!(a.status_line().contains("no frame yet"));
        a.frame = FrameStatus {
            renderer: "cpu".into(),
            dropped: 3,
            unreadable: 2,
            pending: 1,
            ..Default::default()
        };
        let s = a.status_line();
        assert!(s.contains("nothing drawn"), "{s}");
        assert!(
            s.contains("3 tiles given up for the point or memory budget"),
            "{s}"
        );
        assert!(
            s.contains("loading 1 tiles") && s.contains("2 tiles unreadable"),
            "{s}"
        );
        assert!(!s.contains("retrying"), "{s}");
        assert!(a.timing_line().contains("idle"));
        a.fps = 12.5;
        assert!(a.timing_line().contains("12.5 fps"));
    }

    #[test]
    fn view_keys_move_the_camera_and_r_resets() {
        let (_d, mut a) = app();
        let home = a.camera;
        a.apply(Command::Orbit(1, 0));
        assert!(a.camera.yaw != home.yaw);
        a.apply(Command::Zoom(1));
        assert!(a.camera.distance < home.distance);
        a.apply(Command::Pan(1, 0));
        assert!(a.camera.target != home.target);
        a.apply(Command::ResetView);
        assert_eq!(a.camera.target, home.target);
        assert_eq!(a.camera.distance, home.distance);
    }

    #[test]
    fn clip_box_moves_and_sizes_by_keys() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.tif");
        store::write_part(
            &path,
            &crate::synth::scene_classified(20_000, 3),
            &WriteOptions::default(),
        )
        .unwrap();
        let ds = Arc::new(Dataset::open(&path).unwrap());
        let b = ds.bounds();
        let mut a = App::new(ds, Camera::fit(&b), Settings::default());
        assert_eq!(
            a.apply(Command::SlabWidth(1)),
            Effect::Redraw,
            "nothing to size"
        );
        assert!(a.message.contains("o a clip box"), "{}", a.message);
        assert_eq!(a.apply(Command::ToggleClip), Effect::Render);
        let first = a.settings.filter.clip.expect("o shows a clip box");
        assert!((first.extent()[0] - 0.5 * b.extent()[0]).abs() < 1e-6);
        assert!(a.status_line().contains("clip *x"), "{}", a.status_line());
        a.apply(Command::SlabWidth(1));
        let wider = a.settings.filter.clip.unwrap();
        assert!(wider.extent()[0] > first.extent()[0]);
        assert_eq!(wider.extent()[1], first.extent()[1]);
        a.apply(Command::SlabTurn(1));
        assert_eq!(a.clip.unwrap().axis, 1);
        a.apply(Command::SlabMove(1));
        let moved = a.settings.filter.clip.unwrap();
        assert!(moved.min[1] > wider.min[1] && moved.min[0] == wider.min[0]);
        // Off, and on again where it was.
        a.apply(Command::ToggleClip);
        assert_eq!(a.settings.filter.clip, None);
        a.apply(Command::ToggleClip);
        assert_eq!(a.settings.filter.clip, Some(moved));
        // While a section is shown the same keys act on the section.
        a.apply(Command::ToggleSection);
        a.apply(Command::SlabMove(1));
        assert_eq!(a.settings.filter.clip, Some(moved));
        // A --clip box is the one the keys start from.
        let given = Bounds {
            min: b.min,
            max: b.center(),
        };
        let settings = Settings {
            filter: Filter {
                clip: Some(given),
                ..Filter::default()
            },
            ..Settings::default()
        };
        let mut a = App::new(a.dataset.clone(), Camera::fit(&b), settings);
        a.apply(Command::SlabMove(-1));
        assert!(a.settings.filter.clip.unwrap().min[0] < given.min[0]);
    }

    #[test]
    fn legend_toggles_pick_mode_and_sections() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.tif");
        store::write_part(
            &path,
            &crate::synth::scene_classified(50_000, 3),
            &WriteOptions::default(),
        )
        .unwrap();
        let ds = Arc::new(Dataset::open(&path).unwrap());
        let cam = Camera::fit(&ds.bounds());
        let mut a = App::new(ds, cam, Settings::default());
        // The cycle reaches classification on classified data.
        for _ in 0..3 {
            a.apply(Command::CycleColor);
        }
        assert_eq!(a.settings.style.mode, ColorMode::Classification);
        let codes: Vec<u8> = a.class_rows().iter().map(|e| e.code).collect();
        assert_eq!(codes, vec![2, 5, 6]);
        // Select the second row (vegetation) and hide it, then show it again.
        assert_eq!(a.apply(Command::LegendRow(1)), Effect::Redraw);
        assert_eq!(a.apply(Command::ToggleClass), Effect::Render);
        assert!(!a.settings.filter.classes.shows(5));
        assert!(a.settings.filter.classes.shows(2));
        assert!(!a.class_rows()[1].shown);
        a.apply(Command::ToggleClass);
        assert!(a.settings.filter.classes.all());
        a.apply(Command::LegendRow(-2));
        assert_eq!(a.legend_row, 2, "wraps around");
        // A click on a row toggles that row's class.
        assert_eq!(a.apply(Command::ToggleClassRow(0)), Effect::Render);
        assert!(!a.settings.filter.classes.shows(2) && a.legend_row == 0);
        a.apply(Command::ToggleClassRow(0));
        assert_eq!(
            a.apply(Command::ToggleClassRow(3)),
            Effect::None,
            "no such row"
        );
        // Pick mode: the arrows move the crosshair, not the camera.
        let yaw = a.camera.yaw;
        // The crosshair and the picks are drawn over the frame: none of their
        // keys asks for a new one.
        assert_eq!(a.apply(Command::TogglePick), Effect::Redraw);
        assert_eq!(a.apply(Command::Orbit(1, 1)), Effect::Redraw);
        assert_eq!(a.camera.yaw, yaw);
        assert!(a.cursor.0 > 0.5 && a.cursor.1 < 0.5);
        assert_eq!(a.apply(Command::Pick), Effect::Pick);
        assert!(a.pick_pending);
        assert_eq!(a.apply(Command::ClearPicks), Effect::Redraw);
        assert_eq!(a.apply(Command::Quit), Effect::Redraw, "q leaves pick mode");
        assert!(!a.picking);
        // A section draws a slab and looks at it level; z again restores.
        let before = a.camera;
        a.apply(Command::ToggleSection);
        let slab = a.settings.filter.slab.unwrap();
        let b = a.dataset.bounds();
        assert!(2.0 * slab.half < 0.02 * b.extent()[0].max(b.extent()[1]));
        assert!(a.camera.pitch.abs() < 1e-9);
        assert!(a.status_line().contains("section"), "{}", a.status_line());
        a.apply(Command::SlabWidth(1));
        assert!(a.settings.filter.slab.unwrap().half > slab.half);
        let yaw = a.camera.yaw;
        a.apply(Command::SlabTurn(1));
        assert_ne!(a.settings.filter.slab.unwrap().normal, slab.normal);
        assert!(
            (a.camera.yaw - yaw).abs() > 0.1,
            "the profile turns with it"
        );
        a.apply(Command::ToggleSection);
        assert_eq!(a.settings.filter.slab, None);
        assert_eq!(a.camera, before);
        // v cycles the bands: z first, then the part's, and back.
        let bands = a.band_names();
        assert!(bands.len() >= 2 && bands.contains(&"classification".to_string()));
        a.apply(Command::CycleBand);
        assert_eq!(a.settings.style.mode, ColorMode::Band("z".into()));
        for _ in 0..bands.len() {
            a.apply(Command::CycleBand);
        }
        assert_eq!(a.settings.style.mode, ColorMode::Band("z".into()));
        // EDL keys turn it on and stay in range.
        for _ in 0..20 {
            a.apply(Command::EdlStrength(1));
        }
        assert!(a.settings.edl && a.settings.edl_params.strength <= 10.0);
        a.apply(Command::EdlRadius);
        assert_eq!(a.settings.edl_params.radius, 2);
        assert!(
            a.status_line().contains("edl 10.00/2"),
            "{}",
            a.status_line()
        );
    }

    #[test]
    fn settings_cycle_and_stay_in_range() {
        let (_d, mut a) = app();
        for want in [
            ColorMode::Intensity,
            ColorMode::Height,
            ColorMode::Level,
            ColorMode::Part,
            ColorMode::Rgb,
        ] {
            a.apply(Command::CycleColor);
            assert_eq!(a.settings.style.mode, want);
        }
        for want in [2, 3, 1] {
            a.apply(Command::CyclePointSize);
            assert_eq!(a.settings.point_size, want);
        }
        a.apply(Command::ToggleEdl);
        assert!(a.settings.edl);
        for _ in 0..40 {
            a.apply(Command::BudgetDown);
        }
        assert_eq!(a.settings.budget, BUDGET_RANGE.0);
        for _ in 0..40 {
            a.apply(Command::BudgetUp);
        }
        assert_eq!(a.settings.budget, BUDGET_RANGE.1);
        assert_eq!(a.apply(Command::ToggleHelp), Effect::Redraw);
        assert!(a.show_help);
        assert_eq!(
            a.apply(Command::Quit),
            Effect::Redraw,
            "q closes the help first"
        );
        assert!(!a.show_help);
        assert_eq!(a.apply(Command::NextPart), Effect::Redraw);
        let after_next = a.part;
        a.apply(Command::PreviousPart);
        a.apply(Command::PreviousPart);
        let n = a.dataset.part_count();
        assert_eq!(a.part, (after_next + 2 * n - 2) % n);
        assert_eq!(a.part, 0, "one part wraps around");
        assert_eq!(a.apply(Command::SaveFrame), Effect::Save);
        assert_eq!(a.apply(Command::Quit), Effect::Quit);
    }
}
