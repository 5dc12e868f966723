//! The disk cache of fetched ranges (`--cache DIR`): one file per range, named
//! by a hash of URL, ETag and range and holding that key itself (checked on
//! read) and a checksum; written under a temporary name and renamed; the least
//! recently used files evicted down to the size limit. A short, corrupt or
//! foreign file is never served: it is deleted and the range fetched again. An
//! object without an ETag is not cached on disk (a change could not be told).
//! When the disk fills up the cache stops growing ([`full`] says so) and reads
//! go on from the network.

use bytes::Bytes;
use std::collections::HashMap;
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};

/// A file's first bytes: the format and its version.
const MAGIC: &[u8; 8] = b"PCIMGRC1";
/// Extension of a cached range; of an object's last ETag seen.
const RANGE_EXT: &str = "rng";
const ETAG_EXT: &str = "etag";

struct Disk {
    dir: PathBuf,
    limit: u64,
    /// File name → (bytes, last use).
    files: HashMap<String, (u64, u64)>,
    bytes: u64,
    tick: u64,
}

fn slot() -> &'static Mutex<Option<Disk>> {
    static D: OnceLock<Mutex<Option<Disk>>> = OnceLock::new();
    D.get_or_init(|| Mutex::new(None))
}

fn lock() -> std::sync::MutexGuard<'static, Option<Disk>> {
    slot().lock().unwrap_or_else(|p| p.into_inner())
}

/// Hits, misses and ignored (corrupt) files so far in this process.
static HITS: AtomicU64 = AtomicU64::new(0);
static MISSES: AtomicU64 = AtomicU64::new(0);
static BAD: AtomicU64 = AtomicU64::new(0);

/// The disk cache's counters: ranges served from it, ranges looked up and not
/// found, files ignored as short or corrupt.
pub fn counters() -> (u64, u64, u64) {
    (
        HITS.load(Ordering::Relaxed),
        MISSES.load(Ordering::Relaxed),
        BAD.load(Ordering::Relaxed),
    )
}

/// FNV-1a, 64 bits: stable across builds (file names and checksums).
fn fnv(parts: &[&[u8]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in parts {
        for &b in *p {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        // A separator, so ("ab", "c") and ("a", "bc") differ.
        h ^= 0xff;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn key_of(url: &str, etag: &str, r: &Range<u64>) -> String {
    format!("{url}\n{etag}\n{}-{}", r.start, r.end)
}

/// Turns the cache on in `dir` (created if absent), at most `limit` bytes: the
/// files already there are counted (their modification time their last use)
/// and the oldest evicted down to the limit.
pub fn configure(dir: &Path, limit: u64) -> Result<(), String> {
    let shown = crate::text::sanitize(&dir.display().to_string());
    std::fs::create_dir_all(dir).map_err(|e| format!("{shown}: cannot create the cache: {e}"))?;
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{shown}: cannot list: {e}"))?;
    let mut found = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if !name.ends_with(RANGE_EXT) {
            continue;
        }
        let Ok(meta) = e.metadata() else { continue };
        let when = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        found.push((when, name, meta.len()));
    }
    found.sort();
    let mut d = Disk {
        dir: dir.to_path_buf(),
        limit,
        files: HashMap::new(),
        bytes: 0,
        tick: 0,
    };
    for (_, name, len) in found {
        d.tick += 1;
        d.bytes += len;
        d.files.insert(name, (len, d.tick));
    }
    d.evict();
    *lock() = Some(d);
    Ok(())
}

/// Turns the cache off (tests).
pub fn disable() {
    *lock() = None;
}

/// Whether a disk cache is configured.
pub(crate) fn enabled() -> bool {
    lock().is_some()
}

impl Disk {
    fn evict(&mut self) {
        if self.bytes <= self.limit {
            return;
        }
        let mut by_age: Vec<(u64, String, u64)> = self
            .files
            .iter()
            .map(|(n, &(len, t))| (t, n.clone(), len))
            .collect();
        by_age.sort();
        // Down to 90% of the limit, so that eviction does not run on every write.
        let target = self.limit / 10 * 9;
        for (_, name, len) in by_age {
            if self.bytes <= target {
                break;
            }
            let _ = std::fs::remove_file(self.dir.join(&name));
            self.files.remove(&name);
            self.bytes -= len;
        }
    }

    fn forget(&mut self, name: &str) {
        if let Some((len, _)) = self.files.remove(name) {
            self.bytes -= len;
        }
        let _ = std::fs::remove_file(self.dir.join(name));
    }
}

fn range_name(key: &str) -> String {
    format!("{:016x}.{RANGE_EXT}", fnv(&[key.as_bytes()]))
}

/// The cached bytes of `r` of the object at `url` with ETag `etag`, if a
/// whole, uncorrupted file holds them.
pub fn get(url: &str, etag: &str, r: &Range<u64>) -> Option<Bytes> {
    if etag.is_empty() {
        return None;
    }
    let key = key_of(url, etag, r);
    let name = range_name(&key);
    let path = {
        let g = lock();
        g.as_ref()?.dir.join(&name)
    };
    let Ok(data) = std::fs::read(&path) else {
        MISSES.fetch_add(1, Ordering::Relaxed);
        return None;
    };
    match parse(&data, &key, r.end - r.start) {
        Some(body) => {
            HITS.fetch_add(1, Ordering::Relaxed);
            let mut g = lock();
            if let Some(d) = g.as_mut() {
                d.tick += 1;
                let t = d.tick;
                d.files.entry(name).or_insert((data.len() as u64, t)).1 = t;
            }
            // Its last use, for a later process's eviction order.
            if let Ok(f) = std::fs::File::options().append(true).open(&path) {
                let _ = f.set_modified(std::time::SystemTime::now());
            }
            let at = data.len() - 8 - body;
            Some(Bytes::from(data).slice(at..at + body))
        }
        None => {
            BAD.fetch_add(1, Ordering::Relaxed);
            if let Some(d) = lock().as_mut() {
                d.forget(&name);
            }
            None
        }
    }
}

/// The body's length if `data` is a whole cache file of `key` with a `len`-byte
/// body and a matching checksum.
fn parse(data: &[u8], key: &str, len: u64) -> Option<usize> {
    let k = key.len();
    let want = 8 + 4 + k + 8 + len as usize + 8;
    if data.len() != want || &data[..8] != MAGIC {
        return None;
    }
    let klen = u32::from_le_bytes(data[8..12].try_into().ok()?) as usize;
    if klen != k || &data[12..12 + k] != key.as_bytes() {
        return None;
    }
    let blen = u64::from_le_bytes(data[12 + k..20 + k].try_into().ok()?);
    if blen != len {
        return None;
    }
    let body = &data[20 + k..20 + k + len as usize];
    let sum = u64::from_le_bytes(data[want - 8..].try_into().ok()?);
    (sum == fnv(&[key.as_bytes(), body])).then_some(len as usize)
}

/// Keeps `body`, bytes `r` of the object at `url` with ETag `etag` (a
/// temporary file renamed into place); errors are ignored (a cache).
pub fn put(url: &str, etag: &str, r: &Range<u64>, body: &[u8]) {
    if etag.is_empty() || body.len() as u64 != r.end - r.start {
        return;
    }
    let key = key_of(url, etag, r);
    let name = range_name(&key);
    let dir = match lock().as_ref() {
        Some(d) if (body.len() as u64) <= d.limit / 4 => d.dir.clone(),
        _ => return,
    };
    let mut data = Vec::with_capacity(body.len() + key.len() + 28);
    data.extend_from_slice(MAGIC);
    data.extend_from_slice(&(key.len() as u32).to_le_bytes());
    data.extend_from_slice(key.as_bytes());
    data.extend_from_slice(&(body.len() as u64).to_le_bytes());
    data.extend_from_slice(body);
    data.extend_from_slice(&fnv(&[key.as_bytes(), body]).to_le_bytes());
    if let Err(e) = write_atomic(&dir, &name, &data) {
        if is_full(&e) {
            stop_growing(&dir, data.len() as u64);
        }
        return;
    }
    if let Some(d) = lock().as_mut() {
        d.tick += 1;
        let t = d.tick;
        if let Some((old, _)) = d.files.insert(name, (data.len() as u64, t)) {
            d.bytes -= old;
        }
        d.bytes += data.len() as u64;
        d.evict();
    }
}

#[cfg(unix)]
fn is_full(e: &std::io::Error) -> bool {
    pcimg_core::disk::is_full(e)
}

#[cfg(not(unix))]
fn is_full(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::StorageFull
}

/// What happened when the cache's disk filled up, once it has ([`full`]).
static FULL: Mutex<Option<String>> = Mutex::new(None);

/// The disk holding the cache is full: the cache keeps what it has, evicting
/// as before, but grows no more (a view goes on from the network); noted once
/// for [`full`]. `wanted`: the bytes of the file that did not fit.
fn stop_growing(dir: &Path, wanted: u64) {
    let held = match lock().as_mut() {
        Some(d) => {
            d.limit = d.bytes;
            d.bytes
        }
        None => return,
    };
    let mut note = FULL.lock().unwrap_or_else(|p| p.into_inner());
    if note.is_none() {
        #[cfg(unix)]
        let why = pcimg_core::disk::full_note(dir, Some(wanted));
        #[cfg(not(unix))]
        let why = format!("its disk is full ({wanted} bytes more needed)");
        *note = Some(format!(
            "{}: {why}: the cache stopped growing at {}",
            crate::text::sanitize(&dir.display().to_string()),
            crate::text::bytes(held)
        ));
    }
}

/// Whether the cache's disk filled up in this process, and what was said of it
/// (the file system, the room left): the command tells the user once.
pub fn full() -> Option<String> {
    FULL.lock().unwrap_or_else(|p| p.into_inner()).clone()
}

fn write_atomic(dir: &Path, name: &str, data: &[u8]) -> std::io::Result<()> {
    static N: AtomicU64 = AtomicU64::new(0);
    let tmp = dir.join(format!(
        ".{name}.tmp-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let r = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(data))
        .and_then(|()| std::fs::rename(&tmp, dir.join(name)));
    if r.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    r
}

fn etag_name(url: &str) -> String {
    format!("{:016x}.{ETAG_EXT}", fnv(&[url.as_bytes()]))
}

/// The ETag last seen for `url` (so that a later run knows its ranges may be
/// cached, and asks the server only whether the object is unchanged).
pub(crate) fn etag_hint(url: &str) -> Option<String> {
    let dir = lock().as_ref()?.dir.clone();
    let text = std::fs::read_to_string(dir.join(etag_name(url))).ok()?;
    let (u, etag) = text.split_once('\n')?;
    (u == url && !etag.is_empty()).then(|| etag.to_string())
}

/// Notes the ETag seen for `url`.
pub(crate) fn set_etag_hint(url: &str, etag: &str) {
    if etag.is_empty() || etag_hint(url).as_deref() == Some(etag) {
        return;
    }
    let Some(dir) = lock().as_ref().map(|d| d.dir.clone()) else {
        return;
    };
    let _ = write_atomic(&dir, &etag_name(url), format!("{url}\n{etag}").as_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_come_back_only_whole_and_for_their_key() {
        let dir = tempfile::tempdir().unwrap();
        configure(dir.path(), 1 << 20).unwrap();
        let (url, r) = ("s3://b/p.tif", 100..110);
        put(url, "e1", &r, b"0123456789");
        assert_eq!(get(url, "e1", &r).unwrap().as_ref(), b"0123456789");
        // Another ETag or range: not served.
        assert!(get(url, "e2", &r).is_none());
        assert!(get(url, "e1", &(100..109)).is_none());
        assert!(get(url, "", &r).is_none());
        // A corrupt byte or a short file: ignored and removed.
        let name = range_name(&key_of(url, "e1", &r));
        let path = dir.path().join(&name);
        let mut data = std::fs::read(&path).unwrap();
        let n = data.len();
        data[n - 12] ^= 1;
        std::fs::write(&path, &data).unwrap();
        assert!(get(url, "e1", &r).is_none());
        assert!(!path.exists());
        put(url, "e1", &r, b"0123456789");
        let data = std::fs::read(&path).unwrap();
        std::fs::write(&path, &data[..data.len() - 1]).unwrap();
        assert!(get(url, "e1", &r).is_none());
        // The least recently used go first.
        configure(dir.path(), 4000).unwrap();
        let body = vec![7u8; 900];
        for i in 0..4u64 {
            put(url, "e1", &(i * 1000..i * 1000 + 900), &body);
        }
        assert!(get(url, "e1", &(0..900)).is_some());
        put(url, "e1", &(9000..9900), &body);
        assert!(get(url, "e1", &(1000..1900)).is_none(), "oldest evicted");
        assert!(get(url, "e1", &(0..900)).is_some(), "recently used kept");
        let total: u64 = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().metadata().unwrap().len())
            .sum();
        assert!(total <= 4000, "{total} bytes on disk");
        // ETag hints.
        set_etag_hint(url, "e1");
        assert_eq!(etag_hint(url).as_deref(), Some("e1"));
        assert_eq!(etag_hint("s3://b/other.tif"), None);
        disable();
    }
}
