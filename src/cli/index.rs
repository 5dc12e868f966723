//! `pcimg index DIR`: (re)builds a dataset directory's index and overview, for
//! parts made separately, added, replaced or removed since the last index; the
//! finalize step of a cluster conversion (its receipts checked against the plan).

use crate::store::{IndexOptions, IndexReport, build_index};
use crate::text::{bytes, count, sanitize};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A directory of parts (.tif). Its index (pcimg-index.json) and overview
    /// folder (overview/) are replaced; the parts are only read.
    pub dir: PathBuf,
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

pub fn run(a: Args) -> anyhow::Result<()> {
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
