//! One object read by byte ranges: nearby ranges merged into one request, the
//! merged requests sent concurrently, the bytes kept in a process-wide LRU cache
//! keyed by URL, ETag and range (a changed object is never served stale: every
//! ranged request after the first is conditional on the ETag first seen, or
//! every one on the ETag the dataset index records), and optionally on disk
//! (`disk.rs`). From a server that ignores Range (answers a ranged GET with
//! the whole object, as Python's `http.server` does) the object is fetched
//! whole, once, and the ranges cut from it.

use super::{InFlight, Problem, Remote, RemoteError};
use bytes::Bytes;
use futures_util::{StreamExt, TryStreamExt};
use object_store::{GetOptions, GetRange};
use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock};

/// Ranges closer than this are fetched as one (a request costs a round trip; a
/// few kilobytes more cost nothing next to it).
pub const MERGE_GAP: u64 = 64 << 10;
/// Requests in flight at once for one read.
pub(crate) const CONCURRENCY: usize = 16;
/// The in-memory cache's size.
pub(crate) const MEMORY_CACHE: u64 = 512 << 20;

/// An object of a [`Remote`] read by ranges.
#[derive(Debug)]
pub struct RemoteFile {
    pub remote: Arc<Remote>,
    pub name: String,
    /// Size and ETag, from the first response (or from the dataset index).
    seen: OnceLock<(u64, Option<String>)>,
    /// Whether `seen` came from the dataset index (`convert -o URL` recorded
    /// the ETag its upload returned): a mismatch then means the object was
    /// replaced behind the index.
    pinned: bool,
    /// The whole object, where the server ignores Range (fetched once).
    whole: tokio::sync::OnceCell<Bytes>,
}

/// Key of a cached range: URL, ETag, range.
type Key = (String, String, u64, u64);

struct Lru {
    map: HashMap<Key, (Bytes, u64)>,
    tick: u64,
    bytes: u64,
    limit: u64,
}

fn cache() -> &'static Mutex<Lru> {
    static C: OnceLock<Mutex<Lru>> = OnceLock::new();
    C.get_or_init(|| {
        Mutex::new(Lru {
            map: HashMap::new(),
            tick: 0,
            bytes: 0,
            limit: MEMORY_CACHE,
        })
    })
}

impl Lru {
    fn get(&mut self, k: &Key) -> Option<Bytes> {
        self.tick += 1;
        let t = self.tick;
        self.map.get_mut(k).map(|e| {
            e.1 = t;
            e.0.clone()
        })
    }
    fn put(&mut self, k: Key, b: Bytes) {
        if b.len() as u64 > self.limit / 4 {
            return;
        }
        self.tick += 1;
        self.bytes += b.len() as u64;
        if let Some(old) = self.map.insert(k, (b, self.tick)) {
            self.bytes -= old.0.len() as u64;
        }
        while self.bytes > self.limit {
            let Some(oldest) = self.map.iter().min_by_key(|e| e.1.1).map(|e| e.0.clone()) else {
                break;
            };
            if let Some((b, _)) = self.map.remove(&oldest) {
                self.bytes -= b.len() as u64;
            }
        }
    }
}

/// Drops from the in-memory cache every range of the objects whose URL starts
/// with `url` (tests and benchmarks: a later read is then served as by a new
/// process, from the disk cache or the store).
pub fn forget_cached(url: &str) {
    let mut c = cache().lock().unwrap_or_else(|p| p.into_inner());
    let gone: Vec<Key> = c
        .map
        .keys()
        .filter(|k| k.0.starts_with(url))
        .cloned()
        .collect();
    for k in gone {
        if let Some((b, _)) = c.map.remove(&k) {
            c.bytes -= b.len() as u64;
        }
    }
}

/// `ranges` sorted and merged where they overlap or lie within `gap` bytes.
pub fn merge(ranges: &[Range<u64>], gap: u64) -> Vec<Range<u64>> {
    let mut v: Vec<Range<u64>> = ranges.iter().filter(|r| r.end > r.start).cloned().collect();
    v.sort_by_key(|r| r.start);
    let mut out: Vec<Range<u64>> = Vec::with_capacity(v.len());
    for r in v {
        match out.last_mut() {
            Some(last) if r.start <= last.end.saturating_add(gap) => last.end = last.end.max(r.end),
            _ => out.push(r),
        }
    }
    out
}

impl RemoteFile {
    pub fn new(remote: Arc<Remote>, name: &str) -> RemoteFile {
        RemoteFile {
            remote,
            name: name.to_string(),
            seen: OnceLock::new(),
            pinned: false,
            whole: Default::default(),
        }
    }

    /// An object whose size and ETag the dataset index records: no request
    /// learns them (no HEAD, even with a warm disk cache); every range is
    /// fetched conditional on that ETag, and cached under it.
    pub fn pinned(remote: Arc<Remote>, name: &str, size: u64, etag: String) -> RemoteFile {
        RemoteFile {
            remote,
            name: name.to_string(),
            seen: OnceLock::from((size, Some(etag))),
            pinned: true,
            whole: Default::default(),
        }
    }

    /// The object's URL.
    pub fn url(&self) -> String {
        self.remote.url_of(&self.name)
    }

    /// Size and ETag, once a request has answered.
    pub fn seen(&self) -> Option<&(u64, Option<String>)> {
        self.seen.get()
    }

    fn fail(&self, problem: Problem) -> RemoteError {
        RemoteError::new(&self.url(), problem)
    }

    /// The bytes `r`, by ranged requests conditional on the ETag seen first
    /// (tried again as [`Remote::retrying`] says: a body cut short is never
    /// kept), or `r` cut from the whole object where the server ignores Range.
    async fn fetch_one(&self, r: Range<u64>) -> Result<Bytes, RemoteError> {
        use std::sync::atomic::Ordering;
        if self.remote.ignores_range.load(Ordering::Relaxed) {
            return self.cut_from_whole(r).await;
        }
        match self
            .remote
            .retrying(|| self.ranged_once(r.clone(), false))
            .await?
        {
            Some(b) => Ok(b),
            None => {
                // A 200 with the whole object (its body not read): from now on
                // every object of this server is fetched whole.
                self.remote.ignores_range.store(true, Ordering::Relaxed);
                self.cut_from_whole(r).await
            }
        }
    }

    /// One ranged request for `r` (`short_ok`: or for what of it the object
    /// holds, where it ends first); `None` where the server answered with the
    /// whole object instead (it ignores Range).
    async fn ranged_once(
        &self,
        r: Range<u64>,
        short_ok: bool,
    ) -> Result<Option<Bytes>, RemoteError> {
        let loc = self.remote.location(&self.name);
        let opts = GetOptions {
            range: Some(GetRange::Bounded(r.clone())),
            if_match: self.seen.get().and_then(|s| s.1.clone()),
            ..Default::default()
        };
        let f = InFlight::start(&self.remote);
        let got = async {
            let g = self.remote.store.get_opts(&loc, opts).await?;
            let meta = (g.meta.size, g.meta.e_tag.clone());
            let range = g.range.clone();
            Ok::<_, object_store::Error>((g.bytes().await?, meta, range))
        }
        .await;
        match got {
            Ok((b, meta, range)) => {
                f.done(b.len() as u64, true);
                let cut = short_ok && range.start == r.start && range.end == meta.0.min(r.end);
                if (range != r && !cut) || b.len() as u64 != range.end - range.start {
                    return Err(self.fail(Problem::WrongRange {
                        asked: r,
                        got: range,
                        bytes: b.len() as u64,
                    }));
                }
                self.check(meta)?;
                Ok(Some(b))
            }
            Err(e) if ignored_range(&e) => {
                f.done(0, true);
                Ok(None)
            }
            Err(e) => {
                f.done(0, false);
                Err(self.changed_or(&e))
            }
        }
    }

    /// The first `max` bytes of the object, or all of it where it is shorter,
    /// in one request (which pins its size and ETag, as the first ranged read
    /// does): a file's header before its size is known.
    pub fn read_prefix(&self, max: u64) -> Result<Bytes, RemoteError> {
        use std::sync::atomic::Ordering;
        if let Some(&(size, _)) = self.seen.get() {
            return Ok(self
                .read_ranges(std::slice::from_ref(&(0..max.min(size))))?
                .remove(0));
        }
        super::block_on(async {
            if !self.remote.ignores_range.load(Ordering::Relaxed)
                && let Some(b) = self
                    .remote
                    .retrying(|| self.ranged_once(0..max, true))
                    .await?
            {
                return Ok(b);
            }
            self.remote.ignores_range.store(true, Ordering::Relaxed);
            // The whole object (one request), then its first bytes.
            self.cut_from_whole(0..0).await?;
            let len = self.whole.get().map_or(0, |w| w.len() as u64);
            self.cut_from_whole(0..max.min(len)).await
        })
    }

    /// The whole object in one plain request (a small file read whole: a
    /// survey's index, an EPT dataset's JSON), where a ranged read of it would
    /// take two from a server that ignores ranges.
    pub fn read_whole(&self) -> Result<Bytes, RemoteError> {
        super::block_on(async {
            self.cut_from_whole(0..0).await?;
            let len = self.whole.get().map_or(0, |w| w.len() as u64);
            self.cut_from_whole(0..len).await
        })
    }

    /// The object's size: known from a request already made, or asked for by
    /// a HEAD request.
    pub fn object_size(&self) -> Result<u64, RemoteError> {
        self.size()
    }

    /// The bytes of each of `ranges`, in order (as [`RemoteFile::read_ranges`]).
    pub fn ranges(&self, ranges: &[Range<u64>]) -> Result<Vec<Bytes>, RemoteError> {
        self.read_ranges(ranges)
    }

    /// The error for a failed request: for a part pinned by the index, a
    /// failed ETag condition is a part replaced behind the index.
    fn changed_or(&self, e: &object_store::Error) -> RemoteError {
        if self.pinned && matches!(e, object_store::Error::Precondition { .. }) {
            return self.fail(Problem::Replaced { etags: None });
        }
        self.fail(Problem::of(e))
    }

    /// Checks a response's size and ETag against those seen first (or pinned).
    fn check(&self, meta: (u64, Option<String>)) -> Result<(), RemoteError> {
        let first = self.seen.get_or_init(|| meta.clone());
        // (A store that ignored the condition: the ETag says it.)
        if self.pinned && meta.1.is_some() && meta.1 != first.1 {
            return Err(self.fail(Problem::Replaced {
                etags: Some((
                    meta.1.clone().unwrap_or_default(),
                    first.1.clone().unwrap_or_default(),
                )),
            }));
        }
        if first.0 != meta.0 {
            return Err(self.fail(Problem::Changed(format!(
                "changed while being read ({} bytes, {} before): open the dataset again",
                meta.0, first.0
            ))));
        }
        Ok(())
    }

    /// Bytes `r` of the object fetched whole (once, tried again as
    /// [`Remote::retrying`] says; later calls wait for the first). Its length
    /// must be the size the response (and the index) gives: a body cut short
    /// is never kept.
    async fn cut_from_whole(&self, r: Range<u64>) -> Result<Bytes, RemoteError> {
        let whole = self
            .whole
            .get_or_try_init(|| self.remote.retrying(|| self.whole_once()))
            .await?;
        if r.start > r.end || r.end > whole.len() as u64 {
            return Err(self.fail(Problem::WrongRange {
                asked: r,
                got: 0..whole.len() as u64,
                bytes: whole.len() as u64,
            }));
        }
        Ok(whole.slice(r.start as usize..r.end as usize))
    }

    /// One request for the whole object.
    async fn whole_once(&self) -> Result<Bytes, RemoteError> {
        let loc = self.remote.location(&self.name);
        let opts = GetOptions {
            if_match: self.seen.get().and_then(|s| s.1.clone()),
            ..Default::default()
        };
        let f = InFlight::start(&self.remote);
        let got = async {
            let g = self.remote.store.get_opts(&loc, opts).await?;
            let meta = (g.meta.size, g.meta.e_tag.clone());
            Ok::<_, object_store::Error>((g.bytes().await?, meta))
        }
        .await;
        match got {
            Ok((b, meta)) => {
                f.done(b.len() as u64, true);
                if b.len() as u64 != meta.0 {
                    return Err(self.fail(Problem::WrongRange {
                        asked: 0..meta.0,
                        got: 0..b.len() as u64,
                        bytes: b.len() as u64,
                    }));
                }
                self.check(meta)?;
                Ok(b)
            }
            Err(e) => {
                f.done(0, false);
                Err(self.changed_or(&e))
            }
        }
    }

    /// The bytes of each of `ranges`, in order: cached ones from the cache, the
    /// rest merged (`MERGE_GAP`) and fetched concurrently. Blocks the caller.
    pub(crate) fn read_ranges(&self, ranges: &[Range<u64>]) -> Result<Vec<Bytes>, RemoteError> {
        super::block_on(self.read_ranges_async(ranges))
    }

    pub(crate) async fn read_ranges_async(
        &self,
        ranges: &[Range<u64>],
    ) -> Result<Vec<Bytes>, RemoteError> {
        let url = self.url();
        // With a disk cache that saw this object before: one HEAD tells whether
        // it is unchanged (its ETag), and the ranges come from the disk.
        if self.seen.get().is_none()
            && super::disk::enabled()
            && super::disk::etag_hint(&url).is_some()
        {
            self.head().await?;
        }
        // The first request fixes the ETag every later one is checked against.
        if self.seen.get().is_none()
            && let Some(r) = ranges.iter().find(|r| r.end > r.start)
        {
            let got = self.fetch_merged(&url, std::slice::from_ref(r)).await?;
            // Kept under the ETag it revealed (it was fetched without one).
            if let (Some(b), Some(etag)) = (got.first(), self.seen.get().and_then(|s| s.1.clone()))
            {
                let k = (url.clone(), etag.clone(), r.start, r.end);
                cache()
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .put(k, b.clone());
                if super::disk::enabled() {
                    super::disk::put(&url, &etag, r, b);
                }
            }
        }
        if let Some(etag) = self.seen.get().and_then(|s| s.1.as_deref())
            && super::disk::enabled()
        {
            super::disk::set_etag_hint(&url, etag);
        }
        self.fetch_merged(&url, ranges).await
    }

    /// The object's size: known from a request already made, or asked for by
    /// a HEAD request (pinning the ETag as the first ranged request does).
    pub(crate) fn size(&self) -> Result<u64, RemoteError> {
        if let Some(s) = self.seen.get() {
            return Ok(s.0);
        }
        super::block_on(self.head())?;
        Ok(self.seen.get().map_or(0, |s| s.0))
    }

    /// The object's size and ETag by a HEAD request (pinning them as the first
    /// ranged request does).
    async fn head(&self) -> Result<(), RemoteError> {
        use object_store::ObjectStoreExt;
        let loc = &self.remote.location(&self.name);
        let meta = self
            .remote
            .retrying(|| async move {
                let f = InFlight::start(&self.remote);
                match self.remote.store.head(loc).await {
                    Ok(meta) => {
                        f.done(0, true);
                        Ok(meta)
                    }
                    Err(e) => {
                        f.done(0, false);
                        Err(self.fail(Problem::of(&e)))
                    }
                }
            })
            .await?;
        let _ = self.seen.set((meta.size, meta.e_tag));
        Ok(())
    }

    async fn fetch_merged(
        &self,
        url: &str,
        ranges: &[Range<u64>],
    ) -> Result<Vec<Bytes>, RemoteError> {
        let etag = self
            .seen
            .get()
            .and_then(|s| s.1.clone())
            .unwrap_or_default();
        let key = |r: &Range<u64>| (url.to_string(), etag.clone(), r.start, r.end);
        let mut out: Vec<Option<Bytes>> = Vec::with_capacity(ranges.len());
        let mut missing = Vec::new();
        // Before a response has told this object's size and ETag, nothing
        // comes from the cache: the first request is what pins them (a server
        // without ETags, as Python's http.server, would otherwise leave a
        // second opening of the same URL without its size).
        if self.seen.get().is_none() {
            missing.extend(ranges.iter().filter(|r| r.end > r.start).cloned());
            out.extend(ranges.iter().map(|r| (r.end <= r.start).then(Bytes::new)));
        } else {
            let mut c = cache().lock().unwrap_or_else(|p| p.into_inner());
            for r in ranges {
                let hit = if r.end <= r.start {
                    Some(Bytes::new())
                } else {
                    c.get(&key(r))
                };
                if hit.is_none() {
                    missing.push(r.clone());
                }
                out.push(hit);
            }
        }
        // Then the disk cache (also only once pinned).
        if !missing.is_empty() && super::disk::enabled() && self.seen.get().is_some() {
            let mut found = Vec::new();
            for (slot, r) in out.iter_mut().zip(ranges) {
                if slot.is_none()
                    && let Some(b) = super::disk::get(url, &etag, r)
                {
                    found.push((key(r), b.clone()));
                    *slot = Some(b);
                }
            }
            let mut c = cache().lock().unwrap_or_else(|p| p.into_inner());
            for (k, b) in found {
                c.put(k, b);
            }
            missing = ranges
                .iter()
                .zip(&out)
                .filter(|(_, s)| s.is_none())
                .map(|(r, _)| r.clone())
                .collect();
        }
        if !missing.is_empty() {
            let merged = merge(&missing, MERGE_GAP);
            let got: Vec<(Range<u64>, Bytes)> = futures_util::stream::iter(merged)
                .map(|r| async move { self.fetch_one(r.clone()).await.map(|b| (r, b)) })
                .buffer_unordered(CONCURRENCY)
                .try_collect()
                .await?;
            let mut got = got;
            got.sort_by_key(|g| g.0.start);
            let mut c = cache().lock().unwrap_or_else(|p| p.into_inner());
            for (slot, r) in out.iter_mut().zip(ranges) {
                if slot.is_some() {
                    continue;
                }
                let i = got.partition_point(|g| g.0.start <= r.start) - 1;
                let (m, b) = &got[i];
                let b = b.slice((r.start - m.start) as usize..(r.end - m.start) as usize);
                c.put(key(r), b.clone());
                if super::disk::enabled() {
                    super::disk::put(url, &etag, r, &b);
                }
                *slot = Some(b);
            }
        }
        Ok(out.into_iter().map(|b| b.unwrap_or_default()).collect())
    }
}

/// Whether a ranged GET was answered with the whole object (HTTP 200): the
/// HTTP store says "Range request not supported", the cloud stores "non-partial
/// response".
fn ignored_range(e: &object_store::Error) -> bool {
    let text = e.to_string().to_ascii_lowercase();
    text.contains("range request not supported") || text.contains("non-partial response")
}

#[cfg(test)]
mod tests {
    // One range is a list of one here.
    #![allow(clippy::single_range_in_vec_init)]
    use super::*;
    use std::io::{Read, Write};
    use std::sync::atomic::{AtomicU64, Ordering};

    /// A static server that ignores Range (as Python's `http.server` does):
    /// every GET is answered 200 with the whole `body`; the number of requests
    /// that asked for a range is counted.
    fn server_ignoring_range(body: Vec<u8>) -> (String, Arc<AtomicU64>) {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let ranged = Arc::new(AtomicU64::new(0));
        let counted = ranged.clone();
        std::thread::spawn(move || {
            for conn in listener.incoming() {
                let Ok(mut conn) = conn else { continue };
                let mut head = Vec::new();
                let mut byte = [0u8; 1];
                while !head.ends_with(b"\r\n\r\n") && conn.read(&mut byte).is_ok_and(|n| n == 1) {
                    head.push(byte[0]);
                }
                let head = String::from_utf8_lossy(&head).to_ascii_lowercase();
                if head.contains("\r\nrange:") {
                    counted.fetch_add(1, Ordering::Relaxed);
                }
                let _ = write!(
                    conn,
                    "HTTP/1.1 200 OK\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                    body.len()
                );
                if !head.starts_with("head ") {
                    let _ = conn.write_all(&body);
                }
            }
        });
        (url, ranged)
    }

    #[test]
    fn ranges_are_cut_from_the_whole_object_where_the_server_ignores_range() {
        let body: Vec<u8> = (0..300_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let (url, ranged) = server_ignoring_range(body.clone());
        let remote = Arc::new(Remote::open(&url).unwrap());
        let file = remote.file("data.bin");
        let want = [10..20, 200_000..200_100, 0..1, 299_990..300_000];
        let got = file.read_ranges(&want).unwrap();
        for (r, b) in want.iter().zip(&got) {
            assert_eq!(&b[..], &body[r.start as usize..r.end as usize], "{r:?}");
        }
        // One ranged request learnt it; the object came whole once.
        assert_eq!(ranged.load(Ordering::Relaxed), 1);
        assert_eq!(remote.requests.load(Ordering::Relaxed), 2);
        // A second object is fetched whole at once; a range past its end is an
        // error naming the URL, never bytes of something else.
        let other = remote.file("other.bin");
        assert_eq!(&other.read_ranges(&[5..9]).unwrap()[0][..], &body[5..9]);
        assert_eq!(ranged.load(Ordering::Relaxed), 1);
        let e = other.read_ranges(&[299_999..300_001]).unwrap_err();
        assert_eq!(e.url, format!("{url}/other.bin"));
        assert!(matches!(e.problem, Problem::WrongRange { .. }), "{e}");
    }

    #[test]
    fn a_refused_connection_is_a_network_condition_naming_the_url() {
        let port = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
            l.local_addr().unwrap().port()
        };
        let url = format!("http://127.0.0.1:{port}/d.pcimg");
        let remote = Arc::new(Remote::open(&url).unwrap());
        let start = std::time::Instant::now();
        let e = remote.file("part.tif").read_ranges(&[0..10]).unwrap_err();
        // Nothing listens: reported after object_store's few quick retries,
        // not tried until the time limit (30 s).
        assert!(start.elapsed() < std::time::Duration::from_secs(10));
        assert_eq!(e.gave_up, None);
        assert_eq!(e.url, format!("{url}/part.tif"));
        assert!(
            matches!(
                e.problem,
                Problem::Network {
                    condition: crate::remote::Net::Refused,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_eq!(e.to_string(), format!("{url}/part.tif: connection refused"));
    }
}
