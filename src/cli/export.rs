//! `pcimg export`: a dataset's points (all, a level's even sample, a box, some
//! classes, band ranges) written as LAS, LAZ, binary PLY, CSV or XYZ.

use crate::export::{self, OutFormat};
use crate::render::filter::Filter;
use crate::store::Dataset;
use crate::text::{bytes, count};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  pcimg export city.pcimg -o city.laz
  pcimg export city.pcimg -o block.las --clip 637000,851000,0,637500,851500,500
  pcimg export s3://bucket/city.pcimg -o ground.laz --classes 2 --bounds 637000,851000,637500,851500
  pcimg export city.pcimg -o light.ply --level 2      (an even sample, 1/16 of the points)")]
pub struct Args {
    /// A dataset: a part (.tif), a directory of parts, or its URL (s3://,
    /// https://, http://).
    pub path: PathBuf,
    /// Where to write: the format comes from the extension, .las, .laz
    /// (compressed, in parallel; bands LAS has no field for as extra bytes),
    /// .ply (binary), .csv (a header line) or .xyz (space-separated, no
    /// header).
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Replace the output if it exists.
    #[arg(long)]
    pub force: bool,
    /// Export level N of each part: 0 (the default) is every point, each level
    /// up an even sample of about a quarter of the one below (a part with
    /// fewer levels gives its coarsest); `pcimg info` lists them.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub level: usize,
    /// Only points in the box MINX,MINY,MINZ,MAXX,MAXY,MAXZ (dataset
    /// coordinates); tiles outside it are not read.
    #[arg(long, value_name = "BOX", allow_hyphen_values = true)]
    pub clip: Option<String>,
    /// Only points within MINX,MINY,MAXX,MAXY seen from above (any height).
    #[arg(long, value_name = "MINX,MINY,MAXX,MAXY", allow_hyphen_values = true)]
    pub bounds: Option<String>,
    /// Only these classification codes, e.g. 2,6 (ground, building).
    #[arg(long)]
    pub classes: Option<String>,
    /// Not these classification codes, e.g. 7,18 (noise).
    #[arg(long)]
    pub exclude_classes: Option<String>,
    /// Only points whose band lies in a range: NAME=VALUE or NAME=LO..HI (an
    /// end may be left out), e.g. return_number=1 or z=400..450. May be given
    /// several times (all must hold).
    #[arg(long = "where", value_name = "NAME=LO..HI", allow_hyphen_values = true)]
    pub wheres: Vec<String>,
    /// No progress bar or summary.
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub cache: super::remote::CacheArgs,
}

/// Set by Ctrl-C (or a termination signal): the export stops between batches
/// and removes what it wrote.
static STOP: AtomicBool = AtomicBool::new(false);

pub fn run(a: Args) -> anyhow::Result<()> {
    let format = OutFormat::of(&a.output).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: unknown output format; name it .las, .laz, .ply, .csv or .xyz",
            a.output.display()
        )
    })?;
    if a.output.exists() && !a.force {
        anyhow::bail!("{} exists; give --force to replace it", a.output.display());
    }
    if let Some(dir) = a.output.parent().filter(|d| !d.as_os_str().is_empty())
        && !dir.is_dir()
    {
        anyhow::bail!("{}: no such directory", dir.display());
    }
    a.cache.apply()?;
    let ds = Arc::new(Dataset::open_with(&a.path, &a.cache.open_options())?);
    let filter = filter_of(&a, &ds)?;
    let max_level = ds.own_levels() - 1;
    if a.level > max_level {
        anyhow::bail!(
            "--level {}: the dataset's parts have levels 0 to {max_level}",
            a.level
        );
    }
    let plan = export::plan(&ds, a.level, &filter)?;
    let _ = ctrlc::set_handler(|| STOP.store(true, Ordering::SeqCst));
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::with_draw_target(Some(plan.points), ProgressDrawTarget::stderr());
        if let Ok(s) = ProgressStyle::with_template(
            "   export [{bar:30}] {human_pos}/{human_len} points read, {msg} (ETA {eta})",
        ) {
            b.set_style(s.progress_chars("=> "));
        }
        b
    };
    let started = std::time::Instant::now();
    let progress = |read: u64, written: u64| {
        bar.set_position(read);
        bar.set_message(format!("{} written", count(written)));
    };
    let r = export::export(&ds, &plan, &filter, &a.output, format, &STOP, &progress);
    bar.finish_and_clear();
    let s = r?;
    if !a.quiet {
        let secs = started.elapsed().as_secs_f64();
        note!(
            "wrote {} points to {} ({}) in {secs:.1} s ({:.1} M points/s); read {} of {} tiles",
            count(s.points),
            a.output.display(),
            bytes(s.bytes),
            s.points as f64 / secs.max(1e-6) / 1e6,
            s.tiles_read,
            s.tiles_read + plan.skipped,
        );
        if let Some(l) = &s.las {
            note!(
                "LAS {}.{} point format {}, scale {} {} {}, offset {} {} {}{}",
                l.version.0,
                l.version.1,
                l.point_format,
                l.scale[0],
                l.scale[1],
                l.scale[2],
                l.offset[0],
                l.offset[1],
                l.offset[2],
                if s.exact_lattice {
                    " (the source's: every coordinate on its integer as before)"
                } else {
                    " (chosen: the parts keep no common lattice)"
                }
            );
            if !l.wkt && plan.crs.is_some() {
                note!(
                    "note: the CRS ({}) is not WKT, so no WKT record was written",
                    crate::text::sanitize(plan.crs.as_deref().unwrap_or(""))
                );
            }
        }
        if !s.extra_bytes.is_empty() {
            note!(
                "bands LAS has no field for, as extra bytes (doubles): {}",
                s.extra_bytes.join(", ")
            );
        }
    }
    Ok(())
}

/// The filter from `--classes`, `--exclude-classes`, `--where` and `--clip`
/// (as the view commands make it), and `--bounds`, checked against `ds`.
fn filter_of(a: &Args, ds: &Dataset) -> anyhow::Result<Filter> {
    let mut f = super::view::filter_from(
        &super::view::FilterFlags {
            classes: a.classes.as_deref(),
            exclude_classes: a.exclude_classes.as_deref(),
            wheres: &a.wheres,
            clip: a.clip.as_deref(),
            slab: None,
        },
        ds,
    )?;
    if let Some(b) = &a.bounds {
        let v: Vec<f64> = b
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| anyhow::anyhow!("--bounds '{b}': expected MINX,MINY,MAXX,MAXY"))?;
        if v.len() != 4 || v[0] > v[2] || v[1] > v[3] {
            anyhow::bail!("--bounds '{b}': expected MINX,MINY,MAXX,MAXY with MIN ≤ MAX");
        }
        let flat = crate::points::Bounds {
            min: [v[0], v[1], f64::NEG_INFINITY],
            max: [v[2], v[3], f64::INFINITY],
        };
        f.clip = Some(match f.clip {
            Some(c) => crate::points::Bounds {
                min: [0, 1, 2].map(|k| c.min[k].max(flat.min[k])),
                max: [0, 1, 2].map(|k| c.max[k].min(flat.max[k])),
            },
            None => flat,
        });
    }
    Ok(f)
}
