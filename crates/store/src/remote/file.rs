//! One object read by byte ranges: nearby ranges merged into one request, the
//! merged requests sent concurrently, the bytes kept in a process-wide LRU cache
//! keyed by URL, ETag and range (a changed object is never served stale: every
//! ranged request after the first is conditional on the ETag first seen, or
//! every one on the ETag the dataset index records), and optionally on disk
//! (`disk.rs`).

use super::{InFlight, Remote, explain};
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
pub const CONCURRENCY: usize = 16;
/// The in-memory cache's size.
pub const MEMORY_CACHE: u64 = 512 << 20;

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

    /// One request for `r`, conditional on the ETag seen first.
    async fn fetch_one(&self, r: Range<u64>) -> Result<Bytes, String> {
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
                if range != r || b.len() as u64 != r.end - r.start {
                    return Err(format!(
                        "{}: asked for bytes {}..{}, got {}..{} ({} bytes): the server ignores range requests; serve the dataset from one that supports HTTP Range",
                        self.url(),
                        r.start,
                        r.end,
                        range.start,
                        range.end,
                        b.len()
                    ));
                }
                let first = self.seen.get_or_init(|| meta.clone());
                // (A store that ignored the condition: the ETag says it.)
                if self.pinned && meta.1.is_some() && meta.1 != first.1 {
                    return Err(format!(
                        "{}: the part changed since the index was written (ETag {} now, {} in \
                         the index): re-run `pcimg convert -o URL`, or upload the dataset again \
                         together with its index",
                        self.url(),
                        crate::text::sanitize(meta.1.as_deref().unwrap_or_default()),
                        crate::text::sanitize(first.1.as_deref().unwrap_or_default()),
                    ));
                }
                if first.0 != meta.0 {
                    return Err(format!(
                        "{}: changed while being read ({} bytes, {} before): open the dataset again",
                        self.url(),
                        meta.0,
                        first.0
                    ));
                }
                Ok(b)
            }
            Err(object_store::Error::Precondition { .. }) if self.pinned => {
                f.done(0, false);
                Err(format!(
                    "{}: the part changed since the index was written (its ETag is not the one \
                     the dataset index records): re-run `pcimg convert -o URL`, or upload the \
                     dataset again together with its index",
                    self.url()
                ))
            }
            Err(e) => {
                f.done(0, false);
                Err(format!("{}: {}", self.url(), explain(&e)))
            }
        }
    }

    /// The bytes of each of `ranges`, in order: cached ones from the cache, the
    /// rest merged (`MERGE_GAP`) and fetched concurrently. Blocks the caller.
    pub fn read_ranges(&self, ranges: &[Range<u64>]) -> Result<Vec<Bytes>, String> {
        super::block_on(self.read_ranges_async(ranges))
    }

    pub async fn read_ranges_async(&self, ranges: &[Range<u64>]) -> Result<Vec<Bytes>, String> {
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

    /// The object's size and ETag by a HEAD request (pinning them as the first
    /// ranged request does).
    async fn head(&self) -> Result<(), String> {
        use object_store::ObjectStoreExt;
        let loc = self.remote.location(&self.name);
        let f = InFlight::start(&self.remote);
        match self.remote.store.head(&loc).await {
            Ok(meta) => {
                f.done(0, true);
                let _ = self.seen.set((meta.size, meta.e_tag));
                Ok(())
            }
            Err(e) => {
                f.done(0, false);
                Err(format!("{}: {}", self.url(), explain(&e)))
            }
        }
    }

    async fn fetch_merged(&self, url: &str, ranges: &[Range<u64>]) -> Result<Vec<Bytes>, String> {
        let etag = self
            .seen
            .get()
            .and_then(|s| s.1.clone())
            .unwrap_or_default();
        let key = |r: &Range<u64>| (url.to_string(), etag.clone(), r.start, r.end);
        let mut out: Vec<Option<Bytes>> = Vec::with_capacity(ranges.len());
        let mut missing = Vec::new();
        {
            let mut c = cache().lock().unwrap_or_else(|p| p.into_inner());
            for r in ranges {
                let hit = if r.end <= r.start {
                    Some(Bytes::new())
                } else {
                    c.get(&key(r)).or_else(|| {
                        // Inside a merged range fetched before.
                        None
                    })
                };
                if hit.is_none() {
                    missing.push(r.clone());
                }
                out.push(hit);
            }
        }
        // Then the disk cache.
        if !missing.is_empty() && super::disk::enabled() {
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
