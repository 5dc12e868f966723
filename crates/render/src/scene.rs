//! A frame's content: loaded tiles with their colour columns (and, under a
//! filter, heights with the hidden points set to NaN), turned into the
//! `PointBatch`es every rasterizer draws. Colour ranges (intensity percentiles,
//! height, a band's range) are fixed per scene so they do not flicker as tiles
//! stream in.

use super::PointBatch;
use super::color::{self, ColorMode};
use super::filter::Filter;
use super::ramp::{self, Ramp};
use crate::lod::LoadedTile;
use crate::points::Bounds;
use std::sync::Arc;

/// Value ranges that colour modes map from.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ColorRanges {
    pub intensity: (f32, f32),
    pub height: (f64, f64),
    /// Colour bands above 255 are 16-bit and scaled down.
    pub rgb_scale: f32,
    /// The range of the band `band:NAME` colours by, in source units.
    pub band: (f64, f64),
}

/// How points are coloured: the mode, and for ramp modes the ramp and an
/// explicit range (else the data's).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Style {
    pub mode: ColorMode,
    pub ramp: Option<Ramp>,
    pub range: Option<(f64, f64)>,
}

impl Style {
    pub fn of(mode: ColorMode) -> Style {
        Style {
            mode,
            ..Style::default()
        }
    }

    /// The ramp drawn: the chosen one, else gray for intensity, turbo for height
    /// and viridis for other bands.
    pub fn ramp(&self) -> Ramp {
        self.ramp.unwrap_or(match self.mode {
            ColorMode::Intensity => Ramp::Gray,
            ColorMode::Height => Ramp::Turbo,
            _ => Ramp::Viridis,
        })
    }

    /// The value range the ramp spans, in source units (ramp modes only).
    pub(crate) fn value_range(&self, r: &ColorRanges) -> Option<(f64, f64)> {
        let auto = match self.mode {
            ColorMode::Intensity => (r.intensity.0 as f64, r.intensity.1 as f64),
            ColorMode::Height => r.height,
            ColorMode::Band(_) => r.band,
            _ => return None,
        };
        Some(self.range.unwrap_or(auto))
    }
}

/// A band's column in `t` with its offset (x, y, z: the coordinates and origin).
pub(crate) fn band_of<'a>(t: &'a LoadedTile, name: &str) -> Option<(&'a [f32], f64)> {
    match name {
        "x" => Some((&t.x, t.origin[0])),
        "y" => Some((&t.y, t.origin[1])),
        "z" => Some((&t.z, t.origin[2])),
        b => t
            .attributes
            .iter()
            .find(|a| a.0 == b)
            .map(|a| (a.2.as_slice(), a.1)),
    }
}

/// The robust (2nd–98th percentile) range of band `name` over `tiles`, in
/// source units; `None` when no tile has a finite value of it.
pub(crate) fn band_range(tiles: &[Arc<LoadedTile>], name: &str) -> Option<(f64, f64)> {
    let mut sample: Vec<f32> = Vec::new();
    // Values are sampled relative to the first tile's offset, so large offsets
    // (GPS time, coordinates) keep their precision.
    let mut base = None;
    for t in tiles {
        if let Some((v, off)) = band_of(t, name) {
            let b = *base.get_or_insert(off);
            let step = (v.len() / 4096).max(1);
            sample.extend(v.iter().step_by(step).map(|&x| (x as f64 + off - b) as f32));
        }
    }
    let (lo, hi) = color::robust_range(&sample, 2.0, 98.0)?;
    let b = base.unwrap_or(0.0);
    Some((lo as f64 + b, hi as f64 + b))
}

impl ColorRanges {
    /// Ranges from the tiles at hand (robust intensity percentiles) and the
    /// dataset's bounds (height).
    pub fn from_tiles(tiles: &[Arc<LoadedTile>], bounds: &Bounds) -> ColorRanges {
        let mut sample: Vec<f32> = Vec::new();
        let mut rgb_max = 0f32;
        for t in tiles {
            if let Some((v, off)) = band_of(t, "intensity") {
                let step = (v.len() / 4096).max(1);
                sample.extend(v.iter().step_by(step).map(|&x| (x as f64 + off) as f32));
            }
            if let Some(r) = t.attribute("red") {
                rgb_max = r
                    .iter()
                    .step_by((r.len() / 1024).max(1))
                    .fold(rgb_max, |m, &x| m.max(x));
            }
        }
        let intensity = color::robust_range(&sample, 2.0, 98.0).unwrap_or((0.0, 255.0));
        ColorRanges {
            intensity,
            height: (bounds.min[2], bounds.max[2]),
            rgb_scale: if rgb_max > 255.0 { 1.0 / 257.0 } else { 1.0 },
            band: (0.0, 1.0),
        }
    }

    /// [`ColorRanges::from_tiles`] plus the range of the band `style` colours by.
    pub fn for_style(tiles: &[Arc<LoadedTile>], bounds: &Bounds, style: &Style) -> ColorRanges {
        let mut r = ColorRanges::from_tiles(tiles, bounds);
        if let ColorMode::Band(b) = &style.mode {
            r.band = band_range(tiles, b).unwrap_or((0.0, 1.0));
        }
        r
    }
}

/// Loaded tiles and their colours, ready to draw.
pub struct Scene {
    pub tiles: Vec<Arc<LoadedTile>>,
    pub colors: Vec<Vec<u32>>,
    /// Per tile, under a filter: its heights with the hidden points NaN.
    pub hidden: Vec<Option<Vec<f32>>>,
}

/// The colour column of one tile in `mode` with the default ramps and ranges.
/// Modes whose bands the part lacks fall back to height.
pub(crate) fn colorize(t: &LoadedTile, mode: ColorMode, r: &ColorRanges) -> Vec<u32> {
    colorize_style(t, &Style::of(mode), r)
}

/// The colour column of one tile. Modes whose bands the part lacks fall back to
/// height.
pub(crate) fn colorize_style(t: &LoadedTile, style: &Style, r: &ColorRanges) -> Vec<u32> {
    let n = t.len();
    let through_ramp = |v: &[f32], off: f64| {
        let (lo, hi) = style.value_range(r).unwrap_or((0.0, 1.0));
        let mut out = vec![0u32; n];
        ramp::map_into(v, off, lo, hi, style.ramp().lut(), &mut out);
        out
    };
    match &style.mode {
        ColorMode::Intensity => {
            if let Some((v, off)) = band_of(t, "intensity") {
                return through_ramp(v, off);
            }
        }
        ColorMode::Band(b) => {
            if let Some((v, off)) = band_of(t, b) {
                return through_ramp(v, off);
            }
        }
        ColorMode::Classification => {
            if let Some(v) = t.attribute("classification") {
                return super::classes::colorize(v);
            }
        }
        ColorMode::Rgb => {
            if let (Some(red), Some(g), Some(b)) = (
                t.attribute("red"),
                t.attribute("green"),
                t.attribute("blue"),
            ) && let Ok(c) = color::rgb_scaled(red, g, b, r.rgb_scale)
            {
                return c;
            }
            if t.attribute("intensity").is_some() {
                return colorize(t, ColorMode::Intensity, r);
            }
        }
        ColorMode::Level => return color::constant(n, color::level_color(t.key.level as u32)),
        ColorMode::Part => return color::constant(n, color::part_color(t.key.part)),
        ColorMode::Height => return through_ramp(&t.z, t.origin[2]),
    }
    color::height(&t.z, t.origin[2], r.height.0, r.height.1)
}

impl Scene {
    pub fn new(tiles: Vec<Arc<LoadedTile>>, mode: ColorMode, ranges: &ColorRanges) -> Scene {
        Scene::build(tiles, &Style::of(mode), ranges, &Filter::default())
    }

    /// Colours the tiles in `style` and applies `filter`.
    pub fn build(
        tiles: Vec<Arc<LoadedTile>>,
        style: &Style,
        ranges: &ColorRanges,
        filter: &Filter,
    ) -> Scene {
        use rayon::prelude::*;
        let colors = tiles
            .par_iter()
            .map(|t| colorize_style(t, style, ranges))
            .collect();
        let hidden = tiles.par_iter().map(|t| filter.hidden_z(t)).collect();
        Scene {
            tiles,
            colors,
            hidden,
        }
    }

    /// Points the filter lets through.
    pub fn shown_points(&self) -> u64 {
        self.tiles
            .iter()
            .zip(&self.hidden)
            .map(|(t, h)| match h {
                None => t.len() as u64,
                Some(z) => z.iter().filter(|v| !v.is_nan()).count() as u64,
            })
            .sum()
    }

    pub fn points(&self) -> u64 {
        self.tiles.iter().map(|t| t.len() as u64).sum()
    }

    pub fn batches(&self) -> Vec<PointBatch<'_>> {
        self.tiles
            .iter()
            .zip(&self.colors)
            .zip(&self.hidden)
            .map(|((t, c), h)| PointBatch {
                origin: t.origin,
                x: &t.x,
                y: &t.y,
                z: h.as_deref().unwrap_or(&t.z),
                color: c,
            })
            .collect()
    }
}
