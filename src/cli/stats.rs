//! `pcimg stats`: per band count, range, mean, standard deviation,
//! percentiles and a histogram; class counts with their ASPRS names; point
//! density, with a map of it as a PNG.

use crate::stats::{self, SAMPLE_POINTS, Stats};
use crate::store::Dataset;
use crate::text::{count, sanitize};
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  pcimg stats city.pcimg                       (from an even sample of at most 2 M points)
  pcimg stats city.pcimg --exact --band z      (every point)
  pcimg stats city.pcimg --json -o density.png")]
pub struct Args {
    /// A dataset: a part (.tif), a directory of parts, or its URL.
    pub path: PathBuf,
    /// Only this band (x, y, z or any other; repeatable). Default: every band.
    #[arg(long = "band", value_name = "NAME")]
    pub bands: Vec<String>,
    /// Read level N of each part (0: every point). Default: the finest level
    /// of at most 2 M points over all parts, an even sample; the output says
    /// which.
    #[arg(long, value_name = "N", conflicts_with = "exact")]
    pub level: Option<usize>,
    /// Read every point (level 0), streaming.
    #[arg(long)]
    pub exact: bool,
    /// Bins of each band's histogram.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub bins: u32,
    /// Print JSON (stable field names) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write a map of the point density seen from above to this PNG
    /// (points per cell, log-scaled, viridis; 512 cells across).
    #[arg(short, long, value_name = "PNG")]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub cache: super::remote::CacheArgs,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    a.cache.apply()?;
    let ds = Dataset::open_with(&a.path, &a.cache.open_options())?;
    if let Some(b) = a.bands.iter().find(|b| !super::view::has_band(&ds, b)) {
        return Err(super::view::no_band(&ds, b, "--band"));
    }
    let max = ds.own_levels() - 1;
    let level = match (a.exact, a.level) {
        (true, _) => 0,
        (_, Some(l)) if l > max => {
            anyhow::bail!("--level {l}: the dataset's parts have levels 0 to {max}")
        }
        (_, Some(l)) => l,
        _ => stats::sample_level(&ds, SAMPLE_POINTS),
    };
    let s = stats::compute(&ds, level, &a.bands, a.bins as usize, 512)?;
    if let Some(png) = &a.output {
        density_png(&s, png)?;
    }
    if a.json {
        super::print_out(&format!("{}\n", serde_json::to_string_pretty(&s)?))?;
    } else {
        super::print_out(&text(&s, &ds))?;
    }
    if let Some(png) = &a.output
        && !a.json
    {
        note!(
            "wrote the density map to {} ({}×{} cells)",
            png.display(),
            s.map_size.0,
            s.map_size.1
        );
    }
    Ok(())
}

/// A number in a column: six significant digits, no exponent for georeferenced
/// coordinates.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    if v.fract() == 0.0 && v.abs() < 1e15 {
        return format!("{}", v as i64);
    }
    if v != 0.0 && (v.abs() >= 1e12 || v.abs() < 1e-3) {
        return format!("{v:.4e}");
    }
    // Six significant digits, but at least two decimals for large values
    // (coordinates, GPS time).
    let digits = (6 - v.abs().max(1.0).log10().floor() as i32 - 1).clamp(2, 6) as usize;
    format!("{v:.digits$}")
}

/// The histogram as a row of block characters, each bin's height relative
/// to the fullest.
fn sparkline(h: &[u64]) -> String {
    const BARS: [char; 9] = [' ', '▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];
    let top = h.iter().copied().max().unwrap_or(0).max(1) as f64;
    h.iter()
        .map(|&v| {
            if v == 0 {
                ' '
            } else {
                BARS[((v as f64 / top * 8.0).ceil() as usize).clamp(1, 8)]
            }
        })
        .collect()
}

fn text(s: &Stats, ds: &Dataset) -> String {
    use std::fmt::Write as _;
    let mut o = String::new();
    let share = s.sampled as f64 / s.points.max(1) as f64 * 100.0;
    let _ = writeln!(
        o,
        "{}: {} points; {}",
        sanitize(&ds.path.display().to_string()),
        count(s.points),
        if s.level == 0 {
            format!("every point read (level 0, {})", count(s.sampled))
        } else {
            format!(
                "from level {}, an even sample of {} points ({share:.2} %); --exact reads every point",
                s.level,
                count(s.sampled)
            )
        }
    );
    let _ = writeln!(
        o,
        "\n{:<20} {:>11} {:>14} {:>14} {:>14} {:>12} {:>14} {:>14} {:>14} {:>14} {:>14}",
        "band", "count", "min", "max", "mean", "std", "p1", "p2", "p50", "p98", "p99"
    );
    for b in &s.bands {
        let p: Vec<String> = b.percentiles.iter().map(|(_, v)| num(*v)).collect();
        let _ = writeln!(
            o,
            "{:<20} {:>11} {:>14} {:>14} {:>14} {:>12} {:>14} {:>14} {:>14} {:>14} {:>14}",
            sanitize(&b.name),
            count(b.count),
            num(b.min),
            num(b.max),
            num(b.mean),
            num(b.std),
            p[0],
            p[1],
            p[2],
            p[3],
            p[4]
        );
    }
    let _ = writeln!(
        o,
        "\nhistograms ({} bins from min to max):",
        s.bands.first().map_or(0, |b| b.histogram.len())
    );
    for b in &s.bands {
        let _ = writeln!(
            o,
            "{:<20} {:>14} │{}│ {}",
            sanitize(&b.name),
            num(b.min),
            sparkline(&b.histogram),
            num(b.max)
        );
    }
    if !s.classes.is_empty() {
        let total: u64 = s.classes.iter().map(|c| c.points).sum();
        let _ = writeln!(
            o,
            "\nclasses ({}):",
            if s.classes_exact {
                "every point, as recorded when the parts were written"
            } else {
                "from the sample, scaled to the dataset"
            }
        );
        for c in &s.classes {
            let _ = writeln!(
                o,
                "  {:>3}  {:<26} {:>14}  {:>6.2} %",
                c.code,
                sanitize(&c.name),
                count(c.points),
                c.points as f64 / total.max(1) as f64 * 100.0
            );
        }
    }
    let unit = crate::store::crs::unit_symbol(ds.totals().crs.as_deref());
    let square = if unit == "units" {
        "square units".to_string()
    } else {
        format!("{unit}²")
    };
    let _ = writeln!(
        o,
        "\ndensity: {} points over {} {square} seen from above: {} points per {}",
        count(s.points),
        num(s.area),
        num(s.density),
        square.trim_end_matches('s')
    );
    o
}

/// The density map as a PNG: log(1 + points) per cell through viridis, empty
/// cells black.
fn density_png(s: &Stats, path: &std::path::Path) -> anyhow::Result<()> {
    let (w, h) = s.map_size;
    let lut = crate::render::ramp::Ramp::Viridis.lut();
    let top = s
        .density_map
        .iter()
        .copied()
        .fold(0f64, f64::max)
        .ln_1p()
        .max(f64::MIN_POSITIVE);
    let mut f = crate::render::Frame::background(w, h, [0, 0, 0]);
    for (i, &v) in s.density_map.iter().enumerate() {
        if v <= 0.0 {
            continue;
        }
        let c = lut[((v.ln_1p() / top * 255.0) as usize).min(255)];
        f.rgba[i * 4..i * 4 + 3].copy_from_slice(&crate::render::color::unpack_rgb(c));
    }
    f.save_png(path).map_err(|e| anyhow::anyhow!("{e}"))
}
