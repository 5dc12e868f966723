//! What to do about an error: the libraries' errors carry the facts (which file,
//! which line, what would put it right: [`Remedy`], [`IngestError::Columns`], a
//! failed request's [`RemoteError`]); here, and only here, they become advice
//! that names commands and flags.

use crate::ingest::IngestError;
use crate::remote::{Net, Problem, RemoteError};
use crate::render::pipeline::DrawError;
use crate::store::dataset::index::INDEX_FILE;
use crate::store::{Dataset, Remedy, StoreError};
use std::path::Path;

/// The error with what to do about it appended, where the error says.
pub fn with_advice(e: anyhow::Error) -> anyhow::Error {
    match advice_in(&e) {
        Some(a) => anyhow::anyhow!("{e:#}; {a}"),
        None => e,
    }
}

/// `e` (its whole chain) as one line, with what to do about it.
pub fn message(e: &anyhow::Error) -> String {
    match advice_in(e) {
        Some(a) => format!("{e:#}; {a}"),
        None => format!("{e:#}"),
    }
}

/// A store error as one line, with what to do about it.
pub fn store(e: &StoreError) -> String {
    match of_store(e) {
        Some(a) => format!("{e}; {a}"),
        None => e.to_string(),
    }
}

/// A failure that is being retried, in a few words for the status line: for a
/// request, its URL, what happened (without the server's own words) and what
/// to do; otherwise as [`store`] says it.
pub fn retrying(e: &StoreError) -> String {
    let Some(r) = e.remote.as_deref() else {
        return store(e);
    };
    let mut brief = r.problem.clone();
    if let Problem::Network { detail, .. }
    | Problem::Status { detail, .. }
    | Problem::Denied { detail, .. } = &mut brief
    {
        detail.clear();
    }
    let what = format!("{}: {brief}", crate::text::sanitize(&r.url));
    match of_remote(r) {
        Some(a) => format!("{what}; {a}"),
        None => what,
    }
}

/// The advice for the first error in `e`'s chain that has some.
fn advice_in(e: &anyhow::Error) -> Option<String> {
    e.chain().find_map(|c| {
        if let Some(s) = c.downcast_ref::<StoreError>() {
            of_store(s)
        } else if let Some(DrawError::Load(s)) = c.downcast_ref::<DrawError>() {
            of_store(s)
        } else if let Some(r) = c.downcast_ref::<RemoteError>() {
            of_remote(r)
        } else {
            c.downcast_ref::<IngestError>().and_then(of_ingest)
        }
    })
}

/// What to do about a store error: its remedy, or for a failed request what
/// the failure calls for.
fn of_store(e: &StoreError) -> Option<String> {
    if let Some(r) = &e.remedy {
        return Some(remedy(r));
    }
    e.remote.as_deref().and_then(of_remote)
}

/// A remedy in words.
fn remedy(r: &Remedy) -> String {
    match r {
        Remedy::Reindex { dataset }
            if crate::store::location::is_url(&dataset.to_string_lossy()) =>
        {
            format!(
                "rebuild the index with `pcimg index DIR` on a local copy of the dataset and \
                 upload DIR/{INDEX_FILE} beside the parts, or convert again with `-o {}`",
                quoted(&dataset.to_string_lossy())
            )
        }
        Remedy::Reindex { dataset } => format!(
            "rebuild the index from the parts there with `pcimg index {}`",
            quoted_path(dataset)
        ),
        Remedy::Convert { input, output } => format!(
            "convert it first, e.g. `pcimg convert {} -o {}`",
            quoted_path(input),
            quoted_path(output)
        ),
        Remedy::Rewrite => "convert again with `-o URL` (that writes the parts and their index \
                            together), or upload the dataset again together with its index"
            .into(),
        Remedy::Upgrade => format!(
            "it was written by a newer pcimg than this one ({}): upgrade pcimg",
            env!("CARGO_PKG_VERSION")
        ),
        Remedy::MoreMemory { .. } => "give it a larger budget with `--memory`, or split the \
                                       parts into several datasets"
            .into(),
        _ => "see the message".into(),
    }
}

/// What to do about a failed request.
fn of_remote(e: &RemoteError) -> Option<String> {
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
    let advice: String = match &e.problem {
        // (Their text says it.)
        Problem::BadUrl(_) | Problem::Changed(_) | Problem::Other(_) => return None,
        Problem::Replaced { .. } => "convert again with `-o URL` (that writes the index with \
                                     the parts), or upload the dataset again together with its \
                                     index"
            .into(),
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
    };
    // Tried until the time limit: how to give it longer.
    Some(match e.gave_up {
        Some(g) => format!(
            "{advice}; to keep trying longer than {}, raise --timeout (e.g. --timeout {}s)",
            seconds(g.limit),
            (g.limit.as_secs() * 4).max(60)
        ),
        None => advice,
    })
}

/// A duration in words: `2 s`, `0.5 s`.
fn seconds(d: std::time::Duration) -> String {
    let s = d.as_secs_f64();
    if s >= 10.0 || s.fract() == 0.0 {
        format!("{s:.0} s")
    } else {
        format!("{s:.1} s")
    }
}

/// What to do about an input reader's error.
fn of_ingest(e: &IngestError) -> Option<String> {
    match e {
        IngestError::Columns { .. } => Some(
            "name the columns with --columns, e.g. --columns 'x y z intensity' (`_` skips a \
             column)"
                .into(),
        ),
        _ => None,
    }
}

/// The note for a dataset opened without an index, where one would help.
pub fn dataset_note(ds: &Dataset) -> Option<String> {
    ds.unindexed.then(|| {
        format!(
            "note: this dataset has no index (made by an older pcimg); `pcimg index {}` makes \
             one, for faster opening and an overview of all {} parts",
            quoted_path(&ds.path),
            ds.part_count()
        )
    })
}

/// The terminal's fallback note, with the flag that forces a protocol.
pub fn protocol_note(c: &crate::term::detect::Choice) -> Option<String> {
    let n = c.note.as_ref()?;
    Some(
        if c.graphics == crate::term::Graphics::Halfblocks && !c.requested {
            format!("{n} (--protocol forces one)")
        } else {
            n.clone()
        },
    )
}

/// Why the protocol was chosen: a requested one names the flag.
pub fn protocol_reason(c: &crate::term::detect::Choice) -> String {
    if c.requested {
        "--protocol".into()
    } else {
        c.reason.clone()
    }
}

/// A path as typed into a shell.
fn quoted_path(p: &Path) -> String {
    quoted(&p.display().to_string())
}

/// `s` as one shell word (quoted when it holds anything but plain characters),
/// sanitized for the terminal.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remedies_name_the_command_with_the_path_quoted() {
        let e = StoreError::new(
            Path::new("/d/a b/pcimg-index.json"),
            "not a valid dataset index",
        )
        .with_remedy(Remedy::Reindex {
            dataset: "/d/a b".into(),
        });
        let m = store(&e);
        assert!(m.contains("not a valid dataset index; rebuild"), "{m}");
        assert!(m.contains("`pcimg index '/d/a b'`"), "{m}");
        let e = StoreError::new(
            Path::new("s3://b/d.pcimg/x.tif"),
            "changed since the dataset was indexed",
        )
        .with_remedy(Remedy::Reindex {
            dataset: "s3://b/d.pcimg".into(),
        });
        assert!(store(&e).contains("on a local copy"), "{}", store(&e));
        let e = StoreError::new(
            Path::new("scan.las"),
            "a point cloud (.las), not an image dataset",
        )
        .with_remedy(Remedy::Convert {
            input: "scan.las".into(),
            output: "scan.pcimg".into(),
        });
        assert!(store(&e).ends_with("`pcimg convert scan.las -o scan.pcimg`"));
        // Through anyhow, with context on top.
        let e = anyhow::Error::new(e).context("cannot open the dataset");
        assert!(message(&e).contains("pcimg convert scan.las"));
        // No remedy, no advice.
        let e = StoreError::new(Path::new("x.tif"), "truncated");
        assert_eq!(store(&e), "x.tif: truncated");
    }

    #[test]
    fn a_retried_request_is_told_in_a_few_words() {
        let url = "http://127.0.0.1:8765/d.pcimg/part-0001.tif";
        let refused = StoreError::remote(RemoteError::new(
            url,
            Problem::Network {
                condition: Net::Refused,
                detail: "error sending request for url (http://127.0.0.1:8765/…)".into(),
            },
        ));
        assert!(refused.transient());
        let m = retrying(&refused);
        assert_eq!(
            m,
            format!(
                "{url}: connection refused; nothing answers at 127.0.0.1:8765: start the \
                 server, or correct the host and port"
            )
        );
        // The full message keeps the server's words.
        assert!(store(&refused).contains("error sending request"));
        let busy = StoreError::remote(RemoteError::new(
            url,
            Problem::Status {
                status: 503,
                detail: "<Error><Code>SlowDown</Code></Error>".into(),
            },
        ));
        assert!(busy.transient());
        let m = retrying(&busy);
        assert!(
            m.starts_with(&format!(
                "{url}: the server answered HTTP 503 Service Unavailable;"
            )),
            "{m}"
        );
        assert!(!m.contains("SlowDown") && m.contains("throttling"), "{m}");
        // Not worth retrying: missing, bad bytes.
        let missing = StoreError::remote(RemoteError::new(url, Problem::NotFound));
        assert!(!missing.transient());
        assert!(!StoreError::new(Path::new("x.tif"), "truncated").transient());
        // Without a request, as `store` says it.
        let e = StoreError::new(Path::new("x.tif"), "truncated");
        assert_eq!(retrying(&e), "x.tif: truncated");
    }
}
