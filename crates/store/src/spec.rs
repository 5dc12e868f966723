//! The file format's constants in one place: tags, metadata keys, layout numbers.
//! docs/format.md is the prose version of this file; the writer and the reader
//! both take every format decision from here.

/// Format version written in `PCIMG_FORMAT`; a reader refuses newer major versions.
/// Version 2 parts ([`COMPACT_VERSION`]) may hold tiles in row order
/// ([`key::TILE_ORDER`]) and coordinates on a lattice (band `SCALE` other than 1);
/// a part that uses neither is written as version 1, which older readers open.
pub const FORMAT_VERSION: u32 = 2;
/// The version of a part with row-ordered tiles or lattice coordinates.
pub const COMPACT_VERSION: u32 = 2;
/// The first version: Z-ordered tiles, coordinates relative to the origin.
pub const FIRST_VERSION: u32 = 1;

/// Tile edge in pixels (a power of two, so a tile holds one aligned Z-order block).
pub const TILE_LOG2: u32 = 8;
pub const TILE_SIZE: u32 = 1 << TILE_LOG2;
pub const TILE_PIXELS: usize = (TILE_SIZE * TILE_SIZE) as usize;
/// Bytes of one band's tile, uncompressed (`f32` samples).
pub const TILE_BYTES: u64 = (TILE_PIXELS * 4) as u64;

/// The band of GPS time (LAS `gps_time`): row-ordered tiles keep their points
/// in its order where a part has it.
pub const GPS_TIME_BAND: &str = "gps_time";

/// Bands every part starts with, in this order.
pub const COORDINATE_BANDS: [&str; 3] = ["x", "y", "z"];

/// `Software` tag written in every IFD; an overview without it was made by another
/// tool (gdaladdo) and carries no pcimg tile index.
pub const SOFTWARE_PREFIX: &str = "pcimg";

/// TIFF tags used by the format (numbers from TIFF 6.0, BigTIFF and GDAL).
pub mod tag {
    pub const NEW_SUBFILE_TYPE: u16 = 254;
    pub const IMAGE_WIDTH: u16 = 256;
    pub const IMAGE_LENGTH: u16 = 257;
    pub const BITS_PER_SAMPLE: u16 = 258;
    pub const COMPRESSION: u16 = 259;
    pub const PHOTOMETRIC: u16 = 262;
    pub const SAMPLES_PER_PIXEL: u16 = 277;
    pub const PLANAR_CONFIGURATION: u16 = 284;
    pub const SOFTWARE: u16 = 305;
    pub const PREDICTOR: u16 = 317;
    pub const TILE_WIDTH: u16 = 322;
    pub const TILE_LENGTH: u16 = 323;
    pub const TILE_OFFSETS: u16 = 324;
    pub const TILE_BYTE_COUNTS: u16 = 325;
    pub const EXTRA_SAMPLES: u16 = 338;
    pub const SAMPLE_FORMAT: u16 = 339;
    pub const GDAL_METADATA: u16 = 42112;
    pub const GDAL_NODATA: u16 = 42113;
    /// LERC's parameters (libtiff's `TIFFTAG_LERC_PARAMETERS`): LONG[2], the LERC
    /// version and the additional compression.
    pub const LERC_PARAMETERS: u16 = 50674;
}

/// TIFF compression codes.
pub mod compression {
    pub const NONE: u16 = 1;
    pub const ADOBE_DEFLATE: u16 = 8;
    pub const DEFLATE: u16 = 32946;
    pub const ZSTD: u16 = 50000;
    /// LERC (libtiff's `COMPRESSION_LERC`), parameters in [`super::tag::LERC_PARAMETERS`].
    pub const LERC: u16 = 34887;
}

/// Values of the `LercParameters` tag (libtiff's `tif_lerc.c`).
pub mod lerc {
    /// The LERC version libtiff names (`LERC_VERSION_2_4`); the blobs carry
    /// their own (Lerc2 v3 to v6, whatever each needs), which libtiff reads.
    pub const VERSION: u32 = 4;
    /// Additional compression of each blob: none, Deflate (zlib), Zstd.
    pub const ADD_NONE: u32 = 0;
    pub const ADD_DEFLATE: u32 = 1;
    pub const ADD_ZSTD: u32 = 2;
}

/// TIFF predictor codes.
pub mod predictor {
    pub const NONE: u16 = 1;
    pub const HORIZONTAL: u16 = 2;
    pub const FLOATING_POINT: u16 = 3;
}

/// GDAL_METADATA item names (default domain unless noted).
pub mod key {
    pub const FORMAT: &str = "PCIMG_FORMAT";
    pub const POINT_COUNT: &str = "POINT_COUNT";
    pub const ORIGIN: &str = "ORIGIN";
    pub const BOUNDS_MIN: &str = "BOUNDS_MIN";
    pub const BOUNDS_MAX: &str = "BOUNDS_MAX";
    pub const LEVEL_POINTS: &str = "LEVEL_POINTS";
    pub const LAYOUT: &str = "LAYOUT";
    pub const BANDS: &str = "BANDS";
    pub const SOURCE: &str = "SOURCE";
    pub const CRS: &str = "CRS";
    /// An upper bound of |value read - source value| for any coordinate, in
    /// source units: f32 storage relative to the origin, plus the codec's bound
    /// ([`CODEC_MAX_ERROR`]) where the codec is lossy.
    pub const MAX_QUANTIZATION_ERROR: &str = "MAX_QUANTIZATION_ERROR";
    /// LERC parts: the error bound each coordinate band's tiles were encoded
    /// with, `x y z` (0: lossless); attributes are always lossless. Absent for
    /// lossless codecs.
    pub const CODEC_MAX_ERROR: &str = "CODEC_MAX_ERROR";
    /// Points per classification code, `CODE:COUNT` pairs separated by spaces
    /// (codes ascending, absent codes left out), for parts with a
    /// `classification` band; counted when the part is written.
    pub const CLASS_COUNTS: &str = "CLASS_COUNTS";
    /// What a source says of itself, set by the readers on their columns' metadata
    /// (`VIEWPOINT` of PCD, `SCANS` of E57, `LAS_POINT_FORMAT` of LAS):
    /// defined beside the columns.
    pub use crate::points::key::{LAS_POINT_FORMAT, SCANS, VIEWPOINT};
    /// The items above: what a source says of itself, shown by `info`.
    pub const FROM_SOURCE: &[&str] = &[VIEWPOINT, SCANS, LAS_POINT_FORMAT];
    /// Per-band minimum and maximum of the stored values (before the band offset),
    /// as GDAL names its band statistics, so `gdalinfo` shows them.
    pub const STATISTICS_MINIMUM: &str = "STATISTICS_MINIMUM";
    pub const STATISTICS_MAXIMUM: &str = "STATISTICS_MAXIMUM";
    /// Per-level, per-tile bounds and counts (base64), in domain [`TILE_INDEX_DOMAIN`].
    pub const TILE_INDEX: &str = "TILE_INDEX";
    pub const TILE_INDEX_DOMAIN: &str = "pcimg";
    /// How a tile's points lie in its pixels: absent, along the tile's Z-order
    /// curve (point `i` at Morton pixel `i`); [`tile_order::ROWS`]: row-major,
    /// in an order the writer chose to make neighbours alike (version 2).
    pub const TILE_ORDER: &str = "TILE_ORDER";
    /// Row-ordered parts: the stored bytes of each level (the sum of its
    /// `TileByteCounts`), finest first, so overviews that another tool
    /// recomputed in place (`gdaladdo`) are recognised without decoding tiles.
    pub const LEVEL_BYTES: &str = "LEVEL_BYTES";
    /// Lattice coordinates: per coordinate band, the lattice of the source
    /// (`STEP ORIGIN`, the LAS scale and offset) from which GDAL's band scale and
    /// offset were rebased, so an exporter gives back the source's integers.
    pub const LATTICE: &str = "LATTICE";
    /// `1` where the coordinates were rounded onto `LATTICE` (`convert
    /// --precision`: each within half a step of the source, said in
    /// `MAX_QUANTIZATION_ERROR`) rather than found on it; absent otherwise.
    pub const LATTICE_ROUNDED: &str = "LATTICE_ROUNDED";
    /// Row-ordered parts: the bands (numbered from 1) that hold whole numbers
    /// stored plus [`super::WHOLE_BIAS`]: coordinates on a lattice (GDAL's band
    /// scale the step, its offset the lattice point of stored 0) and attributes
    /// of whole values (scale 1). GDAL's scale and offset give every band's
    /// true value; pcimg reads coordinates relative to `ORIGIN` and an
    /// attribute relative to its band offset plus 2^23.
    pub const WHOLE_BANDS: &str = "WHOLE_BANDS";
}

/// What row-ordered parts add to a whole number before storing it as an `f32`
/// ([`key::WHOLE_BANDS`]): 2^23, so that every stored value of such a band
/// has the same sign and exponent and the TIFF floating-point predictor's
/// byte planes hold the number's own bytes (sizes: bench/RESULTS.md,
/// "Compact storage"). Whole numbers in `[-2^23, 2^23)` are kept exactly.
pub const WHOLE_BIAS: f64 = 8_388_608.0;

/// Values of [`key::TILE_ORDER`].
pub mod tile_order {
    /// Row-major: the tile's `n` points are its first `n` pixels.
    pub const ROWS: &str = "rows";
}

/// Values of the `LAYOUT` item: how points are placed in the image. A part without
/// the item is read as [`layout::HILBERT`].
pub mod layout {
    /// Hilbert order along the image's Z-order curve, centroid representatives.
    pub const HILBERT: &str = "hilbert-centroid";
    /// The paper's placement: input order, row-major, plain nearest-neighbour
    /// pyramid (level k keeps pixel (2^k·i, 2^k·j) of level 0).
    pub const PAPER: &str = "paper";
}

/// Magic and version of the binary tile index blob.
pub const TILE_INDEX_MAGIC: &[u8; 4] = b"PCTI";
pub const TILE_INDEX_VERSION: u32 = 1;
