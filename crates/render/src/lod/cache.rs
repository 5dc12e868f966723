//! The tile cache: tiles of (part, level, tile) loaded through the store by worker
//! threads, kept under a memory budget (least recently used out). Callers ask for a
//! selection and never wait: tiles arrive as workers finish, and requests for tiles
//! no longer wanted are skipped. While a tile is missing, a cached coarser tile
//! covering it can stand in.
//!
//! A tile that fails to load is remembered. Where the failure may pass (the
//! server did not answer, or failed or throttled: [`StoreError::transient`]) the
//! tile is tried again in the background, by the same loading threads, when its
//! wait is over and while the view still wants it: the wait starts at
//! [`RETRY_FIRST`] and doubles after each failure up to [`RETRY_MAX`], with
//! jitter (a random 50-100 % of it) so that tiles that failed together are not
//! all asked for again together. A retried tile that loads means the server is
//! back: the others waiting are then tried within [`RETRY_FIRST`]/2 rather than
//! at the end of their waits. [`TileCache::retries`] sums up what is waiting for
//! a status line. Any other failure (bytes that do not decode, a missing or
//! denied object) would fail again the same way: that tile is unreadable, and
//! not asked for again.

use super::select::TileRef;
use crate::store::{Dataset, StoreError};
use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The wait before a tile whose load failed (for a reason that may pass) is
/// tried again the first time; it doubles after each failure.
pub const RETRY_FIRST: Duration = Duration::from_millis(500);
/// The longest wait between two tries of a tile.
pub const RETRY_MAX: Duration = Duration::from_secs(15);

/// Identifies a tile of a dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TileKey {
    pub part: usize,
    pub level: usize,
    pub tile: u32,
}

impl From<&TileRef> for TileKey {
    fn from(t: &TileRef) -> Self {
        TileKey {
            part: t.part,
            level: t.level,
            tile: t.tile,
        }
    }
}

/// A loaded tile: coordinates relative to its part's origin, and the attribute
/// columns used for colouring.
#[derive(Debug, Clone)]
pub struct LoadedTile {
    pub key: TileKey,
    pub origin: [f64; 3],
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    /// Attribute columns by band name (with their offsets).
    pub attributes: Vec<(String, f64, Vec<f32>)>,
    pub load_ms: f64,
}

impl LoadedTile {
    /// The columns a part read (x y z first, then attributes) as a tile.
    pub fn of_points(key: TileKey, p: crate::store::Points, load_ms: f64) -> LoadedTile {
        let mut cols = p.columns.into_iter();
        let (x, y, z) = (
            cols.next().unwrap_or_default(),
            cols.next().unwrap_or_default(),
            cols.next().unwrap_or_default(),
        );
        let attributes = p.bands[3..]
            .iter()
            .zip(&p.offsets[3..])
            .zip(cols)
            .map(|((n, &o), c)| (n.clone(), o, c))
            .collect();
        LoadedTile {
            key,
            origin: [p.offsets[0], p.offsets[1], p.offsets[2]],
            x,
            y,
            z,
            attributes,
            load_ms,
        }
    }

    /// A batch the store's query read, as a tile (keyed by its first tile).
    pub fn of_read(r: crate::store::query::Read) -> LoadedTile {
        let key = TileKey {
            part: r.part,
            level: r.level,
            tile: r.tiles.first().copied().unwrap_or(0),
        };
        LoadedTile::of_points(key, r.points, 0.0)
    }

    /// The points `keep` keeps (all with `None`) as float64 columns in source
    /// units, with `bands` (NaN where the tile lacks one).
    pub fn batch(
        &self,
        keep: Option<&[bool]>,
        bands: &[String],
        lattice: Option<crate::points::Lattice>,
    ) -> crate::store::query::Batch {
        let c = crate::store::query::Columns {
            origin: self.origin,
            xyz: [&self.x, &self.y, &self.z],
        };
        let band = |n: &str| {
            let a = self.attributes.iter().find(|a| a.0 == n)?;
            Some((a.1, a.2.as_slice()))
        };
        crate::store::query::Batch::of(c, band, keep, bands, lattice)
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
    pub fn bytes(&self) -> u64 {
        4 * (self.x.len() as u64 * 3
            + self
                .attributes
                .iter()
                .map(|a| a.2.len() as u64)
                .sum::<u64>())
    }
    pub fn attribute(&self, name: &str) -> Option<&[f32]> {
        self.attributes
            .iter()
            .find(|a| a.0 == name)
            .map(|a| a.2.as_slice())
    }
}

/// Attribute bands loaded for colouring, when the part has them.
pub const COLOR_BANDS: [&str; 4] = ["intensity", "red", "green", "blue"];

/// Loads one tile from the store (x, y, z and the [`COLOR_BANDS`] it has).
pub fn load_tile(ds: &Dataset, key: TileKey) -> Result<LoadedTile, StoreError> {
    load_tile_with(ds, key, &[])
}

/// Which bands a tile load reads besides the coordinates.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Extra {
    /// The [`COLOR_BANDS`] and these (those a part lacks are skipped).
    #[default]
    Color,
    Also(Vec<String>),
    /// Every band of the part.
    All,
}

/// [`load_tile`] reading `extra` bands too (for colour modes and filters on
/// other bands, and for the attributes of a picked point).
pub(crate) fn load_tile_with(
    ds: &Dataset,
    key: TileKey,
    extra: &[String],
) -> Result<LoadedTile, StoreError> {
    load_tile_bands(
        ds,
        key,
        &if extra.is_empty() {
            Extra::Color
        } else {
            Extra::Also(extra.to_vec())
        },
    )
}

/// [`load_tile`] with the bands `extra` names.
pub(crate) fn load_tile_bands(
    ds: &Dataset,
    key: TileKey,
    extra: &Extra,
) -> Result<LoadedTile, StoreError> {
    let t0 = Instant::now();
    if let (Some(src), true) = (ds.source(), key.part == crate::store::SOURCE_PART) {
        let mut names: Vec<String> = match extra {
            Extra::All => ds.totals().shown_bands().skip(3).cloned().collect(),
            Extra::Color | Extra::Also(_) => COLOR_BANDS.iter().map(|n| n.to_string()).collect(),
        };
        if let Extra::Also(also) = extra {
            names.extend(
                also.iter()
                    .filter(|n| !names.contains(n))
                    .cloned()
                    .collect::<Vec<_>>(),
            );
        }
        let p = src.load(key.tile, &names)?;
        return Ok(LoadedTile::of_points(
            key,
            p,
            t0.elapsed().as_secs_f64() * 1e3,
        ));
    }
    let part = ds
        .part(key.part)
        .ok_or_else(|| StoreError::new(&ds.path, format!("has no part {}", key.part)))?;
    let mut bands = vec![0usize, 1, 2];
    match extra {
        // Every band a user can pick (the whole numbers that make GPS time
        // exact only matter to programs that take points out).
        Extra::All => bands.extend(
            (3..part.bands.len())
                .filter(|&b| !pcimg_core::time::is_exact_band(&part.bands[b].name)),
        ),
        Extra::Color | Extra::Also(_) => {
            bands.extend(COLOR_BANDS.iter().filter_map(|n| part.band_index(n)));
            if let Extra::Also(names) = extra {
                for n in names {
                    if let Some(b) = part.band_index(n)
                        && b > 2
                        && !bands.contains(&b)
                    {
                        bands.push(b);
                    }
                }
            }
        }
    }
    let p = part.read_tiles(key.level, &[key.tile], &bands)?;
    Ok(LoadedTile::of_points(
        key,
        p,
        t0.elapsed().as_secs_f64() * 1e3,
    ))
}

struct Entry {
    tile: Arc<LoadedTile>,
    last_used: u64,
}

/// A tile whose loads failed for a reason that may pass.
struct Failure {
    /// Failed tries in a row.
    attempts: u32,
    /// The first of them.
    since: Instant,
    /// The latest, and what it was.
    at: Instant,
    error: StoreError,
    /// When to try again.
    due: Instant,
}

#[derive(Default)]
struct State {
    tiles: HashMap<TileKey, Entry>,
    wanted: HashSet<TileKey>,
    queued: HashSet<TileKey>,
    bytes: u64,
    clock: u64,
    /// Failures that will not pass, since the last [`TileCache::take_errors`].
    errors: Vec<StoreError>,
    /// Tiles whose bytes cannot be read (never queued again).
    unreadable: HashSet<TileKey>,
    /// Tiles waiting to be tried again (queued by the retry thread when due).
    retry: HashMap<TileKey, Failure>,
    /// Jitter for the waits.
    rng: Option<pcimg_core::rng::Rng>,
    /// The cache is being dropped: the retry thread ends.
    closed: bool,
}

impl State {
    /// A random fraction in [0, 1) for jitter.
    fn jitter(&mut self) -> f64 {
        self.rng
            .get_or_insert_with(|| {
                let t = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos() as u64);
                pcimg_core::rng::Rng::new(t ^ ((std::process::id() as u64) << 32))
            })
            .f64()
    }

    /// Records a failed load of `key` that may pass, and when to try it again.
    fn failed_for_now(&mut self, key: TileKey, error: StoreError) {
        let now = Instant::now();
        let jitter = 0.5 + 0.5 * self.jitter();
        match self.retry.get_mut(&key) {
            Some(f) => {
                f.attempts += 1;
                f.at = now;
                f.error = error;
                f.due = now + retry_wait(f.attempts).mul_f64(jitter);
            }
            None => {
                let f = Failure {
                    attempts: 1,
                    since: now,
                    at: now,
                    error,
                    due: now + retry_wait(1).mul_f64(jitter),
                };
                self.retry.insert(key, f);
            }
        }
    }

    /// A tile loaded: if it had failed before, the server answers again, and the
    /// other tiles waiting are tried soon (spread over half the first wait).
    fn loaded(&mut self, key: TileKey) {
        if self.retry.remove(&key).is_none() || self.retry.is_empty() {
            return;
        }
        let now = Instant::now();
        let keys: Vec<TileKey> = self.retry.keys().copied().collect();
        for k in keys {
            let soon = now + (RETRY_FIRST / 2).mul_f64(self.jitter());
            if let Some(f) = self.retry.get_mut(&k) {
                f.due = f.due.min(soon);
            }
        }
    }
}

/// The wait after `attempts` failed tries in a row (before jitter):
/// [`RETRY_FIRST`] doubled each time, at most [`RETRY_MAX`].
pub fn retry_wait(attempts: u32) -> Duration {
    let doublings = attempts.saturating_sub(1).min(16);
    (RETRY_FIRST * (1u32 << doublings)).min(RETRY_MAX)
}

/// The state and the signal that wakes the retry thread (a failure recorded, a
/// new selection, the cache dropped).
struct Shared {
    state: Mutex<State>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> Option<MutexGuard<'_, State>> {
        self.state.lock().ok()
    }
}

/// Tiles waiting to be tried again, summed up for a status line.
#[derive(Debug, Clone, Default)]
pub struct Retries {
    /// Tiles the view wants whose last load failed (for a reason that may
    /// pass): waiting for their next try, or being tried.
    pub tiles: usize,
    /// Until the next try of one of them (zero: one is being tried now).
    pub next_in: Option<Duration>,
    /// The most failed tries in a row of any of them.
    pub attempts: u32,
    /// Since the first failure of the one failing longest.
    pub failing_for: Duration,
    /// The latest failure among them.
    pub last_error: Option<StoreError>,
}

impl std::fmt::Display for Retries {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} tiles waiting to retry", self.tiles)?;
        if let Some(n) = self.next_in {
            write!(f, ", next in {:.1} s", n.as_secs_f64())?;
        }
        if let Some(e) = &self.last_error {
            write!(f, ", last error {e}")?;
        }
        Ok(())
    }
}

/// Counters for the status line.
#[derive(Debug, Clone, Copy, Default)]
pub struct CacheStats {
    pub tiles: usize,
    pub bytes: u64,
    pub budget: u64,
    pub pending: usize,
    pub loads: u64,
    pub load_ms: f64,
}

/// Tiles loaded on worker threads under a memory budget.
pub struct TileCache {
    ds: Arc<Dataset>,
    /// Bands loaded besides the colour bands.
    extra: Arc<Vec<String>>,
    budget: u64,
    shared: Arc<Shared>,
    jobs: Option<Sender<TileKey>>,
    workers: Vec<std::thread::JoinHandle<()>>,
    /// Queues the tiles whose wait is over.
    retrier: Option<std::thread::JoinHandle<()>>,
    loads: Arc<AtomicU64>,
    load_us: Arc<AtomicU64>,
    /// Signalled whenever a tile arrives, or first fails (the interface
    /// redraws). A retry that fails again is not news: [`TileCache::retries`]
    /// says how the tries go.
    pub arrivals: Receiver<TileKey>,
}

impl TileCache {
    pub fn new(ds: Arc<Dataset>, budget: u64, threads: usize) -> TileCache {
        TileCache::with_bands(ds, budget, threads, Vec::new())
    }

    /// A cache whose loads read `extra` bands besides the colour bands.
    pub fn with_bands(
        ds: Arc<Dataset>,
        budget: u64,
        threads: usize,
        extra: Vec<String>,
    ) -> TileCache {
        let extra = Arc::new(extra);
        let (job_tx, job_rx) = channel::<TileKey>();
        let (arrive_tx, arrive_rx) = channel::<TileKey>();
        let job_rx = Arc::new(Mutex::new(job_rx));
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            wake: Condvar::new(),
        });
        let loads = Arc::new(AtomicU64::new(0));
        let load_us = Arc::new(AtomicU64::new(0));
        let workers = (0..threads.max(1))
            .map(|_| {
                let (rx, shared, ds, tx) = (
                    job_rx.clone(),
                    shared.clone(),
                    ds.clone(),
                    arrive_tx.clone(),
                );
                let extra = extra.clone();
                let (loads, load_us) = (loads.clone(), load_us.clone());
                std::thread::spawn(move || {
                    loop {
                        let key = match rx.lock() {
                            Ok(r) => match r.recv() {
                                Ok(k) => k,
                                Err(_) => return,
                            },
                            Err(_) => return,
                        };
                        let still_wanted = shared.lock().is_some_and(|s| s.wanted.contains(&key));
                        if !still_wanted {
                            if let Some(mut s) = shared.lock() {
                                s.queued.remove(&key);
                            }
                            continue;
                        }
                        let res = load_tile_with(&ds, key, &extra);
                        let Some(mut s) = shared.lock() else { return };
                        s.queued.remove(&key);
                        match res {
                            Ok(t) => {
                                loads.fetch_add(1, Ordering::Relaxed);
                                load_us.fetch_add((t.load_ms * 1e3) as u64, Ordering::Relaxed);
                                s.bytes += t.bytes();
                                s.clock += 1;
                                let clock = s.clock;
                                s.tiles.insert(
                                    key,
                                    Entry {
                                        tile: Arc::new(t),
                                        last_used: clock,
                                    },
                                );
                                s.loaded(key);
                                evict(&mut s, budget);
                                drop(s);
                                shared.wake.notify_all();
                                let _ = tx.send(key);
                            }
                            Err(e) if e.transient() => {
                                let first = !s.retry.contains_key(&key);
                                s.failed_for_now(key, e);
                                drop(s);
                                shared.wake.notify_all();
                                // A first failure is news: the tile is no longer
                                // loading but waiting.
                                if first {
                                    let _ = tx.send(key);
                                }
                            }
                            Err(e) => {
                                s.retry.remove(&key);
                                s.unreadable.insert(key);
                                s.errors.push(e);
                                drop(s);
                                // Its outcome is news too: the view stops waiting.
                                let _ = tx.send(key);
                            }
                        }
                    }
                })
            })
            .collect();
        let retrier = {
            let (shared, jobs) = (shared.clone(), job_tx.clone());
            std::thread::Builder::new()
                .name("pcimg-retry".into())
                .spawn(move || retry_loop(&shared, &jobs))
                .ok()
        };
        TileCache {
            ds,
            extra,
            budget,
            shared,
            jobs: Some(job_tx),
            workers,
            retrier,
            loads,
            load_us,
            arrivals: arrive_rx,
        }
    }

    pub fn dataset(&self) -> &Arc<Dataset> {
        &self.ds
    }

    /// Asks for the tiles of a selection; returns at once. Tiles already cached are
    /// kept; tiles of earlier requests not in this one are no longer loaded.
    /// A tile waiting to be tried again is not queued now: the retry thread
    /// queues it when its wait is over.
    pub fn request(&self, tiles: &[TileRef]) {
        let Some(mut s) = self.shared.lock() else {
            return;
        };
        s.wanted = tiles.iter().map(TileKey::from).collect();
        s.clock += 1;
        let clock = s.clock;
        let mut waiting = false;
        let mut new = Vec::new();
        for t in tiles {
            let k = TileKey::from(t);
            if let Some(e) = s.tiles.get_mut(&k) {
                e.last_used = clock;
            } else if s.retry.contains_key(&k) {
                waiting = true;
            } else if !s.queued.contains(&k) && !s.unreadable.contains(&k) {
                s.queued.insert(k);
                new.push(k);
            }
        }
        drop(s);
        let batch: Vec<u32> = new
            .iter()
            .filter(|k| k.part == crate::store::SOURCE_PART)
            .map(|k| k.tile)
            .collect();
        match (self.ds.source(), &self.jobs) {
            // A source's new tiles read ahead as one batch (a remote COPC's
            // chunks: near ranges merged, the rest concurrent) off this
            // thread, then queued: each load finds its bytes fetched.
            (Some(src), Some(j)) if batch.len() > 1 => {
                let (src, j) = (src.clone(), j.clone());
                std::thread::spawn(move || {
                    src.prefetch(&batch);
                    for k in new {
                        let _ = j.send(k);
                    }
                });
            }
            (_, Some(j)) => {
                for k in new {
                    let _ = j.send(k);
                }
            }
            _ => {}
        }
        if waiting {
            // Wanted again, some may be due already.
            self.shared.wake.notify_all();
        }
    }

    /// The cached tiles among `tiles` (others are still loading).
    pub fn ready(&self, tiles: &[TileRef]) -> Vec<Arc<LoadedTile>> {
        let Some(s) = self.shared.lock() else {
            return Vec::new();
        };
        tiles
            .iter()
            .filter_map(|t| s.tiles.get(&TileKey::from(t)).map(|e| e.tile.clone()))
            .collect()
    }

    /// How many of `tiles` cannot be read (they are not asked for again).
    pub fn unreadable(&self, tiles: &[TileRef]) -> usize {
        self.shared.lock().map_or(0, |s| {
            tiles
                .iter()
                .filter(|t| s.unreadable.contains(&TileKey::from(*t)))
                .count()
        })
    }

    /// How many of `tiles` failed to load for a reason that may pass: they
    /// wait to be tried again (or are being tried).
    pub fn retrying(&self, tiles: &[TileRef]) -> usize {
        self.shared.lock().map_or(0, |s| {
            tiles
                .iter()
                .filter(|t| s.retry.contains_key(&TileKey::from(*t)))
                .count()
        })
    }

    /// The tiles the view wants that wait to be tried again, summed up: how
    /// many, when the next try is, how long they have failed, the latest error.
    pub fn retries(&self) -> Retries {
        let Some(s) = self.shared.lock() else {
            return Retries::default();
        };
        let now = Instant::now();
        let mut r = Retries::default();
        let mut latest: Option<&Failure> = None;
        for (k, f) in s.retry.iter().filter(|(k, _)| s.wanted.contains(k)) {
            r.tiles += 1;
            let next = if s.queued.contains(k) {
                Duration::ZERO
            } else {
                f.due.saturating_duration_since(now)
            };
            r.next_in = Some(r.next_in.map_or(next, |n| n.min(next)));
            r.attempts = r.attempts.max(f.attempts);
            r.failing_for = r.failing_for.max(now.saturating_duration_since(f.since));
            if latest.is_none_or(|l| f.at > l.at) {
                latest = Some(f);
            }
        }
        r.last_error = latest.map(|f| f.error.clone());
        r
    }

    /// For tiles of `tiles` not cached (loading, or unreadable), the nearest
    /// cached coarser tile covering each, once each: tile (col, row) of a level is
    /// covered by tile (col/2, row/2) of the next, whose pixels are a
    /// nearest-neighbour sample of it. Drawn meanwhile, they keep the view whole.
    pub fn stand_ins(&self, tiles: &[TileRef]) -> Vec<Arc<LoadedTile>> {
        let Some(mut s) = self.shared.lock() else {
            return Vec::new();
        };
        s.clock += 1;
        let clock = s.clock;
        let mut found: HashSet<TileKey> = HashSet::new();
        for t in tiles {
            let key = TileKey::from(t);
            if s.tiles.contains_key(&key) {
                continue;
            }
            let Some(part) = self.ds.part(t.part) else {
                continue;
            };
            let Some(level) = part.levels.get(t.level) else {
                continue;
            };
            let across = level.tiles_across.max(1);
            let (mut col, mut row) = (t.tile % across, t.tile / across);
            let mut here = false;
            for coarser in part.levels.iter().skip(t.level + 1) {
                (col, row) = (col / 2, row / 2);
                let k = TileKey {
                    part: t.part,
                    level: coarser.index,
                    tile: row * coarser.tiles_across.max(1) + col,
                };
                if let Some(e) = s.tiles.get_mut(&k) {
                    e.last_used = clock;
                    found.insert(k);
                    here = true;
                    break;
                }
            }
            // Then the overview nodes above the part, nearest first.
            let mut up = self.ds.parent(t.part);
            while let Some(n) = up.filter(|_| !here) {
                let Some(top) = self.ds.part(n).and_then(|p| p.levels.last()) else {
                    break;
                };
                let hit = top.tiles.iter().map(|tile| TileKey {
                    part: n,
                    level: top.index,
                    tile: tile.index,
                });
                let hit: Vec<TileKey> = hit.filter(|k| s.tiles.contains_key(k)).collect();
                if !hit.is_empty() {
                    for k in hit {
                        if let Some(e) = s.tiles.get_mut(&k) {
                            e.last_used = clock;
                        }
                        found.insert(k);
                    }
                    break;
                }
                up = self.ds.parent(n);
            }
        }
        let mut keys: Vec<TileKey> = found.into_iter().collect();
        keys.sort();
        keys.iter().map(|k| s.tiles[k].tile.clone()).collect()
    }

    /// Loads the tiles now (in parallel) and returns them all: for one-shot
    /// renders, and the tiles an interface wants before its first frame. They
    /// are kept in the cache (under its budget) like tiles loaded in the
    /// background.
    pub fn load_all(&self, tiles: &[TileRef]) -> Result<Vec<Arc<LoadedTile>>, StoreError> {
        use rayon::prelude::*;
        let ds: &Dataset = &self.ds;
        let extra: &[String] = &self.extra;
        if let Some(src) = ds.source() {
            let ids: Vec<u32> = tiles
                .iter()
                .filter(|t| t.part == crate::store::SOURCE_PART)
                .map(|t| t.tile)
                .collect();
            if ids.len() > 1 {
                src.prefetch(&ids);
            }
        }
        let load = || {
            tiles
                .par_iter()
                .map(|t| load_tile_with(ds, TileKey::from(t), extra).map(Arc::new))
                .collect::<Result<Vec<_>, StoreError>>()
        };
        // Tiles in object storage wait on the network, not the CPU: loaded by
        // more threads than cores, so a frame's requests overlap.
        let out: Vec<Arc<LoadedTile>> = match network_pool().filter(|_| ds.is_remote()) {
            Some(pool) => pool.install(load)?,
            None => load()?,
        };
        for t in &out {
            self.loads.fetch_add(1, Ordering::Relaxed);
            self.load_us
                .fetch_add((t.load_ms * 1e3) as u64, Ordering::Relaxed);
        }
        if let Some(mut s) = self.shared.lock() {
            for t in &out {
                s.clock += 1;
                let last_used = s.clock;
                if s.tiles.contains_key(&t.key) {
                    continue;
                }
                s.bytes += t.bytes();
                s.tiles.insert(
                    t.key,
                    Entry {
                        tile: t.clone(),
                        last_used,
                    },
                );
                s.loaded(t.key);
            }
            evict(&mut s, self.budget);
        }
        Ok(out)
    }

    /// Errors from workers since the last call: the tiles that cannot be read
    /// (failures that may pass are in [`TileCache::retries`]).
    pub fn take_errors(&self) -> Vec<StoreError> {
        self.shared
            .lock()
            .map(|mut s| std::mem::take(&mut s.errors))
            .unwrap_or_default()
    }

    pub fn stats(&self) -> CacheStats {
        let (tiles, bytes, pending) = self
            .shared
            .lock()
            .map(|s| (s.tiles.len(), s.bytes, s.queued.len()))
            .unwrap_or_default();
        CacheStats {
            tiles,
            bytes,
            budget: self.budget,
            pending,
            loads: self.loads.load(Ordering::Relaxed),
            load_ms: self.load_us.load(Ordering::Relaxed) as f64 / 1e3,
        }
    }

    /// Keys of the tiles cached now (for displays of what is loaded).
    pub fn loaded(&self) -> Vec<TileKey> {
        self.shared
            .lock()
            .map(|s| s.tiles.keys().copied().collect())
            .unwrap_or_default()
    }

    /// Whether every tile of `tiles` is cached.
    pub fn has_all(&self, tiles: &[TileRef]) -> bool {
        self.shared.lock().is_some_and(|s| {
            tiles
                .iter()
                .all(|t| s.tiles.contains_key(&TileKey::from(t)))
        })
    }
}

/// The retry thread: sleeps until the next wanted tile's wait is over (or a
/// failure, a new selection or the end wakes it), then queues the tiles due
/// for the loading threads.
fn retry_loop(shared: &Shared, jobs: &Sender<TileKey>) {
    let Some(mut s) = shared.lock() else { return };
    loop {
        if s.closed {
            return;
        }
        let now = Instant::now();
        let mut next: Option<Instant> = None;
        let mut due = Vec::new();
        for (k, f) in &s.retry {
            if !s.wanted.contains(k) || s.queued.contains(k) {
                continue;
            }
            if f.due <= now {
                due.push(*k);
            } else {
                next = Some(next.map_or(f.due, |n| n.min(f.due)));
            }
        }
        for k in due {
            s.queued.insert(k);
            if jobs.send(k).is_err() {
                return;
            }
        }
        s = match next {
            Some(t) => match shared.wake.wait_timeout(s, t - now) {
                Ok((g, _)) => g,
                Err(_) => return,
            },
            None => match shared.wake.wait(s) {
                Ok(g) => g,
                Err(_) => return,
            },
        };
    }
}

/// Drops least recently used tiles that are not wanted until under budget.
fn evict(s: &mut State, budget: u64) {
    while s.bytes > budget {
        let victim = s
            .tiles
            .iter()
            .filter(|(k, _)| !s.wanted.contains(k))
            .min_by_key(|(_, e)| e.last_used)
            .map(|(k, _)| *k);
        let Some(k) = victim else { break };
        if let Some(e) = s.tiles.remove(&k) {
            s.bytes -= e.tile.bytes();
        }
    }
}

impl Drop for TileCache {
    fn drop(&mut self) {
        if let Some(mut s) = self.shared.lock() {
            s.closed = true;
        }
        self.shared.wake.notify_all();
        if let Some(r) = self.retrier.take() {
            let _ = r.join(); // its sender goes with it
        }
        self.jobs = None; // closes the channel: workers finish
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

/// Threads that load remote tiles for [`TileCache::load_all`] (their time is
/// spent waiting on requests); `None` if the pool cannot be built.
fn network_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(NETWORK_LOADERS)
            .thread_name(|i| format!("pcimg-load-{i}"))
            .build()
            .ok()
    })
    .as_ref()
}

/// Remote tiles loaded at once by [`TileCache::load_all`] (the remote reader
/// itself keeps at most 16 requests in flight per read).
const NETWORK_LOADERS: usize = 16;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wait_doubles_from_the_first_to_the_cap() {
        assert_eq!(retry_wait(0), RETRY_FIRST);
        assert_eq!(retry_wait(1), RETRY_FIRST);
        assert_eq!(retry_wait(2), RETRY_FIRST * 2);
        assert_eq!(retry_wait(3), RETRY_FIRST * 4);
        assert_eq!(retry_wait(5), Duration::from_secs(8));
        assert_eq!(retry_wait(6), RETRY_MAX);
        assert_eq!(retry_wait(u32::MAX), RETRY_MAX);
    }

    #[test]
    fn failures_wait_with_jitter_and_a_load_brings_the_others_forward() {
        let mut s = State::default();
        let e = StoreError::new(std::path::Path::new("x"), "refused");
        let keys: Vec<TileKey> = (0..64)
            .map(|tile| TileKey {
                part: 0,
                level: 0,
                tile,
            })
            .collect();
        let t0 = Instant::now();
        for _ in 0..3 {
            for &k in &keys {
                s.failed_for_now(k, e.clone());
            }
        }
        let t1 = Instant::now();
        // Third failure: 2 s, of which 50-100 %; not all the same.
        let waits: Vec<Duration> = keys
            .iter()
            .map(|k| {
                let f = &s.retry[k];
                assert_eq!(f.attempts, 3);
                assert!(f.since >= t0 && f.at <= t1);
                f.due.duration_since(f.at)
            })
            .collect();
        for w in &waits {
            assert!(
                *w >= Duration::from_secs(1) && *w <= Duration::from_secs(2),
                "{w:?}"
            );
        }
        assert!(waits.iter().any(|w| *w != waits[0]), "no jitter");
        // A tile not retried before loads: the others keep their waits.
        s.loaded(TileKey {
            part: 9,
            level: 0,
            tile: 0,
        });
        assert!(
            keys.iter()
                .all(|k| s.retry[k].due >= t0 + Duration::from_secs(1))
        );
        // A retried one loads: the server is back, the others come soon.
        s.loaded(keys[0]);
        let back = Instant::now();
        assert!(!s.retry.contains_key(&keys[0]));
        assert_eq!(s.retry.len(), keys.len() - 1);
        for f in s.retry.values() {
            assert!(f.due <= back + RETRY_FIRST / 2, "{:?}", f.due - back);
            assert_eq!(f.attempts, 3, "the count of tries is kept");
        }
    }
}
