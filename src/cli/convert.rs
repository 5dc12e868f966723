//! `pcimg convert`: an input file into an image dataset, out of core, with progress
//! bars and a summary.

use crate::convert::{self, ConvertOptions, Partition, Progress, budget};
use crate::ingest::ReadOptions;
use crate::store::{self, Compression, Layout};
use crate::text::{bytes, count, sanitize};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::path::{Component, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input point cloud(s): .xyz .txt .csv .asc .pts (text), .ply, .las, .laz,
    /// .pcd, .e57; a COPC file (.copc.laz) or an EPT dataset (its ept.json),
    /// local or at a URL (s3://, https://: -o needed), whole or by --bounds.
    /// Several files (tiles of one survey, `tiles/*.laz`) or a directory (its
    /// point-cloud files, in name order) become one dataset; they must carry the
    /// same attributes and coordinate reference system. A survey of COPC files
    /// (`pcimg index` over them: its directory or pcimg-survey.json) reads only
    /// the files whose recorded bounds reach --bounds/--clip.
    /// With --plan and no inputs, a cluster shard runs instead.
    #[arg(required_unless_present = "plan", num_args = 1.., value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Output: a directory of parts (default: INPUT with extension .pcimg, for a
    /// directory DIR.pcimg beside it; several files need -o), or a single .tif
    /// when the input fits one part. An object-storage URL (s3://bucket/city.pcimg,
    /// gs://, az://) writes the parts in a temporary directory ($TMPDIR), uploads
    /// each as soon as it is written and the index last.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Memory budget, e.g. 256MiB or 4G (default: half the available memory). It
    /// bounds resident memory and decides how many points one part (image) holds.
    #[arg(long, value_parser = crate::text::parse_size)]
    pub memory: Option<u64>,
    /// How points are grouped into parts.
    #[arg(long, value_enum, default_value_t = PartitionArg::Spatial)]
    pub partition: PartitionArg,
    /// Tile compression. zstd (the default) or deflate: lossless and compact, each
    /// tile's points in GPS-time order, LAS coordinates kept as whole numbers on
    /// the LAS lattice (about 2x the LAZ, pyramid included). none: uncompressed,
    /// about 8x larger. lerc, lerc_zstd, lerc_deflate: LERC as GDAL writes it,
    /// coordinates within --max-error, attributes lossless.
    #[arg(long, value_parser = Compression::parse)]
    pub compression: Option<Compression>,
    /// zstd: Zstd's level, 1 (fastest to write) to 19 (smallest). Default: 6
    /// for an input that declares at most 2 M points, else 1. At level 1 the
    /// coordinates' tiles keep Zstd's literals uncoded, to be read fast. On
    /// 47.7 M points of airborne LAS, level 6 is 10 % smaller than 1 but takes
    /// 2x as long to convert and reads 0.85x as fast.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(i32).range(1..=19))]
    pub zstd_level: Option<i32>,
    /// LERC codecs: the largest error allowed in a coordinate, in the input's
    /// units. Default: half a LAS file's scale factor (the coordinates come back
    /// exactly on their lattice), lossless for other inputs.
    #[arg(long, value_name = "UNITS", value_parser = parse_max_error)]
    pub max_error: Option<f64>,
    /// zstd and deflate: keep coordinates as whole multiples of STEP (in the
    /// input's units), each rounded to the nearest, within STEP/2 of the source.
    /// Default: the lattice the input has, kept exactly (a LAS file's scale
    /// factors, the decimals a text file writes); none for float coordinates.
    #[arg(long, value_name = "STEP", value_parser = parse_precision)]
    pub precision: Option<f64>,
    /// Point layout within a part.
    #[arg(long, value_enum, default_value_t = LayoutArg::Hilbert)]
    pub layout: LayoutArg,
    /// Text columns, e.g. "x y z intensity r g b"; "_" skips a column.
    #[arg(long)]
    pub columns: Option<String>,
    /// Skip malformed lines (and report how many) instead of stopping.
    #[arg(long)]
    pub skip_invalid: bool,
    /// Only the points inside this rectangle, every height (in the input's
    /// coordinates): XMIN,YMIN,XMAX,YMAX. COPC and EPT inputs only: just the
    /// octree's nodes that reach it are read (from a URL, just their bytes
    /// fetched).
    #[arg(long, value_name = "XMIN,YMIN,XMAX,YMAX", value_parser = parse_bounds, conflicts_with = "clip")]
    pub bounds: Option<crate::points::Bounds>,
    /// As --bounds, a box in 3D: XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX.
    #[arg(long, value_name = "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", value_parser = parse_clip)]
    pub clip: Option<crate::points::Bounds>,
    /// Replace an existing output.
    #[arg(long)]
    pub force: bool,
    /// Accept parts so large that f32 cannot keep 1 mm.
    #[arg(long)]
    pub allow_lossy: bool,
    /// How tile data is written: buffered (through the page cache, the
    /// disk written later), direct (straight to the disk, O_DIRECT where the file
    /// system allows: no CPU spent copying, and your page cache, your input's
    /// pages among them, left alone), or auto: buffered while the page cache takes
    /// the tiles at 1.5 GB/s or more, then direct (on a VM whose host takes freed
    /// memory back, copying into the page cache can run at a third of the disk's
    /// speed). Compressed tiles go direct from the next 4 KiB block on, in
    /// writes of 4 MiB.
    #[arg(long, default_value = "auto", value_parser = store::TileIo::parse)]
    pub io: store::TileIo,
    /// No progress bars or summary (with --timings, the summary is printed).
    #[arg(short, long)]
    pub quiet: bool,
    /// Conversion on a cluster (docs/cluster.md). With INPUTS: write the plan
    /// (every global choice, the shards' cells and inputs, a hash) to this file,
    /// and convert nothing; -o names the dataset directory the shards write to.
    /// Without INPUTS: run one shard of this plan (--shard).
    #[arg(long, value_name = "PLAN.json")]
    pub plan: Option<PathBuf>,
    /// With --plan INPUTS: the number of shards, balanced by point count
    /// (default: one per spatial region).
    #[arg(long, requires = "plan")]
    pub shards: Option<usize>,
    /// With --plan and no INPUTS: the shard to run, `I/N` with I from 0 to N-1;
    /// or `N` or nothing, the index then taken from SLURM_ARRAY_TASK_ID (use
    /// `--array=0-(N-1)`) or JOB_COMPLETION_INDEX (Kubernetes Indexed Job), both
    /// 0-based. -o overrides the plan's output directory.
    #[arg(long, value_name = "I/N", requires = "plan")]
    pub shard: Option<String>,
    /// Also print the wall and CPU time of each phase (passes over the input, and
    /// the store's phases summed over parts), and how --memory was shared out.
    #[arg(long)]
    pub timings: bool,
    /// For an output in object storage: print the network's counters on exit
    /// (requests, bytes received, failures; benchmarks).
    #[arg(long)]
    pub net_stats: bool,
    // `--timeout`: on an upload that still fails the conversion removes what it uploaded.
    #[command(flatten)]
    pub timeout: super::remote::TimeoutArg,
}

/// `--partition`'s values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PartitionArg {
    /// Non-overlapping spatial parts (one pass when the input fits one part;
    /// else a first pass that reads a sample, about 4 M points, to place the
    /// parts, and a second that reads every point into temporary files beside
    /// the output, 12 bytes a point plus 4 per attribute).
    Spatial,
    /// The paper's single pass, parts in file order.
    Stream,
}

impl From<PartitionArg> for Partition {
    fn from(p: PartitionArg) -> Partition {
        match p {
            PartitionArg::Spatial => Partition::Spatial,
            PartitionArg::Stream => Partition::Stream,
        }
    }
}

/// `--layout`'s values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LayoutArg {
    /// Hilbert order, centroid representatives: every level a spatially even
    /// sample.
    Hilbert,
    /// As Du & Li 2009: file order, row-major image, every other row and column
    /// per level; converts about twice as fast, but its coarser levels thin the
    /// cloud as unevenly as the file's order.
    Paper,
}

impl From<LayoutArg> for Layout {
    fn from(l: LayoutArg) -> Layout {
        match l {
            LayoutArg::Hilbert => Layout::Hilbert,
            LayoutArg::Paper => Layout::Paper,
        }
    }
}

/// Progress bars on stderr, a new one for each phase (so no frame of one phase
/// is drawn in another's units).
struct Bars {
    bar: Mutex<ProgressBar>,
    quiet: bool,
    /// Whether the phase counts points (else input bytes).
    points: AtomicBool,
}

impl Bars {
    fn new(quiet: bool) -> Bars {
        Bars {
            bar: Mutex::new(ProgressBar::hidden()),
            quiet,
            points: AtomicBool::new(false),
        }
    }

    fn bar(&self) -> std::sync::MutexGuard<'_, ProgressBar> {
        self.bar.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn finish(&self) {
        self.bar().finish_and_clear();
    }
}

impl Progress for Bars {
    fn phase(&self, name: &str, total: u64, unit: &'static str) {
        let points = unit != "bytes";
        self.points.store(points, Ordering::Relaxed);
        let style = if points {
            "{prefix:>9} [{bar:30}] {human_pos}/{human_len} points, {msg} (ETA {eta})"
        } else {
            "{prefix:>9} [{bar:30}] {binary_bytes}/{binary_total_bytes}, {msg} (ETA {eta})"
        };
        // A new bar, configured before it is first drawn.
        let mut bar = self.bar();
        bar.finish_and_clear();
        let target = if self.quiet {
            ProgressDrawTarget::hidden()
        } else {
            ProgressDrawTarget::stderr()
        };
        let mut next = ProgressBar::with_draw_target(Some(total), target)
            .with_prefix(name.to_string())
            .with_message("starting");
        if let Ok(s) = ProgressStyle::with_template(style) {
            next = next.with_style(s.progress_chars("=> "));
        }
        *bar = next;
    }
    fn advance(&self, done: u64, points: u64) {
        let bar = self.bar();
        let secs = bar.elapsed().as_secs_f64().max(1e-3);
        let rate = points as f64 / secs / 1e6;
        bar.set_message(if self.points.load(Ordering::Relaxed) {
            format!("{rate:.1} M points/s")
        } else {
            format!("{} points, {rate:.1} M points/s", count(points))
        });
        bar.set_position(done);
    }
    fn note(&self, msg: &str) {
        if self.quiet {
            return;
        }
        self.notice(msg);
    }
    fn notice(&self, msg: &str) {
        let bar = self.bar();
        // A hidden bar (before the first phase, or stderr not a terminal) prints
        // nothing: write the line.
        if bar.is_hidden() {
            note!("{msg}");
        } else {
            bar.println(msg);
        }
    }
}

/// The input files: each argument, or a directory's point-cloud files in name
/// order (not its subdirectories), or a survey's COPC files (`pcimg index`
/// over them) whose recorded bounds reach `region` (all without one: no other
/// file is opened).
fn input_files(
    args: &[PathBuf],
    region: Option<&crate::points::Bounds>,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for a in args {
        if crate::survey::is_survey(a) {
            let here = crate::survey::files_in(a, region)?;
            if here.is_empty() {
                anyhow::bail!(
                    "{}: no file of the survey reaches the region",
                    sanitize(&a.display().to_string())
                );
            }
            files.extend(here);
            continue;
        }
        if !a.is_dir() {
            files.push(a.clone());
            continue;
        }
        let shown = sanitize(&a.display().to_string());
        let mut here: Vec<PathBuf> = std::fs::read_dir(a)
            .map_err(|e| anyhow::anyhow!("{shown}: cannot list the directory: {e}"))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && is_point_cloud(p))
            .collect();
        if here.is_empty() {
            anyhow::bail!(
                "{shown}: a directory with no point-cloud files (.xyz .txt .csv .asc .pts .ply \
                 .las .laz .pcd .e57) in it"
            );
        }
        here.sort();
        files.extend(here);
    }
    Ok(files)
}

/// Whether `p` has a point-cloud extension (hidden files excluded).
fn is_point_cloud(p: &std::path::Path) -> bool {
    let hidden = p
        .file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with('.'));
    !hidden && crate::ingest::kind_by_extension(p).is_some()
}

/// The default output: `INPUT.pcimg` beside one file or directory.
fn default_output(args: &[PathBuf]) -> anyhow::Result<PathBuf> {
    if let Some(url) = args.iter().find(|p| crate::ingest::is_url(p)) {
        anyhow::bail!(
            "{}: an input at a URL: name the output with -o",
            sanitize(&url.to_string_lossy())
        );
    }
    match args {
        [one] if one.is_dir() => {
            // The directory's own name (`tiles/` → `tiles.pcimg` beside it).
            let named = one
                .components()
                .rev()
                .find(|c| !matches!(c, Component::CurDir));
            match named {
                Some(Component::Normal(name)) => {
                    // Appended, not set: `survey.2020/` → `survey.2020.pcimg`.
                    let mut out = name.to_owned();
                    out.push(".pcimg");
                    let out = PathBuf::from(out);
                    let parent = one.components().as_path().parent();
                    Ok(parent.map_or(out.clone(), |p| p.join(&out)))
                }
                _ => anyhow::bail!(
                    "{}: name the output with -o",
                    sanitize(&one.display().to_string())
                ),
            }
        }
        [one] => Ok(one.with_extension("pcimg")),
        _ => anyhow::bail!("{} inputs: name the output with -o", args.len()),
    }
}

/// The conversion options the arguments give, writing to `output`.
fn parse_max_error(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(e) if e.is_finite() && e >= 0.0 => Ok(e),
        _ => Err(format!("'{s}' is not a distance >= 0")),
    }
}

/// `n` comma-separated finite numbers.
fn numbers(s: &str, n: usize, form: &str) -> Result<Vec<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not {form}"))?;
    if v.len() != n || !v.iter().all(|x| x.is_finite()) {
        return Err(format!("'{s}' is not {form} ({n} numbers)"));
    }
    Ok(v)
}

/// The box of `min` and `max`, each at most its maximum.
fn ordered(min: [f64; 3], max: [f64; 3], s: &str) -> Result<crate::points::Bounds, String> {
    if (0..3).any(|a| min[a] > max[a]) {
        return Err(format!("'{s}': a minimum is above its maximum"));
    }
    Ok(crate::points::Bounds { min, max })
}

fn parse_bounds(s: &str) -> Result<crate::points::Bounds, String> {
    let v = numbers(s, 4, "XMIN,YMIN,XMAX,YMAX")?;
    ordered(
        [v[0], v[1], f64::NEG_INFINITY],
        [v[2], v[3], f64::INFINITY],
        s,
    )
}

fn parse_clip(s: &str) -> Result<crate::points::Bounds, String> {
    let v = numbers(s, 6, "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX")?;
    ordered([v[0], v[1], v[2]], [v[3], v[4], v[5]], s)
}

fn parse_precision(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(e) if e.is_finite() && e > 0.0 => Ok(e),
        _ => Err(format!("'{s}' is not a step > 0 (e.g. 0.001)")),
    }
}

fn options(a: &Args, output: PathBuf) -> ConvertOptions {
    let remote = crate::remote::is_url(&output.to_string_lossy());
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let c = cancel.clone();
        // A second handler cannot be set (tests run several conversions): ignore.
        let _ = ctrlc::set_handler(move || c.store(true, std::sync::atomic::Ordering::Relaxed));
    }
    ConvertOptions {
        output,
        force: a.force,
        memory: a.memory.unwrap_or_else(budget::default_budget),
        partition: a.partition.into(),
        compression: a
            .compression
            .unwrap_or_else(|| Compression::default_for(remote)),
        zstd_level: a.zstd_level,
        max_error: a.max_error,
        precision: a.precision,
        layout: a.layout.into(),
        read: ReadOptions {
            columns: a.columns.clone(),
            skip_invalid: a.skip_invalid,
            region: a.bounds.or(a.clip),
            ..Default::default()
        },
        allow_lossy: a.allow_lossy,
        cancel,
        sample_points: convert::DEFAULT_SAMPLE_POINTS,
        io: a.io,
        on_part: None,
    }
}

/// `convert --plan`: writes a cluster plan, or runs one shard of one.
fn run_cluster(a: &Args, plan: &std::path::Path, opts: ConvertOptions) -> anyhow::Result<()> {
    use crate::convert::cluster;
    let bars = Bars::new(a.quiet);
    let shown = |p: &std::path::Path| sanitize(&p.display().to_string());
    if a.inputs.is_empty() {
        if a.shards.is_some() {
            anyhow::bail!(
                "--shards is for planning (--plan with INPUTS); a shard takes --shard I/N"
            );
        }
        let (cp, _) = cluster::ClusterPlan::load(plan)?;
        let env = |k: &str| std::env::var(k).ok();
        let i = cluster::shard_index(a.shard.as_deref(), cp.shards.len(), &env)?;
        let t = std::time::Instant::now();
        let r = cluster::run_shard(plan, i, a.output.as_deref(), &opts, &bars);
        bars.finish();
        let r = r?;
        if !a.quiet {
            super::print_out(&format!(
                "shard {i}/{}: {} points in {} part(s), {:.2} s; receipt {}\n",
                r.shards,
                count(r.points),
                r.parts.len(),
                t.elapsed().as_secs_f64(),
                cluster::RECEIPTS
            ))?;
        }
        return Ok(());
    }
    if a.shard.is_some() {
        anyhow::bail!("--shard runs a planned shard: give --plan PLAN.json without INPUTS");
    }
    super::remote::read_url_inputs(a.timeout.remote_options());
    let inputs = input_files(&a.inputs, a.bounds.as_ref().or(a.clip.as_ref()))?;
    let t = std::time::Instant::now();
    let cp = cluster::make_plan(&inputs, &opts, a.shards, &bars);
    bars.finish();
    let cp = cp?;
    let hash = cp.save(plan)?;
    if !a.quiet {
        let most = cp.shards.iter().map(|s| s.points).max().unwrap_or(0);
        super::print_out(&format!(
            "planned {} points in {} region(s), {} shard(s) (largest {} points) -> {} \
             (hash {hash}, {:.2} s); output {}\n",
            count(cp.plan.points),
            cp.plan.regions.len(),
            cp.shards.len(),
            count(most),
            shown(plan),
            t.elapsed().as_secs_f64(),
            shown(&cp.output)
        ))?;
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let (Some(step), Some(c)) = (a.precision, a.compression)
        && !c.row_ordered()
    {
        anyhow::bail!(
            "--precision {step} keeps coordinates as whole numbers, which only the zstd and \
             deflate codecs store (--compression {} keeps them as floats): leave out \
             --compression, or use --max-error with a LERC codec",
            c.name()
        );
    }
    if let (Some(level), Some(c)) = (a.zstd_level, a.compression)
        && c != Compression::Zstd
    {
        anyhow::bail!(
            "--zstd-level {level} sets the level of the zstd codec, not of --compression {} \
             (lerc_zstd keeps GDAL's level 9): leave out one of them",
            c.name()
        );
    }
    if a.plan.is_some() && a.inputs.is_empty() {
        let plan = a.plan.clone().unwrap_or_default();
        return run_cluster(&a, &plan, options(&a, PathBuf::new()));
    }
    let output = match a.output.clone() {
        Some(o) => o,
        None => default_output(&a.inputs)?,
    };
    super::remote::read_url_inputs(a.timeout.remote_options());
    let inputs = input_files(&a.inputs, a.bounds.as_ref().or(a.clip.as_ref()))?;
    let mut opts = options(&a, output);
    let url = convert::upload::is_remote(&opts.output).map(str::to_string);
    if let Some(plan) = &a.plan {
        if let Some(url) = &url {
            anyhow::bail!(
                "{}: a cluster plan's shards write to a shared directory; convert to object \
                 storage without --plan, or upload the finished dataset",
                sanitize(url)
            );
        }
        return run_cluster(&a, plan, opts);
    }
    // Object storage: written locally, uploaded part by part, the index last.
    let remote = match &url {
        Some(u) => Some(convert::upload::RemoteOutput::prepare(
            u,
            a.force,
            opts.cancel.clone(),
            &a.timeout.remote_options(),
        )?),
        None => None,
    };
    if let Some(r) = &remote {
        opts.output = r.local.clone();
        opts.on_part = Some(r.hook());
    }
    let bars = Bars::new(a.quiet);
    if let Some(n) = remote.as_ref().and_then(|r| r.took_over.as_ref()) {
        bars.notice(n);
    }
    let mut result = convert::convert_files(&inputs, &opts, &bars);
    if let Some(r) = &remote {
        result = result.and_then(|mut s| {
            r.finish(&bars)?;
            s.output = PathBuf::from(&r.url);
            Ok(s)
        });
        if result.is_err() {
            bars.notice(&format!(
                "removing what was uploaded to {}",
                sanitize(&r.url)
            ));
            r.abort(&bars);
        }
    }
    bars.finish();
    let s = result?;
    if a.quiet && !a.timings {
        return Ok(());
    }
    use std::fmt::Write as _;
    let mut out = String::new();
    let secs = s.elapsed.as_secs_f64().max(1e-9);
    let levels = s
        .parts
        .iter()
        .map(|p| p.level_points.len())
        .max()
        .unwrap_or(0);
    let shown = |p: &PathBuf| sanitize(&p.display().to_string());
    let (from, files) = match s.inputs.as_slice() {
        [first, .., last] => {
            let empty = s
                .inputs
                .iter()
                .filter(|p| crate::ingest::multi::is_empty_file(p))
                .count();
            let left_out = if empty > 0 {
                format!(", {empty} empty left out")
            } else {
                String::new()
            };
            (
                format!("{} … {}", shown(first), shown(last)),
                format!("{} files{left_out}, ", s.inputs.len()),
            )
        }
        [one] => (shown(one), String::new()),
        [] => (String::new(), String::new()),
    };
    writeln!(
        out,
        "converted {} ({}{}, {}) -> {}",
        from,
        files,
        sanitize(&s.format),
        bytes(s.input_bytes),
        sanitize(&s.output.display().to_string())
    )?;
    writeln!(
        out,
        "  {} points in {} part(s) of at most {} points (--memory {}), up to {} levels, {}",
        count(s.points),
        s.parts.len(),
        count(s.points_per_part),
        bytes(opts.memory),
        levels,
        bytes(s.bytes())
    )?;
    writeln!(out, "  tiles: {}", tiles_codec(&s, &a))?;
    if s.clamped_colours > 0 {
        writeln!(
            out,
            "  {} colour value(s) did not fit the colour scale {} first {} points show \
             and were clamped to 0-255",
            count(s.clamped_colours),
            if s.inputs.len() > 1 {
                "each file's"
            } else {
                "the input's"
            },
            count(crate::ingest::color::DECIDE_POINTS as u64)
        )?;
    }
    if s.skipped > 0 {
        writeln!(out, "  skipped {} malformed line(s)", count(s.skipped))?;
    }
    if s.left_out > 0 {
        writeln!(
            out,
            "  left out {} point(s) the input marks as holding no measurement \
             (NaN coordinates, invalid state)",
            count(s.left_out)
        )?;
    }
    for n in &s.notes {
        writeln!(out, "  {}", sanitize(n))?;
    }
    writeln!(
        out,
        "  {:.2} s: {:.2} M points/s, {:.0} MB/s of input",
        secs,
        s.points as f64 / secs / 1e6,
        s.input_bytes as f64 / secs / 1e6
    )?;
    let exact = a.precision.is_none() && s.parts.iter().all(|p| p.lattice.is_some());
    writeln!(
        out,
        "  {} within {} of the source",
        if exact {
            // The bands hold the lattice's whole numbers: only a read into
            // 32-bit floats (drawing, picking) rounds; `export` does not.
            "coordinates read as 32-bit floats (drawing, picking)"
        } else {
            "stored coordinates"
        },
        crate::store::crs::distance(s.max_quantization_error, s.crs.as_deref())
    )?;
    if let Some(l) = s.parts.iter().find_map(|p| p.lattice) {
        let on = s.parts.iter().filter(|p| p.lattice.is_some()).count();
        let unit = crate::store::crs::unit_symbol(s.crs.as_deref());
        let step = |a: usize| format!("{} {unit}", l.step[a].abs()).trim_end().to_string();
        writeln!(
            out,
            "  {} {} (steps {}, {}, {})",
            if on == s.parts.len() {
                "every part's coordinates".to_string()
            } else {
                format!("{on} of {} parts' coordinates", s.parts.len())
            },
            if a.precision.is_some() {
                "rounded to whole multiples of --precision, each within half a step of the source"
            } else {
                "kept exactly on the input's lattice"
            },
            step(0),
            step(1),
            step(2)
        )?;
    }
    if let Some(l) = s.lattice {
        let off: Vec<_> = s.parts.iter().filter(|p| p.lattice.is_none()).collect();
        if !off.is_empty() {
            // Why: a part wider than the lattice's reach, or a point off it.
            let reach = crate::store::lattice_extent(&l).unwrap_or([f64::INFINITY; 3]);
            let wide = off
                .iter()
                .filter(|p| (0..3).any(|a| p.bounds.extent()[a] >= reach[a]))
                .count();
            let unit = crate::store::crs::unit_symbol(s.crs.as_deref());
            let span = |a: usize| {
                format!("{:.0} {unit}", l.step[a].abs() * 2f64.powi(24))
                    .trim_end()
                    .to_string()
            };
            let why = match (wide, off.len() - wide) {
                (_, 0) => format!(
                    "they spread wider than 2^24 of its steps ({}){}",
                    span(0),
                    if s.parts.len() == 1 {
                        "; a directory output (-o DIR) is cut into parts narrower than that"
                    } else {
                        ""
                    }
                ),
                (0, _) => "they hold points off it".to_string(),
                (w, o) => format!(
                    "{w} spread wider than 2^24 of its steps ({}), {o} hold points off it",
                    span(0)
                ),
            };
            writeln!(
                out,
                "  {} of {} parts' coordinates not on the input's lattice (steps {}; \
                 stored as 32-bit floats instead): {why}",
                off.len(),
                s.parts.len(),
                l.step.map(|v| v.abs().to_string()).join(", ")
            )?;
        }
    }
    if let Some(r) = &s.index {
        writeln!(out, "  {}", super::index::describe(r))?;
    }
    if let Some(r) = &remote {
        writeln!(
            out,
            "  uploaded {} to {}",
            bytes(r.sent()),
            sanitize(&r.url)
        )?;
    }
    if a.timings {
        writeln!(out, "  memory budget {}", budget::Budget::new(opts.memory))?;
        writeln!(
            out,
            "  phases (wall time, its share, and CPU time: user and system, all threads):"
        )?;
        for (name, d) in &s.phases {
            let t = d.wall.as_secs_f64();
            // (Below the CPU clock's resolution a ratio means nothing.)
            let cores = if t >= 0.05 {
                format!(" = {:.1} cores", d.cores())
            } else {
                String::new()
            };
            writeln!(
                out,
                "    {name:<38} {t:7.2} s  {:5.1}%  CPU {:6.2} s{cores}",
                t / secs * 100.0,
                d.cpu.as_secs_f64(),
            )?;
        }
        writeln!(
            out,
            "  large buffers mapped fresh: {} (the rest reused)",
            crate::text::bytes(crate::alloc::fresh_bytes() as u64)
        )?;
        let direct = s.parts.iter().filter(|p| p.direct).count();
        writeln!(
            out,
            "  tile data written around the page cache: {direct} of {} part(s)",
            s.parts.len()
        )?;
        let mapped = s.parts.iter().filter(|p| p.rows_from_input).count();
        writeln!(
            out,
            "  attribute rows read from the input's map, not copied: {mapped} of {} part(s)",
            s.parts.len()
        )?;
    }
    super::print_out(&out)?;
    Ok(())
}

/// The summary's line on the tiles' codec: Zstd's level, and why that one
/// (what `--zstd-level` would trade), or the codec chosen.
fn tiles_codec(s: &convert::ConvertSummary, a: &Args) -> String {
    let Some(level) = s.zstd_level else {
        return s.compression.name().to_string();
    };
    if a.zstd_level.is_some() {
        return format!("zstd, level {level} (--zstd-level)");
    }
    if level == store::ZSTD_SMALL {
        format!(
            "zstd, level {level}: a small input, written tighter (--zstd-level {} writes \
             faster)",
            store::ZSTD_FAST
        )
    } else {
        format!(
            "zstd, level {level} (--zstd-level {}: about 10 % smaller, 2x the time to \
             convert, 0.85x the read speed)",
            store::ZSTD_SMALL
        )
    }
}
