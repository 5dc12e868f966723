//! The tile cache: tiles of (part, level, tile) loaded through the store by worker
//! threads, kept under a memory budget (least recently used out). Callers ask for a
//! selection and never wait: tiles arrive as workers finish, and requests for tiles
//! no longer wanted are skipped. A tile that fails to load is remembered and not
//! asked for again; while a tile is missing, a cached coarser tile covering it
//! can stand in.

use super::select::TileRef;
use crate::store::{Dataset, StoreError};
use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Instant;

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
    let part = ds
        .part(key.part)
        .ok_or_else(|| StoreError::new(&ds.path, format!("has no part {}", key.part)))?;
    let mut bands = vec![0usize, 1, 2];
    match extra {
        Extra::All => bands.extend(3..part.bands.len()),
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
    Ok(LoadedTile {
        key,
        origin: [p.offsets[0], p.offsets[1], p.offsets[2]],
        x,
        y,
        z,
        attributes,
        load_ms: t0.elapsed().as_secs_f64() * 1e3,
    })
}

struct Entry {
    tile: Arc<LoadedTile>,
    last_used: u64,
}

#[derive(Default)]
struct State {
    tiles: HashMap<TileKey, Entry>,
    wanted: HashSet<TileKey>,
    queued: HashSet<TileKey>,
    bytes: u64,
    clock: u64,
    errors: Vec<StoreError>,
    /// Tiles that failed to load (never queued again).
    failed: HashSet<TileKey>,
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
    state: Arc<Mutex<State>>,
    jobs: Option<Sender<TileKey>>,
    workers: Vec<std::thread::JoinHandle<()>>,
    loads: Arc<AtomicU64>,
    load_us: Arc<AtomicU64>,
    /// Signalled whenever a tile arrives (the interface redraws).
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
        let state = Arc::new(Mutex::new(State::default()));
        let loads = Arc::new(AtomicU64::new(0));
        let load_us = Arc::new(AtomicU64::new(0));
        let workers = (0..threads.max(1))
            .map(|_| {
                let (rx, state, ds, tx) =
                    (job_rx.clone(), state.clone(), ds.clone(), arrive_tx.clone());
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
                        let still_wanted = state
                            .lock()
                            .map(|s| s.wanted.contains(&key))
                            .unwrap_or(false);
                        if !still_wanted {
                            if let Ok(mut s) = state.lock() {
                                s.queued.remove(&key);
                            }
                            continue;
                        }
                        let res = load_tile_with(&ds, key, &extra);
                        let Ok(mut s) = state.lock() else { return };
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
                                evict(&mut s, budget);
                                drop(s);
                                let _ = tx.send(key);
                            }
                            Err(e) => {
                                s.failed.insert(key);
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
        TileCache {
            ds,
            extra,
            budget,
            state,
            jobs: Some(job_tx),
            workers,
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
    pub fn request(&self, tiles: &[TileRef]) {
        let Ok(mut s) = self.state.lock() else { return };
        s.wanted = tiles.iter().map(TileKey::from).collect();
        s.clock += 1;
        let clock = s.clock;
        for t in tiles {
            let k = TileKey::from(t);
            if let Some(e) = s.tiles.get_mut(&k) {
                e.last_used = clock;
            } else if !s.queued.contains(&k) && !s.failed.contains(&k) {
                s.queued.insert(k);
                if let Some(j) = &self.jobs {
                    let _ = j.send(k);
                }
            }
        }
    }

    /// The cached tiles among `tiles` (others are still loading).
    pub fn ready(&self, tiles: &[TileRef]) -> Vec<Arc<LoadedTile>> {
        let Ok(s) = self.state.lock() else {
            return Vec::new();
        };
        tiles
            .iter()
            .filter_map(|t| s.tiles.get(&TileKey::from(t)).map(|e| e.tile.clone()))
            .collect()
    }

    /// How many of `tiles` failed to load (they are not asked for again).
    pub fn unreadable(&self, tiles: &[TileRef]) -> usize {
        self.state
            .lock()
            .map(|s| {
                tiles
                    .iter()
                    .filter(|t| s.failed.contains(&TileKey::from(*t)))
                    .count()
            })
            .unwrap_or(0)
    }

    /// For tiles of `tiles` not cached (loading, or unreadable), the nearest
    /// cached coarser tile covering each, once each: tile (col, row) of a level is
    /// covered by tile (col/2, row/2) of the next, whose pixels are a
    /// nearest-neighbour sample of it. Drawn meanwhile, they keep the view whole.
    pub fn stand_ins(&self, tiles: &[TileRef]) -> Vec<Arc<LoadedTile>> {
        let Ok(mut s) = self.state.lock() else {
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
        if let Ok(mut s) = self.state.lock() {
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
            }
            evict(&mut s, self.budget);
        }
        Ok(out)
    }

    /// Errors from workers since the last call.
    pub fn take_errors(&self) -> Vec<StoreError> {
        self.state
            .lock()
            .map(|mut s| std::mem::take(&mut s.errors))
            .unwrap_or_default()
    }

    pub fn stats(&self) -> CacheStats {
        let (tiles, bytes, pending) = self
            .state
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
        self.state
            .lock()
            .map(|s| s.tiles.keys().copied().collect())
            .unwrap_or_default()
    }

    /// Whether every tile of `tiles` is cached.
    pub fn has_all(&self, tiles: &[TileRef]) -> bool {
        self.state
            .lock()
            .map(|s| {
                tiles
                    .iter()
                    .all(|t| s.tiles.contains_key(&TileKey::from(t)))
            })
            .unwrap_or(false)
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
