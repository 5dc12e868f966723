//! Options for datasets in object storage, shared by `info`, `render`, `preview`
//! and `inspect` (`--cache`, `--cache-size`, `--net-stats`), and the network
//! counters printed on exit with `--net-stats` (also `convert`'s).

use crate::remote::{Net, Problem, RemoteError};
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
}

impl CacheArgs {
    /// Turns the disk cache on when `--cache` is given.
    pub fn apply(&self) -> anyhow::Result<()> {
        if let Some(dir) = &self.cache {
            crate::remote::disk::configure(dir, self.cache_size).map_err(|m| anyhow::anyhow!(m))?;
        }
        Ok(())
    }
}

/// When `asked` (`--net-stats`), the network's counters on stderr: requests,
/// bytes received, failures and the disk cache's hits (benchmarks).
pub fn print_stats_if_asked(asked: bool) {
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

/// The error with what to do about it appended, where it comes from a request
/// to object storage (the library's errors say what happened; the command line
/// says what to do).
pub fn with_advice(e: anyhow::Error) -> anyhow::Error {
    let failed = e.chain().find_map(|c| {
        c.downcast_ref::<RemoteError>().cloned().or_else(|| {
            c.downcast_ref::<crate::store::StoreError>()
                .and_then(|s| s.remote.clone())
        })
    });
    match failed.and_then(|f| advice(&f)) {
        Some(a) => anyhow::anyhow!("{e:#}; {a}"),
        None => e,
    }
}

/// `s` as typed into a shell.
fn quoted(s: &str) -> String {
    let s = crate::text::sanitize(s);
    if s.chars()
        .all(|c| c.is_ascii_alphanumeric() || "-_./+,:@".contains(c))
    {
        s
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// What to do about a failed request.
pub fn advice(e: &RemoteError) -> Option<String> {
    let parsed = url::Url::parse(&e.url).ok();
    let web = parsed
        .as_ref()
        .is_some_and(|u| matches!(u.scheme(), "http" | "https"));
    // Where the request went: the URL's host and port, or for a cloud URL the
    // endpoint the environment names.
    let place = match &parsed {
        Some(u) if web => format!(
            "{}:{}",
            u.host_str().unwrap_or_default(),
            u.port_or_known_default().unwrap_or_default()
        ),
        _ => "the endpoint (AWS_ENDPOINT for an S3-compatible server)".into(),
    };
    let credentials = "AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, \
                       GOOGLE_APPLICATION_CREDENTIALS, AZURE_STORAGE_ACCOUNT_KEY";
    Some(match &e.problem {
        // (Their text says it.)
        Problem::BadUrl(_) | Problem::Changed(_) | Problem::Other(_) => return None,
        Problem::NotFound => match e
            .url
            .strip_suffix(&format!("/{}", crate::store::dataset::index::INDEX_FILE))
        {
            // A static server is written to by copying files, a bucket also by
            // `convert -o URL`.
            Some(_) if web => format!(
                "check the URL (a dataset's URL is the folder that holds {index} and the parts); \
                 a dataset without an index gets one with `pcimg index DIR` on a local copy: \
                 copy DIR/{index} to the server beside the parts",
                index = crate::store::dataset::index::INDEX_FILE,
            ),
            Some(dataset) => format!(
                "check the URL (a dataset's URL is the folder that holds {index} and the parts); \
                 a dataset without an index gets one with `pcimg index DIR` on a local copy: \
                 upload DIR/{index} beside the parts, or convert with `-o {}`",
                quoted(dataset),
                index = crate::store::dataset::index::INDEX_FILE,
            ),
            None => "check the URL; a dataset copied to the server by hand needs all of its \
                     files (the parts and pcimg-index.json)"
                .into(),
        },
        Problem::Denied { .. } if web => {
            "the server refuses to serve it: check the file's permissions and the server's \
             access rules"
                .into()
        }
        Problem::Denied { status: 401, .. } => format!("set the credentials ({credentials})"),
        Problem::Denied { .. } => {
            format!("check the credentials ({credentials}) and that they may read this bucket")
        }
        Problem::Status {
            status: 429 | 503, ..
        } => "the server is busy or throttling (pcimg retried): try again later".into(),
        Problem::Status { status, .. } if *status >= 500 => {
            "the server failed (pcimg retried): try again later, or see the server's log".into()
        }
        Problem::Status { .. } => "check the URL and the server's configuration".into(),
        Problem::Network { condition, .. } => match condition {
            Net::Refused => format!(
                "nothing answers at {place}: start the server, or correct the host and port"
            ),
            Net::UnknownHost => format!("check the host name of {place}"),
            Net::TimedOut => format!(
                "{place} did not answer in time (pcimg retried): check the network and the \
                 server, or try again later"
            ),
            Net::Cut | Net::Other => format!(
                "check the network and the server at {place} (pcimg retried), or try again later"
            ),
        },
        Problem::WrongRange { .. } => {
            "the server answers byte-range requests wrongly: serve the dataset from another \
             server (any static file server does)"
                .into()
        }
        Problem::PlainHttp => {
            "for an S3-compatible server at an http:// AWS_ENDPOINT set AWS_ALLOW_HTTP=true, \
             or use https://"
                .into()
        }
    })
}
