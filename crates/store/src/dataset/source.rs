//! Tiles from outside the store: the hierarchy another format already keeps
//! (COPC's octree; EPT's), drawn through the same level selection, tile
//! cache, loading threads and frame pipeline as parts.
//!
//! A [`TileSource`] gives its root tiles, each tile's children (read as the
//! view reaches them) and a tile's points. Its tiles are named in tile
//! references by `part` [`SOURCE_PART`], `level` the tile's depth and
//! `tile` the source's own id. Refinement is additive where the source says so,
//! tile by tile (a COPC node's points are not repeated in its children: a finer
//! view draws the node and its children), and replaces a tile by its children
//! elsewhere, as a part's pyramid does (a survey's overview nodes above its
//! COPC files).
//!
//! The store implements no source itself: the binary, where readers and the
//! store meet, implements the COPC one over `pcimg-copc` and `pcimg-ingest`.

use crate::error::Result;
use crate::points::Bounds;
use crate::read::points::Points;

/// The `part` of every tile reference to a source's tile.
pub const SOURCE_PART: usize = usize::MAX;

/// A tile of a source: its id, depth (0 at the roots), bounds and points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourceTile {
    pub id: u32,
    pub depth: usize,
    pub bounds: Bounds,
    pub points: u64,
}

/// What a source says of itself for panels and reports: tiles known at each
/// depth and their points (those read so far: a source reads its hierarchy as
/// views reach it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SourceStats {
    /// What the source is, as a panel's title says it ("COPC file").
    pub format: String,
    /// `(tiles, points)` known at each depth.
    pub depths: Vec<(usize, u64)>,
    /// Hierarchy pages read, and known but not yet read.
    pub pages: (usize, usize),
}

/// A hierarchy of tiles kept by another format.
pub trait TileSource: Send + Sync + std::fmt::Debug {
    /// The tiles a view starts from.
    fn roots(&self) -> Vec<SourceTile>;
    /// The children of tile `id` (reading the hierarchy where needed).
    fn children(&self, id: u32) -> Result<Vec<SourceTile>>;
    /// Whether tile `id`'s own points stay drawn when it is refined (a COPC
    /// or EPT node: yes; an overview node, a sample of its children's
    /// points: no, its children replace it).
    fn additive(&self, _id: u32) -> bool {
        true
    }
    /// Tile `id`'s points: x, y, z relative to an origin (the columns'
    /// offsets) and the bands of `bands` it has.
    fn load(&self, id: u32, bands: &[String]) -> Result<Points>;
    /// Reads ahead the bytes of tiles `ids`, about to be loaded one by one:
    /// a remote source fetches them as one batch (near ranges merged, the
    /// rest concurrent), whose bytes the loads then find in its cache.
    fn prefetch(&self, _ids: &[u32]) {}
    /// What the source has read of its hierarchy.
    fn stats(&self) -> SourceStats;
    /// The file tile `id`'s points come from, where the source has several
    /// (a survey's COPC files); `None`: the source's own path.
    fn file_of(&self, _id: u32) -> Option<String> {
        None
    }
}
