//! Opening one part: its headers only (levels, bands, metadata, tile index), and
//! the types that describe it. Reading its points is `read.rs`. Files rewritten by
//! GDAL (pixel-interleaved, recompressed, overviews rebuilt by gdaladdo) open
//! too.

use crate::error::{Result, StoreError};
use crate::points::Bounds;
use crate::spec::{self, key, tag};
use crate::tiff::ifd::{Ifd, Tiff};
use crate::tiff::metadata::{self, LevelIndex};
use crate::tiff::zorder::shared_tile_z_to_raster;
use memmap2::Mmap;
use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Dataset-level metadata of a part.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PartMeta {
    pub format_version: u32,
    pub point_count: u64,
    pub origin: [f64; 3],
    pub bounds: Bounds,
    pub level_points: Vec<u64>,
    pub layout: String,
    pub source: Option<String>,
    pub crs: Option<String>,
    pub max_quantization_error: Option<f64>,
    /// The LERC codecs' error bound of each coordinate band (`CODEC_MAX_ERROR`),
    /// for parts written with one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub codec_max_error: Option<[f64; 3]>,
    /// Points per classification code (`CLASS_COUNTS`), codes ascending; empty
    /// when the part has no classification band or predates the item.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub class_counts: Vec<(u8, u64)>,
    /// The items the source gave about itself (`key::FROM_SOURCE`: a PCD
    /// viewpoint, E57 scans), name and value.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub from_source: Vec<(String, String)>,
    /// The source's coordinate lattice (`LATTICE`), for parts that keep their
    /// coordinates on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<crate::points::Lattice>,
    /// The coordinates were rounded onto [`Self::lattice`] (`--precision`,
    /// `LATTICE_ROUNDED`), not found on it: within half a step of the source.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lattice_rounded: bool,
    /// Every default-domain item, as stored (unsanitized: sanitize before display).
    /// Not kept in the dataset index (the fields above are): empty for a part
    /// opened from it.
    #[serde(skip)]
    pub items: BTreeMap<String, String>,
}

/// One band: its name and the offset added to every stored value.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BandInfo {
    pub name: String,
    pub offset: f64,
    /// Smallest and largest value in source units (stored value + offset), when
    /// the part records them (GDAL's `STATISTICS_MINIMUM` / `_MAXIMUM`).
    pub range: Option<(f64, f64)>,
    /// A band of whole numbers (format version 2: coordinates on a lattice,
    /// whole attributes): `(step, zero)`, GDAL's band scale and offset, the true
    /// value of stored `s` being `zero + step · s`; the reader gives
    /// `zero - offset + step · s`, relative to [`BandInfo::offset`] like every
    /// other band (the part's origin for coordinates).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<(f64, f64)>,
}

impl BandInfo {
    /// The map from a stored value to the value read (`step`, `shift`:
    /// `stored · step + shift`), for a band on a lattice.
    pub(crate) fn stored_map(&self) -> Option<(f64, f64)> {
        self.lattice.map(|(step, base)| (step, base - self.offset))
    }
}

/// One tile of a level that holds data. The dataset index stores it as a row
/// `[index, points, min, max]` (thousands of them: a row parses faster than an
/// object).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(from = "TileRow", into = "TileRow")]
pub struct TileInfo {
    /// Raster index (`row * tiles_across + col`).
    pub index: u32,
    /// Points in the tile, when the tile index knows them.
    pub points: Option<u32>,
    /// Bounds of the points the tile stands for (the part's bounds without an index).
    pub bounds: Bounds,
}

/// [`TileInfo`] as the index stores it.
type TileRow = (u32, Option<u32>, [f64; 3], [f64; 3]);

impl From<TileRow> for TileInfo {
    fn from((index, points, min, max): TileRow) -> Self {
        TileInfo {
            index,
            points,
            bounds: Bounds { min, max },
        }
    }
}

impl From<TileInfo> for TileRow {
    fn from(t: TileInfo) -> Self {
        (t.index, t.points, t.bounds.min, t.bounds.max)
    }
}

/// One pyramid level (one IFD). The dataset index stores it without its index
/// and the file positions of its tiles, which the part's file gives.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Level {
    #[serde(skip)]
    pub index: usize,
    pub width: u32,
    pub height: u32,
    pub tile_width: u32,
    pub tile_height: u32,
    pub tiles_across: u32,
    pub tiles_down: u32,
    pub compression: u16,
    pub predictor: u16,
    /// LERC tiles: the additional compression of each blob (`spec::lerc`; the
    /// second value of the `LercParameters` tag, none without it).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lerc_extra: u32,
    pub planar_separate: bool,
    /// Points in the level, when known (pcimg's own levels).
    pub points: Option<u64>,
    /// Stored bytes of all tiles of all bands.
    pub bytes: u64,
    /// Whether tile points and bounds come from the pcimg tile index.
    pub indexed: bool,
    /// Tiles holding data, in reading order (Z-order where the grid allows).
    pub tiles: Vec<TileInfo>,
    #[serde(skip)]
    pub(crate) offsets: Vec<u64>,
    #[serde(skip)]
    pub(crate) counts: Vec<u64>,
    /// For square power-of-two tiles: raster offset of each Z-rank in a tile.
    #[serde(skip)]
    pub(crate) z_lut: Option<Arc<Vec<u32>>>,
    /// Row-ordered tiles (format version 2): `z_lut` is the identity.
    #[serde(skip)]
    pub(crate) row_order: bool,
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

/// One part (one TIFF file), opened with headers only.
pub struct Part {
    pub path: PathBuf,
    pub file_bytes: u64,
    pub bigtiff: bool,
    pub little_endian: bool,
    pub meta: PartMeta,
    pub bands: Vec<BandInfo>,
    pub levels: Vec<Level>,
    /// Samples per pixel of each level (the band count).
    pub(crate) samples: usize,
    pub(crate) map: Arc<Bytes>,
    /// A part described by the dataset index: its headers are read on its first
    /// tile read (`summary.rs`).
    pub(crate) lazy: Option<Arc<crate::dataset::summary::Deferred>>,
    /// Where tiles are read from for a part in object storage (its `map` then
    /// holds only the head: headers and tile index).
    pub(crate) remote: Option<Arc<crate::remote::RemoteFile>>,
}

/// The bytes of a part: a read-only memory map, or a buffer (tests, fuzzing).
pub(crate) enum Bytes {
    Map(Mmap),
    Owned(Vec<u8>),
}

impl Bytes {
    /// Advice on the whole map (a memory map's only: a buffer has none).
    fn advise(&self, advice: memmap2::Advice) {
        if let Bytes::Map(m) = self {
            let _ = m.advise(advice);
        }
    }

    /// Asks the kernel to read `len` bytes at `offset` now, in one request
    /// (`MADV_WILLNEED`), before they are touched: a fault then finds its page
    /// cached and reads nothing ahead of it.
    pub(crate) fn will_need(&self, offset: u64, len: u64) {
        if let Bytes::Map(m) = self
            && len > 0
            && offset.saturating_add(len) <= m.len() as u64
        {
            let (o, n) = (offset as usize, len as usize);
            let _ = m.advise_range(memmap2::Advice::WillNeed, o, n);
        }
    }
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Map(m) => m,
            Bytes::Owned(v) => v,
        }
    }
}

impl std::fmt::Debug for Part {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Part")
            .field("path", &self.path)
            .field("points", &self.meta.point_count)
            .field("levels", &self.levels.len())
            .finish()
    }
}

fn parse_meta(items: &BTreeMap<String, String>) -> std::result::Result<PartMeta, String> {
    let get = |k: &str| {
        items
            .get(k)
            .ok_or_else(|| format!("metadata item {k} is missing"))
    };
    let format_version: u32 = get(key::FORMAT)?
        .trim()
        .parse()
        .map_err(|_| format!("metadata {} is not a number", key::FORMAT))?;
    if format_version > spec::FORMAT_VERSION {
        return Err(format!(
            "format version {format_version} is newer than this version reads ({})",
            spec::FORMAT_VERSION
        ));
    }
    let point_count: u64 = get(key::POINT_COUNT)?
        .trim()
        .parse()
        .map_err(|_| format!("metadata {} is not a count", key::POINT_COUNT))?;
    let v3 = |k: &str| -> std::result::Result<[f64; 3], String> {
        let v = metadata::parse_f64s(get(k)?, 3, k)?;
        Ok([v[0], v[1], v[2]])
    };
    let level_points: std::result::Result<Vec<u64>, _> = get(key::LEVEL_POINTS)?
        .split_whitespace()
        .map(str::parse)
        .collect();
    let finite = |k: &str| -> std::result::Result<[f64; 3], String> {
        let v = v3(k)?;
        if v.iter().all(|c| c.is_finite()) {
            Ok(v)
        } else {
            Err(format!("metadata {k} is not three finite numbers"))
        }
    };
    // (A part without points has empty bounds: +inf and -inf.)
    let corner = |k: &str| if point_count > 0 { finite(k) } else { v3(k) };
    let bounds = Bounds {
        min: corner(key::BOUNDS_MIN)?,
        max: corner(key::BOUNDS_MAX)?,
    };
    if point_count > 0 && (0..3).any(|a| bounds.min[a] > bounds.max[a]) {
        return Err(format!(
            "metadata {} lies above {} on some axis",
            key::BOUNDS_MIN,
            key::BOUNDS_MAX
        ));
    }
    Ok(PartMeta {
        format_version,
        point_count,
        origin: finite(key::ORIGIN)?,
        bounds,
        level_points: level_points
            .map_err(|_| format!("metadata {} is not a list of counts", key::LEVEL_POINTS))?,
        layout: items.get(key::LAYOUT).cloned().unwrap_or_default(),
        source: items.get(key::SOURCE).cloned(),
        crs: items.get(key::CRS).cloned(),
        max_quantization_error: items
            .get(key::MAX_QUANTIZATION_ERROR)
            .and_then(|s| s.trim().parse().ok()),
        codec_max_error: items
            .get(key::CODEC_MAX_ERROR)
            .and_then(|s| metadata::parse_f64s(s, 3, key::CODEC_MAX_ERROR).ok())
            .map(|v| [v[0], v[1], v[2]]),
        class_counts: items
            .get(key::CLASS_COUNTS)
            .map(|s| metadata::parse_class_counts(s))
            .transpose()?
            .unwrap_or_default(),
        from_source: key::FROM_SOURCE
            .iter()
            .filter_map(|k| items.get(*k).map(|v| (k.to_string(), v.clone())))
            .collect(),
        lattice: items
            .get(key::LATTICE)
            .map(|s| metadata::parse_f64s(s, 6, key::LATTICE))
            .transpose()?
            .map(|v| crate::points::Lattice {
                step: [v[0], v[1], v[2]],
                origin: [v[3], v[4], v[5]],
            }),
        lattice_rounded: items.get(key::LATTICE_ROUNDED).is_some_and(|v| v == "1"),
        items: items.clone(),
    })
}

impl Part {
    /// Opens a part, reading headers only.
    pub fn open(path: &Path) -> Result<Part> {
        let err = |m: String| StoreError::new(path, m);
        let file = File::open(path).map_err(|e| err(format!("cannot open: {e}")))?;
        let file_bytes = file
            .metadata()
            .map_err(|e| err(format!("cannot stat: {e}")))?
            .len();
        if file_bytes == 0 {
            return Err(err("file is empty".into()));
        }
        // SAFETY: the map is read-only; pcimg writes parts under a temporary name
        // and renames them, so a part is never modified in place while mapped.
        // A file truncated by someone else while mapped can fault; that is the
        // documented limit of memory-mapped I/O.
        let map = unsafe { Mmap::map(&file) }.map_err(|e| err(format!("cannot map: {e}")))?;
        let map = Bytes::Map(map);
        // Headers are read without read-ahead (a disk's 8 MiB would read a whole
        // part for its header); tiles then with the default, after asking for
        // their chunks (`will_need`), so a fault maps its neighbours too.
        map.advise(memmap2::Advice::Random);
        let part = Self::parse(path, map)?;
        part.map.advise(memmap2::Advice::Normal);
        Ok(part)
    }

    /// Opens a part held in memory; `name` stands for the file in messages.
    pub fn from_bytes(name: &Path, bytes: Vec<u8>) -> Result<Part> {
        if bytes.is_empty() {
            return Err(StoreError::new(name, "file is empty"));
        }
        Self::parse(name, Bytes::Owned(bytes))
    }

    pub(crate) fn parse(path: &Path, map: Bytes) -> Result<Part> {
        let err = |m: String| StoreError::new(path, m);
        let data: &[u8] = &map;
        let file_bytes = data.len() as u64;
        let tiff = Tiff::parse(data).map_err(err)?;
        let first = &tiff.ifds[0];
        let xml = tiff
            .ascii(data, first, tag::GDAL_METADATA)
            .map_err(err)?
            .ok_or_else(|| {
                err("not a pcimg part: no GDAL_METADATA tag (is this a plain image?)".into())
            })?;
        let items = metadata::from_xml(&xml).map_err(err)?;
        let ds_items = metadata::dataset_items(&items);
        if !metadata::is_pcimg(&ds_items) {
            return Err(err(format!(
                "not a pcimg part: GDAL_METADATA has no {} item",
                key::FORMAT
            )));
        }
        let meta = parse_meta(&ds_items).map_err(|m| {
            let newer = ds_items
                .get(key::FORMAT)
                .and_then(|v| v.trim().parse::<u32>().ok())
                .is_some_and(|v| v > spec::FORMAT_VERSION);
            let e = err(format!("bad metadata: {m}"));
            if newer {
                e.with_remedy(crate::error::Remedy::Upgrade)
            } else {
                e
            }
        })?;
        let names = metadata::band_items(&items, "description");
        let offsets = metadata::band_items(&items, "offset");
        let scales = metadata::band_items(&items, "scale");
        let whole: Vec<usize> = match meta.items.get(key::WHOLE_BANDS) {
            Some(list) if meta.format_version >= spec::COMPACT_VERSION => list
                .split_whitespace()
                .map(|v| v.parse::<usize>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    err(format!(
                        "metadata {} is not a list of band numbers",
                        key::WHOLE_BANDS
                    ))
                })?,
            _ => Vec::new(),
        };
        let minima = metadata::band_named(&items, key::STATISTICS_MINIMUM);
        let maxima = metadata::band_named(&items, key::STATISTICS_MAXIMUM);
        let samples = tiff
            .uint(data, first, tag::SAMPLES_PER_PIXEL)
            .map_err(err)?
            .unwrap_or(1) as usize;
        let listed: Vec<&str> = ds_items
            .get(key::BANDS)
            .map(|s| s.split_whitespace().collect())
            .unwrap_or_default();
        if samples > 256 {
            return Err(err(format!("has {samples} bands; pcimg reads at most 256")));
        }
        if samples < 3 {
            return Err(err(format!(
                "has {samples} band(s); a part needs at least x, y and z"
            )));
        }
        if !listed.is_empty() && listed.len() != samples {
            return Err(err(format!(
                "metadata lists {} bands ({}) but the image has {samples}",
                listed.len(),
                listed.join(" ")
            )));
        }
        let mut bands = Vec::with_capacity(samples);
        for b in 0..samples {
            let name = names
                .get(&b)
                .cloned()
                .or_else(|| listed.get(b).map(|s| s.to_string()))
                .unwrap_or_else(|| format!("band{}", b + 1));
            let mut offset: f64 = match offsets.get(&b) {
                Some(s) => s
                    .trim()
                    .parse()
                    .map_err(|_| err(format!("band {} offset '{s}' is not a number", b + 1)))?,
                None => 0.0,
            };
            let scale: f64 = match scales.get(&b) {
                Some(s) => s
                    .trim()
                    .parse()
                    .map_err(|_| err(format!("band {} scale '{s}' is not a number", b + 1)))?,
                None => 1.0,
            };
            // Version 2 keeps whole numbers plus 2^23 (coordinates on a lattice,
            // whole attributes): GDAL's scale and offset give the true value;
            // coordinates are read relative to the origin, attributes relative
            // to the value of 2^23.
            let lattice = if whole.contains(&(b + 1)) {
                if !(scale.is_finite() && scale != 0.0 && offset.is_finite()) {
                    return Err(err(format!(
                        "band {} has scale {scale} and offset {offset}; whole-number bands \
                         need finite numbers and a scale other than 0",
                        b + 1
                    )));
                }
                let zero = offset;
                offset = if b < 3 {
                    meta.origin[b]
                } else {
                    zero + scale * spec::WHOLE_BIAS
                };
                Some((scale, zero))
            } else {
                None
            };
            // A statistic that does not parse is only not shown: it is a hint.
            let stat =
                |m: &BTreeMap<usize, String>| m.get(&b).and_then(|s| s.trim().parse::<f64>().ok());
            let range = match (stat(&minima), stat(&maxima)) {
                (Some(lo), Some(hi)) if lo <= hi => Some(match lattice {
                    Some((step, base)) => {
                        let (a, z) = (base + step * lo, base + step * hi);
                        (a.min(z), a.max(z))
                    }
                    None => (lo + offset, hi + offset),
                }),
                _ => None,
            };
            bands.push(BandInfo {
                name,
                offset,
                range,
                lattice,
            });
        }
        for (b, want) in spec::COORDINATE_BANDS.iter().enumerate() {
            if bands[b].name != *want {
                return Err(err(format!(
                    "band {} is '{}', expected '{want}'",
                    b + 1,
                    crate::text::sanitize(&bands[b].name)
                )));
            }
        }
        let index: Option<Vec<LevelIndex>> = items
            .iter()
            .find(|i| {
                i.name == key::TILE_INDEX && i.domain.as_deref() == Some(key::TILE_INDEX_DOMAIN)
            })
            .map(|i| metadata::decode_tile_index(&i.value))
            .transpose()
            .map_err(|m| err(format!("bad tile index: {m}")))?;

        // Level 0, then reduced-resolution IFDs, largest first.
        let mut ifds: Vec<&Ifd> = vec![first];
        for ifd in &tiff.ifds[1..] {
            let subfile = tiff
                .uint(data, ifd, tag::NEW_SUBFILE_TYPE)
                .map_err(err)?
                .unwrap_or(0);
            if subfile & 1 == 1 && subfile & 4 == 0 {
                ifds.push(ifd);
            }
        }
        let mut levels = Vec::with_capacity(ifds.len());
        for ifd in &ifds {
            levels.push(
                Self::open_level(&tiff, data, ifd, samples, file_bytes)
                    .map_err(|m| err(format!("IFD at byte {}: {m}", ifd.offset)))?,
            );
        }
        levels.sort_by_key(|l| std::cmp::Reverse(l.width));
        let l0 = &levels[0];
        let pixels0 = l0.width as u64 * l0.height as u64;
        if pixels0 > 1 << 34 {
            return Err(err(format!(
                "level 0 is {}x{} pixels, more than pcimg reads",
                l0.width, l0.height
            )));
        }
        if meta.point_count > pixels0 {
            return Err(err(format!(
                "metadata POINT_COUNT {} exceeds the {} pixels of level 0",
                meta.point_count, pixels0
            )));
        }
        // Overviews recomputed in place (`gdaladdo -r average` on a pcimg file keeps
        // its IFDs and their Software tag) are caught by their pixels.
        let rows = meta.items.get(key::TILE_ORDER).map(String::as_str);
        if let Some(o) = rows.filter(|o| *o != spec::tile_order::ROWS) {
            return Err(err(format!(
                "metadata {} is '{}', which this version does not read",
                key::TILE_ORDER,
                crate::text::sanitize(o)
            ))
            .with_remedy(crate::error::Remedy::Upgrade));
        }
        let rows = rows.is_some();
        // Row-ordered parts record each level's stored bytes: a level of other
        // bytes was rewritten by another tool.
        let level_bytes: Vec<u64> = meta
            .items
            .get(key::LEVEL_BYTES)
            .map(|s| {
                s.split_whitespace()
                    .filter_map(|v| v.parse().ok())
                    .collect()
            })
            .unwrap_or_default();
        let pyramid_ok: Vec<bool> = (0..levels.len())
            .map(|k| {
                if rows {
                    return level_bytes.get(k) == Some(&levels[k].bytes);
                }
                meta.layout == spec::layout::PAPER
                    || overview_samples_level0(
                        data,
                        tiff.little_endian,
                        &levels[0],
                        &levels[k],
                        k,
                        meta.point_count,
                    )
            })
            .collect();
        for (k, level) in levels.iter_mut().enumerate() {
            level.index = k;
            let tw = level.tile_width;
            let z_ok = tw == level.tile_height
                && tw.is_power_of_two()
                && level.width % tw == 0
                && level.height % tw == 0
                && level.tiles_across.is_power_of_two()
                && level.tiles_across == level.tiles_down;
            // The paper's layout is row-major: tiles read in raster order.
            if z_ok && rows {
                level.z_lut = Some(crate::tiff::zorder::shared_rows(tw.trailing_zeros()));
                level.row_order = true;
            } else if z_ok && meta.layout != spec::layout::PAPER {
                level.z_lut = Some(shared_tile_z_to_raster(tw.trailing_zeros()));
            }
            let own = ifds_software(&tiff, data, &ifds, level.width) && pyramid_ok[k];
            Self::attach_index(level, index.as_deref(), k, own, &meta).map_err(err)?;
        }
        Ok(Part {
            path: path.to_path_buf(),
            file_bytes,
            bigtiff: tiff.big,
            little_endian: tiff.little_endian,
            meta,
            bands,
            levels,
            samples,
            map: Arc::new(map),
            lazy: None,
            remote: None,
        })
    }

    fn open_level(
        tiff: &Tiff,
        data: &[u8],
        ifd: &Ifd,
        samples: usize,
        file_bytes: u64,
    ) -> std::result::Result<Level, String> {
        let need = |t: u16, what: &str| -> std::result::Result<u64, String> {
            tiff.uint(data, ifd, t)?
                .ok_or_else(|| format!("{what} (tag {t}) is missing"))
        };
        let width = need(tag::IMAGE_WIDTH, "ImageWidth")? as u32;
        let height = need(tag::IMAGE_LENGTH, "ImageLength")? as u32;
        let spp = tiff.uint(data, ifd, tag::SAMPLES_PER_PIXEL)?.unwrap_or(1) as usize;
        if spp != samples {
            return Err(format!("has {spp} bands where level 0 has {samples}"));
        }
        let bits = tiff
            .uints(data, ifd, tag::BITS_PER_SAMPLE)?
            .unwrap_or(vec![1]);
        let formats = tiff
            .uints(data, ifd, tag::SAMPLE_FORMAT)?
            .unwrap_or(vec![1]);
        if bits.iter().any(|&b| b != 32) || formats.iter().any(|&f| f != 3) {
            return Err(format!(
                "bands are not Float32 (BitsPerSample {bits:?}, SampleFormat {formats:?})"
            ));
        }
        let tile_width = tiff
            .uint(data, ifd, tag::TILE_WIDTH)?
            .ok_or("the image is stored in strips, not tiles (rewrite it with -co TILED=YES)")?
            as u32;
        let tile_height = need(tag::TILE_LENGTH, "TileLength")? as u32;
        if tile_width == 0 || tile_height == 0 || tile_width as u64 * tile_height as u64 > 1 << 22 {
            return Err(format!(
                "tile size {tile_width}x{tile_height} is not usable"
            ));
        }
        if width == 0 || height == 0 || width > 1 << 24 || height > 1 << 24 {
            return Err(format!("image size {width}x{height} is not usable"));
        }
        let planar_separate = tiff
            .uint(data, ifd, tag::PLANAR_CONFIGURATION)?
            .unwrap_or(1)
            == 2;
        let tiles_across = width.div_ceil(tile_width);
        let tiles_down = height.div_ceil(tile_height);
        let per_band = tiles_across as usize * tiles_down as usize;
        let chunks = if planar_separate {
            per_band * samples
        } else {
            per_band
        };
        let offsets = tiff
            .uints(data, ifd, tag::TILE_OFFSETS)?
            .ok_or("TileOffsets (tag 324) is missing")?;
        let counts = tiff
            .uints(data, ifd, tag::TILE_BYTE_COUNTS)?
            .ok_or("TileByteCounts (tag 325) is missing")?;
        if offsets.len() != chunks || counts.len() != chunks {
            return Err(format!(
                "has {} tile offsets and {} byte counts, expected {chunks}",
                offsets.len(),
                counts.len()
            ));
        }
        for (c, (&o, &n)) in offsets.iter().zip(&counts).enumerate() {
            if n > 0 && o.checked_add(n).is_none_or(|end| end > file_bytes) {
                return Err(format!(
                    "tile {} of band {} lies at bytes {o}..{} past the end of the file ({file_bytes} bytes)",
                    c % per_band,
                    if planar_separate { c / per_band + 1 } else { 1 },
                    o.saturating_add(n)
                ));
            }
        }
        let compression = tiff.uint(data, ifd, tag::COMPRESSION)?.unwrap_or(1) as u16;
        let predictor = tiff.uint(data, ifd, tag::PREDICTOR)?.unwrap_or(1) as u16;
        let lerc_extra = match tiff.uints(data, ifd, tag::LERC_PARAMETERS)? {
            Some(p) if compression == spec::compression::LERC => match p.get(1) {
                Some(&e) => u32::try_from(e).unwrap_or(u32::MAX),
                None => {
                    return Err(format!(
                        "LercParameters holds {} value(s), 2 expected",
                        p.len()
                    ));
                }
            },
            _ => spec::lerc::ADD_NONE,
        };
        let level = Level {
            index: 0,
            width,
            height,
            tile_width,
            tile_height,
            tiles_across,
            tiles_down,
            compression,
            predictor,
            lerc_extra,
            planar_separate,
            points: None,
            bytes: counts.iter().sum(),
            indexed: false,
            tiles: Vec::new(),
            offsets,
            counts,
            z_lut: None,
            row_order: false,
        };
        level.codec(tiff.little_endian, 1).check()?;
        Ok(level)
    }

    /// Fills the level's tile list: from the tile index where it matches this
    /// level, otherwise every tile with data, with the part's bounds.
    fn attach_index(
        level: &mut Level,
        index: Option<&[LevelIndex]>,
        k: usize,
        own: bool,
        meta: &PartMeta,
    ) -> std::result::Result<(), String> {
        let per_band = (level.tiles_across * level.tiles_down) as usize;
        let pixels = level.tile_width as u64 * level.tile_height as u64;
        let has_data = |t: usize| level.counts[t] > 0;
        if let Some(li) = index.and_then(|ix| ix.get(k)) {
            // Level 0 pixels survive a GDAL rewrite unchanged; overviews must be ours.
            let geometry_ok = li.size == level.width
                && li.size == level.height
                && li.tile_size == level.tile_width
                && li.tile_size == level.tile_height;
            let tiles_ok = li
                .tiles
                .iter()
                .all(|t| (t.index as usize) < per_band && has_data(t.index as usize));
            if geometry_ok && tiles_ok && (k == 0 || own) {
                // The index must agree with the level: counts fit their tiles and
                // add up to the level's count.
                let sum: u64 = li.tiles.iter().map(|t| t.points as u64).sum();
                let expected = meta.level_points.get(k).copied();
                if li.tiles.iter().any(|t| t.points as u64 > pixels) {
                    return Err(format!(
                        "the tile index of level {k} gives a tile more points than its \
                         {pixels} pixels"
                    ));
                }
                if expected.is_some_and(|e| e != sum) || sum > meta.point_count {
                    return Err(format!(
                        "the tile index of level {k} disagrees with the metadata: its tiles \
                         hold {sum} points, the metadata says {} for the level and {} in all",
                        expected
                            .map(|e| e.to_string())
                            .unwrap_or_else(|| "nothing".into()),
                        meta.point_count
                    ));
                }
                level.indexed = true;
                level.points = meta.level_points.get(k).copied();
                level.tiles = li
                    .tiles
                    .iter()
                    .map(|t| TileInfo {
                        index: t.index,
                        points: Some(t.points),
                        bounds: t.bounds,
                    })
                    .collect();
                return Ok(());
            }
        }
        let order: Vec<u32> = if level.z_lut.is_some() {
            (0..per_band as u64)
                .map(|z| {
                    let (c, r) = crate::tiff::zorder::z_pixel(z);
                    r * level.tiles_across + c
                })
                .collect()
        } else {
            (0..per_band as u32).collect()
        };
        level.tiles = order
            .into_iter()
            .filter(|&t| has_data(t as usize))
            .map(|t| TileInfo {
                index: t,
                points: None,
                bounds: meta.bounds,
            })
            .collect();
        Ok(())
    }

    /// Index of band `name`.
    pub fn band_index(&self, name: &str) -> Option<usize> {
        self.bands.iter().position(|b| b.name == name)
    }

    /// Indices of bands by name, with an error naming a missing one.
    pub fn band_indices(&self, names: &[&str]) -> Result<Vec<usize>> {
        names
            .iter()
            .map(|n| {
                self.band_index(n)
                    .ok_or_else(|| StoreError::new(&self.path, format!("has no band named '{n}'")))
            })
            .collect()
    }
}

/// Whether level `k`'s first pixels along the Z-curve (`j` = 0..4) are level 0's
/// pixels `j · 4^k` in the x band, as pcimg's nearest-neighbour pyramid makes
/// them. Checked straight from the map where tiles are uncompressed, planar and
/// in native byte order (a few 4-byte reads); other files are taken as they
/// claim.
fn overview_samples_level0(
    data: &[u8],
    little_endian: bool,
    l0: &Level,
    lk: &Level,
    k: usize,
    points: u64,
) -> bool {
    let plain = |l: &Level| {
        l.compression == 1
            && l.planar_separate
            && l.tile_width == l.tile_height
            && l.tile_width.is_power_of_two()
    };
    if k == 0
        || k >= 32
        || little_endian != cfg!(target_endian = "little")
        || !plain(l0)
        || !plain(lk)
    {
        return true;
    }
    // The x value at Z-index `z` of a level, if its tile is stored.
    let at = |l: &Level, z: u64| -> Option<u32> {
        let (px, py) = crate::tiff::zorder::z_pixel(z);
        let tw = l.tile_width;
        if px >= l.width || py >= l.height {
            return None;
        }
        let chunk = ((py / tw) * l.tiles_across + px / tw) as usize;
        let (off, len) = (*l.offsets.get(chunk)?, *l.counts.get(chunk)?);
        let within = ((py % tw) as u64 * tw as u64 + (px % tw) as u64) * 4;
        if within + 4 > len {
            return None;
        }
        let o = (off + within) as usize;
        Some(u32::from_le_bytes(data.get(o..o + 4)?.try_into().ok()?))
    };
    let step = 1u64 << (2 * k);
    (0..4u64)
        .take_while(|j| j * step < points)
        .all(|j| match (at(lk, j), at(l0, j * step)) {
            (Some(a), Some(b)) => a == b,
            _ => true,
        })
}

/// Whether the IFD of the level `width` wide was written by pcimg.
fn ifds_software(tiff: &Tiff, data: &[u8], ifds: &[&Ifd], width: u32) -> bool {
    ifds.iter().any(|ifd| {
        tiff.uint(data, ifd, tag::IMAGE_WIDTH).ok().flatten() == Some(width as u64)
            && tiff
                .ascii(data, ifd, tag::SOFTWARE)
                .ok()
                .flatten()
                .is_some_and(|s| s.starts_with(spec::SOFTWARE_PREFIX))
    })
}
