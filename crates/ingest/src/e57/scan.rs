//! One E57 scan's records to points: where each value sits in the prototype,
//! spherical coordinates to cartesian, the scan's pose applied, invalid states
//! left out, intensity and colour normalised to their declared limits.

use e57::{PointCloud, RecordDataType, RecordName, RecordValue};

// The values a point is made of come from `records.rs`, one per record of the
// prototype, already as numbers (scaled integers scaled).

/// The attribute columns of a file (the union over its scans), by role.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Layout {
    pub names: Vec<String>,
    pub intensity: Option<usize>,
    /// Red; green and blue follow it.
    pub color: Option<usize>,
    pub row: Option<usize>,
    pub column: Option<usize>,
    pub return_number: Option<usize>,
    pub number_of_returns: Option<usize>,
    pub time: Option<usize>,
    pub scan: Option<usize>,
}

fn has(pc: &PointCloud, n: &RecordName) -> bool {
    pc.prototype.iter().any(|r| &r.name == n)
}

impl Layout {
    /// The columns of `scans`: each attribute any scan has, and `scan` when
    /// there are several.
    pub fn of(scans: &[PointCloud]) -> Layout {
        let mut l = Layout::default();
        let any = |n: RecordName| scans.iter().any(|pc| has(pc, &n));
        let mut add = |name: &str| {
            l.names.push(name.to_string());
            Some(l.names.len() - 1)
        };
        let intensity = any(RecordName::Intensity)
            .then(|| add("intensity"))
            .flatten();
        let color = any(RecordName::ColorRed).then(|| {
            let r = add("red");
            add("green");
            add("blue");
            r
        });
        let row = any(RecordName::RowIndex).then(|| add("row")).flatten();
        let column = any(RecordName::ColumnIndex)
            .then(|| add("column"))
            .flatten();
        let return_number = any(RecordName::ReturnIndex)
            .then(|| add("return_number"))
            .flatten();
        let number_of_returns = any(RecordName::ReturnCount)
            .then(|| add("number_of_returns"))
            .flatten();
        let time = any(RecordName::TimeStamp).then(|| add("time")).flatten();
        let scan = (scans.len() > 1).then(|| add("scan")).flatten();
        Layout {
            intensity,
            color: color.flatten(),
            row,
            column,
            return_number,
            number_of_returns,
            time,
            scan,
            ..l
        }
    }
}

/// A value's position in the prototype and how to scale it to `0..=1`.
#[derive(Debug, Clone, Copy)]
struct Norm {
    at: usize,
    min: f64,
    inv: f64,
}

impl Norm {
    fn new(at: usize, min: f64, max: f64) -> Norm {
        let range = max - min;
        Norm {
            at,
            min,
            inv: if range > 0.0 && range.is_finite() {
                1.0 / range
            } else {
                0.0
            },
        }
    }
}

/// A limit of the file's `intensityLimits` / `colorLimits`.
fn limit(v: &Option<RecordValue>) -> Option<f64> {
    match v {
        Some(RecordValue::Double(d)) => Some(*d),
        Some(RecordValue::Single(s)) => Some(*s as f64),
        Some(RecordValue::Integer(i)) | Some(RecordValue::ScaledInteger(i)) => Some(*i as f64),
        None => None,
    }
}

/// The range of a record type, when it declares one.
fn type_range(dt: &RecordDataType) -> Option<(f64, f64)> {
    match dt {
        RecordDataType::Single { min, max } => Some(((*min)? as f64, (*max)? as f64)),
        RecordDataType::Double { min, max } => Some(((*min)?, (*max)?)),
        RecordDataType::ScaledInteger {
            min,
            max,
            scale,
            offset,
        } => Some((*min as f64 * scale + offset, *max as f64 * scale + offset)),
        RecordDataType::Integer { min, max } => Some((*min as f64, *max as f64)),
    }
}

/// How to read one scan's records.
pub struct Scan {
    cart: Option<[usize; 3]>,
    cart_state: Option<usize>,
    sph: Option<[usize; 3]>,
    sph_state: Option<usize>,
    intensity: Option<Norm>,
    intensity_state: Option<usize>,
    color: Option<[Norm; 3]>,
    color_state: Option<usize>,
    row: Option<usize>,
    column: Option<usize>,
    return_index: Option<usize>,
    return_count: Option<usize>,
    time: Option<usize>,
    /// Row-major rotation and the translation of the pose.
    rotation: [f64; 9],
    translation: [f64; 3],
    index: usize,
}

/// The values of one point, as [`Scan::point`] gives them.
pub enum Point {
    /// Coordinates, and each attribute of the layout in order.
    Valid([f64; 3]),
    /// Marked invalid (or only a direction): left out.
    Invalid,
}

impl Scan {
    pub fn new(pc: &PointCloud, index: usize) -> Scan {
        let at = |n: RecordName| pc.prototype.iter().position(|r| r.name == n);
        let triple = |a, b, c| match (at(a), at(b), at(c)) {
            (Some(a), Some(b), Some(c)) => Some([a, b, c]),
            _ => None,
        };
        let types: Vec<&RecordDataType> = pc.prototype.iter().map(|r| &r.data_type).collect();
        let norm = |i: usize, lim: (Option<f64>, Option<f64>)| {
            let (lo, hi) = match lim {
                (Some(lo), Some(hi)) => (lo, hi),
                _ => type_range(types[i]).unwrap_or((0.0, 1.0)),
            };
            Norm::new(i, lo, hi)
        };
        let intensity = at(RecordName::Intensity).map(|i| {
            let l = pc.intensity_limits.as_ref();
            norm(
                i,
                (
                    l.and_then(|l| limit(&l.intensity_min)),
                    l.and_then(|l| limit(&l.intensity_max)),
                ),
            )
        });
        let color = triple(
            RecordName::ColorRed,
            RecordName::ColorGreen,
            RecordName::ColorBlue,
        )
        .map(|[r, g, b]| {
            let l = pc.color_limits.as_ref();
            [
                norm(
                    r,
                    (
                        l.and_then(|l| limit(&l.red_min)),
                        l.and_then(|l| limit(&l.red_max)),
                    ),
                ),
                norm(
                    g,
                    (
                        l.and_then(|l| limit(&l.green_min)),
                        l.and_then(|l| limit(&l.green_max)),
                    ),
                ),
                norm(
                    b,
                    (
                        l.and_then(|l| limit(&l.blue_min)),
                        l.and_then(|l| limit(&l.blue_max)),
                    ),
                ),
            ]
        });
        let (rotation, translation) = pose(pc);
        Scan {
            cart: triple(
                RecordName::CartesianX,
                RecordName::CartesianY,
                RecordName::CartesianZ,
            ),
            cart_state: at(RecordName::CartesianInvalidState),
            sph: triple(
                RecordName::SphericalRange,
                RecordName::SphericalAzimuth,
                RecordName::SphericalElevation,
            ),
            sph_state: at(RecordName::SphericalInvalidState),
            intensity,
            intensity_state: at(RecordName::IsIntensityInvalid),
            color,
            color_state: at(RecordName::IsColorInvalid),
            row: at(RecordName::RowIndex),
            column: at(RecordName::ColumnIndex),
            return_index: at(RecordName::ReturnIndex),
            return_count: at(RecordName::ReturnCount),
            time: at(RecordName::TimeStamp),
            rotation,
            translation,
            index,
        }
    }

    /// Whether the scan has coordinates at all.
    pub(crate) fn has_coordinates(&self) -> bool {
        self.cart.is_some() || self.sph.is_some()
    }

    fn get(v: &[f64], i: usize) -> f64 {
        v.get(i).copied().unwrap_or(0.0)
    }

    /// Whether the state value at `i` (when the scan has one) says "valid" (0).
    fn valid(v: &[f64], i: Option<usize>) -> bool {
        i.is_none_or(|i| Self::get(v, i) == 0.0)
    }

    /// The point of the record values `v`: its coordinates in the file's
    /// frame, and its attributes written into `attrs` (laid out by `layout`).
    pub fn point(&self, v: &[f64], layout: &Layout, attrs: &mut [f64]) -> Point {
        let get = |i| Self::get(v, i);
        let local = if let (Some([x, y, z]), true) = (self.cart, Self::valid(v, self.cart_state)) {
            [get(x), get(y), get(z)]
        } else if let (Some([r, a, e]), true) = (self.sph, Self::valid(v, self.sph_state)) {
            let (r, a, e) = (get(r), get(a), get(e));
            [r * e.cos() * a.cos(), r * e.cos() * a.sin(), r * e.sin()]
        } else {
            return Point::Invalid;
        };
        let m = &self.rotation;
        let p = [
            m[0] * local[0] + m[1] * local[1] + m[2] * local[2] + self.translation[0],
            m[3] * local[0] + m[4] * local[1] + m[5] * local[2] + self.translation[1],
            m[6] * local[0] + m[7] * local[1] + m[8] * local[2] + self.translation[2],
        ];
        attrs.fill(0.0);
        let unit = |n: &Norm| ((get(n.at) - n.min) * n.inv).clamp(0.0, 1.0);
        if let (Some(n), Some(a)) = (&self.intensity, layout.intensity)
            && Self::valid(v, self.intensity_state)
        {
            attrs[a] = unit(n);
        }
        if let (Some(c), Some(a)) = (&self.color, layout.color)
            && Self::valid(v, self.color_state)
        {
            for k in 0..3 {
                attrs[a + k] = unit(&c[k]) * 255.0;
            }
        }
        let plain = [
            (self.row, layout.row, 0.0),
            (self.column, layout.column, 0.0),
            // E57 counts returns from 0, LAS (whose band names these are) from 1.
            (self.return_index, layout.return_number, 1.0),
            (self.return_count, layout.number_of_returns, 0.0),
            (self.time, layout.time, 0.0),
        ];
        for (from, to, plus) in plain {
            if let (Some(i), Some(a)) = (from, to) {
                attrs[a] = get(i) + plus;
            }
        }
        if let Some(a) = layout.scan {
            attrs[a] = self.index as f64;
        }
        Point::Valid(p)
    }
}

/// The lattice every scan's points lie on, when there is one: each scan's
/// cartesian x, y and z are scaled integers (`raw · scale + offset`), its pose
/// has no rotation (an identity matrix: a turned lattice is no grid of the
/// file's axes), and every scan's steps are the same and its lattice points
/// (offset plus translation) one lattice apart from the first's. Spherical
/// coordinates and floats have none.
pub fn lattice(scans: &[PointCloud]) -> Option<crate::points::Lattice> {
    const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let mut found: Option<crate::points::Lattice> = None;
    for pc in scans {
        let (m, t) = pose(pc);
        if m != IDENTITY {
            return None;
        }
        let mut step = [0.0; 3];
        let mut origin = [0.0; 3];
        for (a, name) in [
            RecordName::CartesianX,
            RecordName::CartesianY,
            RecordName::CartesianZ,
        ]
        .into_iter()
        .enumerate()
        {
            let r = pc.prototype.iter().find(|r| r.name == name)?;
            let RecordDataType::ScaledInteger { scale, offset, .. } = r.data_type else {
                return None;
            };
            if !(scale.is_finite() && scale > 0.0 && offset.is_finite() && t[a].is_finite()) {
                return None;
            }
            step[a] = scale;
            origin[a] = offset + t[a];
        }
        match &found {
            None => found = Some(crate::points::Lattice { step, origin }),
            Some(l) => {
                for a in 0..3 {
                    let k = (origin[a] - l.origin[a]) / l.step[a];
                    if step[a] != l.step[a] || (k - k.round()).abs() > 1e-6 {
                        return None;
                    }
                }
            }
        }
    }
    found
}

/// The scan's pose: a row-major rotation matrix (of the quaternion, normalised)
/// and the translation; identity without one.
pub fn pose(pc: &PointCloud) -> ([f64; 9], [f64; 3]) {
    let Some(t) = &pc.transform else {
        return ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], [0.0; 3]);
    };
    let q = &t.rotation;
    let n = (q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z).sqrt();
    let (w, x, y, z) = if n > 0.0 {
        (q.w / n, q.x / n, q.y / n, q.z / n)
    } else {
        (1.0, 0.0, 0.0, 0.0)
    };
    (
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
        [t.translation.x, t.translation.y, t.translation.z],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quarter_turn_about_z() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let mut pc = PointCloud::default();
        pc.transform = Some(e57::Transform {
            rotation: e57::Quaternion {
                w: h,
                x: 0.0,
                y: 0.0,
                z: h,
            },
            translation: e57::Translation {
                x: 10.0,
                y: 0.0,
                z: 0.0,
            },
        });
        let (m, t) = pose(&pc);
        // (1, 0, 0) turns to (0, 1, 0), then moves by t.
        let p = [m[0] + t[0], m[3] + t[1], m[6] + t[2]];
        assert!((p[0] - 10.0).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12 && p[2].abs() < 1e-12);
    }
}
