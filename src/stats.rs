//! Statistics of a dataset's bands: count, min, max, mean, standard deviation,
//! percentiles and a histogram per band, the points of each ASPRS class, and
//! the point density with a map of it.
//!
//! Fast by default: a level is an even sample of the points (the Hilbert
//! layout's levels are spatially even), so the statistics of the finest level
//! with at most [`SAMPLE_POINTS`] points stand for the whole; `exact` reads
//! every point (level 0). Two passes over the level's tiles, a batch at a time
//! (bounded memory): the first finds each band's range, count and moments, the
//! second a histogram of [`FINE_BINS`] bins over that range, from which the
//! percentiles are read (to within a bin: the range / 4,096). Class counts
//! come from what the parts recorded when written (exact) where every part
//! has them, else from the sample.

use crate::export::ExportError;
use crate::points::Bounds;
use crate::render::lod::LoadedTile;
use crate::store::Dataset;
use crate::store::query::read_batches;
use serde::Serialize;

/// The most points the default sample holds.
pub const SAMPLE_POINTS: u64 = 2_000_000;

/// Bins of the histogram percentiles are read from.
const FINE_BINS: usize = 4096;

/// The percentiles reported.
pub const PERCENTILES: [f64; 5] = [1.0, 2.0, 50.0, 98.0, 99.0];

/// One band's statistics, in source units.
#[derive(Debug, Clone, Serialize)]
pub struct BandStats {
    pub name: String,
    /// Finite values seen (points whose part lacks the band, or NaN, not
    /// counted).
    pub count: u64,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub std: f64,
    /// `(p, value)` for each of [`PERCENTILES`].
    pub percentiles: Vec<(f64, f64)>,
    /// Points per bin of equal width over `[min, max]`.
    pub histogram: Vec<u64>,
}

/// One ASPRS class.
#[derive(Debug, Clone, Serialize)]
pub struct ClassCount {
    pub code: u8,
    pub name: String,
    pub points: u64,
}

/// What `compute` found.
#[derive(Debug, Clone, Serialize)]
pub struct Stats {
    /// The level read (0: every point).
    pub level: usize,
    /// Points read (the sample), and in the dataset.
    pub sampled: u64,
    pub points: u64,
    pub bands: Vec<BandStats>,
    pub classes: Vec<ClassCount>,
    /// Whether the class counts are the parts' own (every point), not the
    /// sample's scaled up.
    pub classes_exact: bool,
    /// The dataset's bounds, its area seen from above, and points per square
    /// unit over it.
    pub bounds: Bounds,
    pub area: f64,
    pub density: f64,
    /// Points per cell of a grid over the bounds seen from above (the
    /// sample's, scaled to the dataset's count), row by row from the north;
    /// its size.
    #[serde(skip)]
    pub density_map: Vec<f64>,
    pub map_size: (u32, u32),
}

/// The finest level whose points over all parts are at most `target` (each
/// part's coarsest where it has fewer levels); 0 if every level has fewer.
pub fn sample_level(ds: &Dataset, target: u64) -> usize {
    let levels = ds.own_levels();
    (0..levels)
        .find(|&l| level_points(ds, l) <= target)
        .unwrap_or(levels - 1)
}

/// Points in level `l` of every part (each part's coarsest where it has fewer).
pub fn level_points(ds: &Dataset, l: usize) -> u64 {
    ds.parts()
        .unwrap_or_default()
        .into_iter()
        .filter_map(|p| p.levels.get(l.min(p.levels.len().saturating_sub(1))))
        .map(|lv| lv.points.unwrap_or(0))
        .sum()
}

/// Statistics of `bands` (x, y, z and any other; all when empty) over level
/// `level` of every part, with `bins` histogram bins and a density map
/// `map_width` cells across.
pub fn compute(
    ds: &Dataset,
    level: usize,
    bands: &[String],
    bins: usize,
    map_width: u32,
) -> Result<Stats, ExportError> {
    // Statistics are of every part: every page of a paged index.
    let ids = ds.part_ids()?;
    let parts = ids
        .iter()
        .map(|&i| ds.try_part(i))
        .collect::<Result<Vec<_>, _>>()?;
    let mut names: Vec<String> = if bands.is_empty() {
        let mut v: Vec<String> = vec!["x".into(), "y".into(), "z".into()];
        for p in &parts {
            for b in p.bands.iter().skip(3) {
                if !v.contains(&b.name) && !crate::time::is_exact_band(&b.name) {
                    v.push(b.name.clone());
                }
            }
        }
        v
    } else {
        bands.to_vec()
    };
    names.dedup();
    let attrs: Vec<String> = names
        .iter()
        .filter(|n| !["x", "y", "z"].contains(&n.as_str()))
        .cloned()
        .chain(std::iter::once("classification".to_string()))
        .collect();
    let tiles: Vec<(usize, usize, u32)> = parts
        .iter()
        .zip(&ids)
        .filter_map(|(p, &i)| {
            let l = p.levels.get(level.min(p.levels.len().saturating_sub(1)))?;
            Some(l.tiles.iter().map(move |t| (i, l.index, t.index)))
        })
        .flatten()
        .collect();
    let bounds = ds.bounds();
    let (w, h) = map_size(&bounds, map_width);
    let mut map = vec![0f64; (w * h) as usize];
    let cell = |x: f64, y: f64| -> Option<usize> {
        let fx = (x - bounds.min[0]) / (bounds.max[0] - bounds.min[0]).max(f64::MIN_POSITIVE);
        let fy = (bounds.max[1] - y) / (bounds.max[1] - bounds.min[1]).max(f64::MIN_POSITIVE);
        let (cx, cy) = ((fx * w as f64) as i64, (fy * h as f64) as i64);
        (fx.is_finite() && fy.is_finite())
            .then(|| (cx.clamp(0, w as i64 - 1) + cy.clamp(0, h as i64 - 1) * w as i64) as usize)
    };
    // Pass 1: count, range and moments (sums of the differences from the
    // first value, which keeps the variance exact for georeferenced values).
    let n = names.len();
    let mut count = vec![0u64; n];
    let mut lo = vec![f64::INFINITY; n];
    let mut hi = vec![f64::NEG_INFINITY; n];
    let mut shift = vec![f64::NAN; n];
    let mut s1 = vec![0f64; n];
    let mut s2 = vec![0f64; n];
    // Bands of whole numbers (classes, returns, colour): their percentiles are
    // values of the band, exactly, where the range has fewer than FINE_BINS.
    let mut whole = vec![true; n];
    let mut sampled = 0u64;
    let mut class_sample = [0u64; 256];
    // A band's values in source units; coordinates on the part's lattice,
    // where it keeps one, exactly (as `export` gives them).
    let column = |t: &crate::lod::LoadedTile, name: &str, f: &mut dyn FnMut(f64)| -> bool {
        let lattice = ds.part(t.key.part).and_then(|p| p.meta.lattice);
        let (col, off, axis): (&[f32], f64, Option<usize>) = match name {
            "x" => (&t.x, t.origin[0], Some(0)),
            "y" => (&t.y, t.origin[1], Some(1)),
            "z" => (&t.z, t.origin[2], Some(2)),
            b => match t
                .attributes
                .iter()
                .find(|a| a.0 == b)
                .map(|a| (a.2.as_slice(), a.1, None))
            {
                Some(c) => c,
                None => return false,
            },
        };
        match (axis, lattice) {
            (Some(a), Some(l)) => {
                for &v in col {
                    let k = ((off + v as f64 - l.origin[a]) / l.step[a]).round();
                    f(l.origin[a] + k * l.step[a]);
                }
            }
            _ => col.iter().for_each(|&v| f(off + v as f64)),
        }
        true
    };
    read_batches::<ExportError>(ds, &tiles, &attrs, |r| {
        let t = LoadedTile::of_read(r);
        sampled += t.len() as u64;
        for i in 0..t.len() {
            let (x, y) = (t.origin[0] + t.x[i] as f64, t.origin[1] + t.y[i] as f64);
            if let Some(c) = cell(x, y) {
                map[c] += 1.0;
            }
        }
        if let Some(c) = t.attribute("classification") {
            for &v in c {
                if let Some(k) = crate::points::class_code(v) {
                    class_sample[k as usize] += 1;
                }
            }
        }
        for (k, name) in names.iter().enumerate() {
            column(&t, name, &mut |v| {
                if !v.is_finite() {
                    return;
                }
                if shift[k].is_nan() {
                    shift[k] = v;
                }
                let d = v - shift[k];
                count[k] += 1;
                s1[k] += d;
                s2[k] += d * d;
                lo[k] = lo[k].min(v);
                hi[k] = hi[k].max(v);
                whole[k] &= v.fract() == 0.0;
            });
        }
        Ok(())
    })?;
    // Pass 2: the fine histogram over each band's range.
    let mut fine = vec![vec![0u64; FINE_BINS]; n];
    let unit = |k: usize| whole[k] && hi[k] - lo[k] < FINE_BINS as f64;
    let bin = |k: usize, v: f64, bins: usize| -> usize {
        let span = hi[k] - lo[k];
        if span <= 0.0 {
            return 0;
        }
        if unit(k) {
            return (v - lo[k]) as usize;
        }
        (((v - lo[k]) / span * bins as f64) as usize).min(bins - 1)
    };
    read_batches::<ExportError>(ds, &tiles, &attrs, |r| {
        let t = LoadedTile::of_read(r);
        for (k, name) in names.iter().enumerate() {
            let fine = &mut fine[k];
            column(&t, name, &mut |v| {
                if v.is_finite() {
                    fine[bin(k, v, FINE_BINS)] += 1;
                }
            });
        }
        Ok(())
    })?;
    let bands = (0..n)
        .map(|k| {
            let c = count[k];
            let mean = if c > 0 {
                shift[k] + s1[k] / c as f64
            } else {
                f64::NAN
            };
            let var = if c > 1 {
                ((s2[k] - s1[k] * s1[k] / c as f64) / (c - 1) as f64).max(0.0)
            } else {
                0.0
            };
            let percentiles = PERCENTILES
                .iter()
                .map(|&p| {
                    let v = if unit(k) {
                        whole_percentile(&fine[k], c, p, lo[k])
                    } else {
                        percentile(&fine[k], c, p, lo[k], hi[k])
                    };
                    (p, v)
                })
                .collect();
            // The shown histogram: the fine one's bins added up (a band of
            // whole numbers has one fine bin a value, from its minimum).
            let shown = bins.max(1);
            let mut histogram = vec![0u64; shown];
            let span = hi[k] - lo[k];
            for (j, &v) in fine[k].iter().enumerate() {
                let at = if unit(k) {
                    if span > 0.0 {
                        ((j as f64 / span * shown as f64) as usize).min(shown - 1)
                    } else {
                        0
                    }
                } else {
                    j * shown / FINE_BINS
                };
                histogram[at] += v;
            }
            BandStats {
                name: names[k].clone(),
                count: c,
                min: lo[k],
                max: hi[k],
                mean,
                std: var.sqrt(),
                percentiles,
                histogram,
            }
        })
        .collect();
    let points = ds.points();
    let scale = if sampled > 0 {
        points as f64 / sampled as f64
    } else {
        0.0
    };
    map.iter_mut().for_each(|v| *v *= scale);
    let has_class = parts
        .iter()
        .any(|p| p.band_index("classification").is_some());
    let exact = has_class
        && parts
            .iter()
            .all(|p| p.band_index("classification").is_none() || !p.meta.class_counts.is_empty());
    let mut classes = [0u64; 256];
    if exact {
        for p in &parts {
            for &(c, k) in &p.meta.class_counts {
                classes[c as usize] += k;
            }
        }
    } else {
        for (c, &k) in class_sample.iter().enumerate() {
            classes[c] = (k as f64 * scale).round() as u64;
        }
    }
    let classes = (0..=255u8)
        .filter(|&c| classes[c as usize] > 0)
        .map(|c| ClassCount {
            code: c,
            name: crate::render::classes::name(c),
            points: classes[c as usize],
        })
        .collect();
    let area = (bounds.max[0] - bounds.min[0]).max(0.0) * (bounds.max[1] - bounds.min[1]).max(0.0);
    Ok(Stats {
        level,
        sampled,
        points,
        bands,
        classes,
        classes_exact: exact,
        bounds,
        area,
        density: if area > 0.0 {
            points as f64 / area
        } else {
            f64::NAN
        },
        density_map: map,
        map_size: (w, h),
    })
}

/// A grid `width` cells across over the bounds seen from above, as many down
/// as keep cells square (at least 1).
fn map_size(b: &Bounds, width: u32) -> (u32, u32) {
    let (dx, dy) = (b.max[0] - b.min[0], b.max[1] - b.min[1]);
    let w = width.max(1);
    let h = if dx > 0.0 && dy > 0.0 {
        ((w as f64 * dy / dx).round() as u32).clamp(1, 4 * w)
    } else {
        1
    };
    (w, h)
}

/// The `p`th percentile of `count` values whose histogram over `[lo, hi]` is
/// `fine`, interpolated within its bin.
fn percentile(fine: &[u64], count: u64, p: f64, lo: f64, hi: f64) -> f64 {
    if count == 0 {
        return f64::NAN;
    }
    let want = p / 100.0 * count as f64;
    let width = (hi - lo) / fine.len() as f64;
    let mut seen = 0f64;
    for (j, &c) in fine.iter().enumerate() {
        let next = seen + c as f64;
        if next >= want && c > 0 {
            let f = ((want - seen) / c as f64).clamp(0.0, 1.0);
            return (lo + (j as f64 + f) * width).clamp(lo, hi);
        }
        seen = next;
    }
    hi
}

/// The `p`th percentile (nearest rank) of `count` whole numbers counted one
/// bin a value from `lo`.
fn whole_percentile(fine: &[u64], count: u64, p: f64, lo: f64) -> f64 {
    if count == 0 {
        return f64::NAN;
    }
    let rank = ((p / 100.0 * count as f64).ceil() as u64).max(1);
    let mut seen = 0;
    for (j, &c) in fine.iter().enumerate() {
        seen += c;
        if seen >= rank {
            return lo + j as f64;
        }
    }
    lo + (fine.len() - 1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_read_from_the_histogram_within_a_bin() {
        // 100 values 0..99 over [0, 99] in 4096 bins: each percentile within
        // one bin's width (99 / 4096) of the value itself.
        let mut fine = vec![0u64; FINE_BINS];
        for v in 0..100 {
            fine[((v as f64 / 99.0 * FINE_BINS as f64) as usize).min(FINE_BINS - 1)] += 1;
        }
        for p in [1.0, 50.0, 99.0] {
            let got = percentile(&fine, 100, p, 0.0, 99.0);
            assert!(
                (got - (p - 1.0)).abs() <= 1.0 + 99.0 / 4096.0,
                "p{p}: {got}"
            );
        }
        assert!(percentile(&fine, 0, 50.0, 0.0, 1.0).is_nan());
        // Whole numbers: 90 ones and 10 twos; nearest rank.
        let mut w = vec![0u64; 4];
        (w[0], w[1]) = (90, 10);
        assert_eq!(whole_percentile(&w, 100, 50.0, 1.0), 1.0);
        assert_eq!(whole_percentile(&w, 100, 90.0, 1.0), 1.0);
        assert_eq!(whole_percentile(&w, 100, 91.0, 1.0), 2.0);
        assert_eq!(whole_percentile(&w, 100, 99.0, 1.0), 2.0);
    }

    #[test]
    fn the_density_map_keeps_cells_square() {
        let b = Bounds {
            min: [0.0, 0.0, 0.0],
            max: [200.0, 100.0, 1.0],
        };
        assert_eq!(map_size(&b, 64), (64, 32));
        let flat = Bounds {
            min: [0.0; 3],
            max: [10.0, 0.0, 0.0],
        };
        assert_eq!(map_size(&flat, 64), (64, 1));
    }
}
