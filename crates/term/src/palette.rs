//! Reducing a frame to at most 256 colours for sixel: a histogram over 6 bits per
//! channel (only the bins a frame touches are visited), then median cut over the
//! occupied bins — the box with the largest squared error is split at the
//! pixel-weighted median of its widest channel — and every pixel takes its bin's
//! box. No dithering: dithered point clouds cost many more sixel bytes.
//!
//! Why adaptive rather than a fixed 6×6×6 cube: scans coloured by their own RGB
//! are muted (greens and browns of 40–120), and a cube with steps of 51 turns
//! them grey.

/// The most colours a palette holds (sixel terminals commonly have 256 registers).
pub const MAX_COLORS: usize = 256;

/// Bits per channel of the histogram.
const BITS: u32 = 6;

/// An image as palette indices.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Indexed {
    /// At most [`MAX_COLORS`] colours.
    pub palette: Vec<[u8; 3]>,
    /// One palette index per pixel, row-major.
    pub indices: Vec<u8>,
}

/// One occupied histogram bin.
#[derive(Debug, Clone, Copy)]
struct Bin {
    key: u32,
    /// The first colour seen in the bin: exact for images of few colours.
    rgb: [u8; 3],
    count: u64,
}

#[inline]
fn key(p: &[u8]) -> u32 {
    let s = 8 - BITS;
    ((p[0] >> s) as u32) << (2 * BITS) | ((p[1] >> s) as u32) << BITS | (p[2] >> s) as u32
}

/// Squared error of a box of bins around its weighted mean, and that mean.
fn box_error(bins: &[Bin]) -> (f64, [f64; 3]) {
    let n: f64 = bins.iter().map(|b| b.count as f64).sum();
    if n == 0.0 {
        return (0.0, [0.0; 3]);
    }
    let mut mean = [0.0f64; 3];
    for b in bins {
        for c in 0..3 {
            mean[c] += b.rgb[c] as f64 * b.count as f64;
        }
    }
    mean = mean.map(|m| m / n);
    let mut err = 0.0;
    for b in bins {
        for c in 0..3 {
            let d = b.rgb[c] as f64 - mean[c];
            err += d * d * b.count as f64;
        }
    }
    (err, mean)
}

/// Splits `bins` (more than one) along the channel of largest weighted variance
/// at the pixel-weighted median; returns the length of the first half (≥ 1).
fn split(bins: &mut [Bin]) -> usize {
    let n: f64 = bins.iter().map(|b| b.count as f64).sum();
    let (_, mean) = box_error(bins);
    let mut var = [0.0f64; 3];
    for b in bins.iter() {
        for c in 0..3 {
            let d = b.rgb[c] as f64 - mean[c];
            var[c] += d * d * b.count as f64;
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| var[a].total_cmp(&var[b]))
        .unwrap_or(0);
    bins.sort_unstable_by_key(|b| (b.rgb[axis], b.key));
    let mut acc = 0.0;
    for (i, b) in bins.iter().enumerate() {
        acc += b.count as f64;
        if acc >= n / 2.0 {
            return (i + 1).clamp(1, bins.len() - 1);
        }
    }
    bins.len() / 2
}

/// Reduces an RGBA image (alpha ignored) to at most `colors` colours (clamped to
/// 1…[`MAX_COLORS`]).
pub fn reduce(rgba: &[u8], colors: usize) -> Indexed {
    let colors = colors.clamp(1, MAX_COLORS);
    let size = 1usize << (3 * BITS);
    // Per bin: its place in `bins` + 1 (0: not seen yet).
    let mut slot = vec![0u32; size];
    let mut bins: Vec<Bin> = Vec::new();
    // Runs of one colour (the background, flat surfaces) skip the table.
    let mut last: Option<([u8; 3], usize)> = None;
    for p in rgba.chunks_exact(4) {
        let rgb = [p[0], p[1], p[2]];
        if let Some((c, i)) = last
            && c == rgb
        {
            bins[i].count += 1;
            continue;
        }
        let k = key(p) as usize;
        let i = match slot[k] {
            0 => {
                bins.push(Bin {
                    key: k as u32,
                    rgb,
                    count: 1,
                });
                slot[k] = bins.len() as u32;
                bins.len() - 1
            }
            s => {
                bins[s as usize - 1].count += 1;
                s as usize - 1
            }
        };
        last = Some((rgb, i));
    }

    // Boxes are ranges of `bins`, each with its error.
    let mut boxes: Vec<(usize, usize, f64)> = Vec::new();
    if !bins.is_empty() {
        let (e, _) = box_error(&bins);
        boxes.push((0, bins.len(), e));
    }
    while boxes.len() < colors {
        let Some((i, &(start, end, err))) = boxes
            .iter()
            .enumerate()
            .filter(|(_, b)| b.1 - b.0 > 1)
            .max_by(|a, b| a.1.2.total_cmp(&b.1.2))
        else {
            break;
        };
        if err <= 0.0 {
            break;
        }
        let mid = start + split(&mut bins[start..end]);
        boxes[i] = (start, mid, box_error(&bins[start..mid]).0);
        boxes.push((mid, end, box_error(&bins[mid..end]).0));
    }

    let mut palette = Vec::with_capacity(boxes.len());
    let mut lut = vec![0u8; size];
    boxes.sort_unstable_by_key(|b| b.0);
    for (index, &(start, end, _)) in boxes.iter().enumerate() {
        let (_, mean) = box_error(&bins[start..end]);
        palette.push(mean.map(|m| m.round().clamp(0.0, 255.0) as u8));
        for b in &bins[start..end] {
            lut[b.key as usize] = index as u8;
        }
    }
    let mut indices = Vec::with_capacity(rgba.len() / 4);
    let mut last: Option<([u8; 3], u8)> = None;
    for p in rgba.chunks_exact(4) {
        let rgb = [p[0], p[1], p[2]];
        let i = match last {
            Some((c, i)) if c == rgb => i,
            _ => lut[key(p) as usize],
        };
        last = Some((rgb, i));
        indices.push(i);
    }
    Indexed { palette, indices }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rgba(px: &[[u8; 3]]) -> Vec<u8> {
        px.iter().flat_map(|p| [p[0], p[1], p[2], 255]).collect()
    }

    #[test]
    fn few_colours_are_kept_exactly() {
        let px = [
            [0, 0, 0],
            [255, 0, 0],
            [0, 0, 0],
            [12, 200, 77],
            [255, 0, 0],
        ];
        let q = reduce(&rgba(&px), MAX_COLORS);
        assert_eq!(q.palette.len(), 3);
        for (p, &i) in px.iter().zip(&q.indices) {
            assert_eq!(q.palette[i as usize], *p);
        }
    }

    #[test]
    fn many_colours_make_at_most_256_entries_near_every_pixel() {
        let mut px = Vec::new();
        let mut s = 99u64;
        for _ in 0..50_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            px.push([s as u8, (s >> 8) as u8, (s >> 16) as u8]);
        }
        let q = reduce(&rgba(&px), MAX_COLORS);
        assert_eq!(q.palette.len(), MAX_COLORS);
        // 256 boxes over the RGB cube: each about 40 wide per channel, so no
        // pixel lies far from its entry.
        let worst = px
            .iter()
            .zip(&q.indices)
            .map(|(p, &i)| {
                let e = q.palette[i as usize];
                (0..3)
                    .map(|c| p[c].abs_diff(e[c]) as u32)
                    .max()
                    .unwrap_or(0)
            })
            .max()
            .unwrap_or(0);
        assert!(worst <= 64, "a pixel {worst} away from its colour");
    }

    #[test]
    fn muted_scan_colours_stay_coloured_beside_a_black_background() {
        // 80% black, then greens and browns of an aerial scan's RGB, in shades.
        let mut px = vec![[0u8, 0, 0]; 40_000];
        for i in 0..10_000u32 {
            let t = (i % 50) as u8;
            px.push([60 + t, 85 + t, 45 + t / 2]); // grass
            px.push([110 + t / 2, 90 + t / 2, 60 + t / 3]); // soil
        }
        let q = reduce(&rgba(&px), MAX_COLORS);
        let bg = q.indices[0];
        assert_eq!(q.palette[bg as usize], [0, 0, 0]);
        for (p, &i) in px.iter().zip(&q.indices).skip(40_000) {
            let e = q.palette[i as usize];
            assert_ne!(i, bg);
            for c in 0..3 {
                assert!(p[c].abs_diff(e[c]) <= 4, "{p:?} became {e:?}");
            }
            // Green stays greener than red and blue.
            if p[1] > p[0] {
                assert!(e[1] > e[0] && e[1] > e[2], "{p:?} became {e:?}");
            }
        }
    }

    #[test]
    fn an_empty_image_has_an_empty_palette() {
        let q = reduce(&[], MAX_COLORS);
        assert!(q.palette.is_empty() && q.indices.is_empty());
    }
}
