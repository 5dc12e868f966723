//! Options for datasets in object storage, shared by `info`, `render`, `preview`
//! and `inspect` (`--cache`, `--cache-size`, `--net-stats`, `--timeout`; `convert`
//! takes `--timeout` too), and the network
//! counters printed on exit with `--net-stats` (also `convert`'s).

use std::path::PathBuf;

#[derive(Debug, Clone, Default, clap::Args)]
pub struct CacheArgs {
    /// For a dataset in object storage: keep the fetched byte ranges in this
    /// directory too, so that a later run reads them from the disk (keyed by URL,
    /// ETag and range: a changed object is fetched again; a later run still asks
    /// the server once per object whether it changed).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// The disk cache's size limit, e.g. 500MiB or 10G (the least recently used
    /// ranges are removed beyond it).
    #[arg(long, value_parser = crate::text::parse_size, default_value = "2GiB", requires = "cache")]
    pub cache_size: u64,
    /// For a dataset in object storage: print the network's counters on exit
    /// (requests, bytes received, failures, the disk cache's hits; benchmarks).
    #[arg(long)]
    pub net_stats: bool,
    #[command(flatten)]
    pub timeout: TimeoutArg,
}

/// `--timeout`, for every command that reads or writes object storage.
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct TimeoutArg {
    /// For a dataset in object storage (read, or `convert -o URL`'s upload):
    /// how long a failing request is tried again, with exponential backoff and
    /// jitter (HTTP 5xx, 429, 503 SlowDown; reset or stalled connections;
    /// bodies cut short), before pcimg gives up with an error; e.g. 30s,
    /// 500ms, 2m. A connection that sends nothing for a quarter of this (at
    /// most 10 s) counts as stalled.
    #[arg(long, value_name = "DURATION", value_parser = crate::text::parse_duration, default_value = "30s")]
    pub timeout: std::time::Duration,
}

impl Default for TimeoutArg {
    fn default() -> Self {
        TimeoutArg {
            timeout: crate::store::OpenOptions::default().timeout,
        }
    }
}

impl TimeoutArg {
    /// How the dataset is opened.
    pub fn open_options(&self) -> crate::store::OpenOptions {
        crate::store::OpenOptions {
            timeout: self.timeout,
        }
    }

    /// How requests to object storage are retried.
    pub fn remote_options(&self) -> crate::remote::Options {
        crate::remote::Options {
            timeout: self.timeout,
        }
    }
}

/// Lets the input readers open COPC files at URLs (object storage, HTTP)
/// through the store's ranged reads, retried as `net` says.
pub fn read_url_inputs(net: crate::remote::Options) {
    crate::ingest::set_url_opener(Box::new(move |url| {
        let s =
            crate::store::remote::copc::RemoteBytes::open(url, &net).map_err(|e| e.to_string())?;
        Ok(std::sync::Arc::new(s) as std::sync::Arc<dyn pcimg_copc::ByteSource>)
    }));
}

/// Whether `path` names a COPC file: a local one by its first bytes, a URL
/// by its name (`.copc.laz`).
pub fn is_copc(path: &std::path::Path) -> bool {
    if crate::ingest::is_url(path) {
        return path
            .to_string_lossy()
            .to_ascii_lowercase()
            .ends_with(".copc.laz");
    }
    path.is_file() && crate::ingest::copc::is_copc(path)
}

/// The dataset at `path` for a view: a dataset of parts; or a COPC file, an
/// EPT dataset or a survey of COPC files (`pcimg index` over them), local or
/// at a URL, whose octrees are drawn with no conversion.
pub fn open_for_view(
    path: &std::path::Path,
    cache: &CacheArgs,
) -> anyhow::Result<crate::store::Dataset> {
    if is_copc(path) {
        read_url_inputs(cache.timeout.remote_options());
        return crate::copc_tiles::open(path);
    }
    if crate::ingest::ept::is_ept(path) {
        read_url_inputs(cache.timeout.remote_options());
        return crate::copc_tiles::open_ept(path);
    }
    if crate::survey::is_survey(path) {
        read_url_inputs(cache.timeout.remote_options());
        return crate::survey::open(path);
    }
    Ok(crate::store::Dataset::open_with(
        path,
        &cache.open_options(),
    )?)
}

impl CacheArgs {
    /// How the dataset is opened (`--timeout`).
    pub fn open_options(&self) -> crate::store::OpenOptions {
        self.timeout.open_options()
    }

    /// Turns the disk cache on when `--cache` is given.
    pub fn apply(&self) -> anyhow::Result<()> {
        if let Some(dir) = &self.cache {
            crate::remote::disk::configure(dir, self.cache_size).map_err(|m| anyhow::anyhow!(m))?;
        }
        Ok(())
    }
}

/// When the disk cache's file system filled up, says so; when `asked`
/// (`--net-stats`), the network's counters on stderr: requests, bytes
/// received, failures and the disk cache's hits (benchmarks).
pub fn print_stats_if_asked(asked: bool) {
    if let Some(full) = crate::remote::disk::full() {
        note!("pcimg: disk cache: {full}");
    }
    if asked {
        let s = crate::remote::stats();
        let (hits, misses, bad) = crate::remote::disk::counters();
        note!(
            "pcimg: network: {} requests, {} bytes received, {} failed; disk cache: {} hits, {} misses, {} ignored",
            s.requests,
            s.bytes,
            s.failed,
            hits,
            misses,
            bad
        );
    }
}
