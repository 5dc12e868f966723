//! The multi-band image store: the file format (see docs/format.md), its writer and
//! its reader. Everything above the input readers goes through this crate.
//!
//! The folders say what they are:
//! * [`tiff`]: the TIFF layer: directories, tile codecs, pixel geometry, metadata;
//! * [`write`]: ordering a part's points and writing it;
//! * [`read`]: opening a part and reading its points, from a file or object storage;
//! * [`dataset`]: many parts as one: the index, the overview nodes above them;
//! * `remote` (feature `remote`): object storage, the byte source of remote reads.
//!
//! What a program uses is at the root: opening ([`Dataset::open`]: a part, a
//! folder, or with `remote` a URL), a part's levels, tiles and bands ([`Part`],
//! [`Level`], [`TileInfo`], [`BandInfo`], [`PartMeta`]), reading
//! ([`Part::read_level`], [`Part::read_tiles`], [`Points`]), writing
//! ([`write_part`], [`PartBuilder`], [`WriteOptions`], [`Layout`],
//! [`Compression`]), indexing ([`build_index`]) and errors ([`StoreError`] with
//! the [`Remedy`] that would put it right). The format's own names are public
//! too: [`spec`] (tags, metadata keys), [`tiff::ifd`] and [`tiff::zorder`] (the
//! directory parser and pixel geometry a third-party reader needs) and
//! [`dataset::index`] (the index file). Everything else is `pub(crate)`.
//!
//! Write a part, open it as a dataset (a part, a directory of parts, or with
//! `remote` a URL), walk its levels and tiles, and read columns back:
//!
//! ```
//! use pcimg_core::points::{Attribute, PointColumns};
//! use pcimg_store::{Dataset, WriteOptions, write_part};
//!
//! // 10 000 points on a slope, with an intensity.
//! let n = 10_000;
//! let x: Vec<f64> = (0..n).map(|i| 500_000.0 + (i % 100) as f64).collect();
//! let y: Vec<f64> = (0..n).map(|i| 4_000_000.0 + (i / 100) as f64).collect();
//! let z: Vec<f64> = x.iter().map(|x| 0.1 * (x - 500_000.0)).collect();
//! let intensity = Attribute { name: "intensity".into(), offset: 0.0, values: vec![7.0; n] };
//! let points = PointColumns { x, y, z, attributes: vec![intensity] };
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("slope.tif");
//! write_part(&path, &points, &WriteOptions::default())?;
//!
//! let ds = Dataset::open(&path)?;
//! assert_eq!(ds.points(), n as u64);
//! // (Parts are named by ids; `parts()` lists every one, reading every page
//! // of a paged index.)
//! let part = ds.parts()?[0];
//! for level in &part.levels {
//!     for tile in &level.tiles {
//!         assert!(tile.bounds.min[2] <= tile.bounds.max[2]);
//!     }
//! }
//! // Every point of level 0: x y z and intensity, as f32 plus each band's offset.
//! let bands = part.band_indices(&["x", "y", "z", "intensity"])?;
//! let read = part.read_level(0, &bands)?;
//! assert_eq!(read.len(), n);
//! assert!(read.column("intensity").unwrap().iter().all(|&v| v == 7.0));
//! // Or only the first tile of the coarsest level.
//! let top = part.levels.len() - 1;
//! let some = part.read_tiles(top, &[0], &bands)?;
//! assert!(some.len() <= n);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

#[cfg(test)]
use pcimg_core::rng;
use pcimg_core::{alloc, bigvec, clock, points, text};

pub mod crs;
pub mod dataset;
mod error;
pub mod location;
pub mod query;
mod read;
#[cfg(feature = "remote")]
pub mod remote;
/// Without the `remote` feature: the remote types exist, but no value of them
/// can, so every remote path is unreachable (and opening a URL is an error).
#[cfg(not(feature = "remote"))]
pub mod remote {
    /// An object in object storage (never made without the `remote` feature).
    #[derive(Debug)]
    pub enum RemoteFile {}
}
pub mod spec;
pub mod tiff;
pub mod write;

pub use dataset::overview::{
    GROUP_POINTS, IndexOptions, IndexReport, MAX_CHILDREN, append as append_columns, build_index,
    group_compact, next_coarser,
};
pub use dataset::paged::Totals;
pub use dataset::source::{SOURCE_PART, SourceStats, SourceTile, TileSource};
pub use dataset::{Dataset, LayerSummary, Node, OpenOptions, PartHeader};
pub use error::{Remedy, Result, StoreError};
pub use read::part::{BandInfo, Level, Part, PartMeta, TileInfo};
pub use read::points::Points;
pub use tiff::codec::{Compression, ZSTD_FAST, ZSTD_SMALL, compression_name, level_codec_name};
pub use write::builder::{PartBuilder, packed_size};
pub use write::layout::Layout;
pub use write::out::TileIo;
pub use write::part::{
    INTERRUPTED, PartSummary, WriteOptions, lattice_extent, write_part, write_part_built,
    write_part_chunks, write_part_owned,
};
