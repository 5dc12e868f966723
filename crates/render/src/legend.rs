//! Legends: the classes present in a dataset with their counts (from each
//! part's `CLASS_COUNTS`, recorded at conversion: nothing is scanned at view
//! time), a ramp's values, and a scale bar in ground units; drawn onto a frame
//! by `render --legend` and listed by the inspector.

use super::classes::{self, ClassMask};
use super::color::unpack_rgb;
use super::font;
use super::ramp::Ramp;
use super::{Camera, Frame};
use crate::store::Dataset;

/// One class of the legend.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClassEntry {
    pub code: u8,
    pub name: String,
    pub color: u32,
    /// Points of this class in the whole dataset.
    pub count: u64,
    pub shown: bool,
}

/// The classes present in `ds` (summed over its parts' recorded counts), codes
/// ascending; empty when no part records classes.
pub fn class_entries(ds: &Dataset, mask: &ClassMask) -> Vec<ClassEntry> {
    let mut counts = [0u64; 256];
    for &(c, n) in &ds.totals().class_counts {
        counts[c as usize] += n;
    }
    (0..=255u8)
        .filter(|&c| counts[c as usize] > 0)
        .map(|c| ClassEntry {
            code: c,
            name: classes::name(c),
            color: classes::color(c),
            count: counts[c as usize],
            shown: mask.shows(c),
        })
        .collect()
}

/// What a legend shows.
#[derive(Debug, Clone, PartialEq)]
pub enum Legend {
    Classes(Vec<ClassEntry>),
    Ramp {
        title: String,
        ramp: Ramp,
        lo: f64,
        hi: f64,
    },
}

impl Legend {
    /// The legend of frames drawn in `style`: the classes present (with the
    /// filter's hidden ones marked) when colouring by class, the ramp and its
    /// values when colouring through one, else none. The one place a legend is
    /// chosen, for `render --legend` and the inspector's panel alike.
    pub fn for_style(
        ds: &Dataset,
        style: &crate::scene::Style,
        filter: &crate::filter::Filter,
        ranges: &crate::scene::ColorRanges,
    ) -> Option<Legend> {
        match &style.mode {
            crate::ColorMode::Classification => {
                Some(Legend::Classes(class_entries(ds, &filter.classes)))
            }
            m if m.uses_ramp() => {
                let (lo, hi) = style.value_range(ranges)?;
                Some(Legend::Ramp {
                    title: m.band().unwrap_or("value").to_string(),
                    ramp: style.ramp(),
                    lo,
                    hi,
                })
            }
            _ => None,
        }
    }
}

/// Points of `tiles` per bin of `bins` equal bins over `[lo, hi]` of `band`
/// (`x`, `y`, `z` or an attribute, in source units): the values a ramp's
/// legend spans, drawn under its colours. Values outside the range, NaN, and
/// tiles without the band are not counted.
pub fn histogram(
    tiles: &[std::sync::Arc<crate::lod::LoadedTile>],
    band: &str,
    lo: f64,
    hi: f64,
    bins: usize,
) -> Vec<u32> {
    let mut h = vec![0u32; bins];
    if bins == 0 || hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return h;
    }
    let k = bins as f64 / (hi - lo);
    for t in tiles {
        let (col, off): (&[f32], f64) = match band {
            "x" => (&t.x, t.origin[0]),
            "y" => (&t.y, t.origin[1]),
            "z" => (&t.z, t.origin[2]),
            b => match t.attributes.iter().find(|a| a.0 == b) {
                Some(a) => (&a.2, a.1),
                None => continue,
            },
        };
        for &v in col {
            let x = off + v as f64;
            if x >= lo && x <= hi {
                h[(((x - lo) * k) as usize).min(bins - 1)] += 1;
            }
        }
    }
    h
}

/// `v` with about four significant digits, without float noise.
pub fn value_label(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e7).contains(&a) {
        return format!("{v:.3e}");
    }
    let decimals = if a >= 1000.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 {
        2
    } else {
        3
    };
    format!("{v:.decimals$}")
}

/// `v` as a tick of a range `span` wide: enough decimals to tell the ticks
/// apart (GPS times 1e8 apart by seconds keep their seconds).
pub fn tick_label(v: f64, span: f64) -> String {
    if !(span.is_finite() && span > 0.0) || v.abs() >= 1e15 {
        return value_label(v);
    }
    let decimals = (2 - span.log10().floor() as i64).clamp(0, 6) as usize;
    format!("{v:.decimals$}")
}

/// Values at `n` evenly spaced ticks of `lo..=hi` (`n >= 2`).
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let n = n.max(2);
    (0..n)
        .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
        .collect()
}

/// A scale bar: a round length (1, 2 or 5 × 10^k ground units) that spans at
/// most `max_px` pixels, and its length in pixels, for the ground seen at the
/// orbit target (or `distance` ahead in fly mode) of `camera` on a frame
/// `height` pixels high.
pub fn scale_bar(camera: &Camera, height: u32, max_px: f64) -> Option<(f64, f64)> {
    let ppu = camera.pixels_per_unit(camera.distance, height);
    if !(ppu.is_finite() && ppu > 0.0 && max_px > 0.0) {
        return None;
    }
    let most = max_px / ppu;
    let p = 10f64.powf(most.log10().floor());
    let len = [5.0, 2.0, 1.0].iter().map(|m| m * p).find(|&l| l <= most)?;
    Some((len, len * ppu))
}

/// A scale bar's label: `len` with a sensible precision and `unit` (the
/// dataset's, [`dataset_unit`]): `20 m`, `0.500 ft`.
pub fn length_label(len: f64, unit: &str) -> String {
    let v = value_label(len);
    let v = if len >= 1.0 {
        v.trim_end_matches(".00").trim_end_matches(".0").to_string()
    } else {
        v
    };
    format!("{v} {unit}")
}

/// The symbol lengths in `ds` are labelled in: its first part's CRS's unit
/// (`m`, `ft`; `units` when no CRS says, see [`crate::store::crs::unit_symbol`]).
pub fn dataset_unit(ds: &Dataset) -> String {
    crate::store::crs::unit_symbol(ds.totals().crs.as_deref())
}

fn fill(f: &mut Frame, x: i64, y: i64, w: i64, h: i64, c: [u8; 3]) {
    for py in y.max(0)..(y + h).min(f.height as i64) {
        for px in x.max(0)..(x + w).min(f.width as i64) {
            let i = (py as usize * f.width as usize + px as usize) * 4;
            f.rgba[i..i + 3].copy_from_slice(&c);
        }
    }
}

/// Darkens a box so text over points stays readable.
fn shade(f: &mut Frame, x: i64, y: i64, w: i64, h: i64) {
    for py in y.max(0)..(y + h).min(f.height as i64) {
        for px in x.max(0)..(x + w).min(f.width as i64) {
            let i = (py as usize * f.width as usize + px as usize) * 4;
            for c in &mut f.rgba[i..i + 3] {
                *c /= 3;
            }
        }
    }
}

/// The text scale for a frame: 1 below 900 pixels high, then 2.
fn text_scale(f: &Frame) -> u32 {
    if f.height >= 900 { 2 } else { 1 }
}

/// Draws `legend` in the frame's top-right corner.
pub fn draw(f: &mut Frame, legend: &Legend) {
    let s = text_scale(f);
    let line = (font::H + 4) as i64 * s as i64;
    let pad = 6 * s as i64;
    let white = [240, 240, 240];
    match legend {
        Legend::Classes(entries) => {
            let lines: Vec<String> = entries
                .iter()
                .map(|e| format!("{:>3} {} {}", e.code, e.name, crate::text::count(e.count)))
                .collect();
            let tw = lines
                .iter()
                .map(|l| font::text_width(l, s))
                .max()
                .unwrap_or(0) as i64;
            let sw = line - 2 * s as i64;
            let bw = tw + sw + 3 * pad;
            let bh = line * lines.len() as i64 + 2 * pad;
            let x0 = f.width as i64 - bw - pad;
            shade(f, x0, pad, bw, bh);
            for (k, (e, l)) in entries.iter().zip(&lines).enumerate() {
                let y = 2 * pad + k as i64 * line;
                let c = if e.shown {
                    unpack_rgb(e.color)
                } else {
                    [60, 60, 60]
                };
                fill(f, x0 + pad, y, sw, sw, c);
                let tc = if e.shown { white } else { [120, 120, 120] };
                font::draw_text(&mut f.rgba, f.width, x0 + 2 * pad + sw, y, l, s, tc);
            }
        }
        Legend::Ramp {
            title,
            ramp,
            lo,
            hi,
        } => {
            let bar_h = (f.height as i64 / 3).clamp(40, 400);
            let bar_w = 14 * s as i64;
            let labels: Vec<String> = ticks(*lo, *hi, 5)
                .iter()
                .map(|&v| tick_label(v, hi - lo))
                .collect();
            let lw = labels
                .iter()
                .map(|l| font::text_width(l, s))
                .max()
                .unwrap_or(0) as i64;
            let tw = font::text_width(title, s) as i64;
            let bw = (bar_w + pad + lw).max(tw) + 2 * pad;
            let bh = bar_h + line + 3 * pad;
            let x0 = f.width as i64 - bw - pad;
            shade(f, x0, pad, bw, bh);
            font::draw_text(&mut f.rgba, f.width, x0 + pad, 2 * pad, title, s, white);
            let top = 2 * pad + line;
            let lut = ramp.lut();
            for r in 0..bar_h {
                // High values at the top.
                let i = (255 - r * 255 / (bar_h - 1).max(1)) as usize;
                fill(f, x0 + pad, top + r, bar_w, 1, unpack_rgb(lut[i]));
            }
            let n = labels.len() as i64;
            for (k, l) in labels.iter().enumerate() {
                let y = top + bar_h - 1 - k as i64 * (bar_h - 1) / (n - 1);
                fill(f, x0 + pad + bar_w, y, 3 * s as i64, s as i64, white);
                let ty = (y - (font::H as i64 * s as i64) / 2).max(top);
                font::draw_text(&mut f.rgba, f.width, x0 + 2 * pad + bar_w, ty, l, s, white);
            }
        }
    }
}

/// Draws a scale bar for `camera` in the bottom-left corner, labelled in `unit`.
pub(crate) fn draw_scale_bar(f: &mut Frame, camera: &Camera, unit: &str) {
    let s = text_scale(f);
    let pad = 8 * s as i64;
    let Some((len, px)) = scale_bar(camera, f.height, f.width as f64 / 4.0) else {
        return;
    };
    let px = px.round() as i64;
    let label = length_label(len, unit);
    let th = font::H as i64 * s as i64;
    let y = f.height as i64 - pad - 3 * s as i64;
    shade(
        f,
        pad / 2,
        y - th - 3 * pad / 2,
        px.max(font::text_width(&label, s) as i64) + pad,
        th + 2 * pad,
    );
    let white = [240, 240, 240];
    fill(f, pad, y, px, 2 * s as i64, white);
    fill(f, pad, y - 4 * s as i64, s as i64, 6 * s as i64, white);
    fill(
        f,
        pad + px - s as i64,
        y - 4 * s as i64,
        s as i64,
        6 * s as i64,
        white,
    );
    font::draw_text(
        &mut f.rgba,
        f.width,
        pad,
        y - th - 6 * s as i64,
        &label,
        s,
        white,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_ticks_bars() {
        assert_eq!(value_label(1234.5678), "1235");
        assert_eq!(value_label(12.345), "12.3");
        assert_eq!(value_label(0.5), "0.500");
        assert_eq!(value_label(1.0e8), "1.000e8");
        assert_eq!(ticks(0.0, 10.0, 3), vec![0.0, 5.0, 10.0]);
        assert_eq!(tick_label(100_000_001.5, 3.0), "100000001.50");
        assert_eq!(tick_label(420.0, 50.0), "420.0");
        let cam = Camera {
            distance: 100.0,
            ..Camera::default()
        };
        let (len, px) = scale_bar(&cam, 720, 300.0).unwrap();
        assert!(px <= 300.0 && px > 60.0, "{len} {px}");
        let m = len / 10f64.powf(len.log10().floor());
        assert!(
            [1.0, 2.0, 5.0].iter().any(|x| (x - m).abs() < 1e-9),
            "{len}"
        );
        assert_eq!(length_label(20.0, "m"), "20 m");
        assert_eq!(length_label(0.5, "m"), "0.500 m");
        assert_eq!(length_label(200.0, "ft"), "200 ft");
        assert_eq!(length_label(2.5, "units"), "2.50 units");
    }
}
