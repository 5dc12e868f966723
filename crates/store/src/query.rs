//! Points out of a dataset, for programs that take them elsewhere (`pcimg
//! export` and `stats`, the Python package): which tiles a selection reaches
//! ([`plan`]), reading them a bounded batch at a time ([`read_batches`]), and
//! each batch as float64 columns in source units, coordinates back on the
//! source's lattice ([`Batch`]).
//!
//! A [`Selection`] is the part of a viewer's filter that the store can apply
//! alone: a box and a set of classes. The renderer's filter (band ranges,
//! slabs, the inspector's legend) decides per tile through the same [`plan`]
//! and [`Batch::of`] with its own tests.

use crate::points::{Bounds, Lattice, class_code, round_whole};
use crate::{Dataset, Points, StoreError};
use pcimg_core::time;
use std::collections::HashMap;

/// The tiles a selection reaches and what they hold.
#[derive(Debug, Clone)]
pub struct Plan {
    /// Part, level and tile of every tile the selection can reach, part by part.
    pub tiles: Vec<(usize, usize, u32)>,
    /// Points in those tiles (the most a reader of them gets).
    pub points: u64,
    /// Tiles of the chosen levels, in the parts looked at, that the selection
    /// cannot reach (not read).
    pub skipped: usize,
    /// Parts not looked at: their bounds (or their overview node's) lie
    /// outside the selection.
    pub parts_passed: usize,
    /// Bands besides x, y, z, in the order of the first part that has each.
    pub bands: Vec<String>,
    /// The lattice every part's coordinates lie on, when one holds them all
    /// (`Lattice::common`).
    pub lattice: Option<Lattice>,
    /// The bounds of the tiles read.
    pub bounds: Bounds,
    /// The CRS the parts give (the first part's).
    pub crs: Option<String>,
}

/// The tiles of level `level` (each part's coarsest where it has fewer) whose
/// bounds `may_hold` accepts, in the parts only (overview nodes hold copies).
///
/// Parts whose bounds it refuses are not looked at, and with an overview whole
/// subtrees of them are not (a paged index's pages for them are not read):
/// [`Plan::parts_passed`] counts them.
pub fn plan(
    ds: &Dataset,
    level: usize,
    may_hold: impl Fn(&Bounds) -> bool,
) -> Result<Plan, StoreError> {
    let mut tiles = Vec::new();
    let (mut points, mut skipped) = (0u64, 0usize);
    // Every part's bands (the index's totals), whether reached or not; the
    // bands that make `gps_time` exact are read with it, as part of it.
    let bands: Vec<String> = ds
        .totals()
        .bands
        .iter()
        .filter(|b| !["x", "y", "z"].contains(&b.as_str()) && !time::is_exact_band(b))
        .cloned()
        .collect();
    let mut bounds = Bounds::EMPTY;
    let mut lattices = Vec::new();
    let ids = ds.parts_where(&may_hold)?;
    let parts_passed = ds.part_count().saturating_sub(ids.len());
    for i in ids {
        let part = ds.try_part(i)?;
        let Some(l) = part
            .levels
            .get(level.min(part.levels.len().saturating_sub(1)))
        else {
            continue;
        };
        lattices.push(part.meta.lattice);
        for t in &l.tiles {
            if may_hold(&t.bounds) {
                tiles.push((i, l.index, t.index));
                points += t.points.unwrap_or(0) as u64;
                bounds = bounds.union(&t.bounds);
            } else {
                skipped += 1;
            }
        }
    }
    // Parts of one conversion share one; parts of a cluster's shards, each
    // from its own files, may name different points of one lattice.
    let lattice = lattices
        .into_iter()
        .collect::<Option<Vec<Lattice>>>()
        .and_then(|l| Lattice::common(&l));
    Ok(Plan {
        tiles,
        points,
        skipped,
        parts_passed,
        bands,
        lattice,
        bounds,
        crs: ds.totals().crs.clone(),
    })
}

/// Points read at most at once (a batch of tiles): about 100 MB of columns.
pub const BATCH_POINTS: u64 = 4 << 20;

/// A batch of tiles read: whose they are and their columns (x y z, then the
/// asked bands the part has, in the order asked).
#[derive(Debug)]
pub struct Read {
    pub part: usize,
    pub level: usize,
    pub tiles: Vec<u32>,
    pub points: Points,
}

/// Groups `tiles` (part, level, tile; each part's run of tiles together) into
/// batches of at most [`BATCH_POINTS`] points of one part and level (a tile
/// larger than that is a batch alone).
pub fn batches(ds: &Dataset, tiles: &[(usize, usize, u32)]) -> Vec<(usize, usize, Vec<u32>)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < tiles.len() {
        let (p, l, _) = tiles[i];
        // The points of each tile of this part and level (one map a run).
        let counts: HashMap<u32, u64> = ds
            .part(p)
            .and_then(|part| part.levels.get(l))
            .map(|level| {
                level
                    .tiles
                    .iter()
                    .map(|t| (t.index, t.points.unwrap_or(0) as u64))
                    .collect()
            })
            .unwrap_or_default();
        while i < tiles.len() && tiles[i].0 == p && tiles[i].1 == l {
            let (mut batch, mut n) = (Vec::new(), 0);
            while i < tiles.len() && tiles[i].0 == p && tiles[i].1 == l {
                let c = counts.get(&tiles[i].2).copied().unwrap_or(0);
                if !batch.is_empty() && n + c > BATCH_POINTS {
                    break;
                }
                n += c;
                batch.push(tiles[i].2);
                i += 1;
            }
            out.push((p, l, batch));
        }
    }
    out
}

/// Reads one batch of [`batches`]: x y z and those of `bands` the part has.
pub fn read_batch(
    ds: &Dataset,
    (p, l, tiles): (usize, usize, Vec<u32>),
    bands: &[String],
) -> Result<Read, StoreError> {
    let part = ds
        .part(p)
        .ok_or_else(|| StoreError::new(&ds.path, format!("has no part {p}")))?;
    let mut idx = vec![0usize, 1, 2];
    idx.extend(bands.iter().filter_map(|b| part.band_index(b)));
    // `gps_time` comes with the bands that make it exact ([`Batch::of`]), at
    // level 0: coarser levels keep the Float32 alone (their NaN there would
    // be read for nothing).
    if l == 0 && bands.iter().any(|b| b == time::TIME_BAND) {
        idx.extend(time::EXACT_BANDS.iter().filter_map(|b| part.band_index(b)));
    }
    let points = part.read_tiles(l, &tiles, &idx)?;
    Ok(Read {
        part: p,
        level: l,
        tiles,
        points,
    })
}

/// Reads `tiles` a batch at a time ([`batches`], [`read_batch`]) and hands
/// each to `f`; stops at the first error. Returns the tiles read.
pub fn read_batches<E: From<StoreError>>(
    ds: &Dataset,
    tiles: &[(usize, usize, u32)],
    bands: &[String],
    mut f: impl FnMut(Read) -> Result<(), E>,
) -> Result<usize, E> {
    for b in batches(ds, tiles) {
        f(read_batch(ds, b, bands)?)?;
    }
    Ok(tiles.len())
}

/// Columns as stored: each true value is its offset plus the Float32.
#[derive(Debug, Clone, Copy)]
pub struct Columns<'a> {
    /// The coordinates' offsets and columns.
    pub origin: [f64; 3],
    pub xyz: [&'a [f32]; 3],
}

/// Points ready to leave: coordinates in source units (on the lattice where
/// there is one), and each asked band's values (NaN where a part lacks it).
#[derive(Debug, Default)]
pub struct Batch {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub z: Vec<f64>,
    /// One column per asked band, in the order asked.
    pub bands: Vec<Vec<f64>>,
}

impl Batch {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// The points of `c` that `keep` keeps (all with `None`), with the bands
    /// `bands` found by `band` (its offset and column).
    pub fn of<'a>(
        c: Columns<'a>,
        band: impl Fn(&str) -> Option<(f64, &'a [f32])>,
        keep: Option<&[bool]>,
        bands: &[String],
        lattice: Option<Lattice>,
    ) -> Batch {
        use rayon::prelude::*;
        let n = c.xyz[0].len();
        let kept: Vec<usize> = match keep {
            Some(k) => (0..n).filter(|&i| k[i]).collect(),
            None => (0..n).collect(),
        };
        let axis = |a: usize| -> Vec<f64> {
            let (o, col) = (c.origin[a], c.xyz[a]);
            kept.par_iter()
                .map(|&i| {
                    let v = o + col[i] as f64;
                    match lattice {
                        // The whole number the point was stored as, exactly
                        // (a part keeps its lattice offsets below 2^23, where
                        // a Float32 is exact to well under half a step).
                        Some(l) => l.nearest(a, v),
                        None => v,
                    }
                })
                .collect()
        };
        let mut b = Batch {
            x: axis(0),
            y: axis(1),
            z: axis(2),
            bands: Vec::with_capacity(bands.len()),
        };
        for name in bands {
            let exact = (name == time::TIME_BAND)
                .then(|| time::exact_columns(|b| band(b).map(|(_, c)| c)))
                .flatten();
            let col = match (band(name), exact) {
                // GPS time bit for bit, from its value and the whole numbers
                // beside it (`pcimg_core::time`).
                (Some((off, c)), Some([lo, mid, hi])) => kept
                    .iter()
                    .map(|&i| time::join(off, c[i], lo[i], mid[i], hi[i]))
                    .collect(),
                (Some((off, c)), None) => kept.iter().map(|&i| off + c[i] as f64).collect(),
                (None, _) => vec![f64::NAN; kept.len()],
            };
            b.bands.push(col);
        }
        b
    }

    /// The points of `p` (as [`Part::read_tiles`](crate::Part::read_tiles)
    /// gives them: x y z first) that `keep` keeps.
    pub fn of_points(
        p: &Points,
        keep: Option<&[bool]>,
        bands: &[String],
        lattice: Option<Lattice>,
    ) -> Batch {
        let c = Columns {
            origin: [p.offsets[0], p.offsets[1], p.offsets[2]],
            xyz: [&p.columns[0], &p.columns[1], &p.columns[2]],
        };
        let band = |name: &str| {
            let i = p.bands.iter().skip(3).position(|b| b == name)? + 3;
            Some((p.offsets[i], p.columns[i].as_slice()))
        };
        Batch::of(c, band, keep, bands, lattice)
    }
}

/// What the store itself can select: points in a box, of some classes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Selection {
    /// Only points inside this box (world coordinates; inclusive).
    pub clip: Option<Bounds>,
    /// Only points whose class is listed (`None`: every point, classified
    /// or not).
    pub classes: Option<Vec<u8>>,
}

impl Selection {
    /// Whether a tile with `bounds` may hold a selected point.
    pub fn may_hold(&self, bounds: &Bounds) -> bool {
        self.clip.is_none_or(|c| c.intersects(bounds))
    }

    /// The bands the selection reads besides x, y, z.
    pub fn bands(&self) -> Vec<String> {
        match self.classes {
            Some(_) => vec!["classification".to_string()],
            None => Vec::new(),
        }
    }

    /// Per point of `p` (x y z first), whether it is selected; `None` when all
    /// are. A part without classes has none of the listed classes. With a
    /// `lattice`, the box tests each coordinate on it (as [`Batch`] gives it),
    /// so a point on the box's face is inside whatever its Float32 rounding.
    pub fn keep(&self, p: &Points, lattice: Option<Lattice>) -> Option<Vec<bool>> {
        if self.clip.is_none() && self.classes.is_none() {
            return None;
        }
        let n = p.len();
        let mut keep = vec![true; n];
        if let Some(list) = &self.classes {
            let mut mask = [false; 256];
            list.iter().for_each(|&c| mask[c as usize] = true);
            match p.column("classification") {
                Some(c) => {
                    for (k, &v) in keep.iter_mut().zip(c) {
                        *k = class_code(v).is_some_and(|c| mask[c as usize]);
                    }
                }
                None => keep.fill(false),
            }
        }
        if let Some(c) = &self.clip {
            for a in 0..3 {
                let (o, col) = (p.offsets[a], &p.columns[a]);
                for (k, &v) in keep.iter_mut().zip(col) {
                    let mut w = o + v as f64;
                    if let Some(l) = lattice {
                        w = l.origin[a] + round_whole((w - l.origin[a]) / l.step[a]) * l.step[a];
                    }
                    *k &= w >= c.min[a] && w <= c.max[a];
                }
            }
        }
        if keep.iter().all(|&k| k) {
            None
        } else {
            Some(keep)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{WriteOptions, write_part};
    use pcimg_core::points::{Attribute, PointColumns};

    /// 400 000 points on a 1000 × 400 m grid; class = i % 4.
    fn dataset(dir: &std::path::Path) -> Dataset {
        let n = 400_000;
        let x: Vec<f64> = (0..n).map(|i| 1000.0 + (i % 1000) as f64).collect();
        let y: Vec<f64> = (0..n).map(|i| 2000.0 + (i / 1000) as f64).collect();
        let z: Vec<f64> = (0..n).map(|i| (i % 7) as f64 * 0.25).collect();
        let class = Attribute {
            name: "classification".into(),
            offset: 0.0,
            values: (0..n).map(|i| (i % 4) as f32).collect(),
        };
        let points = PointColumns {
            x,
            y,
            z,
            attributes: vec![class],
        };
        let path = dir.join("square.tif");
        write_part(&path, &points, &WriteOptions::default()).unwrap();
        Dataset::open(&path).unwrap()
    }

    #[test]
    fn a_selection_reads_only_the_tiles_it_reaches_and_keeps_only_its_points() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        let sel = Selection {
            clip: Some(Bounds {
                min: [1000.0, 2000.0, -1.0],
                max: [1099.0, 2099.0, 10.0],
            }),
            classes: Some(vec![1, 3]),
        };
        let all = plan(&ds, 0, |_| true).unwrap();
        let p = plan(&ds, 0, |b| sel.may_hold(b)).unwrap();
        assert_eq!(all.points, 400_000);
        assert!(p.tiles.len() < all.tiles.len(), "{} tiles", p.tiles.len());
        assert_eq!(p.skipped, all.tiles.len() - p.tiles.len());
        let mut got = Vec::new();
        let mut bands = sel.bands();
        bands.extend(p.bands.iter().cloned());
        bands.dedup();
        let read = read_batches::<StoreError>(&ds, &p.tiles, &bands, |r| {
            let keep = sel.keep(&r.points, None);
            let b = Batch::of_points(&r.points, keep.as_deref(), &bands, None);
            for i in 0..b.len() {
                got.push((b.x[i], b.y[i], b.bands[0][i]));
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(read, p.tiles.len());
        // 100 × 100 points in the box, half of them of class 1 or 3.
        assert_eq!(got.len(), 5000);
        assert!(
            got.iter()
                .all(|&(x, y, c)| x <= 1099.0 && y <= 2099.0 && c % 2.0 == 1.0)
        );
    }

    #[test]
    fn batches_hold_one_part_and_level_and_at_most_the_batch_points() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        let p = plan(&ds, 0, |_| true).unwrap();
        let b = batches(&ds, &p.tiles);
        let tiles: usize = b.iter().map(|b| b.2.len()).sum();
        assert_eq!(tiles, p.tiles.len());
        assert!(b.iter().all(|(part, level, _)| *part == 0 && *level == 0));
    }
}
