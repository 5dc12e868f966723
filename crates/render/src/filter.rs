//! Which points are drawn: a class mask (`--classes`, `--exclude-classes`, the
//! inspector's legend), band ranges (`--where NAME=LO..HI`) and a clip box
//! (`--clip`) and a slab, a thickness around any plane (`--slab`). A filter is applied once per tile when a scene is built: hidden
//! points get a NaN height in a copy of the tile's `z`, which every rasterizer
//! already rejects in its clip test, so the frame path itself is unchanged and
//! point indices stay those of the tile (picking maps back without a table).

use super::classes::ClassMask;
use crate::lod::LoadedTile;
use crate::points::Bounds;

/// Points kept by a band range: `lo <= value <= hi` in source units.
#[derive(Debug, Clone, PartialEq)]
pub struct Where {
    pub band: String,
    pub lo: f64,
    pub hi: f64,
}

impl Where {
    /// Parses `NAME=V`, `NAME=LO..HI`, `NAME=LO..` or `NAME=..HI`.
    pub fn parse(s: &str) -> Result<Where, String> {
        let bad = || {
            format!(
                "'{s}': expected NAME=VALUE or NAME=LO..HI (either end may be left \
                 out), e.g. return_number=1 or z=400..450"
            )
        };
        let (name, v) = s.split_once('=').ok_or_else(bad)?;
        let name = name.trim();
        if name.is_empty() {
            return Err(bad());
        }
        let num = |t: &str, empty: f64| -> Result<f64, String> {
            let t = t.trim();
            if t.is_empty() {
                return Ok(empty);
            }
            t.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(bad)
        };
        let (lo, hi) = match v.split_once("..") {
            Some((a, b)) => (num(a, f64::NEG_INFINITY)?, num(b, f64::INFINITY)?),
            None if !v.trim().is_empty() => {
                let x = num(v, 0.0)?;
                (x, x)
            }
            None => return Err(bad()),
        };
        if lo > hi {
            return Err(format!("'{s}': the low end lies above the high end"));
        }
        Ok(Where {
            band: name.to_string(),
            lo,
            hi,
        })
    }
}

/// What a frame draws of the points it is given.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Filter {
    pub classes: ClassMask,
    pub wheres: Vec<Where>,
    /// Only points inside this box (world coordinates) are drawn.
    pub clip: Option<Bounds>,
    /// Only points within this slab are drawn.
    pub slab: Option<Slab>,
}

/// The points within `half` of the plane through `point` with unit `normal`
/// (world coordinates): a section of any orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    pub point: [f64; 3],
    pub normal: [f64; 3],
    pub half: f64,
}

impl Slab {
    /// A slab `thickness` thick around the plane through `point` across
    /// `normal` (normalized here); `None` for a zero normal or a thickness that
    /// is not positive and finite.
    pub fn new(point: [f64; 3], normal: [f64; 3], thickness: f64) -> Option<Slab> {
        let l = normal.iter().map(|v| v * v).sum::<f64>().sqrt();
        let ok = l.is_finite() && l > 0.0 && thickness.is_finite() && thickness > 0.0;
        (ok && point.iter().all(|v| v.is_finite())).then(|| Slab {
            point,
            normal: normal.map(|v| v / l),
            half: thickness * 0.5,
        })
    }

    /// Signed distance of `p` from the plane.
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        (0..3)
            .map(|a| (p[a] - self.point[a]) * self.normal[a])
            .sum()
    }

    /// Whether `p` lies within the slab.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.distance(p).abs() <= self.half
    }

    /// Whether a box may hold a point of the slab: the box's centre is no
    /// farther from the plane than its half extent along the normal plus the
    /// slab's half thickness.
    pub fn touches(&self, b: &Bounds) -> bool {
        let c = b.center();
        let reach: f64 = (0..3)
            .map(|a| 0.5 * (b.max[a] - b.min[a]) * self.normal[a].abs())
            .sum();
        self.distance(c).abs() <= reach + self.half
    }
}

impl Slab {
    /// A camera looking across the slab (along its normal, from the side
    /// `current` looks from) at its point, far enough back to see all of
    /// `bounds` cut by it: the profile.
    pub fn profile_camera(
        &self,
        bounds: &Bounds,
        current: &crate::camera::Camera,
    ) -> crate::camera::Camera {
        let mut c = *current;
        let n = glam::DVec3::from(self.normal);
        let f = if current.forward().dot(n) >= 0.0 {
            n
        } else {
            -n
        };
        c.mode = crate::camera::CameraMode::Orbit;
        c.yaw = f.y.atan2(f.x);
        c.pitch = f.z.clamp(-1.0, 1.0).asin();
        c.target = glam::DVec3::from(self.point);
        // Frame the cut: the data's extent across the image (level, along the
        // plane) at a 16:9 aspect, and up it.
        let e = bounds.extent();
        let mut u = glam::DVec3::Z.cross(f).normalize_or_zero();
        if u == glam::DVec3::ZERO {
            u = glam::DVec3::X;
        }
        let v = u.cross(f);
        let across = |d: glam::DVec3| e[0] * d.x.abs() + e[1] * d.y.abs() + e[2] * d.z.abs();
        let (run, rise) = (across(u), across(v));
        let t = (0.5 * c.fov_y).tan();
        c.distance = (run * 0.55 / (t * 16.0 / 9.0))
            .max(rise * 0.6 / t)
            .max(1e-3);
        c.set_clip_from_bounds(bounds);
        c
    }

    /// Turns the plane about the vertical by `radians` (its point stays).
    pub fn rotate(&mut self, radians: f64) {
        let (s, c) = radians.sin_cos();
        let [x, y, z] = self.normal;
        self.normal = [c * x - s * y, s * x + c * y, z];
    }
}

/// Parses `--slab X,Y,Z,NX,NY,NZ,THICK`.
pub fn parse_slab(s: &str) -> Result<Slab, String> {
    let bad = || {
        format!(
            "'{s}': expected seven numbers X,Y,Z,NX,NY,NZ,THICK (a point, the \
             plane's normal, not zero, and a positive thickness)"
        )
    };
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    if v.len() != 7 {
        return Err(bad());
    }
    Slab::new([v[0], v[1], v[2]], [v[3], v[4], v[5]], v[6]).ok_or_else(bad)
}

/// Parses `--clip MINX,MINY,MINZ,MAXX,MAXY,MAXZ`.
pub fn parse_clip(s: &str) -> Result<Bounds, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}': expected six numbers MINX,MINY,MINZ,MAXX,MAXY,MAXZ"))?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "'{s}': expected six finite numbers MINX,MINY,MINZ,MAXX,MAXY,MAXZ"
        ));
    }
    if (0..3).any(|a| v[a] > v[a + 3]) {
        return Err(format!("'{s}': a minimum lies above its maximum"));
    }
    Ok(Bounds {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
    })
}

impl Filter {
    /// Whether every point is drawn.
    pub fn is_empty(&self) -> bool {
        self.classes.all() && self.wheres.is_empty() && self.clip.is_none() && self.slab.is_none()
    }

    /// The bands the filter reads besides x, y, z.
    pub fn bands(&self) -> Vec<String> {
        let mut b: Vec<String> = self
            .wheres
            .iter()
            .map(|w| w.band.clone())
            .filter(|n| !["x", "y", "z"].contains(&n.as_str()))
            .collect();
        if !self.classes.all() {
            b.push("classification".into());
        }
        b.sort();
        b.dedup();
        b
    }

    /// Whether a tile with `bounds` may hold a drawn point (the clip box culls).
    pub fn may_show(&self, bounds: &Bounds) -> bool {
        self.clip.is_none_or(|c| c.intersects(bounds))
            && self.slab.is_none_or(|s| s.touches(bounds))
    }

    /// Per point of `t`, whether it is drawn; `None` when all are.
    pub fn shown(&self, t: &LoadedTile) -> Option<Vec<bool>> {
        if self.is_empty() {
            return None;
        }
        let n = t.len();
        let mut keep = vec![true; n];
        if !self.classes.all() {
            match t.attribute("classification") {
                Some(c) => {
                    for (k, &v) in keep.iter_mut().zip(c) {
                        *k = self.classes.shows_value(v);
                    }
                }
                // A part without classes has none of the classes shown.
                None => keep.fill(false),
            }
        }
        for w in &self.wheres {
            let (col, off): (&[f32], f64) = match w.band.as_str() {
                "x" => (&t.x, t.origin[0]),
                "y" => (&t.y, t.origin[1]),
                "z" => (&t.z, t.origin[2]),
                b => match t.attributes.iter().find(|a| a.0 == b) {
                    Some(a) => (&a.2, a.1),
                    None => {
                        keep.fill(false);
                        continue;
                    }
                },
            };
            // In stored units: lo - off <= v <= hi - off (f64 for exactness).
            for (k, &v) in keep.iter_mut().zip(col) {
                let s = v as f64 + off;
                *k &= s >= w.lo && s <= w.hi;
            }
        }
        // The clip box and the slab test each point's world position.
        let clip = self.clip.as_ref();
        let slab = self.slab.as_ref();
        if clip.is_some() || slab.is_some() {
            let o = t.origin;
            for (i, k) in keep.iter_mut().enumerate() {
                let p = [
                    t.x[i] as f64 + o[0],
                    t.y[i] as f64 + o[1],
                    t.z[i] as f64 + o[2],
                ];
                *k &= clip.is_none_or(|c| (0..3).all(|a| p[a] >= c.min[a] && p[a] <= c.max[a]))
                    && slab.is_none_or(|sl| sl.contains(p));
            }
        }
        if keep.iter().all(|&k| k) {
            None
        } else {
            Some(keep)
        }
    }

    /// `t`'s heights with the hidden points set to NaN; `None` when all are drawn.
    pub(crate) fn hidden_z(&self, t: &LoadedTile) -> Option<Vec<f32>> {
        let keep = self.shown(t)?;
        Some(
            t.z.iter()
                .zip(&keep)
                .map(|(&z, &k)| if k { z } else { f32::NAN })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses() {
        assert_eq!(
            Where::parse("return_number=1").unwrap(),
            Where {
                band: "return_number".into(),
                lo: 1.0,
                hi: 1.0
            }
        );
        let w = Where::parse("z=400..450").unwrap();
        assert_eq!((w.lo, w.hi), (400.0, 450.0));
        assert_eq!(Where::parse("z=..3").unwrap().lo, f64::NEG_INFINITY);
        assert_eq!(Where::parse("z=3..").unwrap().hi, f64::INFINITY);
        for bad in ["z", "=3", "z=", "z=a", "z=5..1", "z=1..2..3"] {
            assert!(Where::parse(bad).is_err(), "{bad}");
        }
        let c = parse_clip("0,0,0,1,2,3").unwrap();
        assert_eq!(c.max, [1.0, 2.0, 3.0]);
        assert!(parse_clip("0,0,0,1,2").is_err());
        assert!(parse_clip("0,0,5,1,2,3").is_err());
        assert!(parse_clip("0,0,0,1,2,inf").is_err());
        let sl = parse_slab("10,0,0,2,0,0,1").unwrap();
        assert_eq!(sl.normal, [1.0, 0.0, 0.0]);
        assert!(sl.contains([10.5, 7.0, -3.0]) && !sl.contains([10.51, 0.0, 0.0]));
        for bad in [
            "1,2,3",
            "0,0,0,0,0,0,1",
            "0,0,0,1,0,0,0",
            "0,0,0,1,0,0,-1",
            "a,0,0,1,0,0,1",
        ] {
            assert!(parse_slab(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_slab_touches_the_boxes_it_crosses() {
        // A vertical plane at 45° through the origin: x = y, 1 thick.
        let s = Slab::new([0.0; 3], [1.0, -1.0, 0.0], 1.0).unwrap();
        let b = |min: [f64; 3], max: [f64; 3]| Bounds { min, max };
        assert!(s.touches(&b([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0])));
        assert!(s.touches(&b([1.0, 1.5, 0.0], [2.0, 2.0, 1.0])));
        // Its nearest corner (2, 0) lies sqrt(2) from the plane: beyond 0.5.
        assert!(!s.touches(&b([2.0, -2.0, 0.0], [3.0, 0.0, 5.0])));
        // Every box that holds a point of the slab is touched.
        let p = [3.2, 3.0, 9.0];
        assert!(s.contains(p));
        assert!(s.touches(&b([3.1, 2.9, 8.0], [3.3, 3.1, 10.0])));
    }
}
