//! Eye-dome lighting (Boucheny 2009, as in Potree/CloudCompare): a CPU post pass
//! that darkens each pixel by how much nearer its neighbours are, in log depth.
//! It brings out shape in uncoloured or flatly coloured clouds. Background pixels
//! (depth `INFINITY`) are left untouched and do not shade their neighbours.

use rayon::prelude::*;

/// Eye-dome lighting parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdlParams {
    /// Shading strength (Potree's default 1.0).
    pub strength: f32,
    /// Neighbour distance in pixels.
    pub radius: u32,
}

impl Default for EdlParams {
    fn default() -> Self {
        EdlParams {
            strength: 1.0,
            radius: 1,
        }
    }
}

/// Shades `rgba` (`width*height*4`) in place from the linear view depth `depth`
/// (`width*height`, `INFINITY` or non-positive for background). Mismatched
/// sizes leave the image unchanged.
pub fn apply(rgba: &mut [u8], depth: &[f32], width: u32, height: u32, p: &EdlParams) {
    let (w, h) = (width as usize, height as usize);
    let n = w * h;
    if n == 0 || rgba.len() != n * 4 || depth.len() != n {
        return;
    }
    // log2 depth, NaN for background.
    let logd: Vec<f32> = depth
        .par_iter()
        .map(|&d| {
            if d.is_finite() && d > 0.0 {
                d.log2()
            } else {
                f32::NAN
            }
        })
        .collect();
    let r = p.radius.max(1) as isize;
    let offsets: [(isize, isize); 8] = [
        (r, 0),
        (-r, 0),
        (0, r),
        (0, -r),
        (r, r),
        (-r, r),
        (r, -r),
        (-r, -r),
    ];
    let k = 300.0 * p.strength;
    rgba.par_chunks_mut(w * 4).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let l = logd[y * w + x];
            if l.is_nan() {
                continue;
            }
            let mut sum = 0.0f32;
            for &(dx, dy) in &offsets {
                let nx = x as isize + dx;
                let ny = y as isize + dy;
                if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                    continue;
                }
                let ln = logd[ny as usize * w + nx as usize];
                if !ln.is_nan() {
                    sum += (l - ln).max(0.0);
                }
            }
            if sum <= 0.0 {
                continue;
            }
            let shade = (-(sum / 8.0) * k).exp();
            for c in &mut row[x * 4..x * 4 + 3] {
                *c = (*c as f32 * shade + 0.5) as u8;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edl_darkens_far_side_of_an_edge_and_skips_background() {
        let (w, h) = (8u32, 4u32);
        let n = (w * h) as usize;
        let mut rgba = vec![200u8; n * 4];
        let mut depth = vec![10.0f32; n];
        for y in 0..h as usize {
            for x in 4..w as usize {
                depth[y * w as usize + x] = 20.0; // far half
            }
            depth[y * w as usize] = f32::INFINITY; // background column
        }
        apply(&mut rgba, &depth, w, h, &EdlParams::default());
        let px = |x: usize, y: usize| rgba[(y * w as usize + x) * 4];
        assert_eq!(px(0, 1), 200, "background untouched");
        assert_eq!(px(2, 1), 200, "flat near region untouched");
        assert!(px(4, 1) < 150, "far pixel next to a near one is darkened");
        assert_eq!(px(6, 1), 200);
        // Size mismatch: no-op, no panic.
        let mut small = vec![1u8; 4];
        apply(&mut small, &depth, w, h, &EdlParams::default());
        apply(&mut [], &[], 0, 0, &EdlParams::default());
    }
}
