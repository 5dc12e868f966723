//! A frame's content: loaded tiles with their colour columns, turned into the
//! `PointBatch`es every rasterizer draws. Colour ranges (intensity percentiles,
//! height) are fixed per scene so they do not flicker as tiles stream in.

use super::PointBatch;
use super::color::{self, ColorMode};
use crate::lod::LoadedTile;
use crate::points::Bounds;
use std::sync::Arc;

/// Value ranges that colour modes map from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorRanges {
    pub intensity: (f32, f32),
    pub height: (f64, f64),
    /// Colour bands above 255 are 16-bit and scaled down.
    pub rgb_scale: f32,
}

impl ColorRanges {
    /// Ranges from the tiles at hand (robust intensity percentiles) and the
    /// dataset's bounds (height).
    pub fn from_tiles(tiles: &[Arc<LoadedTile>], bounds: &Bounds) -> ColorRanges {
        let mut sample: Vec<f32> = Vec::new();
        let mut rgb_max = 0f32;
        for t in tiles {
            if let Some(v) = t.attribute("intensity") {
                let step = (v.len() / 4096).max(1);
                sample.extend(v.iter().step_by(step));
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
        }
    }
}

/// Loaded tiles and their colours, ready to draw.
pub struct Scene {
    pub tiles: Vec<Arc<LoadedTile>>,
    pub colors: Vec<Vec<u32>>,
}

/// The colour column of one tile. Modes whose bands the part lacks fall back to
/// height.
pub fn colorize(t: &LoadedTile, mode: ColorMode, r: &ColorRanges) -> Vec<u32> {
    let n = t.len();
    match mode {
        ColorMode::Intensity => {
            if let Some(v) = t.attribute("intensity") {
                let mut out = vec![0u32; n];
                color::intensity_with_range(v, r.intensity.0, r.intensity.1, &mut out);
                return out;
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
        ColorMode::Height => {}
    }
    color::height(&t.z, t.origin[2], r.height.0, r.height.1)
}

impl Scene {
    pub fn new(tiles: Vec<Arc<LoadedTile>>, mode: ColorMode, ranges: &ColorRanges) -> Scene {
        use rayon::prelude::*;
        let colors = tiles
            .par_iter()
            .map(|t| colorize(t, mode, ranges))
            .collect();
        Scene { tiles, colors }
    }

    pub fn points(&self) -> u64 {
        self.tiles.iter().map(|t| t.len() as u64).sum()
    }

    pub fn batches(&self) -> Vec<PointBatch<'_>> {
        self.tiles
            .iter()
            .zip(&self.colors)
            .map(|(t, c)| PointBatch {
                origin: t.origin,
                x: &t.x,
                y: &t.y,
                z: &t.z,
                color: c,
            })
            .collect()
    }
}
