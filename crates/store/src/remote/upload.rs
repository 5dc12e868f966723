//! Local files uploaded to object storage in the background: `put` for small
//! files, a multipart upload (aborted on failure or cancel) above
//! [`MULTIPART_ABOVE`]. Every request is retried within the time limit as
//! [`Remote::retrying`] says: the whole `put`, and each part of a multipart
//! upload on its own ([`put_parts`], through the store's low-level multipart
//! API: object_store's `WriteMultipart` retries a part only as its own client
//! does, three times, and a part cannot be sent again through it). Every object started is remembered so that a failed or
//! interrupted upload can delete what it wrote, and every object uploaded its
//! ETag (for the dataset index). A queued file is held by a hard link in a
//! queue directory, not an open file, and opened when its upload starts (a
//! conversion of thousands of parts would otherwise hit the open-file limit).

use super::{InFlight, Problem, Remote, RemoteError, explain};
use object_store::{ObjectStoreExt, PutPayload, WriteMultipart};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::task::JoinHandle;

/// Files larger than this go up as multipart uploads (S3's parts are 5 MiB at
/// least; below this size one request is cheaper than several).
pub const MULTIPART_ABOVE: u64 = 16 << 20;
/// Bytes of one part of a multipart upload (the file is read this much at a time).
pub(crate) const PART_SIZE: usize = 8 << 20;
/// Parts of one multipart upload in flight at once.
const PARTS_AT_ONCE: usize = 4;
/// Each uploaded object's size and ETag (where the store gave one), by name.
type Uploaded = HashMap<String, (u64, Option<String>)>;

/// Files uploaded at once.
const FILES_AT_ONCE: usize = 4;

/// Uploads files into a [`Remote`]'s prefix in the background.
pub struct Uploader {
    remote: Arc<Remote>,
    /// Set to stop: multipart uploads abort between parts; nothing new starts.
    cancel: Arc<AtomicBool>,
    /// Bytes of finished uploads (and of the parts handed over so far).
    sent: Arc<AtomicU64>,
    files: Arc<tokio::sync::Semaphore>,
    /// Every object an upload was started for, and its latest upload.
    tasks: Mutex<HashMap<String, JoinHandle<Result<u64, String>>>>,
    started: Mutex<Vec<String>>,
    /// The first error, reported by the next call.
    error: Arc<Mutex<Option<String>>>,
    /// Object name → size and ETag of its finished upload.
    uploaded: Arc<Mutex<Uploaded>>,
    /// Where queued files are hard-linked until their upload starts.
    queue: Option<QueueDir>,
    queued: AtomicU64,
}

/// A directory removed with everything in it when dropped.
struct QueueDir(PathBuf);
impl Drop for QueueDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A file waiting for its upload: a hard link (opened, then removed, when the
/// upload starts), or the file already open where no link could be made.
struct Queued {
    link: Option<PathBuf>,
    file: Option<std::fs::File>,
}

impl Queued {
    fn open(mut self, shown: &str) -> Result<std::fs::File, String> {
        match (self.file.take(), &self.link) {
            (Some(f), _) => Ok(f),
            (None, Some(p)) => {
                std::fs::File::open(p).map_err(|e| format!("{shown}: cannot open: {e}"))
            }
            (None, None) => Err(format!("{shown}: cannot open")),
        }
        // (The link goes with `self`: the open file keeps the data.)
    }
}

impl Drop for Queued {
    fn drop(&mut self) {
        if let Some(p) = &self.link {
            let _ = std::fs::remove_file(p);
        }
    }
}

impl Uploader {
    pub fn new(remote: Arc<Remote>, cancel: Arc<AtomicBool>) -> Uploader {
        static N: AtomicU64 = AtomicU64::new(0);
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!(
            "pcimg-queue-{}-{stamp}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let queue = std::fs::create_dir_all(&dir).ok().map(|()| QueueDir(dir));
        Uploader {
            remote,
            cancel,
            sent: Default::default(),
            files: Arc::new(tokio::sync::Semaphore::new(FILES_AT_ONCE)),
            tasks: Default::default(),
            started: Default::default(),
            error: Default::default(),
            uploaded: Default::default(),
            queue,
            queued: AtomicU64::new(0),
        }
    }

    /// The size and ETag of the finished upload of `name` (the ETag where the
    /// store returned one).
    pub fn uploaded(&self, name: &str) -> Option<(u64, Option<String>)> {
        lock(&self.uploaded).get(name).cloned()
    }

    /// Where queued files wait (hard links), if anywhere (tests).
    pub fn queue_dir(&self) -> Option<&Path> {
        self.queue.as_ref().map(|q| q.0.as_path())
    }

    /// Bytes uploaded so far.
    pub fn sent(&self) -> u64 {
        self.sent.load(Ordering::Relaxed)
    }

    /// The objects an upload was started for (in order).
    pub fn started(&self) -> Vec<String> {
        lock(&self.started).clone()
    }

    /// Starts uploading `local` as the object `name` (relative to the prefix)
    /// and returns; a later upload of the same name waits for this one first.
    /// Fails with the first error any upload met so far.
    pub fn start(&self, local: &Path, name: &str) -> Result<(), String> {
        if let Some(e) = lock(&self.error).clone() {
            return Err(e);
        }
        let mut tasks = lock(&self.tasks);
        let before = tasks.remove(name);
        {
            let mut s = lock(&self.started);
            if !s.iter().any(|n| n == name) {
                s.push(name.to_string());
            }
        }
        let (remote, cancel, sent, files, error, uploaded) = (
            self.remote.clone(),
            self.cancel.clone(),
            self.sent.clone(),
            self.files.clone(),
            self.error.clone(),
            self.uploaded.clone(),
        );
        // Held now: the conversion may move its directory (publishing it)
        // before this upload's turn comes. A hard link keeps the file without
        // holding it open; where none can be made, the file is opened now.
        let shown = crate::text::sanitize(&local.display().to_string());
        let queued = self.queue.as_ref().and_then(|q| {
            let leaf = local.file_name().map(|n| n.to_string_lossy().into_owned());
            let link = q.0.join(format!(
                "{}-{}",
                self.queued.fetch_add(1, Ordering::Relaxed),
                leaf.unwrap_or_default()
            ));
            std::fs::hard_link(local, &link).ok().map(|()| Queued {
                link: Some(link),
                file: None,
            })
        });
        let queued = match queued {
            Some(q) => q,
            None => Queued {
                link: None,
                file: Some(
                    std::fs::File::open(local).map_err(|e| format!("{shown}: cannot open: {e}"))?,
                ),
            },
        };
        let (local, name2) = (local.to_path_buf(), name.to_string());
        let task = super::runtime().spawn(async move {
            if let Some(b) = before {
                let _ = b.await;
            }
            let _permit = files.acquire_owned().await.map_err(|e| e.to_string())?;
            let r = match queued.open(&shown) {
                Ok(file) => put_file(&remote, file, &local, &name2, &cancel, &sent).await,
                Err(e) => Err(e),
            };
            match &r {
                Ok(done) => {
                    lock(&uploaded).insert(name2.clone(), done.clone());
                }
                Err(e) => {
                    lock(&error).get_or_insert_with(|| e.clone());
                }
            }
            r.map(|d| d.0)
        });
        tasks.insert(name.to_string(), task);
        Ok(())
    }

    /// Uploads not finished yet.
    pub fn pending(&self) -> usize {
        lock(&self.tasks)
            .values()
            .filter(|t| !t.is_finished())
            .count()
    }

    /// Waits for every upload started; the first error if any failed.
    pub fn wait(&self) -> Result<(), String> {
        let tasks: Vec<_> = lock(&self.tasks).drain().collect();
        super::block_on(async {
            for (name, t) in tasks {
                match t.await {
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => {
                        lock(&self.error).get_or_insert(e);
                    }
                    Err(e) => {
                        lock(&self.error).get_or_insert_with(|| {
                            format!("{}: upload failed: {e}", self.remote.url_of(&name))
                        });
                    }
                }
            }
        });
        match lock(&self.error).clone() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Uploads `local` as `name` now and waits for it (the last object).
    pub fn put_now(&self, local: &Path, name: &str) -> Result<(), String> {
        self.start(local, name)?;
        self.wait()
    }

    /// Stops every upload (multipart ones are aborted) and deletes every object
    /// an upload was started for. Returns the objects it could not delete.
    pub fn remove_all(&self) -> Vec<String> {
        self.cancel.store(true, Ordering::Relaxed);
        let _ = self.wait();
        let names = self.started();
        self.delete(&names)
    }

    /// Deletes the objects `names` (absent ones are fine); the ones that could
    /// not be deleted, with why.
    pub fn delete(&self, names: &[String]) -> Vec<String> {
        let remote = &self.remote;
        super::block_on(async {
            use futures_util::StreamExt;
            futures_util::stream::iter(names.iter())
                .map(|n| async move {
                    let f = InFlight::start(remote);
                    match remote.store.delete(&remote.location(n)).await {
                        Ok(()) | Err(object_store::Error::NotFound { .. }) => {
                            f.done(0, true);
                            None
                        }
                        Err(e) => {
                            f.done(0, false);
                            Some(format!("{}: {}", remote.url_of(n), explain(&e)))
                        }
                    }
                })
                .buffer_unordered(8)
                .filter_map(|r| async move { r })
                .collect()
                .await
        })
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Uploads one file: one `put`, or a multipart upload aborted on any failure
/// or on `cancel`. The bytes uploaded.
async fn put_file(
    remote: &Remote,
    mut file: std::fs::File,
    local: &Path,
    name: &str,
    cancel: &AtomicBool,
    sent: &AtomicU64,
) -> Result<(u64, Option<String>), String> {
    let url = remote.url_of(name);
    let shown = crate::text::sanitize(&local.display().to_string());
    let cancelled = || format!("{url}: upload interrupted");
    if cancel.load(Ordering::Relaxed) {
        return Err(cancelled());
    }
    let size = file
        .metadata()
        .map_err(|e| format!("{shown}: cannot read: {e}"))?
        .len();
    let loc = remote.location(name);
    let fail = |e: object_store::Error| format!("{url}: cannot upload: {}", Problem::of(&e));
    if size <= MULTIPART_ABOVE {
        let mut data = Vec::with_capacity(size as usize);
        file.read_to_end(&mut data)
            .map_err(|e| format!("{shown}: cannot read: {e}"))?;
        let n = data.len() as u64;
        let payload = &PutPayload::from(data);
        let (loc, url) = (&loc, &url);
        // A whole object put again is the same object: tried again (as
        // `Remote::retrying` says) where object_store does not (a connection
        // reset or stalled mid-request: it retries those only for requests it
        // knows to be idempotent).
        let put = remote
            .retrying(|| async move {
                let f = InFlight::start(remote);
                let r = remote.store.put(loc, payload.clone()).await;
                f.done(0, r.is_ok());
                r.map_err(|e| RemoteError::new(url, Problem::of(&e)))
            })
            .await
            .map_err(|e| {
                let gave_up = e.gave_up.map(|g| g.to_string()).unwrap_or_default();
                format!("{}: cannot upload: {}{gave_up}", e.url, e.problem)
            })?;
        sent.fetch_add(n, Ordering::Relaxed);
        return Ok((n, put.e_tag));
    }
    if let Some(mp) = &remote.multipart {
        return put_parts(remote, mp.as_ref(), file, &shown, name, cancel, sent).await;
    }
    let f = InFlight::start(remote);
    let up = remote.store.put_multipart(&loc).await;
    f.done(0, up.is_ok());
    let mut w = WriteMultipart::new_with_chunk_size(up.map_err(fail)?, PART_SIZE);
    let mut done = 0u64;
    loop {
        if cancel.load(Ordering::Relaxed) {
            let _ = w.abort().await;
            return Err(cancelled());
        }
        if let Err(e) = w.wait_for_capacity(PARTS_AT_ONCE).await {
            let _ = w.abort().await;
            return Err(fail(e));
        }
        let chunk = match read_part(&mut file) {
            Ok(c) => c,
            Err(e) => {
                let _ = w.abort().await;
                return Err(format!("{shown}: cannot read: {e}"));
            }
        };
        let got = chunk.len();
        if got == 0 {
            break;
        }
        w.put(chunk.into());
        done += got as u64;
        sent.fetch_add(got as u64, Ordering::Relaxed);
    }
    // The last parts, still abortable by `cancel`.
    loop {
        if cancel.load(Ordering::Relaxed) {
            let _ = w.abort().await;
            return Err(cancelled());
        }
        match tokio::time::timeout(Duration::from_millis(100), w.wait_for_capacity(0)).await {
            Ok(Ok(())) => break,
            Ok(Err(e)) => {
                let _ = w.abort().await;
                return Err(fail(e));
            }
            Err(_) => {}
        }
    }
    let f = InFlight::start(remote);
    let r = w.finish().await;
    f.done(0, r.is_ok());
    let put = r.map_err(fail)?;
    Ok((done, put.e_tag))
}

/// One request of a multipart upload, retried within the time limit; `what`
/// names the step in the error.
async fn step<T, Fut>(
    remote: &Remote,
    url: &str,
    what: &str,
    mut attempt: impl FnMut() -> Fut,
) -> Result<T, String>
where
    Fut: std::future::Future<Output = object_store::Result<T>>,
{
    remote
        .retrying(|| {
            let f = InFlight::start(remote);
            let a = attempt();
            async move {
                let r = a.await;
                f.done(0, r.is_ok());
                r.map_err(|e| RemoteError::new(url, Problem::of(&e)))
            }
        })
        .await
        .map_err(|e| {
            let gave_up = e.gave_up.map(|g| g.to_string()).unwrap_or_default();
            format!("{}: cannot upload ({what}): {}{gave_up}", e.url, e.problem)
        })
}

/// A file above [`MULTIPART_ABOVE`] sent as a multipart upload through the
/// store's own multipart API: parts of [`PART_SIZE`] read in turn,
/// [`PARTS_AT_ONCE`] in flight, each retried on its own (the same part number
/// again, so a part sent twice is stored once). Aborted (the parts the server
/// holds deleted) on any failure or on `cancel`. The bytes and the ETag.
async fn put_parts(
    remote: &Remote,
    mp: &dyn object_store::multipart::MultipartStore,
    mut file: std::fs::File,
    shown: &str,
    name: &str,
    cancel: &AtomicBool,
    sent: &AtomicU64,
) -> Result<(u64, Option<String>), String> {
    use futures_util::StreamExt;
    use futures_util::stream::FuturesUnordered;
    let url = remote.url_of(name);
    let loc = remote.location(name);
    let (url, loc) = (&url, &loc);
    let id = &step(remote, url, "starting a multipart upload", || {
        mp.create_multipart(loc)
    })
    .await?;
    let abort = || async {
        // Best effort: a server that keeps failing keeps the parts until its
        // own lifecycle rule removes them; the error says the upload failed.
        let _ = tokio::time::timeout(remote.options.timeout, mp.abort_multipart(loc, id)).await;
    };
    let mut parts: Vec<Option<object_store::multipart::PartId>> = Vec::new();
    let mut flying = FuturesUnordered::new();
    let mut done = 0u64;
    let mut eof = false;
    let result: Result<(), String> = async {
        loop {
            if cancel.load(Ordering::Relaxed) {
                return Err(format!("{url}: upload interrupted"));
            }
            if !eof && flying.len() < PARTS_AT_ONCE {
                let chunk =
                    read_part(&mut file).map_err(|e| format!("{shown}: cannot read: {e}"))?;
                if chunk.is_empty() {
                    eof = true;
                } else {
                    let idx = parts.len();
                    parts.push(None);
                    let n = chunk.len() as u64;
                    let payload = PutPayload::from(chunk);
                    let what = format!("part {}", idx + 1);
                    flying.push(async move {
                        let r = step(remote, url, &what, || {
                            mp.put_part(loc, id, idx, payload.clone())
                        })
                        .await;
                        (idx, n, r)
                    });
                    continue;
                }
            }
            // Wait for a part, waking now and then to see `cancel`.
            match tokio::time::timeout(Duration::from_millis(100), flying.next()).await {
                Ok(Some((idx, n, r))) => {
                    parts[idx] = Some(r?);
                    done += n;
                    sent.fetch_add(n, Ordering::Relaxed);
                }
                Ok(None) => return Ok(()),
                Err(_) => {}
            }
        }
    }
    .await;
    if let Err(e) = result {
        drop(flying);
        abort().await;
        return Err(e);
    }
    let parts: Vec<_> = parts
        .into_iter()
        .map(|p| p.expect("every part sent"))
        .collect();
    let mut tries = 0;
    let completed = step(remote, url, "completing the multipart upload", || {
        tries += 1;
        let first = tries == 1;
        let parts = parts.clone();
        async move {
            match mp.complete_multipart(loc, id, parts).await {
                // A retry after an answer lost: the first try completed it,
                // and the upload is gone. The object is there if it did.
                Err(object_store::Error::NotFound { .. }) if !first => {
                    let head = remote.store.head(loc).await?;
                    Ok(object_store::PutResult {
                        e_tag: head.e_tag,
                        version: head.version,
                        extensions: Default::default(),
                    })
                }
                r => r,
            }
        }
    })
    .await;
    match completed {
        Ok(put) => Ok((done, put.e_tag)),
        Err(e) => {
            abort().await;
            Err(e)
        }
    }
}

/// The next [`PART_SIZE`] bytes of `file` (fewer at its end, none after it).
fn read_part(file: &mut std::fs::File) -> std::io::Result<Vec<u8>> {
    let mut chunk = vec![0u8; PART_SIZE];
    let mut got = 0;
    while got < chunk.len() {
        match file.read(&mut chunk[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    chunk.truncate(got);
    Ok(chunk)
}
