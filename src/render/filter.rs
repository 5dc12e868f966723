//! Which points are drawn: a class mask (`--classes`, `--exclude-classes`, the
//! inspector's legend), band ranges (`--where NAME=LO..HI`) and a clip box
//! (`--clip`). A filter is applied once per tile when a scene is built: hidden
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
                "--where '{s}': expected NAME=VALUE or NAME=LO..HI (either end may be left \
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
            return Err(format!(
                "--where '{s}': the low end lies above the high end"
            ));
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
}

/// Parses `--clip MINX,MINY,MINZ,MAXX,MAXY,MAXZ`.
pub fn parse_clip(s: &str) -> Result<Bounds, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--clip '{s}': expected six numbers MINX,MINY,MINZ,MAXX,MAXY,MAXZ"))?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "--clip '{s}': expected six finite numbers MINX,MINY,MINZ,MAXX,MAXY,MAXZ"
        ));
    }
    if (0..3).any(|a| v[a] > v[a + 3]) {
        return Err(format!("--clip '{s}': a minimum lies above its maximum"));
    }
    Ok(Bounds {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
    })
}

impl Filter {
    /// Whether every point is drawn.
    pub fn is_empty(&self) -> bool {
        self.classes.all() && self.wheres.is_empty() && self.clip.is_none()
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
        if let Some(c) = &self.clip {
            let o = t.origin;
            for (i, k) in keep.iter_mut().enumerate() {
                let p = [
                    t.x[i] as f64 + o[0],
                    t.y[i] as f64 + o[1],
                    t.z[i] as f64 + o[2],
                ];
                *k &= (0..3).all(|a| p[a] >= c.min[a] && p[a] <= c.max[a]);
            }
        }
        if keep.iter().all(|&k| k) {
            None
        } else {
            Some(keep)
        }
    }

    /// `t`'s heights with the hidden points set to NaN; `None` when all are drawn.
    pub fn hidden_z(&self, t: &LoadedTile) -> Option<Vec<f32>> {
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
    }
}
