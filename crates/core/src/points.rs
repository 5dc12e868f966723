//! Point columns: the in-memory form of a point cloud that flows from the input
//! readers into the image store. Coordinates are `f64` (georeferenced inputs keep
//! millimetres); every other attribute is an `f32` column plus an `f64` offset.

/// Metadata keys the input readers set on their columns, which the store keeps as
/// they are (its `spec::key` re-exports them).
pub mod key {
    /// PCD inputs: the `VIEWPOINT` of the header, `tx ty tz qw qx qy qz`.
    pub const VIEWPOINT: &str = "VIEWPOINT";
    /// E57 inputs: the scans, as JSON: `[{"scan", "name", "guid", "points",
    /// "rotation": [w, x, y, z], "translation": [x, y, z]}]`; `scan` is the
    /// value of the `scan` band.
    pub const SCANS: &str = "SCANS";
    /// LAS and LAZ inputs: the source's point format, `0` to `10` (an export
    /// writes an extended format, 6 to 8, for a source in one).
    pub const LAS_POINT_FORMAT: &str = "LAS_POINT_FORMAT";
}

/// `v` rounded to the nearest whole number (halves away from zero) without a
/// libm call (`f64::round` is one on x86-64's baseline, and took a tenth of an
/// export's time); exact for |v| < 2^52.
#[inline(always)]
pub fn round_whole(v: f64) -> f64 {
    (if v >= 0.0 { v + 0.5 } else { v - 0.5 }) as i64 as f64
}

/// The ASPRS class code of a stored `classification` value: a whole number
/// 0..=255, else `None` (such points belong to no class).
#[inline(always)]
pub fn class_code(v: f32) -> Option<u8> {
    ((0.0..=255.0).contains(&v) && v.fract() == 0.0).then_some(v as u8)
}

/// A coordinate lattice: every coordinate on axis `a` is `origin[a] + step[a] · k`
/// for a whole number `k` (a LAS file's scale factors and offsets), so a store can
/// keep `k` instead of the coordinate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Lattice {
    pub step: [f64; 3],
    pub origin: [f64; 3],
}

impl Lattice {
    /// The decimal places that write every point of axis `a` (the origin plus
    /// whole multiples of the step) exactly, if at most 9 do: a 0.01 step from
    /// 0 needs 2, from 636000.005 (an odd LAS offset) 3; a step of 1/3, none.
    pub fn decimals(&self, a: usize) -> Option<usize> {
        let whole = |v: f64, d: usize| {
            let scaled = v.abs() * 10f64.powi(d as i32);
            // (f64's own rounding of the value, scaled: far below a unit.)
            (scaled - scaled.round()).abs() <= 1e-9 + 1e-12 * scaled
        };
        (0..=9).find(|&d| whole(self.step[a], d) && whole(self.origin[a], d))
    }

    /// The lattice point on axis `a` nearest `v`: the coordinate a store that
    /// keeps whole numbers of steps held for a value read back near it.
    #[inline(always)]
    pub fn nearest(&self, a: usize, v: f64) -> f64 {
        let k = round_whole((v - self.origin[a]) / self.step[a]);
        self.origin[a] + k * self.step[a]
    }

    /// The lattice all of `lattices` lie on, when there is one: each axis's
    /// finest step among them, on the lattice point of the one that has it,
    /// where every step is a whole multiple of it and every lattice's points
    /// lie on it. LAS tiles of one survey share their scale and differ in
    /// their offsets by whole steps (each tile's own round number): one
    /// lattice. Text files written with 2 and 3 decimals: the 3 decimals'.
    pub fn common(lattices: &[Lattice]) -> Option<Lattice> {
        let mut out = *lattices.first()?;
        for l in lattices {
            for a in 0..3 {
                if l.step[a].abs() < out.step[a].abs() {
                    out.step[a] = l.step[a];
                    out.origin[a] = l.origin[a];
                }
            }
        }
        // Whole within a thousandth of a step: f64's rounding of offsets of
        // millions at steps of micrometres is far below it. (The store checks
        // every point against the lattice as it writes, and drops a lattice a
        // point is off.)
        let whole = |v: f64| v.is_finite() && (v - v.round()).abs() <= 1e-3;
        let fits = lattices.iter().all(|l| {
            (0..3).all(|a| {
                let s = out.step[a].abs();
                s > 0.0 && whole(l.step[a] / s) && whole((l.origin[a] - out.origin[a]) / s)
            })
        });
        fits.then_some(out)
    }
}

/// One scalar attribute column (intensity, red, classification, gps_time...).
///
/// The true value of point `i` is `offset + values[i] as f64`. Readers use the offset
/// for attributes whose magnitude would cost precision in `f32` (GPS time).
#[derive(Debug, Clone, PartialEq)]
pub struct Attribute {
    pub name: String,
    pub offset: f64,
    pub values: Vec<f32>,
}

impl Attribute {
    pub fn new(name: impl Into<String>, values: Vec<f32>) -> Self {
        Self {
            name: name.into(),
            offset: 0.0,
            values,
        }
    }
}

/// Most attribute columns (bands besides x y z) a point may carry: every band of
/// every level costs at least one 256 KiB tile, and readers refuse wider inputs.
pub const MAX_ATTRIBUTES: usize = 64;

/// A set of points as columns of equal length.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointColumns {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub z: Vec<f64>,
    pub attributes: Vec<Attribute>,
}

/// Attribute values (and, where it can, coordinates) that a reader can produce again
/// for any point, from where the input itself keeps them (an uncompressed LAS file's
/// memory map), so a part need not hold a copy: the store then asks for the rows
/// (and positions) of one tile's points at a time.
///
/// Point `i` is the `i`-th point the reader delivered; a row is the values of the
/// reader's attributes in their order, exactly as its chunks deliver them (offsets
/// included: `Attribute::offset` is the chunks' own).
pub trait RowSource: Send + Sync {
    /// Points it can give rows for.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Values in a row (the reader's attributes).
    fn width(&self) -> usize;
    /// Appends the rows of points `idx` (each below [`RowSource::len`]) to `out`.
    fn gather(&self, idx: &[u32], out: &mut Vec<f32>);
    /// The rows of points `idx` as columns: value `k` of point `idx[i]` into
    /// `cols[k][i]` (`cols`: [`RowSource::width`] columns, each at least
    /// `idx.len()` long). The default gathers rows and moves them over;
    /// a source that decodes field by field writes the columns directly.
    fn gather_columns(&self, idx: &[u32], cols: &mut [&mut [f32]]) {
        let m = self.width();
        let mut rows = Vec::with_capacity(idx.len() * m);
        self.gather(idx, &mut rows);
        columns_of_rows(&rows, m, cols);
    }
    /// Whether it gives the points' coordinates as well ([`RowSource::positions`]).
    fn has_positions(&self) -> bool {
        false
    }
    /// Appends the coordinates of points `idx` less `origin`, each exactly
    /// `(c - origin) as f32` of the `f64` coordinate `c` the reader's chunks
    /// delivered, to `out`; nothing where it has none ([`RowSource::has_positions`]).
    fn positions(&self, _idx: &[u32], _origin: [f64; 3], _out: &mut Vec<[f32; 3]>) {}
    /// [`RowSource::positions`] and [`RowSource::gather`] of points `idx`, each
    /// point read once for both where the source can (the default reads twice).
    fn positions_and_rows(
        &self,
        idx: &[u32],
        origin: [f64; 3],
        pos: &mut Vec<[f32; 3]>,
        rows: &mut Vec<f32>,
    ) {
        self.positions(idx, origin, pos);
        self.gather(idx, rows);
    }
    /// [`RowSource::positions`] of the points `range`, in order.
    fn positions_in(
        &self,
        _range: std::ops::Range<usize>,
        _origin: [f64; 3],
        _out: &mut Vec<[f32; 3]>,
    ) {
    }
}

/// What a first pass keeps of a chunk whose points a [`RowSource`] gives again,
/// positions and rows: how many, their bounds, the attributes (names and
/// offsets) with the range of each one's values, and the first point with a
/// coordinate that is not finite. A reader that gives its rows back can make
/// this straight from its input, without the chunk's columns.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkExtent {
    pub len: usize,
    /// The bounds of the finite coordinates (`Bounds::EMPTY` when none).
    pub bounds: Bounds,
    pub attributes: Vec<(String, f64)>,
    /// Each attribute's smallest and largest value, NaN ignored
    /// (`(inf, -inf)` when it has none); for the whole numbers that make GPS
    /// time exact, the range they may take (`time::EXACT_RANGE`).
    pub ranges: Vec<(f32, f32)>,
    /// The first point (its index in the chunk and its coordinates) with a
    /// coordinate that is NaN or infinite.
    pub not_finite: Option<(usize, [f64; 3])>,
}

impl ChunkExtent {
    /// The extent of the points `c`.
    pub fn of(c: &PointColumns) -> ChunkExtent {
        use rayon::prelude::*;
        let at = |i: usize| [c.x[i], c.y[i], c.z[i]];
        ChunkExtent {
            len: c.len(),
            bounds: c.bounds(),
            attributes: c
                .attributes
                .iter()
                .map(|a| (a.name.clone(), a.offset))
                .collect(),
            ranges: c
                .attributes
                .par_iter()
                .map(|a| {
                    // (The whole numbers that make GPS time exact: the range
                    // they may take, as the store records it.)
                    if crate::time::is_exact_band(&a.name) {
                        return crate::time::EXACT_RANGE;
                    }
                    a.values
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |r, &v| {
                            (r.0.min(v), r.1.max(v))
                        })
                })
                .collect(),
            not_finite: (0..c.len())
                .into_par_iter()
                .find_first(|&i| !at(i).iter().all(|v| v.is_finite()))
                .map(|i| (i, at(i))),
        }
    }
}

/// Axis-aligned bounds in source coordinates.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Bounds {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Bounds {
    /// The empty bounds: `min` is +inf and `max` is -inf, so any point extends it.
    pub const EMPTY: Bounds = Bounds {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.min[a] > self.max[a])
    }

    pub fn extend(&mut self, p: [f64; 3]) {
        for a in 0..3 {
            self.min[a] = self.min[a].min(p[a]);
            self.max[a] = self.max[a].max(p[a]);
        }
    }

    pub fn union(&self, o: &Bounds) -> Bounds {
        let mut b = *self;
        for a in 0..3 {
            b.min[a] = b.min[a].min(o.min[a]);
            b.max[a] = b.max[a].max(o.max[a]);
        }
        b
    }

    pub fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| 0.5 * (self.min[a] + self.max[a]))
    }

    pub fn extent(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| (self.max[a] - self.min[a]).max(0.0))
    }

    /// Whether the two boxes share a point (touching counts).
    pub fn intersects(&self, o: &Bounds) -> bool {
        (0..3).all(|a| self.min[a] <= o.max[a] && o.min[a] <= self.max[a])
    }

    pub fn contains(&self, o: &Bounds) -> bool {
        (0..3).all(|a| self.min[a] <= o.min[a] && o.max[a] <= self.max[a])
    }
}

impl PointColumns {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Whether point `i` has finite coordinates.
    pub fn finite_at(&self, i: usize) -> bool {
        self.x[i].is_finite() && self.y[i].is_finite() && self.z[i].is_finite()
    }

    /// Drops the points with a non-finite coordinate (NaN or infinity); returns
    /// how many were dropped.
    pub fn drop_non_finite(&mut self) -> u64 {
        let keep: Vec<bool> = (0..self.len()).map(|i| self.finite_at(i)).collect();
        let dropped = keep.iter().filter(|k| !**k).count() as u64;
        if dropped == 0 {
            return 0;
        }
        fn retain<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut k = keep.iter();
            v.retain(|_| k.next().copied().unwrap_or(false));
        }
        retain(&mut self.x, &keep);
        retain(&mut self.y, &keep);
        retain(&mut self.z, &keep);
        for a in &mut self.attributes {
            retain(&mut a.values, &keep);
        }
        dropped
    }

    /// An empty set with the same attribute names and offsets as `self`.
    pub fn empty_like(&self) -> Self {
        self.map_columns(|_| Vec::new(), |_| Vec::new())
    }

    /// A set with the same attribute names and offsets, each coordinate column
    /// made by `xyz` and each attribute column by `attr` from `self`'s.
    fn map_columns(
        &self,
        xyz: impl Fn(&[f64]) -> Vec<f64>,
        attr: impl Fn(&[f32]) -> Vec<f32>,
    ) -> Self {
        Self {
            x: xyz(&self.x),
            y: xyz(&self.y),
            z: xyz(&self.z),
            attributes: self
                .attributes
                .iter()
                .map(|a| Attribute {
                    name: a.name.clone(),
                    offset: a.offset,
                    values: attr(&a.values),
                })
                .collect(),
        }
    }

    /// Every `n`-th point (the first, the `n + 1`-th...), as a new set.
    pub fn every_nth(&self, n: usize) -> Self {
        let n = n.max(1);
        self.map_columns(
            |v| v.iter().step_by(n).copied().collect(),
            |v| v.iter().step_by(n).copied().collect(),
        )
    }

    /// Checks that every column has the same length; readers call this before
    /// handing columns on.
    pub fn check_lengths(&self) -> Result<(), String> {
        let n = self.x.len();
        if self.y.len() != n || self.z.len() != n {
            return Err(format!(
                "coordinate columns differ in length: x {} y {} z {}",
                n,
                self.y.len(),
                self.z.len()
            ));
        }
        for a in &self.attributes {
            if a.values.len() != n {
                return Err(format!(
                    "attribute '{}' has {} values for {} points",
                    a.name,
                    a.values.len(),
                    n
                ));
            }
        }
        Ok(())
    }

    /// The bounds of all points (`Bounds::EMPTY` when there are none).
    pub fn bounds(&self) -> Bounds {
        use rayon::prelude::*;
        let axis = |col: &[f64]| {
            col.par_chunks(1 << 16)
                .map(|c| {
                    c.iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                            (lo.min(v), hi.max(v))
                        })
                })
                .reduce(
                    || (f64::INFINITY, f64::NEG_INFINITY),
                    |a, b| (a.0.min(b.0), a.1.max(b.1)),
                )
        };
        if self.is_empty() {
            return Bounds::EMPTY;
        }
        let r = [axis(&self.x), axis(&self.y), axis(&self.z)];
        Bounds {
            min: r.map(|a| a.0),
            max: r.map(|a| a.1),
        }
    }

    /// Appends all points of `other`, whose attributes must match by name and order.
    /// Appends points `from..to` of `src`, which has the same attributes (their
    /// offsets are taken from `src`).
    pub fn append_range(&mut self, src: &PointColumns, from: usize, to: usize) {
        self.x.extend_from_slice(&src.x[from..to]);
        self.y.extend_from_slice(&src.y[from..to]);
        self.z.extend_from_slice(&src.z[from..to]);
        for (d, s) in self.attributes.iter_mut().zip(&src.attributes) {
            d.offset = s.offset;
            d.values.extend_from_slice(&s.values[from..to]);
        }
    }

    pub fn append(&mut self, other: &PointColumns) -> Result<(), String> {
        if self.attributes.len() != other.attributes.len()
            || self
                .attributes
                .iter()
                .zip(&other.attributes)
                .any(|(a, b)| a.name != b.name)
        {
            return Err("attribute columns differ between chunks".into());
        }
        self.x.extend_from_slice(&other.x);
        self.y.extend_from_slice(&other.y);
        self.z.extend_from_slice(&other.z);
        for (a, b) in self.attributes.iter_mut().zip(&other.attributes) {
            if a.values.is_empty() {
                a.offset = b.offset;
            }
            if a.offset == b.offset {
                a.values.extend_from_slice(&b.values);
            } else {
                let shift = b.offset - a.offset;
                a.values
                    .extend(b.values.iter().map(|&v| (v as f64 + shift) as f32));
            }
        }
        Ok(())
    }
}

/// Rows of `m` values (`rows`) into columns (`cols[k][i]`: value `k` of row
/// `i`), a block of rows at a time so that the block stays in the first-level
/// cache while each column takes its values.
pub fn columns_of_rows(rows: &[f32], m: usize, cols: &mut [&mut [f32]]) {
    if m == 0 {
        return;
    }
    const BLOCK: usize = 128;
    for (b, chunk) in rows.chunks(BLOCK * m).enumerate() {
        let i0 = b * BLOCK;
        for (k, col) in cols.iter_mut().enumerate().take(m) {
            let dst = &mut col[i0..i0 + chunk.len() / m];
            for (d, row) in dst.iter_mut().zip(chunk.chunks_exact(m)) {
                *d = row[k];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_nth_keeps_every_column_in_step() {
        let c = PointColumns {
            x: (0..10).map(f64::from).collect(),
            y: (0..10).map(|i| f64::from(i) * 2.0).collect(),
            z: vec![5.0; 10],
            attributes: vec![Attribute {
                name: "intensity".into(),
                offset: 3.0,
                values: (0..10).map(|i| i as f32).collect(),
            }],
        };
        let t = c.every_nth(4);
        assert_eq!(t.x, [0.0, 4.0, 8.0]);
        assert_eq!(t.y, [0.0, 8.0, 16.0]);
        assert_eq!(t.z, [5.0; 3]);
        assert_eq!(t.attributes[0].values, [0.0, 4.0, 8.0]);
        assert_eq!(
            (t.attributes[0].name.as_str(), t.attributes[0].offset),
            ("intensity", 3.0)
        );
        assert!(c.empty_like().is_empty());
        assert_eq!(c.every_nth(0).len(), 10);
    }
}

#[cfg(test)]
mod lattice_tests {
    use super::Lattice;

    #[test]
    fn a_lattice_axis_is_written_with_the_decimals_of_its_step_and_origin() {
        let d = |step: f64, origin: f64| {
            Lattice {
                step: [step; 3],
                origin: [origin; 3],
            }
            .decimals(0)
        };
        assert_eq!(d(0.01, 0.0), Some(2));
        assert_eq!(d(0.05, 636_000.0), Some(2));
        assert_eq!(d(0.01, 636_000.005), Some(3));
        assert_eq!(d(0.001, 4_000_000.0), Some(3));
        assert_eq!(d(0.000001, -0.02), Some(6));
        assert_eq!(d(1.0 / 3.0, 0.0), None);
    }
}
