//! Picking: which point a frame shows at a pixel. The frame path keeps no
//! per-pixel point index (that would add a 4-byte write per splat to every
//! frame); instead a pick projects the frame's points again with the CPU
//! rasterizer's own transform (`Projector`) and keeps, for the pixels near
//! the cursor, the point with the smallest packed `depth << 32 | colour`: the
//! very point the CPU rasterizer drew there. It costs one pass over the drawn
//! points, only when the user picks.

use glam::DVec3;
use rayon::prelude::*;

use super::cpu::Projector;
use super::{Camera, PointBatch, RenderError, RenderOptions, total_points};

/// The point shown at a pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Which batch, and which point of it.
    pub batch: usize,
    pub index: usize,
    /// The pixel it covers nearest the cursor.
    pub pixel: (u32, u32),
    /// Its world position (`origin + stored`, in f64).
    pub position: [f64; 3],
}

/// The point drawn nearest pixel `(x, y)` (column, row from the top-left),
/// looking up to `radius` pixels away (0: that pixel only); `None` when no point
/// is drawn there. Ties in distance go to the nearer point.
pub fn pick(
    camera: &Camera,
    batches: &[PointBatch<'_>],
    opts: &RenderOptions,
    x: u32,
    y: u32,
    radius: u32,
) -> Result<Option<Hit>, RenderError> {
    let point_size = opts.validate()?;
    total_points(batches)?;
    if x >= opts.width || y >= opts.height {
        return Err(RenderError::InvalidOptions(format!(
            "pixel ({x}, {y}) lies outside the {}x{} frame",
            opts.width, opts.height
        )));
    }
    let (w, h) = (opts.width, opts.height);
    let r = radius.min(256) as i64;
    let (x0, y0) = ((x as i64 - r).max(0), (y as i64 - r).max(0));
    let (x1, y1) = (
        (x as i64 + r).min(w as i64 - 1),
        (y as i64 + r).min(h as i64 - 1),
    );
    let ww = (x1 - x0 + 1) as usize;
    let cells = ww * (y1 - y0 + 1) as usize;
    let aspect = opts.aspect();
    // Per window pixel: (packed, batch, index); merged over chunks with min.
    type Best = Vec<(u64, usize, usize)>;
    let empty = || vec![(u64::MAX, 0usize, 0usize); cells];
    let mut items = Vec::new();
    for (bi, b) in batches.iter().enumerate() {
        let mut s = 0;
        while s < b.len() {
            items.push((bi, s, (s + (1 << 16)).min(b.len())));
            s += 1 << 16;
        }
    }
    let projs: Vec<Projector> = batches
        .iter()
        .map(|b| Projector::new(camera.view_proj_aspect(b.origin, aspect), w, h, point_size))
        .collect();
    let best: Best = items
        .par_iter()
        .fold(empty, |mut best, &(bi, s, e)| {
            projs[bi].splat(&batches[bi], s, e, |i, v, j| {
                let (px, py) = ((i % w as usize) as i64, (i / w as usize) as i64);
                if px < x0 || px > x1 || py < y0 || py > y1 {
                    return;
                }
                let c = (py - y0) as usize * ww + (px - x0) as usize;
                if (v, bi, j) < best[c] {
                    best[c] = (v, bi, j);
                }
            });
            best
        })
        .reduce(empty, |a, b| {
            a.into_iter().zip(b).map(|(p, q)| p.min(q)).collect()
        });
    let hit = best
        .iter()
        .enumerate()
        .filter(|(_, b)| b.0 != u64::MAX)
        .min_by_key(|(c, b)| {
            let (px, py) = ((c % ww) as i64 + x0, (c / ww) as i64 + y0);
            let d2 = (px - x as i64).pow(2) + (py - y as i64).pow(2);
            (d2, b.0)
        });
    Ok(hit.map(|(c, &(_, bi, j))| {
        let b = &batches[bi];
        let p = DVec3::from(b.origin) + DVec3::new(b.x[j] as f64, b.y[j] as f64, b.z[j] as f64);
        Hit {
            batch: bi,
            index: j,
            pixel: (((c % ww) as i64 + x0) as u32, ((c / ww) as i64 + y0) as u32),
            position: p.to_array(),
        }
    }))
}

/// Distances between two points: straight, horizontal (x y) and vertical (z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distance {
    pub d3: f64,
    pub horizontal: f64,
    pub vertical: f64,
}

/// The distances from `a` to `b` (vertical is signed: `b` above `a` is positive).
pub fn distance(a: [f64; 3], b: [f64; 3]) -> Distance {
    let (dx, dy, dz) = (b[0] - a[0], b[1] - a[1], b[2] - a[2]);
    let horizontal = (dx * dx + dy * dy).sqrt();
    Distance {
        d3: (horizontal * horizontal + dz * dz).sqrt(),
        horizontal,
        vertical: dz,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        let d = distance([0.0, 0.0, 0.0], [3.0, 4.0, 12.0]);
        assert_eq!((d.d3, d.horizontal, d.vertical), (13.0, 5.0, 12.0));
        assert_eq!(distance([1.0, 1.0, 5.0], [1.0, 1.0, 2.0]).vertical, -3.0);
    }
}
