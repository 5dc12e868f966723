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

/// `e^-x` for `x >= 0` (under 2e-4 relative error), branch-free so the shading
/// loop vectorizes; plenty for 8-bit colour.
#[inline(always)]
fn fast_exp_neg(x: f32) -> f32 {
    // 2^(-x log2 e) = 2^-i * 2^-f with i integer, f in [0, 1).
    // Truncation is floor for t >= 0 (and needs no libm call without SSE4.1).
    let t = (x * std::f32::consts::LOG2_E).clamp(0.0, 126.0);
    let i = t as i32;
    let f = t - i as f32;
    // 2^-f on [0, 1): Taylor series of e^(-f ln 2) to the 5th power.
    let p = 1.0
        + f * (-std::f32::consts::LN_2
            + f * (0.240_226_5 + f * (-0.055_504_11 + f * (0.009_618_13 - f * 0.001_333_36))));
    p * f32::from_bits(((127 - i) as u32) << 23)
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
    let r = p.radius.clamp(1, 64) as usize;
    // log2 depth with an r-pixel border; background and border are +inf, so a
    // background neighbour adds max(0, l - inf) = 0 and needs no test.
    let pw = w + 2 * r;
    let mut logd = vec![f32::INFINITY; pw * (h + 2 * r)];
    logd[r * pw..(r + h) * pw]
        .par_chunks_mut(pw)
        .zip(depth.par_chunks(w))
        .for_each(|(dst, src)| {
            for (o, &d) in dst[r..r + w].iter_mut().zip(src) {
                *o = if d.is_finite() && d > 0.0 {
                    d.log2()
                } else {
                    f32::INFINITY
                };
            }
        });
    // Potree: shade = exp(-300 * strength * mean difference).
    let k = (300.0 / 8.0)
        * if p.strength.is_finite() {
            p.strength.max(0.0)
        } else {
            0.0
        };
    let logd = &logd;
    rgba.par_chunks_mut(w * 4).enumerate().for_each_init(
        || vec![1.0f32; w],
        |shade, (y, row)| {
            // Padded rows y (above), y + r (this one) and y + 2r (below); pixel
            // x of this row is at column x + r.
            let up = &logd[y * pw..(y + 1) * pw];
            let mid = &logd[(y + r) * pw..(y + r + 1) * pw];
            let down = &logd[(y + 2 * r) * pw..(y + 2 * r + 1) * pw];
            // Branch-free so it vectorizes: background pixels get shade 1.
            for (x, s) in shade.iter_mut().enumerate() {
                let l = mid[x + r];
                let d = |n: f32| (l - n).max(0.0);
                // Neighbours at (±r, 0), (0, ±r) and the four diagonals.
                let sum = d(mid[x])
                    + d(mid[x + 2 * r])
                    + d(up[x + r])
                    + d(down[x + r])
                    + d(up[x])
                    + d(up[x + 2 * r])
                    + d(down[x])
                    + d(down[x + 2 * r]);
                let v = fast_exp_neg(sum * k);
                *s = if l == f32::INFINITY { 1.0 } else { v };
            }
            for (px, &s) in row.chunks_exact_mut(4).zip(shade.iter()) {
                if s < 1.0 {
                    for c in &mut px[..3] {
                        *c = (*c as f32 * s + 0.5) as u8;
                    }
                }
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_is_close() {
        for i in 0..2000 {
            let x = i as f32 * 0.05;
            let (a, b) = (fast_exp_neg(x), (-x).exp());
            assert!((a - b).abs() <= 5e-4 * b + 1e-30, "{x}: {a} vs {b}");
        }
        assert_eq!(fast_exp_neg(1e30), fast_exp_neg(1000.0));
        assert!(fast_exp_neg(1000.0) < 1e-30);
    }

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
