//! One point's every attribute, for picking: its tile is read again with all
//! of the part's bands (tiles load deterministically, so the point keeps its
//! index) and each value is given in source units (stored value + offset).

use super::cache::{Extra, TileKey, load_tile_bands};
use crate::store::Dataset;

/// A picked point as the user sees it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PointRecord {
    /// The part's file (sanitize before display).
    pub part: String,
    pub level: usize,
    pub tile: u32,
    /// The point's index in its tile.
    pub index: usize,
    /// x, y, z in the dataset's coordinates.
    pub position: [f64; 3],
    /// Every other band, in the part's order, in source units.
    pub attributes: Vec<(String, f64)>,
}

/// Reads point `index` of tile `key` with every band.
pub fn point_record(ds: &Dataset, key: TileKey, index: usize) -> Result<PointRecord, String> {
    let t = load_tile_bands(ds, key, &Extra::All).map_err(|e| e.to_string())?;
    if index >= t.len() {
        return Err(format!(
            "tile {} of level {} has {} points, not {}",
            key.tile,
            key.level,
            t.len(),
            index + 1
        ));
    }
    let part = ds
        .part(key.part)
        .map(|p| p.path.display().to_string())
        // (A source's tile: the file it came from.)
        .or_else(|| ds.source().and_then(|s| s.file_of(key.tile)))
        .unwrap_or_else(|| ds.path.display().to_string());
    Ok(PointRecord {
        part,
        level: key.level,
        tile: key.tile,
        index,
        position: [
            t.origin[0] + t.x[index] as f64,
            t.origin[1] + t.y[index] as f64,
            t.origin[2] + t.z[index] as f64,
        ],
        attributes: t
            .attributes
            .iter()
            .map(|(n, off, v)| (n.clone(), v[index] as f64 + off))
            .collect(),
    })
}
