//! A conversion whose output is in object storage (`-o s3://bucket/city.pcimg`):
//! the dataset is written into a local temporary directory, each part uploaded
//! as soon as it is written, then the overview nodes, and the index last, so that
//! the dataset in the store is complete or absent. On a failure or Ctrl-C every
//! object uploaded is deleted (multipart uploads aborted) and no index is written.

use super::{PartHook, Progress};
use crate::remote::Remote;
use crate::remote::lock::{Lock, Taken};
use crate::remote::upload::Uploader;
use crate::store::dataset::index::{INDEX_FILE, Index, PAGES_DIR, rewrite_entries};
use anyhow::{Result, anyhow, bail};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Where a conversion to object storage writes, and what it has uploaded.
pub struct RemoteOutput {
    /// The URL as given (without a trailing `/`).
    pub url: String,
    remote: Arc<Remote>,
    uploader: Arc<Uploader>,
    cancel: Arc<AtomicBool>,
    /// The local output the conversion writes (inside `_scratch`).
    pub local: PathBuf,
    /// A single `.tif` part rather than a dataset directory.
    as_file: bool,
    /// The objects of the dataset this one replaces (`--force`): removed, the
    /// index first, before anything is uploaded.
    old: Vec<String>,
    /// Where a lock of a run that was stopped was taken over, a line that
    /// says so.
    pub took_over: Option<String>,
    _scratch: super::spill::TempDir,
    /// One conversion at a time to a prefix (released last).
    _lock: Lock,
}

/// Whether `output` names object storage.
pub fn is_remote(output: &Path) -> Option<&str> {
    output.to_str().filter(|s| crate::remote::is_url(s))
}

impl RemoteOutput {
    /// Checks the target (an index there, or any object under the prefix, is
    /// refused without `force`), and makes the local temporary directory (in
    /// `$TMPDIR`: the parts and the conversion's spill files).
    pub fn prepare(
        url: &str,
        force: bool,
        cancel: Arc<AtomicBool>,
        net: &crate::remote::Options,
    ) -> Result<RemoteOutput> {
        let remote = Arc::new(Remote::open_with(url, net).map_err(|m| anyhow!(m))?);
        Self::prepare_in(remote, force, cancel)
    }

    /// As [`RemoteOutput::prepare`], into a given store (tests: an in-memory one).
    pub fn prepare_in(
        remote: Arc<Remote>,
        force: bool,
        cancel: Arc<AtomicBool>,
    ) -> Result<RemoteOutput> {
        let url = remote.url.clone();
        let url = url.as_str();
        let shown = crate::text::sanitize(url);
        let lock = match crate::remote::lock::take(&remote).map_err(|m| anyhow!(m))? {
            Taken::Held(l) => l,
            Taken::Busy { holder, url: lock } => {
                let lock = crate::text::sanitize(&lock);
                let host = holder.host.as_deref().map(crate::text::sanitize);
                let mut who = Vec::new();
                if let Some(pid) = holder.pid {
                    who.push(format!("process {pid}"));
                }
                if let Some(h) = &host {
                    who.push(format!("on {h}"));
                }
                if let Some(t) = holder.since {
                    let now = std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(t, |d| d.as_secs());
                    who.push(format!(
                        "started {} ago",
                        crate::text::duration(std::time::Duration::from_secs(
                            now.saturating_sub(t)
                        ))
                    ));
                }
                bail!(
                    "{shown}: another pcimg run is writing it ({}; its lock is {lock}); wait for \
                     it to finish, or write another prefix. If that run is gone (stopped on \
                     another machine), delete the lock with your store's tool, e.g. `aws s3 rm \
                     {lock}`",
                    who.join(", ")
                );
            }
        };
        let took_over = lock.took_over.as_ref().map(|h| {
            format!(
                "took over the lock {} of process {}, a run that was stopped",
                crate::text::sanitize(&lock.url()),
                h.pid.unwrap_or(0)
            )
        });
        let lower = url.to_ascii_lowercase();
        let as_file = lower.ends_with(".tif") || lower.ends_with(".tiff");
        let mut old = Vec::new();
        if as_file {
            if remote.exists("").map_err(|m| anyhow!(m))? && !force {
                bail!("{shown}: already exists (use --force to replace it)");
            }
        } else if let Some((text, _, _)) = remote.get(INDEX_FILE).map_err(|m| anyhow!(m))? {
            if !force {
                bail!(
                    "{shown}: a dataset already exists there ({shown}/{INDEX_FILE}); use --force \
                     to replace it"
                );
            }
            let index = Index::parse(&text, Path::new(url))?;
            let page = |name: &str| -> crate::store::Result<Vec<u8>> {
                match remote.get(name).map_err(crate::store::StoreError::remote)? {
                    Some((t, _, _)) => Ok(t.to_vec()),
                    None => Err(crate::store::StoreError::new(
                        Path::new(&remote.url_of(name)),
                        "an index page is missing",
                    )),
                }
            };
            // The index first: the old dataset is absent from its first deletion on.
            old.push(INDEX_FILE.to_string());
            old.extend(index.files(Path::new(url), &page)?);
        } else if !force && let Some(first) = remote.first_object().map_err(|m| anyhow!(m))? {
            bail!(
                "{shown}: holds objects but no dataset index (e.g. {}): not a pcimg dataset, or \
                 an unfinished upload; choose another prefix, or use --force to write there",
                crate::text::sanitize(&first)
            );
        }
        let name = if as_file { "part.tif" } else { "dataset.pcimg" };
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        // (Those of uploads that were killed go first: their lock is free.)
        super::spill::sweep(&std::env::temp_dir(), "pcimg-", "upload-", "");
        let dir = std::env::temp_dir().join(format!("pcimg-upload-{}-{stamp}", std::process::id()));
        let scratch = super::spill::TempDir::locked(dir)
            .map_err(|e| anyhow!("cannot create the local copy of the upload: {e}"))?;
        let uploader = Arc::new(Uploader::new(
            remote.clone(),
            Arc::new(AtomicBool::new(false)),
        ));
        let out = RemoteOutput {
            url: url.to_string(),
            local: scratch.path.join(name),
            remote,
            uploader,
            cancel,
            as_file,
            old,
            took_over,
            _scratch: scratch,
            _lock: lock,
        };
        if !out.old.is_empty() {
            let left = out.uploader.delete(&out.old[..1]);
            if let Some(e) = left.first() {
                bail!("{e}: cannot remove the dataset it replaces");
            }
        }
        Ok(out)
    }

    /// The hook that uploads each part as soon as it is written.
    pub fn hook(&self) -> PartHook {
        // (A conversion's options may cross `catch_unwind`; the uploader holds
        // no state a panic could leave half-changed that a later call trusts.)
        let up = std::panic::AssertUnwindSafe(self.uploader.clone());
        let as_file = self.as_file;
        PartHook(Arc::new(move |path: &Path| {
            let name = if as_file {
                String::new()
            } else {
                path.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            };
            up.start(path, &name).map_err(|m| anyhow!(m))?;
            Ok(format!(
                "; uploading ({} sent)",
                crate::text::bytes(up.sent())
            ))
        }))
    }

    /// After the conversion: the rest of the dataset (the overview nodes) is
    /// uploaded, every upload awaited, then the index; what the old dataset
    /// (`--force`) or an earlier attempt left and this one does not hold is
    /// deleted. On an error the caller calls [`RemoteOutput::abort`].
    pub fn finish(&self, progress: &dyn Progress) -> Result<()> {
        let files = if self.as_file {
            vec![(self.local.clone(), String::new())]
        } else {
            files_under(&self.local)?
        };
        let total: u64 = files
            .iter()
            .filter_map(|(p, _)| std::fs::metadata(p).ok())
            .map(|m| m.len())
            .sum();
        let started = self.uploader.started();
        let index = files.iter().find(|(_, n)| n == INDEX_FILE).cloned();
        // The index's root and pages go last, once they record the parts'
        // ETags.
        let is_index = |n: &str| n == INDEX_FILE || n.starts_with(&format!("{PAGES_DIR}-"));
        for (path, name) in &files {
            if !is_index(name) && !started.contains(name) {
                self.uploader.start(path, name).map_err(|m| anyhow!(m))?;
            }
        }
        progress.phase("upload", total, "bytes");
        while self.uploader.pending() > 0 {
            if self.cancel.load(Ordering::Relaxed) {
                bail!("{}: interrupted while uploading", self.url);
            }
            progress.advance(self.uploader.sent(), 0);
            std::thread::sleep(Duration::from_millis(100));
        }
        self.uploader.wait().map_err(|m| anyhow!(m))?;
        if self.cancel.load(Ordering::Relaxed) {
            bail!("{}: interrupted while uploading", self.url);
        }
        // Parts an earlier attempt uploaded under names this dataset does not use.
        let names: Vec<&String> = files.iter().map(|(_, n)| n).collect();
        let stale: Vec<String> = started
            .iter()
            .chain(&self.old)
            .filter(|n| !names.contains(n))
            .cloned()
            .collect();
        let left = self.uploader.delete(&stale);
        if let Some(e) = left.first() {
            bail!("{e}: cannot remove an object the dataset does not hold");
        }
        if let Some((path, name)) = index {
            let dir = path.parent().unwrap_or(Path::new("."));
            for page in self.record_etags(&path)? {
                self.uploader
                    .put_now(&dir.join(&page), &page)
                    .map_err(|m| anyhow!(m))?;
            }
            self.uploader
                .put_now(&path, &name)
                .map_err(|m| anyhow!(m))?;
        }
        progress.advance(self.uploader.sent(), 0);
        Ok(())
    }

    /// Writes into the local index each object's ETag as its upload returned
    /// it, and the URL they hold for: a reader then learns no ETag by request
    /// (no HEAD per part with a warm disk cache) and sends its range requests
    /// conditional on these. An entry whose upload returned no ETag, or another
    /// size, keeps none (the reader asks, as for an index written locally).
    fn record_etags(&self, index: &Path) -> Result<Vec<String>> {
        let dir = index.parent().unwrap_or(Path::new("."));
        let fill = |e: &mut crate::store::dataset::index::FileEntry| {
            e.etag = match self.uploader.uploaded(&e.file) {
                Some((size, Some(etag))) if size == e.bytes && !etag.is_empty() => Some(etag),
                _ => None,
            };
        };
        Ok(rewrite_entries(dir, Some(self.url.clone()), &fill)?)
    }

    /// Deletes every object uploaded (and, with `--force`, what is left of the
    /// dataset replaced); a note names any that could not be deleted.
    pub fn abort(&self, progress: &dyn Progress) {
        let mut left = self.uploader.remove_all();
        left.extend(self.uploader.delete(&self.old));
        // What was removed: every object an upload was started for (and of
        // the dataset replaced) but those that could not be deleted.
        let url = crate::text::sanitize(&self.url);
        let mut removed: Vec<String> = self.uploader.started();
        removed.extend(self.old.iter().cloned());
        removed.dedup();
        removed.retain(|n| {
            let u = self.remote.url_of(n);
            !left.iter().any(|e| e.starts_with(&format!("{u}: ")))
        });
        if removed.is_empty() && left.is_empty() {
            progress.notice(&format!("nothing had been uploaded to {url}"));
        } else if !removed.is_empty() {
            const SHOWN: usize = 8;
            let mut names: Vec<String> = removed
                .iter()
                .take(SHOWN)
                .map(|n| crate::text::sanitize(if n.is_empty() { &self.url } else { n }))
                .collect();
            if removed.len() > SHOWN {
                names.push(format!("and {} more", removed.len() - SHOWN));
            }
            progress.notice(&format!(
                "removed {} object(s) from {url}: {}",
                removed.len(),
                names.join(", ")
            ));
        }
        for e in &left {
            progress.notice(&format!("could not delete {e}"));
        }
        if left.is_empty() {
            progress.notice(&format!("nothing of this conversion is left at {url}"));
        }
    }

    /// Bytes uploaded.
    pub fn sent(&self) -> u64 {
        self.uploader.sent()
    }

    /// The dataset's store (tests).
    pub fn remote(&self) -> &Arc<Remote> {
        &self.remote
    }
}

/// Every file under `dir`, with its `/`-separated name relative to `dir`, sorted.
fn files_under(dir: &Path) -> Result<Vec<(PathBuf, String)>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let entries =
            std::fs::read_dir(&d).map_err(|e| anyhow!("{}: cannot list: {e}", d.display()))?;
        for e in entries {
            let p = e?.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(rel) = p.strip_prefix(dir) {
                let name: Vec<String> = rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                out.push((p.clone(), name.join("/")));
            }
        }
    }
    out.sort_by(|a, b| a.1.cmp(&b.1));
    Ok(out)
}
