//! Colour scaling: every reader delivers `red`, `green` and `blue` on a 0–255 scale.
//!
//! The rule, decided once per file from its first [`DECIDE_POINTS`] points (the
//! first chunk's; readers' chunks are at least that large, so the decision does
//! not depend on `--memory`) and then applied to every chunk:
//!
//! * any colour value above 255 → the file holds 16-bit colour: divide by 257
//!   (65535 → 255);
//! * otherwise, for floating-point sources (PLY `float`/`double` colour, or text
//!   whose colour columns contain a non-integer value) with every value ≤ 1.0 →
//!   unit-scale colour: multiply by 255;
//! * otherwise the values are already 8-bit (this includes LAS files that store
//!   8-bit values in their 16-bit colour fields) and are kept as they are.
//!
//! After scaling, values are clamped to 0–255, so a later chunk that breaks the
//! pattern of the first cannot leave the range.

/// Points whose colour decides a file's scale.
pub const DECIDE_POINTS: usize = 1 << 16;

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// How colour values of one file are mapped to 0–255.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ColorScale {
    /// Already 0–255.
    Identity,
    /// 16-bit colour: divide by 257.
    From16Bit,
    /// Unit colour (0–1): multiply by 255.
    FromUnit,
}

impl ColorScale {
    /// Decides the scale from sample values. `float_source` says whether the
    /// source stores colour as floating point (which makes the 0–1 rule apply).
    pub fn detect<'a>(samples: impl IntoIterator<Item = &'a [f32]>, float_source: bool) -> Self {
        let cols: Vec<&[f32]> = samples.into_iter().collect();
        let mut max = f32::NEG_INFINITY;
        for col in &cols {
            max = col
                .iter()
                .filter(|v| v.is_finite())
                .fold(max, |m, &v| m.max(v));
        }
        let any = max > f32::NEG_INFINITY;
        // Only a 0–1 sample needs the (slower) fractional test.
        let fractional = any
            && max <= 1.0
            && cols
                .iter()
                .any(|c| c.iter().any(|v| v.is_finite() && v.fract() != 0.0));
        if !any {
            ColorScale::Identity
        } else if max > 255.0 {
            ColorScale::From16Bit
        } else if max <= 1.0 && (float_source || fractional) {
            ColorScale::FromUnit
        } else {
            ColorScale::Identity
        }
    }

    /// The factor a value is scaled by.
    fn factor(self) -> f32 {
        match self {
            ColorScale::Identity => 1.0,
            ColorScale::From16Bit => 1.0 / 257.0,
            ColorScale::FromUnit => 255.0,
        }
    }

    /// One value scaled and clamped, as [`ColorScale::apply`] does it.
    #[inline]
    pub fn one(self, v: f32) -> f32 {
        (v * self.factor()).clamp(0.0, 255.0)
    }

    /// Whether scaling `v` leaves 0–255, so [`ColorScale::one`] clamps it (what
    /// [`ColorScale::apply`] counts).
    #[inline]
    pub fn clamps(self, v: f32) -> bool {
        let s = v * self.factor();
        s.clamp(0.0, 255.0) != s && !s.is_nan()
    }

    /// Scales a column in place and clamps it to 0–255; how many values the clamp
    /// changed (the scale did not fit them).
    pub fn apply(self, values: &mut [f32]) -> u64 {
        let f = self.factor();
        use rayon::prelude::*;
        values
            .par_chunks_mut(1 << 16)
            .map(|c| {
                let mut clamped = 0u64;
                for v in c {
                    let s = *v * f;
                    *v = s.clamp(0.0, 255.0);
                    clamped += (*v != s && !s.is_nan()) as u64;
                }
                clamped
            })
            .sum()
    }
}

/// The canonical band name for a source colour property name, if it is one.
pub(crate) fn color_name(name: &str) -> Option<&'static str> {
    match name {
        "r" | "red" | "diffuse_red" => Some("red"),
        "g" | "green" | "diffuse_green" => Some("green"),
        "b" | "blue" | "diffuse_blue" => Some("blue"),
        _ => None,
    }
}

pub(crate) fn is_color(name: &str) -> bool {
    matches!(name, "red" | "green" | "blue")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rules() {
        let eight: Vec<f32> = vec![0.0, 40.0, 236.0];
        assert_eq!(
            ColorScale::detect([&eight[..]], false),
            ColorScale::Identity
        );
        let sixteen: Vec<f32> = vec![0.0, 40.0 * 257.0, 65535.0];
        assert_eq!(
            ColorScale::detect([&sixteen[..]], false),
            ColorScale::From16Bit
        );
        let unit: Vec<f32> = vec![0.0, 0.5, 1.0];
        assert_eq!(ColorScale::detect([&unit[..]], true), ColorScale::FromUnit);
        // Text (not float typed): 0/1 integers stay 8-bit.
        let ints: Vec<f32> = vec![0.0, 1.0];
        assert_eq!(ColorScale::detect([&ints[..]], false), ColorScale::Identity);
        let mut v = sixteen.clone();
        assert_eq!(ColorScale::From16Bit.apply(&mut v), 0);
        assert_eq!(v, vec![0.0, 40.0, 255.0]);
        let mut v = vec![0.5f32, 2.0];
        assert_eq!(ColorScale::FromUnit.apply(&mut v), 1);
        assert_eq!(v, vec![127.5, 255.0]);
        let mut v = vec![200.0f32, 60_000.0, -1.0];
        assert_eq!(ColorScale::Identity.apply(&mut v), 2);
        assert_eq!(v, vec![200.0, 255.0, 0.0]);
    }
}

/// Applies the colour rule to the `red`/`green`/`blue` attributes of each chunk,
/// deciding the scale on the first [`DECIDE_POINTS`] points of the first chunk
/// that has colour values.
#[derive(Debug, Clone)]
pub(crate) struct ColorNormalizer {
    float_source: bool,
    scale: Option<ColorScale>,
    /// Values so far outside the decided scale, clamped to 0–255 (shared, so a
    /// reader can report it while a decoder thread owns the normalizer).
    clamped: Arc<AtomicU64>,
}

impl ColorNormalizer {
    pub fn new(float_source: bool) -> Self {
        Self {
            float_source,
            scale: None,
            clamped: Arc::default(),
        }
    }

    /// The count of clamped values, shared with this normalizer.
    pub fn clamped(&self) -> Arc<AtomicU64> {
        self.clamped.clone()
    }

    /// The scale decided so far (`None` before the first chunk with colour).
    pub fn scale(&self) -> Option<ColorScale> {
        self.scale
    }

    /// Decides the scale from the colour values of the file's first points (at
    /// most [`DECIDE_POINTS`] of each channel), unless decided already; the scale.
    pub fn decide<'a>(&mut self, first: impl IntoIterator<Item = &'a [f32]>) -> ColorScale {
        *self.scale.get_or_insert_with(|| {
            let first: Vec<&[f32]> = first
                .into_iter()
                .map(|c| &c[..c.len().min(DECIDE_POINTS)])
                .collect();
            ColorScale::detect(first, self.float_source)
        })
    }

    /// Counts `n` more values clamped (by a reader that scales them itself).
    pub(crate) fn add_clamped(&self, n: u64) {
        self.clamped.fetch_add(n, Ordering::Relaxed);
    }

    pub fn apply(&mut self, cols: &mut crate::points::PointColumns) {
        if !cols.attributes.iter().any(|a| is_color(&a.name)) {
            return;
        }
        if self.scale.is_none() && cols.is_empty() {
            return;
        }
        let scale = self.decide(
            cols.attributes
                .iter()
                .filter(|a| is_color(&a.name))
                .map(|a| &a.values[..]),
        );
        for a in cols.attributes.iter_mut().filter(|a| is_color(&a.name)) {
            let n = scale.apply(&mut a.values);
            self.clamped.fetch_add(n, Ordering::Relaxed);
        }
    }
}
