//! The multi-band image store: the file format (see docs/format.md), its writer and
//! its reader. Everything above the input readers goes through this module.

pub mod builder;
pub mod coarse;
pub mod codec;
pub mod crs;
pub mod error;
pub mod hilbert;
pub mod layout;
mod lerc_z;
pub mod metadata;
pub mod out;
pub mod paper;
mod remote_open;
pub mod sink;
mod source;
pub mod spec;
pub mod tiles;
pub mod writer;
pub mod zorder;

pub use builder::PartBuilder;
pub use codec::Compression;
pub use error::StoreError;
pub use layout::Layout;
pub use out::TileIo;
pub use writer::{
    PartSummary, WriteOptions, write_part, write_part_built, write_part_chunks, write_part_owned,
};
pub mod dataset;
pub mod ifd;
pub mod index;
pub mod overview;
pub mod read;
pub mod reader;
pub mod summary;

pub use dataset::{Dataset, Overview};
pub use read::Points;
pub use reader::{BandInfo, Level, Part, PartMeta, TileInfo};
