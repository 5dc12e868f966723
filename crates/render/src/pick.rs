//! Picking: which point a frame shows at a pixel. A rasterizer asked to
//! (`Rasterizer::keep_ids`) keeps, per pixel, the id of the point that won it
//! ([`point_id`]: batch and index); [`from_ids`] reads that buffer. The CPU
//! and wgpu rasterizers fill it with a second projection pass over the frame's
//! points only when a pick is asked for, so frames nobody picks in cost nothing
//! more. Without an id buffer (a frame too large for 32-bit device ids),
//! [`pick`] projects the points again with the CPU rasterizer's own transform
//! (`Projector`) and keeps, near the cursor, the point with the smallest packed
//! `depth << 32 | colour`.

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

/// An id buffer's value where no point was drawn.
pub const NO_POINT: u64 = u64::MAX;

/// The id of point `index` of batch `batch` in an id buffer.
pub fn point_id(batch: usize, index: usize) -> u64 {
    ((batch as u64) << 32) | index as u64
}

/// The pixel nearest `(x, y)` within `radius` whose id is set in `ids` (a
/// `width`×`height` buffer from `Rasterizer::last_ids`), resolved to its point
/// in `batches` (those the frame was drawn from). Ties in distance go to the
/// smaller id.
pub fn from_ids(
    ids: &[u64],
    batches: &[PointBatch<'_>],
    width: u32,
    height: u32,
    x: u32,
    y: u32,
    radius: u32,
) -> Result<Option<Hit>, RenderError> {
    if ids.len() != width as usize * height as usize {
        return Err(RenderError::InvalidInput(format!(
            "id buffer holds {} pixels, not {width}x{height}",
            ids.len()
        )));
    }
    if x >= width || y >= height {
        return Err(RenderError::InvalidOptions(format!(
            "pixel ({x}, {y}) lies outside the {width}x{height} frame"
        )));
    }
    let r = radius.min(256) as i64;
    let mut best: Option<(i64, u64, (u32, u32))> = None;
    for py in (y as i64 - r).max(0)..=(y as i64 + r).min(height as i64 - 1) {
        for px in (x as i64 - r).max(0)..=(x as i64 + r).min(width as i64 - 1) {
            let id = ids[py as usize * width as usize + px as usize];
            if id == NO_POINT {
                continue;
            }
            let d2 = (px - x as i64).pow(2) + (py - y as i64).pow(2);
            if best.is_none_or(|b| (d2, id) < (b.0, b.1)) {
                best = Some((d2, id, (px as u32, py as u32)));
            }
        }
    }
    let Some((_, id, pixel)) = best else {
        return Ok(None);
    };
    let (bi, j) = ((id >> 32) as usize, (id & 0xffff_ffff) as usize);
    let b = batches.get(bi).filter(|b| j < b.len()).ok_or_else(|| {
        RenderError::InvalidInput(format!(
            "id buffer names point {j} of batch {bi}, which the frame does not hold"
        ))
    })?;
    let p = DVec3::from(b.origin) + DVec3::new(b.x[j] as f64, b.y[j] as f64, b.z[j] as f64);
    Ok(Some(Hit {
        batch: bi,
        index: j,
        pixel,
        position: p.to_array(),
    }))
}

/// The point `renderer` drew nearest `(x, y)` in its last frame (drawn from
/// `batches` with `camera` and `opts`): read from its id buffer when it kept
/// one, else found by [`pick`]'s projection.
pub(crate) fn pick_drawn(
    renderer: &dyn super::Rasterizer,
    camera: &Camera,
    batches: &[PointBatch<'_>],
    opts: &RenderOptions,
    x: u32,
    y: u32,
    radius: u32,
) -> Result<Option<Hit>, RenderError> {
    match renderer.last_ids() {
        Some(ids) => from_ids(ids, batches, opts.width, opts.height, x, y, radius),
        None => pick(camera, batches, opts, x, y, radius),
    }
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
