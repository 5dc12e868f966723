//! Options shared by `render` and `preview`: the camera, level selection, colour,
//! and the steps from a dataset to a frame (select → load → colour → rasterize).

use crate::camera::{self, Camera};
use crate::lod::{self, LodMode, Selection, TileCache};
use crate::render::color::ColorMode;
use crate::render::scene::{ColorRanges, Scene};
use crate::render::{self, Frame, RenderOptions, RendererChoice};
use crate::store::Dataset;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(Debug, Clone, clap::Args)]
pub struct ViewArgs {
    /// A part (.tif) or a directory of parts.
    pub path: PathBuf,
    /// Viewpoint as `yaw,pitch[,distance]` in degrees (and world units) around the
    /// centre of the bounds: yaw from +x, pitch -90 (straight down) to 90 (within
    /// 0.1° of either pole the view stops); the default fits the whole cloud in
    /// view.
    #[arg(long, allow_hyphen_values = true)]
    pub view: Option<String>,
    /// A camera as JSON, as --print-camera prints it; fields left out keep the
    /// fitted default's values, unknown fields are an error.
    #[arg(long, conflicts_with = "view")]
    pub camera: Option<String>,
    /// Level of detail: view (per tile, under --budget), distance (the paper's
    /// rule, one level for all parts) or a level number (0 = finest).
    #[arg(long, default_value = "view")]
    pub lod: String,
    /// Most points drawn with --lod view. Each frame draws about two points a
    /// pixel (at least 65,536), never more than this (at least 1,000; the nearest
    /// tile is drawn whatever the budget).
    #[arg(long, default_value_t = crate::lod::DEFAULT_BUDGET_CAP,
          value_parser = clap::value_parser!(u64).range(1_000..))]
    pub budget: u64,
    /// Colour: rgb, intensity, height, level or part (rgb falls back to intensity,
    /// then height, when the data has no colour).
    #[arg(long, default_value = "rgb")]
    pub color: String,
    /// Splat size in pixels, 1 to 3.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=3))]
    pub point_size: u32,
    /// Eye-dome lighting: shades depth edges so dense clouds read as surfaces.
    #[arg(long)]
    pub edl: bool,
    /// Renderer: auto (wgpu when an adapter exists, else CPU), gpu or cpu.
    #[arg(long, default_value = "auto")]
    pub renderer: String,
    /// Memory for loaded points, e.g. 1G (tiles beyond it are not loaded).
    #[arg(long, value_parser = crate::convert::budget::parse_size, default_value = "2G")]
    pub memory: u64,
    /// Print the camera as JSON (for --camera) on stderr.
    #[arg(long)]
    pub print_camera: bool,
}

/// Parses `--lod` (see [`lod_for`]).
fn parse_lod(s: &str, budget: u64) -> anyhow::Result<LodMode> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "view" => LodMode::View { budget },
        "distance" => LodMode::Distance,
        n => LodMode::Fixed(n.parse().map_err(|_| {
            anyhow::anyhow!("--lod '{s}': expected view, distance or a level number")
        })?),
    })
}

/// Parses `--lod` for `ds`: a level number must be one of its levels (parts
/// with fewer levels draw their coarsest).
pub fn lod_for(s: &str, budget: u64, ds: &Dataset) -> anyhow::Result<LodMode> {
    let mode = parse_lod(s, budget)?;
    if let LodMode::Fixed(k) = mode {
        let levels = lod::level_count(ds);
        if k >= levels {
            let above = ds.overview.as_ref().map_or(String::new(), |o| {
                format!(
                    " (the last {} above the parts: the overview)",
                    o.layer_count()
                )
            });
            anyhow::bail!(
                "--lod {k}: {} has levels 0 (finest) to {}{above}",
                crate::text::sanitize(&ds.path.display().to_string()),
                levels.saturating_sub(1)
            );
        }
    }
    Ok(mode)
}

/// The camera for a dataset from `--camera`, `--view` or the fitted default.
pub fn camera_for(a: &ViewArgs, ds: &Dataset) -> anyhow::Result<Camera> {
    let bounds = ds.bounds();
    let fitted = Camera::fit(&bounds);
    let mut cam = match &a.camera {
        Some(json) => Camera::from_json_over(json, &fitted)?,
        None => fitted,
    };
    if let Some(v) = &a.view {
        cam.apply_view(&camera::parse_view(v)?);
    }
    cam.set_clip_from_bounds(&bounds);
    Ok(cam)
}

/// What one frame took, for the report and the status line.
#[derive(Debug, Clone, Default)]
pub struct FrameReport {
    pub selection: Selection,
    pub select_ms: f64,
    pub load_ms: f64,
    pub render_ms: f64,
    pub renderer: String,
}

/// Selects, loads (all at once), colours and renders one frame.
pub fn render_once(
    ds: Arc<Dataset>,
    a: &ViewArgs,
    cam: &Camera,
    width: u32,
    height: u32,
) -> anyhow::Result<(Frame, FrameReport)> {
    let mode = lod_for(&a.lod, lod::budget_for_pixels(width, height, a.budget), &ds)?;
    let color: ColorMode = a.color.parse()?;
    let choice: RendererChoice = a.renderer.parse()?;
    let t = Instant::now();
    let sel = lod::select(&ds, cam, width, height, mode, a.memory);
    let select_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let cache = TileCache::new(ds.clone(), a.memory, 1);
    let tiles = cache.load_all(&sel.tiles).map_err(anyhow::Error::msg)?;
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    let ranges = ColorRanges::from_tiles(&tiles, &ds.bounds());
    let scene = Scene::new(tiles, color, &ranges);
    let mut r = render::create(choice)?;
    let opts = RenderOptions {
        width,
        height,
        point_size: a.point_size,
        eye_dome_lighting: a.edl,
        background: [0, 0, 0],
    };
    let t = Instant::now();
    let frame = r.render(cam, &scene.batches(), &opts)?;
    let render_ms = t.elapsed().as_secs_f64() * 1e3;
    Ok((
        frame,
        FrameReport {
            selection: sel,
            select_ms,
            load_ms,
            render_ms,
            renderer: r.name(),
        },
    ))
}

/// A one-line summary of a frame.
pub fn describe(r: &FrameReport) -> String {
    let s = &r.selection;
    let mut levels = match s.levels {
        Some((lo, hi)) if lo == hi => format!("level {lo}"),
        Some((lo, hi)) => format!("levels {lo}-{hi}"),
        None => "no level".into(),
    };
    if s.overview_tiles > 0 {
        levels = format!("{} overview, {levels}", s.overview_tiles);
    }
    let mut line = format!(
        "{} points from {} tiles ({levels}), {} culled; select {:.1} ms, load {:.0} ms, render {:.0} ms on {}",
        crate::text::count(s.points),
        s.tiles.len(),
        s.culled,
        r.select_ms,
        r.load_ms,
        r.render_ms,
        r.renderer
    );
    if s.dropped_tiles > 0 {
        line.push_str(&format!(
            "; gave up loading {} tiles ({} points) for the point or memory budget",
            s.dropped_tiles,
            crate::text::count(s.dropped_points)
        ));
    }
    line
}
