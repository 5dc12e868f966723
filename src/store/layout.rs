//! The order in which a part's points are laid out in its image: a 3D Hilbert sort,
//! then, block by block up the pyramid, the point nearest each block's centroid moved
//! to the block's first slot, so that every down-sampled level is a spatially even
//! sample (see `../shared/notes/lod-layout.md` for the measurements behind this).

use rayon::prelude::*;
use std::sync::OnceLock;

/// Bits per axis of the space-filling key (3 × 21 = 63 bits).
pub const KEY_BITS: u32 = 21;

/// How points are placed along the image's Z-order curve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Layout {
    /// Hilbert order with centroid representatives (the default).
    #[default]
    Hilbert,
    /// The paper's layout: input order, row-major image, plain nearest-neighbour
    /// pyramid (`super::paper`).
    Paper,
}

impl Layout {
    /// The value of the `LAYOUT` metadata item.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Hilbert => super::spec::layout::HILBERT,
            Layout::Paper => super::spec::layout::PAPER,
        }
    }
}

/// One transition of the Hilbert state machine: the 3-bit digit and the next state.
#[derive(Clone, Copy, Default)]
struct Step {
    digit: u8,
    next: u8,
}

/// The 24-state table of the 3D Hilbert curve (Hamilton, "Compact Hilbert Indices",
/// 2006): state = (entry corner e, direction d); input = one bit of each axis.
fn hilbert_table() -> &'static [[Step; 8]; 24] {
    static TABLE: OnceLock<[[Step; 8]; 24]> = OnceLock::new();
    TABLE.get_or_init(|| {
        const N: u32 = 3;
        let rotr = |x: u32, r: u32| ((x >> (r % N)) | (x << ((N - r % N) % N))) & 7;
        let rotl = |x: u32, r: u32| ((x << (r % N)) | (x >> ((N - r % N) % N))) & 7;
        let gc = |i: u32| i ^ (i >> 1);
        let gc_inv = |g: u32| {
            let mut i = g;
            let mut s = g >> 1;
            while s != 0 {
                i ^= s;
                s >>= 1;
            }
            i
        };
        let entry = |i: u32| if i == 0 { 0 } else { gc(2 * ((i - 1) / 2)) };
        let dir = |i: u32| {
            if i == 0 {
                0
            } else if i.is_multiple_of(2) {
                (i - 1).trailing_ones() % N
            } else {
                i.trailing_ones() % N
            }
        };
        let mut t = [[Step::default(); 8]; 24];
        for e in 0..8u32 {
            for d in 0..3u32 {
                for l in 0..8u32 {
                    let w = gc_inv(rotr(l ^ e, d + 1));
                    let ne = e ^ rotl(entry(w), d + 1);
                    let nd = (d + dir(w) + 1) % N;
                    t[(e * 3 + d) as usize][l as usize] = Step {
                        digit: w as u8,
                        next: (ne * 3 + nd) as u8,
                    };
                }
            }
        }
        t
    })
}

/// Three levels of the Hilbert state machine per lookup: 9 input bits (three bits
/// of each axis) give 9 digit bits and the next state, packed as
/// `digits | next << 9` in a `u16` (24 KiB: stays in L1).
fn hilbert_table3() -> &'static [[u16; 512]; 24] {
    static TABLE: OnceLock<[[u16; 512]; 24]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let t = hilbert_table();
        let mut t3 = [[0u16; 512]; 24];
        for (state, row) in t3.iter_mut().enumerate() {
            for (input, out) in row.iter_mut().enumerate() {
                let a = t[state][input >> 6];
                let b = t[a.next as usize][(input >> 3) & 7];
                let c = t[b.next as usize][input & 7];
                let digits = ((a.digit as u16) << 6) | ((b.digit as u16) << 3) | c.digit as u16;
                *out = digits | ((c.next as u16) << 9);
            }
        }
        t3
    })
}

/// Hilbert index of a point with `KEY_BITS`-bit integer coordinates.
#[inline]
pub fn hilbert_key(q: [u32; 3]) -> u64 {
    let t3 = hilbert_table3();
    // Morton-interleave the three coordinates: 3 bits per level, x lowest.
    let m = spread3(q[0]) | (spread3(q[1]) << 1) | (spread3(q[2]) << 2);
    // KEY_BITS = 21 levels: seven steps of three levels.
    let mut h = 0u64;
    let mut state = 0usize;
    let mut shift = 54i32;
    while shift >= 0 {
        let s = t3[state][((m >> shift) & 511) as usize];
        h = (h << 9) | (s & 511) as u64;
        state = (s >> 9) as usize;
        shift -= 9;
    }
    h
}

/// Spreads the low 21 bits of `v` to every third bit.
#[inline]
fn spread3(v: u32) -> u64 {
    let mut x = v as u64 & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Bits needed to number `n` items.
fn index_bits(n: usize) -> u32 {
    (usize::BITS - n.saturating_sub(1).leading_zeros()).max(1)
}

/// Indices of `pos` in Hilbert order (`lo`, `hi`: bounds of `pos`). Positions are quantized over a cube (the
/// largest extent on every axis; measured ~5% better on flat airborne clouds than
/// per-axis ranges). Each key keeps its top `64 - log2(n)` bits and carries the
/// point's index in the rest, so one `u64` sort orders everything; points that
/// share a truncated key (a cell of 2^-10 of the extent or finer) keep input order.
pub fn hilbert_order(pos: &[[f32; 3]], lo: [f32; 3], hi: [f32; 3]) -> Vec<u32> {
    let n = pos.len();
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0f32, f32::max) as f64;
    let max = ((1u32 << KEY_BITS) - 1) as f64;
    let scale = if side > 0.0 { max / side } else { 0.0 };
    let ib = index_bits(n);
    let mask = (1u64 << ib) - 1;
    let mut packed: Vec<u64> = pos
        .par_iter()
        .enumerate()
        .with_min_len(1 << 14)
        .map(|(i, p)| {
            let q = [0, 1, 2].map(|a| (((p[a] - lo[a]) as f64 * scale) as u32).min(max as u32));
            // The 63-bit key moved up to bit 63, the index in the low bits.
            ((hilbert_key(q) << 1) & !mask) | i as u64
        })
        .collect();
    sort_u64(&mut packed);
    packed.par_iter().map(|&k| (k & mask) as u32).collect()
}

/// Sorts `v`: one pass scatters by the top bits into buckets, then the buckets are
/// sorted in parallel.
pub fn sort_u64(v: &mut Vec<u64>) {
    let n = v.len();
    if n < 1 << 16 {
        v.sort_unstable();
        return;
    }
    const BUCKET_BITS: u32 = 12;
    let (kmin, kmax) = v
        .iter()
        .fold((u64::MAX, 0u64), |(a, b), &k| (a.min(k), b.max(k)));
    let span_bits = 64 - (kmax - kmin).leading_zeros();
    let shift = span_bits.saturating_sub(BUCKET_BITS);
    let bucket = |k: u64| ((k - kmin) >> shift) as usize;
    let mut counts = vec![0usize; (1 << BUCKET_BITS) + 1];
    for &k in v.iter() {
        counts[bucket(k) + 1] += 1;
    }
    for b in 1..counts.len() {
        counts[b] += counts[b - 1];
    }
    let mut out = vec![0u64; n];
    let mut fill = counts.clone();
    for &k in v.iter() {
        let b = bucket(k);
        out[fill[b]] = k;
        fill[b] += 1;
    }
    let mut slices: Vec<&mut [u64]> = Vec::with_capacity(1 << BUCKET_BITS);
    let mut rest = out.as_mut_slice();
    for b in 0..(1 << BUCKET_BITS) {
        let (head, tail) = rest.split_at_mut(counts[b + 1] - counts[b]);
        slices.push(head);
        rest = tail;
    }
    slices.par_iter_mut().for_each(|s| s.sort_unstable());
    *v = out;
}

/// Levels over which [`choose_representatives`] runs for `n` points: every level
/// whose blocks can hold more than one sub-block, beyond the stored pyramid too, so
/// any stride-`4^k` subset of a stored level (of its last tile, say) is even as well.
pub fn representative_levels(n: usize) -> usize {
    let mut levels = 1;
    while (1u128 << (2 * (levels - 1))) < n as u128 {
        levels += 1;
    }
    levels
}

/// Rearranges points (`pos` and their source indices `perm`, already in Hilbert
/// order) so that for every level `k` in `1..levels`, the first slot of each aligned
/// block of `4^k` slots holds the block's point nearest its centroid. Works
/// bottom-up, moving whole sub-blocks, so each level's choice is among the
/// representatives of the level below and the pyramid stays nested. Only full
/// sub-blocks move, so the filled slots stay a prefix.
pub fn choose_representatives(pos: &mut [[f32; 3]], perm: &mut [u32], levels: usize) {
    let n = pos.len();
    if n < 2 || levels < 2 {
        return;
    }
    // Sums and counts of the current level's blocks, in block order.
    let mut sums: Vec<[f64; 3]> = Vec::new();
    let mut counts: Vec<u32> = Vec::new();
    for level in 1..levels {
        let block = 1usize << (2 * level);
        let sub = block / 4;
        let nblocks = n.div_ceil(block);
        let (new_sums, new_counts): (Vec<[f64; 3]>, Vec<u32>) = if level == 1 {
            pos.par_chunks(4)
                .map(|c| {
                    let mut s = [0f64; 3];
                    for p in c {
                        for a in 0..3 {
                            s[a] += p[a] as f64;
                        }
                    }
                    (s, c.len() as u32)
                })
                .unzip()
        } else {
            (0..nblocks)
                .into_par_iter()
                .map(|b| {
                    let mut s = [0f64; 3];
                    let mut c = 0;
                    for j in 4 * b..(4 * b + 4).min(sums.len()) {
                        for a in 0..3 {
                            s[a] += sums[j][a];
                        }
                        c += counts[j];
                    }
                    (s, c)
                })
                .unzip()
        };
        sums = new_sums;
        counts = new_counts;
        let (sums_ref, counts_ref) = (&sums, &counts);
        pos.par_chunks_mut(block)
            .zip(perm.par_chunks_mut(block))
            .enumerate()
            .for_each(|(b, (chunk, idx))| {
                let c = counts_ref[b] as f64;
                let centroid = sums_ref[b].map(|s| s / c);
                let mut best = 0usize;
                let mut best_d = f64::INFINITY;
                for j in 0..4 {
                    let start = j * sub;
                    // Only full sub-blocks may move (sub-block 0 is where they go).
                    if j > 0 && start + sub > chunk.len() {
                        break;
                    }
                    let p = chunk[start];
                    let d: f64 = (0..3).map(|a| (p[a] as f64 - centroid[a]).powi(2)).sum();
                    if d < best_d {
                        best_d = d;
                        best = j;
                    }
                }
                if best > 0 {
                    let (head, tail) = chunk.split_at_mut(best * sub);
                    head[..sub].swap_with_slice(&mut tail[..sub]);
                    let (head, tail) = idx.split_at_mut(best * sub);
                    head[..sub].swap_with_slice(&mut tail[..sub]);
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hilbert_visits_neighbours_in_turn() {
        // On an 8×8×8 grid, consecutive Hilbert indices are face neighbours.
        let bits = 3;
        let mut cells: Vec<(u64, [u32; 3])> = Vec::new();
        for x in 0..8u32 {
            for y in 0..8u32 {
                for z in 0..8u32 {
                    let shift = KEY_BITS - bits;
                    let q = [x << shift, y << shift, z << shift];
                    cells.push((hilbert_key(q) >> (3 * shift), [x, y, z]));
                }
            }
        }
        cells.sort();
        for (i, c) in cells.iter().enumerate() {
            assert_eq!(c.0, i as u64, "indices are a permutation");
        }
        for w in cells.windows(2) {
            let d: i64 = (0..3)
                .map(|a| (w[0].1[a] as i64 - w[1].1[a] as i64).abs())
                .sum();
            assert_eq!(d, 1, "{:?} -> {:?}", w[0].1, w[1].1);
        }
    }

    #[test]
    fn three_level_table_matches_single_steps() {
        let t = hilbert_table();
        let single = |q: [u32; 3]| {
            let mut state = 0usize;
            let mut h = 0u64;
            for bit in (0..KEY_BITS).rev() {
                let l =
                    ((q[0] >> bit) & 1) | (((q[1] >> bit) & 1) << 1) | (((q[2] >> bit) & 1) << 2);
                let s = t[state][l as usize];
                h = (h << 3) | s.digit as u64;
                state = s.next as usize;
            }
            h
        };
        let mut r = crate::synth::Rng::new(3);
        for _ in 0..10_000 {
            let q = [0, 1, 2].map(|_| (r.next_u64() & 0x1f_ffff) as u32);
            assert_eq!(hilbert_key(q), single(q));
        }
    }

    #[test]
    fn sort_matches_std() {
        let mut v: Vec<u64> = (0..200_000u64)
            .map(|i| i.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 3)
            .collect();
        let mut w = v.clone();
        w.sort();
        sort_u64(&mut v);
        assert_eq!(v, w);
    }

    #[test]
    fn hilbert_order_is_a_local_permutation() {
        let mut r = crate::synth::Rng::new(9);
        let pos: Vec<[f32; 3]> = (0..100_000)
            .map(|_| {
                [
                    r.f64() as f32 * 100.0,
                    r.f64() as f32 * 50.0,
                    r.f64() as f32,
                ]
            })
            .collect();
        let order = hilbert_order(&pos, [0.0; 3], [100.0, 50.0, 1.0]);
        let mut seen = vec![false; pos.len()];
        for &i in &order {
            seen[i as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        // Consecutive points are close: the mean step is far below the extent.
        let step: f64 = order
            .windows(2)
            .map(|w| {
                let (a, b) = (pos[w[0] as usize], pos[w[1] as usize]);
                (0..3)
                    .map(|k| ((a[k] - b[k]) as f64).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .sum::<f64>()
            / order.len() as f64;
        assert!(step < 1.0, "mean step {step}");
    }

    #[test]
    fn representative_is_nearest_centroid_and_prefix_kept() {
        // 4 points of a block: the one at the centroid moves to slot 0.
        let mut pos = vec![
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            [5.0, 0.1, 0.0],
            [5.0, 9.0, 0.0],
        ];
        let mut order = vec![0u32, 1, 2, 3];
        choose_representatives(&mut pos, &mut order, 2);
        assert_eq!(order[0], 2);
        assert_eq!(pos[0], [5.0, 0.1, 0.0]);
        // A partial last block never moves a partial sub-block forward.
        let mut pos: Vec<[f32; 3]> = (0..22).map(|i| [i as f32, 0.0, 0.0]).collect();
        let mut order: Vec<u32> = (0..22).collect();
        choose_representatives(&mut pos, &mut order, 3);
        for (p, &i) in pos.iter().zip(&order) {
            assert_eq!(p[0], i as f32, "positions move with their indices");
        }
        let mut sorted = order.clone();
        sorted.sort();
        assert_eq!(sorted, (0..22).collect::<Vec<_>>());
        // Block 1 (slots 16..22) holds sub-block 1 (slots 20, 21) partial: it stays.
        assert!(order[16..20].iter().all(|&i| (16..20).contains(&i)));
    }
}
