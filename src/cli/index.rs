//! `pcimg index DIR`: (re)builds a dataset directory's index and overview, for
//! parts made separately, added, replaced or removed since the last index; the
//! finalize step of a cluster conversion (its receipts checked against the plan).
//! Over COPC files (a directory of them, or a text file listing paths and
//! URLs) it writes a survey instead (`crate::survey`): one dataset of them all,
//! with overview nodes above their root nodes, and no conversion.

use crate::store::{IndexOptions, IndexReport, build_index};
use crate::text::{bytes, count, sanitize};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A directory of parts (.tif): its index (pcimg-index.json) and overview
    /// folder (overview/) are replaced; the parts are only read. Or COPC files
    /// (a tiled survey): a directory of .copc.laz files, or a text file
    /// listing them, one path (relative to the list) or URL (s3://, https://,
    /// ...) a line. Their survey (pcimg-survey.json and a survey-overview-*
    /// folder) is written to --output (default: the directory), built from
    /// each file's header and root node only; `pcimg render|inspect` then
    /// open the survey as one dataset.
    #[arg(value_name = "DIR_OR_LIST")]
    pub dir: PathBuf,
    /// Where a survey of COPC files is written (a directory; needed for a
    /// list of files).
    #[arg(short, long, value_name = "DIR")]
    pub output: Option<PathBuf>,
    /// Memory budget for a directory of parts, e.g. 256MiB or 4G (default:
    /// half the available memory). Indexing holds about 0.5 KiB a part (the
    /// parts' entries wait in a file beside them) and builds as many overview
    /// nodes at once as the rest allows (up to 24 MiB each for parts of 12
    /// bands); a budget too small for the parts' count is refused before any
    /// node is written.
    #[arg(long, value_parser = crate::text::parse_size)]
    pub memory: Option<u64>,
    #[command(flatten)]
    pub timeout: super::remote::TimeoutArg,
    /// Print nothing but errors.
    #[arg(short, long)]
    pub quiet: bool,
}

/// The report's lines, for `index` and `convert`.
pub fn describe(r: &IndexReport) -> String {
    let overview = match &r.no_overview {
        Some(why) => format!("no overview ({})", sanitize(why)),
        None => format!(
            "overview of {} node(s) in {} layer(s), {} points, {}",
            count(r.nodes as u64),
            r.layers,
            count(r.node_points),
            bytes(r.node_bytes)
        ),
    };
    let pages = match r.index_pages {
        0 | 1 => String::new(),
        n => format!(" and {} more pages", count(n as u64 - 1)),
    };
    format!(
        "indexed {} part(s), {} points: {overview}; index {}{pages}; {:.2} s",
        count(r.parts as u64),
        count(r.points),
        bytes(r.index_bytes),
        r.seconds
    )
}

/// Whether `a` asks for a survey of COPC files: a list of files, or a
/// directory with COPC files and no parts.
fn is_survey(a: &Args) -> bool {
    if a.dir.is_file() {
        // (A part is not a list: it is refused below, as needing no index.)
        return !a.dir.to_string_lossy().to_lowercase().ends_with(".tif");
    }
    let has = |ext: &str| {
        std::fs::read_dir(&a.dir).is_ok_and(|mut d| {
            d.any(|e| {
                e.is_ok_and(|e| {
                    e.file_name()
                        .to_string_lossy()
                        .to_lowercase()
                        .ends_with(ext)
                })
            })
        })
    };
    a.dir.is_dir() && has(".copc.laz") && !has(".tif")
}

/// `pcimg index` over COPC files: their survey.
fn run_survey(a: Args) -> anyhow::Result<()> {
    let out = match (&a.output, a.dir.is_dir()) {
        (Some(o), _) => o.clone(),
        (None, true) => a.dir.clone(),
        (None, false) => anyhow::bail!(
            "{}: a list of COPC files needs -o DIR, the directory to write their survey to",
            sanitize(&a.dir.display().to_string())
        ),
    };
    let inputs = crate::survey::inputs_of(&a.dir)?;
    super::remote::read_url_inputs(a.timeout.remote_options());
    // One run at a time in a directory (a second is refused, naming the first).
    let created = !out.exists();
    std::fs::create_dir_all(&out).map_err(|e| {
        anyhow::anyhow!(
            "{}: cannot create: {e}",
            sanitize(&out.display().to_string())
        )
    })?;
    let _lock = crate::convert::output::lock(&out.canonicalize()?)?;
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let c = cancel.clone();
        let _ = ctrlc::set_handler(move || c.store(true, std::sync::atomic::Ordering::Relaxed));
    }
    use std::io::IsTerminal;
    let show = !a.quiet && std::io::stderr().is_terminal();
    let progress = move |what: &str, done: usize, of: usize| {
        if show {
            use std::io::Write;
            let of = if of > 0 {
                format!(" of {of}")
            } else {
                String::new()
            };
            let _ = write!(std::io::stderr(), "\r\x1b[Ksurvey: {done}{of} {what}");
        }
    };
    let r = crate::survey::build(&inputs, &out, &cancel, &progress);
    if show {
        note!("");
    }
    if r.is_err() && created {
        // (Only if empty: a failed build leaves nothing else.)
        let _ = std::fs::remove_dir(&out);
    }
    let r = r?;
    for gone in &r.removed {
        note!(
            "removed {}, an earlier survey's overview or a stopped run's",
            sanitize(&gone.display().to_string())
        );
    }
    if !a.quiet {
        let overview = match r.nodes {
            0 => "no overview (a single file is its own)".to_string(),
            n => format!(
                "overview of {} node(s) in {} layer(s), {} points, {}",
                count(n as u64),
                r.layers,
                count(r.node_points),
                bytes(r.node_bytes)
            ),
        };
        super::print_out(&format!(
            "surveyed {} COPC file(s), {} points: {overview}; {} {}; {:.2} s\n",
            count(r.files as u64),
            count(r.points),
            sanitize(&out.join(crate::survey::SURVEY_FILE).display().to_string()),
            bytes(r.survey_bytes),
            r.seconds
        ))?;
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if is_survey(&a) {
        return run_survey(a);
    }
    if a.output.is_some() {
        anyhow::bail!(
            "{}: -o is for a survey of COPC files; a directory of parts is indexed in place",
            sanitize(&a.dir.display().to_string())
        );
    }
    if !a.dir.is_dir() {
        anyhow::bail!(
            "{}: not a directory of parts (a single .tif part needs no index)",
            sanitize(&a.dir.display().to_string())
        );
    }
    // One run at a time (a conversion to the same output included); what
    // killed shards left goes first.
    let _lock = match a.dir.canonicalize() {
        Ok(real) if real.file_name().is_some() => Some(crate::convert::output::lock(&real)?),
        _ => None,
    };
    let mut leftovers = crate::convert::cluster::remove_leftovers(&a.dir);
    // A dataset made by cluster shards (docs/cluster.md): every shard's receipt
    // checked against its plan first.
    let checked = crate::convert::cluster::check_receipts(&a.dir)?;
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let c = cancel.clone();
        let _ = ctrlc::set_handler(move || c.store(true, std::sync::atomic::Ordering::Relaxed));
    }
    let o = IndexOptions {
        compression: None,
        cancel: Some(cancel),
        memory: Some(
            a.memory
                .unwrap_or_else(crate::convert::budget::default_budget),
        ),
        refuse_over_memory: true,
    };
    use std::io::IsTerminal;
    let show = !a.quiet && std::io::stderr().is_terminal();
    let progress = move |done: usize| {
        if show {
            use std::io::Write;
            let _ = write!(std::io::stderr(), "\roverview: {done} node(s) written");
        }
    };
    let r = build_index(&a.dir, &o, &progress);
    if show {
        note!("");
    }
    let r = r?;
    leftovers.extend(r.leftovers.iter().cloned());
    for gone in &leftovers {
        note!(
            "removed {}, left by a run that was stopped",
            sanitize(&gone.display().to_string())
        );
    }
    if !a.quiet {
        if let Some(c) = checked {
            super::print_out(&format!(
                "receipts of {} shard(s) match the plan: {} part(s), {} points\n",
                count(c.shards as u64),
                count(c.parts as u64),
                count(c.points)
            ))?;
        }
        super::print_out(&format!("{}\n", describe(&r)))?;
    }
    Ok(())
}
