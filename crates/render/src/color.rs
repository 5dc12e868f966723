//! Colour modes: build the packed `u32` colour column (`r | g << 8 | b << 16`,
//! alpha 255 in the top byte) that renderers consume, from attribute columns —
//! intensity (robust 2nd–98th percentile range, greyscale), rgb (0–255 bands),
//! height (turbo ramp), level (one colour per LOD level), part (one colour
//! per part), classification (ASPRS colours, `classes.rs`) and any band through
//! a ramp (`ramp.rs`). Large columns are converted in parallel; percentiles come from a
//! strided sample, so they cost the same for 10 k or 10 G points.

use std::sync::OnceLock;

use rayon::prelude::*;

use super::RenderError;

/// Values sampled for percentile estimates.
const SAMPLE: usize = 1 << 16;
/// Columns shorter than this are converted on the calling thread.
const PAR_MIN: usize = 1 << 20;
const PAR_CHUNK: usize = 1 << 16;

/// Which attribute drives the colour.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum ColorMode {
    Intensity,
    #[default]
    Rgb,
    Height,
    Level,
    Part,
    /// The `classification` band in ASPRS colours.
    Classification,
    /// Any band (by name) through a ramp.
    Band(String),
}

impl ColorMode {
    /// The name `--color` takes (`band:NAME` for a band).
    pub fn name(&self) -> String {
        match self {
            ColorMode::Intensity => "intensity".into(),
            ColorMode::Rgb => "rgb".into(),
            ColorMode::Height => "height".into(),
            ColorMode::Level => "level".into(),
            ColorMode::Part => "part".into(),
            ColorMode::Classification => "classification".into(),
            ColorMode::Band(b) => format!("band:{b}"),
        }
    }

    /// Whether the mode maps values through a ramp (and so has a ramp legend).
    pub fn uses_ramp(&self) -> bool {
        matches!(
            self,
            ColorMode::Intensity | ColorMode::Height | ColorMode::Band(_)
        )
    }

    /// The band the mode reads, if one.
    pub fn band(&self) -> Option<&str> {
        match self {
            ColorMode::Intensity => Some("intensity"),
            ColorMode::Height => Some("z"),
            ColorMode::Classification => Some("classification"),
            ColorMode::Band(b) => Some(b),
            _ => None,
        }
    }
}

impl std::str::FromStr for ColorMode {
    type Err = RenderError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "intensity" | "i" => Ok(Self::Intensity),
            "rgb" | "color" | "colour" => Ok(Self::Rgb),
            "height" | "z" | "elevation" => Ok(Self::Height),
            "level" | "lod" => Ok(Self::Level),
            "part" => Ok(Self::Part),
            "classification" | "class" => Ok(Self::Classification),
            b if b.starts_with("band:") => {
                // The band name keeps its case (band names are case-sensitive).
                let name = s.trim()[5..].trim();
                if name.is_empty() {
                    return Err(RenderError::InvalidOptions(
                        "band:NAME needs a band name, e.g. band:gps_time".into(),
                    ));
                }
                Ok(Self::Band(name.to_string()))
            }
            other => Err(RenderError::InvalidOptions(format!(
                "unknown colour mode '{other}', expected intensity, rgb, height, level, part, \
                 classification or band:NAME"
            ))),
        }
    }
}

/// Packs 8-bit channels (alpha 255).
#[inline(always)]
pub const fn pack_rgb(r: u8, g: u8, b: u8) -> u32 {
    r as u32 | (g as u32) << 8 | (b as u32) << 16 | 0xff00_0000
}

/// Unpacks to `[r, g, b]`.
#[inline(always)]
pub const fn unpack_rgb(c: u32) -> [u8; 3] {
    [c as u8, (c >> 8) as u8, (c >> 16) as u8]
}

/// Fills `out[i] = f(values[i])`, in parallel for long columns.
fn map_into<F: Fn(f32) -> u32 + Sync>(values: &[f32], out: &mut [u32], f: F) {
    let n = values.len().min(out.len());
    let (values, out) = (&values[..n], &mut out[..n]);
    if n < PAR_MIN {
        for (o, &v) in out.iter_mut().zip(values) {
            *o = f(v);
        }
    } else {
        out.par_chunks_mut(PAR_CHUNK)
            .zip(values.par_chunks(PAR_CHUNK))
            .for_each(|(o, v)| {
                for (o, &v) in o.iter_mut().zip(v) {
                    *o = f(v);
                }
            });
    }
}

/// The `lo_pct`-th and `hi_pct`-th percentiles (0..=100) of the finite values,
/// estimated from an evenly strided sample of at most 65536 values. `None`
/// when there is no finite value.
pub fn robust_range(values: &[f32], lo_pct: f64, hi_pct: f64) -> Option<(f32, f32)> {
    let step = values.len().div_ceil(SAMPLE).max(1);
    let mut s: Vec<f32> = values
        .iter()
        .step_by(step)
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    if s.is_empty() {
        return None;
    }
    let n = s.len();
    let idx = |p: f64| -> usize {
        let p = if p.is_finite() {
            p.clamp(0.0, 100.0)
        } else {
            0.0
        };
        ((p / 100.0) * (n - 1) as f64).round() as usize
    };
    let (a, b) = (idx(lo_pct), idx(hi_pct));
    let (il, ih) = (a.min(b), a.max(b));
    let (_, &mut hi, _) = s.select_nth_unstable_by(ih, f32::total_cmp);
    let (_, &mut lo, _) = s[..=ih].select_nth_unstable_by(il, f32::total_cmp);
    Some((lo, hi))
}

/// Greyscale from `values` mapped linearly from `lo` (black) to `hi` (white),
/// clamped; non-finite values are black.
pub fn intensity_with_range(values: &[f32], lo: f32, hi: f32, out: &mut [u32]) {
    let span = hi - lo;
    let scale = if span > 0.0 && span.is_finite() {
        255.0 / span
    } else {
        0.0
    };
    let base = if scale == 0.0 { 128.0 } else { 0.0 };
    map_into(values, out, move |v| {
        // NaN → 0 through the saturating cast.
        let g = ((v - lo) * scale + base + 0.5).clamp(0.0, 255.0) as u8;
        pack_rgb(g, g, g)
    });
}

/// Greyscale intensity over the robust 2nd–98th percentile range.
pub fn intensity(values: &[f32]) -> Vec<u32> {
    let mut out = vec![0u32; values.len()];
    let (lo, hi) = robust_range(values, 2.0, 98.0).unwrap_or((0.0, 1.0));
    intensity_with_range(values, lo, hi, &mut out);
    out
}

/// Packs 0–255 `f32` bands (rounded, clamped). Errors when lengths differ.
pub fn rgb(r: &[f32], g: &[f32], b: &[f32]) -> Result<Vec<u32>, RenderError> {
    rgb_scaled(r, g, b, 1.0)
}

/// Like [`rgb`] with each band multiplied by `scale` first (`1.0 / 257.0` for
/// 16-bit LAS colours).
pub fn rgb_scaled(r: &[f32], g: &[f32], b: &[f32], scale: f32) -> Result<Vec<u32>, RenderError> {
    let n = r.len();
    if g.len() != n || b.len() != n {
        return Err(RenderError::InvalidInput(format!(
            "colour bands differ in length: r {n} g {} b {}",
            g.len(),
            b.len()
        )));
    }
    let mut out = vec![0u32; n];
    let q = move |v: f32| (v * scale + 0.5).clamp(0.0, 255.0) as u8;
    let body = |o: &mut [u32], r: &[f32], g: &[f32], b: &[f32]| {
        for i in 0..o.len() {
            o[i] = pack_rgb(q(r[i]), q(g[i]), q(b[i]));
        }
    };
    if n < PAR_MIN {
        body(&mut out, r, g, b);
    } else {
        out.par_chunks_mut(PAR_CHUNK)
            .enumerate()
            .for_each(|(k, o)| {
                let s = k * PAR_CHUNK;
                let e = s + o.len();
                body(o, &r[s..e], &g[s..e], &b[s..e]);
            });
    }
    Ok(out)
}

/// The turbo colour map (Mikhailov 2019, polynomial fit) at `t` in 0..=1.
pub fn turbo(t: f32) -> u32 {
    turbo_lut()[(t.clamp(0.0, 1.0) * 255.0 + 0.5) as usize]
}

pub(crate) fn turbo_lut() -> &'static [u32; 256] {
    static LUT: OnceLock<[u32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut lut = [0u32; 256];
        for (i, c) in lut.iter_mut().enumerate() {
            let x = i as f64 / 255.0;
            let poly =
                |k: [f64; 6]| k[0] + x * (k[1] + x * (k[2] + x * (k[3] + x * (k[4] + x * k[5]))));
            let r = poly([
                0.13572138,
                4.61539260,
                -42.66032258,
                132.13108234,
                -152.94239396,
                59.28637943,
            ]);
            let g = poly([
                0.09140261,
                2.19418839,
                4.84296658,
                -14.18503333,
                4.27729857,
                2.82956604,
            ]);
            let b = poly([
                0.10667330,
                12.64194608,
                -60.58204836,
                110.36276771,
                -89.90310912,
                27.34824973,
            ]);
            let q = |v: f64| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            *c = pack_rgb(q(r), q(g), q(b));
        }
        lut
    })
}

/// Height ramp: `z` values relative to `z_origin` (a part's origin), coloured by
/// their absolute height between `lo` and `hi` with the turbo map, so parts
/// with different origins share one scale. NaN maps to the low end.
pub fn height_into(z: &[f32], z_origin: f64, lo: f64, hi: f64, out: &mut [u32]) {
    let lut = turbo_lut();
    let span = hi - lo;
    let scale = if span > 0.0 && span.is_finite() {
        (255.0 / span) as f32
    } else {
        0.0
    };
    let shift = (z_origin - lo) as f32;
    map_into(z, out, move |v| {
        let i = ((v + shift) * scale + 0.5).clamp(0.0, 255.0) as usize;
        lut[i]
    });
}

/// [`height_into`] into a new column.
pub fn height(z: &[f32], z_origin: f64, lo: f64, hi: f64) -> Vec<u32> {
    let mut out = vec![0u32; z.len()];
    height_into(z, z_origin, lo, hi, &mut out);
    out
}

/// Height ramp over the column's own robust (1st–99th percentile) range.
pub fn height_auto(z: &[f32], z_origin: f64) -> Vec<u32> {
    let (lo, hi) = robust_range(z, 1.0, 99.0).unwrap_or((0.0, 1.0));
    height(z, z_origin, lo as f64 + z_origin, hi as f64 + z_origin)
}

/// Twelve well-separated colours (Tableau-like) for categorical modes.
const PALETTE: [u32; 12] = [
    pack_rgb(78, 121, 167),
    pack_rgb(242, 142, 43),
    pack_rgb(225, 87, 89),
    pack_rgb(118, 183, 178),
    pack_rgb(89, 161, 79),
    pack_rgb(237, 201, 72),
    pack_rgb(176, 122, 161),
    pack_rgb(255, 157, 167),
    pack_rgb(156, 117, 95),
    pack_rgb(186, 176, 172),
    pack_rgb(31, 119, 180),
    pack_rgb(214, 39, 40),
];

/// A colour per level of detail: level 0 (coarsest) blue, rising through the
/// turbo ramp to red at level 15 and beyond.
pub fn level_color(level: u32) -> u32 {
    turbo(0.1 + 0.85 * (level.min(15) as f32 / 15.0))
}

/// A colour per part index (cycles through 12 distinct colours).
pub(crate) fn part_color(part: usize) -> u32 {
    PALETTE[part % PALETTE.len()]
}

/// A column of `n` copies of `color` (level and part modes).
pub fn constant(n: usize, color: u32) -> Vec<u32> {
    vec![color; n]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_ignore_outliers() {
        let mut v: Vec<f32> = (0..100_000).map(|i| (i % 1000) as f32).collect();
        v[10] = 1e9;
        v[20] = -1e9;
        v[30] = f32::NAN;
        v[40] = f32::INFINITY;
        let (lo, hi) = robust_range(&v, 2.0, 98.0).unwrap();
        assert!((lo - 20.0).abs() <= 2.0, "{lo}");
        assert!((hi - 979.0).abs() <= 2.0, "{hi}");
        let g = intensity(&v);
        assert_eq!(unpack_rgb(g[10]), [255, 255, 255]);
        assert_eq!(unpack_rgb(g[20]), [0, 0, 0]);
        assert_eq!(unpack_rgb(g[30]), [0, 0, 0], "NaN is black");
        let mid = unpack_rgb(g[500]);
        assert!((mid[0] as i32 - 128).abs() <= 3 && mid[0] == mid[1] && mid[1] == mid[2]);
        assert_eq!(robust_range(&[], 2.0, 98.0), None);
        assert_eq!(robust_range(&[f32::NAN], 2.0, 98.0), None);
        assert_eq!(robust_range(&[5.0], 2.0, 98.0), Some((5.0, 5.0)));
        // Constant column: mid grey, no division by zero.
        assert_eq!(unpack_rgb(intensity(&[7.0; 10])[0]), [128, 128, 128]);
    }

    #[test]
    fn rgb_is_exact() {
        let r: Vec<f32> = (0..256).map(|i| i as f32).collect();
        let g: Vec<f32> = (0..256).map(|i| (255 - i) as f32).collect();
        let b: Vec<f32> = (0..256).map(|i| ((i * 7) % 256) as f32).collect();
        let c = rgb(&r, &g, &b).unwrap();
        for (i, &ci) in c.iter().enumerate() {
            assert_eq!(ci, pack_rgb(i as u8, 255 - i as u8, ((i * 7) % 256) as u8));
        }
        assert_eq!(
            unpack_rgb(rgb(&[300.0], &[-5.0], &[f32::NAN]).unwrap()[0]),
            [255, 0, 0]
        );
        assert!(rgb(&[1.0], &[], &[]).is_err());
        let s = rgb_scaled(&[65535.0], &[257.0], &[0.0], 1.0 / 257.0).unwrap();
        assert_eq!(unpack_rgb(s[0]), [255, 1, 0]);
        // The parallel path gives the same result.
        let n = PAR_MIN + 5;
        let big: Vec<f32> = (0..n).map(|i| (i % 256) as f32).collect();
        let c = rgb(&big, &big, &big).unwrap();
        assert!(
            c.iter()
                .enumerate()
                .all(|(i, &v)| v == pack_rgb((i % 256) as u8, (i % 256) as u8, (i % 256) as u8))
        );
    }

    #[test]
    fn height_levels_parts() {
        let z = [0.0f32, 50.0, 100.0, -10.0, f32::NAN];
        // Origin 1000: absolute heights 1000..1100.
        let c = height(&z, 1000.0, 1000.0, 1100.0);
        assert_eq!(c[0], turbo(0.0));
        assert_eq!(c[2], turbo(1.0));
        assert_eq!(c[3], turbo(0.0));
        assert_eq!(c[4], turbo(0.0));
        assert_ne!(c[1], c[0]);
        assert_eq!(height_auto(&[], 0.0), Vec::<u32>::new());
        assert_ne!(level_color(0), level_color(5));
        assert_eq!(level_color(15), level_color(99));
        assert_ne!(part_color(0), part_color(1));
        assert_eq!(part_color(12), part_color(0));
        assert_eq!(constant(3, 7), vec![7, 7, 7]);
        assert_eq!("Height".parse::<ColorMode>().unwrap(), ColorMode::Height);
        assert!("nope".parse::<ColorMode>().is_err());
    }
}
