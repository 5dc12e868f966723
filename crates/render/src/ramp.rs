//! Colour ramps for continuous values (`--ramp`): turbo, viridis, magma,
//! inferno, plasma, gray, as 256-entry lookup tables, and the mapping of a
//! band's values through one over a range (`--range`, or robust percentiles).
//! Intensity, height and `band:NAME` colouring all go through [`map_into`].

use std::sync::OnceLock;

use super::RenderError;
use super::color::{pack_rgb, turbo_lut};

/// A colour ramp from low to high values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ramp {
    #[default]
    Turbo,
    Viridis,
    Magma,
    Inferno,
    Plasma,
    Gray,
}

/// Every ramp with its name, in the order `--help` lists them.
pub(crate) const RAMPS: [(Ramp, &str); 6] = [
    (Ramp::Turbo, "turbo"),
    (Ramp::Viridis, "viridis"),
    (Ramp::Magma, "magma"),
    (Ramp::Inferno, "inferno"),
    (Ramp::Plasma, "plasma"),
    (Ramp::Gray, "gray"),
];

impl std::str::FromStr for Ramp {
    type Err = RenderError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim().to_ascii_lowercase();
        let t = if t == "grey" { "gray".to_string() } else { t };
        RAMPS.iter().find(|r| r.1 == t).map(|r| r.0).ok_or_else(|| {
            let names: Vec<&str> = RAMPS.iter().map(|r| r.1).collect();
            RenderError::InvalidOptions(format!(
                "unknown ramp '{s}', expected {}",
                names.join(", ")
            ))
        })
    }
}

// Stops of the matplotlib maps (van der Walt and Smith), evenly spaced.
const VIRIDIS: [u32; 10] = [
    0x440154, 0x482878, 0x3e4a89, 0x31688e, 0x26828e, 0x1f9e89, 0x35b779, 0x6dcd59, 0xb4de2c,
    0xfde725,
];
const MAGMA: [u32; 9] = [
    0x000004, 0x1c1044, 0x4f127b, 0x812581, 0xb5367a, 0xe55064, 0xfb8861, 0xfec287, 0xfcfdbf,
];
const INFERNO: [u32; 10] = [
    0x000004, 0x1b0c41, 0x4a0c6b, 0x781c6d, 0xa52c60, 0xcf4446, 0xed6925, 0xfb9b06, 0xf7d13d,
    0xfcffa4,
];
const PLASMA: [u32; 11] = [
    0x0d0887, 0x41049d, 0x6a00a8, 0x8f0da4, 0xb12a90, 0xcc4778, 0xe16462, 0xf2844b, 0xfca636,
    0xfcce25, 0xf0f921,
];

/// A 256-entry table interpolated linearly between `stops` (`0xRRGGBB`).
fn from_stops(stops: &[u32]) -> [u32; 256] {
    let ch = |c: u32, k: u32| ((c >> (16 - 8 * k)) & 0xff) as f64;
    let mut lut = [0u32; 256];
    for (i, o) in lut.iter_mut().enumerate() {
        let t = i as f64 / 255.0 * (stops.len() - 1) as f64;
        let a = (t.floor() as usize).min(stops.len() - 2);
        let f = t - a as f64;
        let c = |k| (ch(stops[a], k) * (1.0 - f) + ch(stops[a + 1], k) * f).round() as u8;
        *o = pack_rgb(c(0), c(1), c(2));
    }
    lut
}

impl Ramp {
    /// The ramp's 256 colours, low to high.
    pub fn lut(self) -> &'static [u32; 256] {
        static L: [OnceLock<[u32; 256]>; 5] = [const { OnceLock::new() }; 5];
        match self {
            Ramp::Turbo => turbo_lut(),
            Ramp::Viridis => L[0].get_or_init(|| from_stops(&VIRIDIS)),
            Ramp::Magma => L[1].get_or_init(|| from_stops(&MAGMA)),
            Ramp::Inferno => L[2].get_or_init(|| from_stops(&INFERNO)),
            Ramp::Plasma => L[3].get_or_init(|| from_stops(&PLASMA)),
            Ramp::Gray => {
                L[4].get_or_init(|| std::array::from_fn(|i| pack_rgb(i as u8, i as u8, i as u8)))
            }
        }
    }

    pub fn name(self) -> &'static str {
        RAMPS.iter().find(|r| r.0 == self).map_or("turbo", |r| r.1)
    }
}

/// Parses `--range LO,HI` (finite, LO < HI).
pub fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let bad = || format!("'{s}': expected LO,HI with LO below HI, e.g. 0,255");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let lo: f64 = a.trim().parse().map_err(|_| bad())?;
    let hi: f64 = b.trim().parse().map_err(|_| bad())?;
    if !(lo.is_finite() && hi.is_finite() && lo < hi) {
        return Err(bad());
    }
    Ok((lo, hi))
}

/// Colours `values` (stored values; the source value is `v + offset`) through
/// `lut` over the source range `lo..=hi`, clamped at both ends. NaN takes the
/// low end; an empty range (`lo == hi`) the middle.
pub fn map_into(values: &[f32], offset: f64, lo: f64, hi: f64, lut: &[u32; 256], out: &mut [u32]) {
    let span = hi - lo;
    let (scale, base) = if span > 0.0 && span.is_finite() {
        ((255.0 / span) as f32, 0.5f32)
    } else {
        (0.0, 128.0)
    };
    let shift = (offset - lo) as f32;
    for (o, &v) in out.iter_mut().zip(values) {
        // NaN → 0 through the saturating cast.
        let i = ((v + shift) * scale + base).clamp(0.0, 255.0) as usize;
        *o = lut[i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramps_and_ranges() {
        for (r, n) in RAMPS {
            assert_eq!(n.parse::<Ramp>().unwrap(), r);
            assert_eq!(r.name(), n);
            let l = r.lut();
            assert_ne!(l[0], l[255], "{n}");
        }
        assert_eq!(Ramp::Viridis.lut()[0], pack_rgb(0x44, 0x01, 0x54));
        assert_eq!(Ramp::Viridis.lut()[255], pack_rgb(0xfd, 0xe7, 0x25));
        assert_eq!("grey".parse::<Ramp>().unwrap(), Ramp::Gray);
        assert!("rainbow".parse::<Ramp>().is_err());
        assert_eq!(parse_range("0, 255").unwrap(), (0.0, 255.0));
        for bad in ["5,5", "9,1", "a,b", "1", "nan,2"] {
            assert!(parse_range(bad).is_err(), "{bad}");
        }
        let g = Ramp::Gray.lut();
        let mut out = [0u32; 5];
        // Stored values with offset 100: source 100, 150, 200, 300, NaN.
        map_into(
            &[0.0, 50.0, 100.0, 200.0, f32::NAN],
            100.0,
            100.0,
            200.0,
            g,
            &mut out,
        );
        assert_eq!(out, [g[0], g[128], g[255], g[255], g[0]]);
        map_into(&[3.0], 0.0, 3.0, 3.0, g, &mut out[..1]);
        assert_eq!(out[0], g[128]);
    }
}
