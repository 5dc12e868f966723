//! Options shared by `render` and `preview`: the camera, level selection, colour,
//! filters, and the steps from a dataset to a frame (select → load → colour →
//! rasterize).

use crate::camera::{self, Camera};
use crate::lod::{self, LodMode, TileCache};
use crate::render::classes::{self, ClassMask};
use crate::render::color::ColorMode;
use crate::render::edl::EdlParams;
use crate::render::filter::{self, Filter, Where};
use crate::render::pipeline::{Drawn, FrameReport, FrameRequest, Loading, Overlays, Pipeline};
use crate::render::ramp::{self, Ramp};
use crate::render::scene::Style;
use crate::render::{Frame, RendererChoice};
use crate::store::Dataset;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, Clone, clap::Args)]
pub struct ViewArgs {
    /// A part (.tif) or a directory of parts (local or at a URL); or a COPC
    /// file (.copc.laz) or an EPT dataset (its ept.json), local or at a URL,
    /// drawn from its octree with no conversion: only the nodes a view needs
    /// are read.
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
    /// pixel (at least 262,144), never more than this (at least 1,000; the nearest
    /// tile is drawn whatever the budget).
    #[arg(long, default_value_t = crate::lod::DEFAULT_BUDGET_CAP,
          value_parser = clap::value_parser!(u64).range(1_000..))]
    pub budget: u64,
    /// Colour: rgb, intensity, height, level, part, classification (ASPRS
    /// colours) or band:NAME (any band through --ramp, e.g. band:gps_time). rgb
    /// falls back to intensity, then height, when the data has no colour.
    #[arg(long, default_value = "rgb")]
    pub color: String,
    /// Ramp for intensity, height and band:NAME: turbo, viridis, magma,
    /// inferno, plasma or gray (default: gray for intensity, turbo for height,
    /// viridis for a band).
    #[arg(long)]
    pub ramp: Option<String>,
    /// The values the ramp spans, LO,HI in the band's units (default: the 2nd
    /// to 98th percentile of the loaded points; height: the dataset's bounds).
    #[arg(long, allow_hyphen_values = true)]
    pub range: Option<String>,
    /// Draw only these classification codes, e.g. 2,6 (ground, building).
    #[arg(long)]
    pub classes: Option<String>,
    /// Do not draw these classification codes, e.g. 7,18 (noise).
    #[arg(long)]
    pub exclude_classes: Option<String>,
    /// Draw only points whose band lies in a range: NAME=VALUE or NAME=LO..HI
    /// (an end may be left out), e.g. return_number=1 or z=400..450. May be
    /// given several times (all must hold).
    #[arg(long = "where", value_name = "NAME=LO..HI", allow_hyphen_values = true)]
    pub wheres: Vec<String>,
    /// Draw only what lies in the box MINX,MINY,MINZ,MAXX,MAXY,MAXZ (dataset
    /// coordinates); tiles outside it are not loaded.
    #[arg(long, value_name = "BOX", allow_hyphen_values = true)]
    pub clip: Option<String>,
    /// Draw only what lies within THICK of the plane through X,Y,Z with normal
    /// NX,NY,NZ (dataset coordinates), seen across it as a profile unless
    /// --camera or --view says otherwise; tiles the slab misses are not loaded.
    #[arg(long, value_name = "X,Y,Z,NX,NY,NZ,THICK", allow_hyphen_values = true)]
    pub slab: Option<String>,
    /// Splat size in pixels, 1 to 3.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=3))]
    pub point_size: u32,
    /// Eye-dome lighting: shades depth edges so dense clouds read as surfaces.
    #[arg(long)]
    pub edl: bool,
    /// Eye-dome lighting strength (0.1 to 10; default 1); implies --edl.
    #[arg(long)]
    pub edl_strength: Option<f32>,
    /// Eye-dome lighting radius in pixels (1 to 8; default 1); implies --edl.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=8))]
    pub edl_radius: Option<u32>,
    /// Renderer: auto (wgpu when an adapter exists, else CPU), gpu or cpu.
    #[arg(long, default_value = "auto")]
    pub renderer: String,
    /// Memory for loaded points, e.g. 1G (tiles beyond it are not loaded).
    #[arg(long, value_parser = crate::text::parse_size, default_value = "2G")]
    pub memory: u64,
    /// Print the camera as JSON (for --camera) on stderr.
    #[arg(long)]
    pub print_camera: bool,
    #[command(flatten)]
    pub cache: super::remote::CacheArgs,
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
            let above = if ds.has_overview() {
                format!(
                    " (the last {} above the parts: the overview)",
                    ds.layer_count()
                )
            } else {
                String::new()
            };
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
    if let Some(s) = &a.slab
        && a.camera.is_none()
        && a.view.is_none()
    {
        let slab = filter::parse_slab(s).map_err(|e| anyhow::anyhow!("--slab {e}"))?;
        cam = slab.profile_camera(&bounds, &cam);
    }
    cam.set_clip_from_bounds(&bounds);
    Ok(cam)
}

/// Whether some part of `ds` has band `name` (x, y and z always exist).
pub fn has_band(ds: &Dataset, name: &str) -> bool {
    ["x", "y", "z"].contains(&name) || ds.totals().shown_bands().any(|b| b == name)
}

/// The error for a band no part has, listing those there are.
pub fn no_band(ds: &Dataset, name: &str, what: &str) -> anyhow::Error {
    let mut names: Vec<String> = ds.totals().shown_bands().cloned().collect();
    names.sort();
    names.dedup();
    anyhow::anyhow!(
        "{what}: {} has no band '{}'; its bands: {}",
        crate::text::sanitize(&ds.path.display().to_string()),
        crate::text::sanitize(name),
        crate::text::sanitize(&names.join(", "))
    )
}

/// The colour style from `--color`, `--ramp` and `--range`, checked against `ds`.
pub fn style_for(a: &ViewArgs, ds: &Dataset) -> anyhow::Result<Style> {
    let mode: ColorMode = a
        .color
        .parse()
        .map_err(|e| anyhow::anyhow!("--color {}: {e}", a.color))?;
    if let ColorMode::Band(b) = &mode
        && !has_band(ds, b)
    {
        return Err(no_band(ds, b, &format!("--color {}", a.color)));
    }
    if mode == ColorMode::Classification && !has_band(ds, "classification") {
        return Err(no_band(ds, "classification", "--color classification"));
    }
    let ramp: Option<Ramp> = a.ramp.as_deref().map(str::parse).transpose()?;
    let range = a
        .range
        .as_deref()
        .map(ramp::parse_range)
        .transpose()
        .map_err(|e| anyhow::anyhow!("--range {e}"))?;
    if (ramp.is_some() || range.is_some()) && !mode.uses_ramp() {
        anyhow::bail!(
            "--ramp and --range apply to --color intensity, height or band:NAME, not {}",
            mode.name()
        );
    }
    Ok(Style { mode, ramp, range })
}

/// The flags a filter is made from: `--classes`, `--exclude-classes`,
/// `--where`, `--clip` and `--slab` (the view commands' and `export`'s).
pub struct FilterFlags<'a> {
    pub classes: Option<&'a str>,
    pub exclude_classes: Option<&'a str>,
    pub wheres: &'a [String],
    pub clip: Option<&'a str>,
    pub slab: Option<&'a str>,
}

/// The filter from the view options' flags, checked against `ds`.
pub fn filter_for(a: &ViewArgs, ds: &Dataset) -> anyhow::Result<Filter> {
    filter_from(
        &FilterFlags {
            classes: a.classes.as_deref(),
            exclude_classes: a.exclude_classes.as_deref(),
            wheres: &a.wheres,
            clip: a.clip.as_deref(),
            slab: a.slab.as_deref(),
        },
        ds,
    )
}

/// The filter from `a`'s flags, checked against `ds`.
pub fn filter_from(a: &FilterFlags<'_>, ds: &Dataset) -> anyhow::Result<Filter> {
    let include = a
        .classes
        .map(|s| classes::parse_list(s, "--classes"))
        .transpose()
        .map_err(anyhow::Error::msg)?;
    let exclude = a
        .exclude_classes
        .map(|s| classes::parse_list(s, "--exclude-classes"))
        .transpose()
        .map_err(anyhow::Error::msg)?
        .unwrap_or_default();
    if (include.is_some() || !exclude.is_empty()) && !has_band(ds, "classification") {
        return Err(no_band(ds, "classification", "--classes"));
    }
    let wheres: Vec<Where> = a
        .wheres
        .iter()
        .map(|w| Where::parse(w))
        .collect::<Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("--where {e}"))?;
    for w in &wheres {
        if !has_band(ds, &w.band) {
            return Err(no_band(ds, &w.band, "--where"));
        }
    }
    let clip = a
        .clip
        .map(filter::parse_clip)
        .transpose()
        .map_err(|e| anyhow::anyhow!("--clip {e}"))?;
    let slab = a
        .slab
        .map(filter::parse_slab)
        .transpose()
        .map_err(|e| anyhow::anyhow!("--slab {e}"))?;
    Ok(Filter {
        classes: ClassMask::new(include.as_deref(), &exclude),
        wheres,
        clip,
        slab,
    })
}

/// Eye-dome lighting from `--edl`, `--edl-strength` and `--edl-radius`: on or
/// off, and its parameters.
pub fn edl_for(a: &ViewArgs) -> anyhow::Result<(bool, EdlParams)> {
    let mut p = EdlParams::default();
    if let Some(s) = a.edl_strength {
        if !(0.1..=10.0).contains(&s) {
            anyhow::bail!("--edl-strength {s}: expected 0.1 to 10");
        }
        p.strength = s;
    }
    if let Some(r) = a.edl_radius {
        p.radius = r;
    }
    Ok((
        a.edl || a.edl_strength.is_some() || a.edl_radius.is_some(),
        p,
    ))
}

/// The bands loads must read for `style` and `filter` besides the colour bands.
pub fn bands_for(style: &Style, filter: &Filter) -> Vec<String> {
    let mut b = filter.bands();
    if let Some(n) = style.mode.band()
        && !["x", "y", "z"].contains(&n)
    {
        b.push(n.to_string());
    }
    b.sort();
    b.dedup();
    b
}

/// Everything `render`, `preview` and the turntable draw frames from, parsed and
/// checked once (a turntable draws many frames from one); the drawing itself is
/// the frame pipeline's ([`Pipeline`]), as in the inspector.
pub struct Drawing {
    pub style: Style,
    pub filter: Filter,
    width: u32,
    height: u32,
    point_size: u32,
    edl: (bool, EdlParams),
    mode: LodMode,
    memory: u64,
    pipeline: Pipeline,
}

impl Drawing {
    pub fn new(ds: Arc<Dataset>, a: &ViewArgs, width: u32, height: u32) -> anyhow::Result<Drawing> {
        let mode = lod_for(&a.lod, lod::budget_for_pixels(width, height, a.budget), &ds)?;
        let style = style_for(a, &ds)?;
        let filter = filter_for(a, &ds)?;
        let edl = edl_for(a)?;
        let choice: RendererChoice = a.renderer.parse()?;
        let cache = TileCache::with_bands(ds.clone(), a.memory, 1, bands_for(&style, &filter));
        let mut pipeline = Pipeline::new(ds, cache, choice, Loading::Wait);
        // A rasterizer that cannot start is the first error, before any loading.
        pipeline.renderer()?;
        Ok(Drawing {
            style,
            filter,
            width,
            height,
            point_size: a.point_size,
            edl,
            mode,
            memory: a.memory,
            pipeline,
        })
    }

    pub fn dataset(&self) -> &Arc<Dataset> {
        self.pipeline.dataset()
    }

    /// Draws the frame `cam` sees (colour ranges fixed by the first frame, so a
    /// turntable keeps one scale); picks the point nearest `pick` (3 pixels
    /// around); with `legend`, the legend and the scale bar over it.
    pub fn draw(
        &mut self,
        cam: &Camera,
        pick: Option<(u32, u32)>,
        legend: bool,
    ) -> anyhow::Result<Drawn> {
        Ok(self.pipeline.draw(&FrameRequest {
            camera: cam,
            width: self.width,
            height: self.height,
            style: &self.style,
            filter: &self.filter,
            mode: self.mode,
            memory: self.memory,
            point_size: self.point_size,
            eye_dome_lighting: self.edl.0,
            edl: self.edl.1,
            pick: pick.map(|(x, y)| (x, y, 3)),
            overlays: Overlays {
                legend,
                scale_bar: legend,
                ..Default::default()
            },
        })?)
    }
}

/// Selects, loads (all at once), colours and renders one frame.
pub fn render_once(
    ds: Arc<Dataset>,
    a: &ViewArgs,
    cam: &Camera,
    width: u32,
    height: u32,
) -> anyhow::Result<(Frame, FrameReport)> {
    let d = Drawing::new(ds, a, width, height)?.draw(cam, None, false)?;
    Ok((d.frame, d.report))
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
    // With a filter: the points loaded, and those it kept (and so drew).
    let kept = if r.kept < r.points {
        format!(", {} kept by the filter", crate::text::count(r.kept))
    } else {
        String::new()
    };
    let mut line = format!(
        "{} points from {} tiles ({levels}){kept}, {} culled; select {:.1} ms, load {:.0} ms, colour {:.0} ms, render {:.0} ms on {}",
        crate::text::count(s.points),
        s.tiles.len(),
        s.culled,
        r.select_ms,
        r.load_ms,
        r.color_ms,
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
