//! A COPC file or an EPT dataset (local or at a URL) as the viewer's tile source: its octree's
//! nodes are tiles, selected, cached and drawn as parts' tiles are
//! (`store::TileSource`). The hierarchy is read as views reach it (the root
//! page when opened); a node is fetched, decompressed (only the fields the
//! frame draws) and decoded when the cache loads it, on the loading threads.
//!
//! Here, in the binary, because this is where a reader (`pcimg-ingest`'s COPC
//! decoding) meets the store's tiles.

use crate::ingest::copc::NodeDecoder;
use crate::points::Bounds;
use crate::store::{Dataset, Points, SourceStats, SourceTile, StoreError, TileSource, Totals};
use pcimg_copc::{Copc, Entry, Key};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// The nodes handed out so far, by id.
#[derive(Debug, Default)]
struct Registry {
    entries: Vec<Entry>,
    ids: HashMap<Key, u32>,
}

impl Registry {
    /// Node `e`'s id (given the first time).
    fn id_of(&mut self, e: Entry) -> u32 {
        if let Some(&id) = self.ids.get(&e.key) {
            return id;
        }
        let id = self.entries.len() as u32;
        self.entries.push(e);
        self.ids.insert(e.key, id);
        id
    }
}

/// Node `key` with id `id` as a tile: its cube cut to the points' bounds `b`
/// (views cull by where points are).
fn source_tile(id: u32, key: Key, cube: pcimg_copc::Cube, b: &Bounds, points: u64) -> SourceTile {
    let (lo, hi) = cube;
    SourceTile {
        id,
        depth: key.d.max(0) as usize,
        bounds: Bounds {
            min: std::array::from_fn(|a| lo[a].max(b.min[a]).min(b.max[a])),
            max: std::array::from_fn(|a| hi[a].min(b.max[a]).max(b.min[a])),
        },
        points,
    }
}

#[derive(Debug)]
pub struct CopcTiles {
    copc: Arc<Copc>,
    decoder: NodeDecoder,
    path: PathBuf,
    /// The points' bounds (the header's): a node's cube is cut to them, so
    /// that views cull by where points are.
    bounds: Bounds,
    nodes: Mutex<Registry>,
    /// At a URL: chunks are read ahead in batches.
    remote: bool,
}

impl CopcTiles {
    fn err(&self, e: impl std::fmt::Display) -> StoreError {
        StoreError::new(&self.path, e.to_string())
    }

    /// Node `e` as a tile.
    fn tile(&self, e: Entry) -> SourceTile {
        let id = self
            .nodes
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .id_of(e);
        let cube = e.key.bounds(&self.copc.info);
        source_tile(id, e.key, cube, &self.bounds, u64::from(e.points))
    }

    fn entry(&self, id: u32) -> Result<Entry, StoreError> {
        let r = self.nodes.lock().unwrap_or_else(|p| p.into_inner());
        r.entries
            .get(id as usize)
            .copied()
            .ok_or_else(|| StoreError::new(&self.path, format!("has no octree node {id}")))
    }
}

impl TileSource for CopcTiles {
    fn roots(&self) -> Vec<SourceTile> {
        vec![self.tile(self.copc.root())]
    }

    fn children(&self, id: u32) -> crate::store::Result<Vec<SourceTile>> {
        let e = self.entry(id)?;
        let kids = self.copc.children(&e.key).map_err(|e| self.err(e))?;
        Ok(kids.into_iter().map(|k| self.tile(k)).collect())
    }

    fn load(&self, id: u32, bands: &[String]) -> crate::store::Result<Points> {
        let e = self.entry(id)?;
        let cols = self
            .decoder
            .read(&self.copc, &e, bands)
            .map_err(|e| self.err(e))?;
        // Relative to the node's cube's centre: f32 keeps its points to well
        // under the file's scale.
        let (lo, hi) = e.key.bounds(&self.copc.info);
        let o: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
        Ok(points_of(cols, o, bands))
    }

    fn prefetch(&self, ids: &[u32]) {
        if !self.remote {
            return;
        }
        let entries: Vec<Entry> = ids.iter().filter_map(|&id| self.entry(id).ok()).collect();
        // (A failure is met again, and reported, by the tile's own load.)
        let _ = self.copc.fetch(&entries);
    }

    fn stats(&self) -> SourceStats {
        let r = self.nodes.lock().unwrap_or_else(|p| p.into_inner());
        SourceStats {
            format: "COPC file".into(),
            depths: depths_of(&r.entries),
            pages: self.copc.pages(),
        }
    }
}

/// The COPC file at `path` (local, or a URL once `cli::remote::read_url_inputs`
/// set how URLs are read) as a dataset of its octree's nodes.
pub fn open(path: &Path) -> anyhow::Result<Dataset> {
    let (tiles, totals) = CopcTiles::open(path)?;
    Ok(Dataset::from_source(path, totals, Arc::new(tiles)))
}

impl CopcTiles {
    /// The COPC file at `path` (local or a URL) as tiles, and its totals.
    pub fn open(path: &Path) -> anyhow::Result<(CopcTiles, Totals)> {
        let copc = crate::ingest::copc::open_any(path)?;
        let decoder = NodeDecoder::new(&copc)?;
        let (crs, _) = crate::ingest::copc::describe(&copc)?;
        let h = &copc.header;
        let bounds = Bounds {
            min: h.min,
            max: h.max,
        };
        let mut bands: Vec<String> = ["x", "y", "z"].map(String::from).to_vec();
        bands.extend(decoder.names().iter().cloned());
        // Depths the root hierarchy page knows (`--lod N` counts from the finest).
        let known = deepest_known(|k| copc.known(k).map(|e| e.key));
        let totals = Totals {
            parts: 0,
            nodes: 0,
            points: h.points,
            bytes: copc.len,
            bounds,
            own_levels: known,
            crs,
            class_counts: Vec::new(),
            ranges: vec![None; bands.len()],
            bands,
            classes_complete: false,
            level_points: Vec::new(),
        };
        let tiles = CopcTiles {
            copc,
            decoder,
            path: path.to_path_buf(),
            bounds,
            nodes: Mutex::new(Registry::default()),
            remote: crate::ingest::is_url(path),
        };
        Ok((tiles, totals))
    }

    /// The nodes handed out so far: `(nodes, points)` at each depth.
    pub fn depths(&self) -> Vec<(usize, u64)> {
        depths_of(&self.nodes.lock().unwrap_or_else(|p| p.into_inner()).entries)
    }
}

/// An EPT dataset (its `ept.json`, local or at a URL) as the viewer's tile
/// source: its octree's nodes are tiles, each node's LAZ file read when the
/// cache loads it.
#[derive(Debug)]
pub struct EptTiles {
    ept: crate::ingest::ept::Ept,
    path: PathBuf,
    gps_offset: f64,
    nodes: Mutex<Registry>,
}

impl EptTiles {
    fn err(&self, e: impl std::fmt::Display) -> StoreError {
        StoreError::new(&self.path, e.to_string())
    }

    fn tile(&self, n: crate::ingest::ept::Node) -> SourceTile {
        let id = self
            .nodes
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .id_of(Entry {
                key: n.key,
                offset: 0,
                bytes: 0,
                points: n.points.min(u64::from(u32::MAX)) as u32,
            });
        source_tile(
            id,
            n.key,
            self.ept.cube_of(&n.key),
            &self.ept.bounds,
            n.points,
        )
    }

    fn node(&self, id: u32) -> Result<crate::ingest::ept::Node, StoreError> {
        let r = self.nodes.lock().unwrap_or_else(|p| p.into_inner());
        r.entries
            .get(id as usize)
            .map(|e| crate::ingest::ept::Node {
                key: e.key,
                points: u64::from(e.points),
            })
            .ok_or_else(|| StoreError::new(&self.path, format!("has no octree node {id}")))
    }
}

impl TileSource for EptTiles {
    fn roots(&self) -> Vec<SourceTile> {
        vec![self.tile(self.ept.root())]
    }

    fn children(&self, id: u32) -> crate::store::Result<Vec<SourceTile>> {
        let n = self.node(id)?;
        let kids = self.ept.children(&n.key).map_err(|e| self.err(e))?;
        Ok(kids.into_iter().map(|k| self.tile(k)).collect())
    }

    fn load(&self, id: u32, bands: &[String]) -> crate::store::Result<Points> {
        let n = self.node(id)?;
        let cols = self
            .ept
            .read(&n, self.gps_offset)
            .map_err(|e| self.err(e))?;
        let (lo, hi) = self.ept.cube_of(&n.key);
        let o: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
        Ok(points_of(cols, o, bands))
    }

    fn stats(&self) -> SourceStats {
        let r = self.nodes.lock().unwrap_or_else(|p| p.into_inner());
        SourceStats {
            format: "EPT dataset".into(),
            depths: depths_of(&r.entries),
            pages: self.ept.hierarchy_files(),
        }
    }
}

/// Columns as a tile's points: x, y, z relative to `o`, and the bands asked
/// for that they have.
fn points_of(cols: crate::points::PointColumns, o: [f64; 3], bands: &[String]) -> Points {
    let rel = |v: &[f64], a: usize| v.iter().map(|&x| (x - o[a]) as f32).collect::<Vec<_>>();
    let mut p = Points {
        bands: vec!["x".into(), "y".into(), "z".into()],
        offsets: o.to_vec(),
        columns: vec![rel(&cols.x, 0), rel(&cols.y, 1), rel(&cols.z, 2)],
        tile_points: vec![cols.len() as u32],
    };
    for a in cols.attributes {
        if bands.contains(&a.name) && !crate::time::is_exact_band(&a.name) {
            p.bands.push(a.name);
            p.offsets.push(a.offset);
            p.columns.push(a.values);
        }
    }
    p
}

/// Depths reachable from the root through nodes `known` knows, counted.
fn deepest_known(known: impl Fn(&Key) -> Option<Key>) -> usize {
    let mut level = vec![Key::ROOT];
    let mut depths = 0;
    while !level.is_empty() {
        depths += 1;
        level = level
            .iter()
            .flat_map(|k| k.children())
            .filter_map(|k| known(&k))
            .collect();
    }
    depths
}

/// `(nodes, points)` at each depth of `entries`.
fn depths_of(entries: &[Entry]) -> Vec<(usize, u64)> {
    let mut depths: Vec<(usize, u64)> = Vec::new();
    for e in entries {
        let d = e.key.d.max(0) as usize;
        if depths.len() <= d {
            depths.resize(d + 1, (0, 0));
        }
        depths[d].0 += 1;
        depths[d].1 += u64::from(e.points);
    }
    depths
}

/// The EPT dataset whose `ept.json` is at `path` as a dataset of its nodes.
pub fn open_ept(path: &Path) -> anyhow::Result<Dataset> {
    let ept = crate::ingest::ept::Ept::open(path)?;
    let (names, gps_offset) = ept.probe()?;
    let mut bands: Vec<String> = ["x", "y", "z"].map(String::from).to_vec();
    bands.extend(names);
    let known = deepest_known(|k| ept.known(k).map(|n| n.key));
    let totals = Totals {
        parts: 0,
        nodes: 0,
        points: ept.points,
        bytes: 0,
        bounds: ept.bounds,
        own_levels: known,
        crs: ept.srs.clone(),
        class_counts: Vec::new(),
        ranges: vec![None; bands.len()],
        bands,
        classes_complete: false,
        level_points: Vec::new(),
    };
    let tiles = EptTiles {
        ept,
        path: path.to_path_buf(),
        gps_offset,
        nodes: Mutex::new(Registry::default()),
    };
    Ok(Dataset::from_source(path, totals, Arc::new(tiles)))
}
