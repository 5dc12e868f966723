//! A COPC file (local or at a URL) as the viewer's tile source: its octree's
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

    /// Node `e` as a tile (given an id the first time).
    fn tile(&self, e: Entry) -> SourceTile {
        let mut r = self.nodes.lock().unwrap_or_else(|p| p.into_inner());
        let id = match r.ids.get(&e.key) {
            Some(&id) => id,
            None => {
                let id = r.entries.len() as u32;
                r.entries.push(e);
                r.ids.insert(e.key, id);
                id
            }
        };
        let (lo, hi) = e.key.bounds(&self.copc.info);
        let b = &self.bounds;
        SourceTile {
            id,
            depth: e.key.d.max(0) as usize,
            bounds: Bounds {
                min: std::array::from_fn(|a| lo[a].max(b.min[a]).min(b.max[a])),
                max: std::array::from_fn(|a| hi[a].min(b.max[a]).max(b.min[a])),
            },
            points: u64::from(e.points),
        }
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
        let rel = |v: &[f64], a: usize| v.iter().map(|&x| (x - o[a]) as f32).collect::<Vec<_>>();
        let mut p = Points {
            bands: vec!["x".into(), "y".into(), "z".into()],
            offsets: o.to_vec(),
            columns: vec![rel(&cols.x, 0), rel(&cols.y, 1), rel(&cols.z, 2)],
            tile_points: vec![cols.len() as u32],
        };
        for a in cols.attributes {
            if bands.contains(&a.name) {
                p.bands.push(a.name);
                p.offsets.push(a.offset);
                p.columns.push(a.values);
            }
        }
        Ok(p)
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
        let mut depths: Vec<(usize, u64)> = Vec::new();
        for e in &r.entries {
            let d = e.key.d.max(0) as usize;
            if depths.len() <= d {
                depths.resize(d + 1, (0, 0));
            }
            depths[d].0 += 1;
            depths[d].1 += u64::from(e.points);
        }
        SourceStats {
            format: "COPC".into(),
            depths,
            pages: self.copc.pages(),
        }
    }
}

/// The COPC file at `path` (local, or a URL once `cli::remote::read_url_inputs`
/// set how URLs are read) as a dataset of its octree's nodes.
pub fn open(path: &Path) -> anyhow::Result<Dataset> {
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
    let totals = Totals {
        parts: 0,
        nodes: 0,
        points: h.points,
        bytes: copc.len,
        bounds,
        own_levels: 1,
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
    Ok(Dataset::from_source(path, totals, Arc::new(tiles)))
}
