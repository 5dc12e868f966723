//! Hilbert keys and the sort of a part's points along the curve: the 24-state
//! table (two levels per lookup, only the levels the sort keeps, eight keys walked
//! in lockstep, the Morton spread by BMI2 `pdep` where the CPU has it), and the
//! radix sort of the keys (the top-digit histograms counted while the keys are
//! made, then a parallel most-significant-digit scatter and in-cache
//! least-significant-digit passes per bucket). The representatives that follow
//! the sort are `layout.rs`.

use crate::bigvec;
use crate::write::layout::Positions;
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::sync::OnceLock;

/// Bits per axis of the space-filling key (3 × 21 = 63 bits).
pub const KEY_BITS: u32 = 21;

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
/// Only the curve levels that survive the truncation are computed.
pub fn hilbert_order(pos: Positions<'_>, lo: [f32; 3], hi: [f32; 3]) -> Vec<u32> {
    let n = pos.len();
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0f32, f32::max) as f64;
    let max = ((1u32 << KEY_BITS) - 1) as f64;
    let scale = if side > 0.0 { max / side } else { 0.0 };
    let ib = index_bits(n);
    let mask = (1u64 << ib) - 1;
    // Key bit j lands at bit j + 1 and survives when j + 1 >= ib.
    let levels = ((63 - ib) / 3 + 1).min(KEY_BITS);
    let mut packed: Vec<u64> = bigvec::with_capacity(n);
    let keys = Keys {
        lo,
        scale,
        max: max as u32,
        mask,
        t3: hilbert_table3(),
        steps: levels.div_ceil(3).min(KEY_BITS / 3) as usize,
    };
    let bmi2 = has_bmi2();
    const CHUNK: usize = 1 << 14;
    // The keys of each piece of the sort's scatter, a run of CHUNK at a time,
    // each run counted into the piece's histogram of top digits while in cache.
    let digit = Digit::top(ib);
    let piece = scatter_piece(n).next_multiple_of(CHUNK);
    let hists: Vec<Vec<u32>> = packed.spare_capacity_mut()[..n]
        .par_chunks_mut(piece)
        .enumerate()
        .map_init(Vec::new, |scratch, (p, out)| {
            let mut h = vec![0u32; digit.buckets()];
            for (c, out) in out.chunks_mut(CHUNK).enumerate() {
                let first = p * piece + c * CHUNK;
                let pts = pos.slice(first..first + out.len(), scratch);
                if bmi2 {
                    // SAFETY: the CPU has BMI2 (checked above).
                    unsafe { keys.write_bmi2(pts, out, first as u64) }
                } else {
                    keys.write::<false>(pts, out, first as u64)
                }
                for k in out.iter() {
                    // SAFETY: `write` wrote every key of the run.
                    h[digit.bucket(unsafe { k.assume_init() })] += 1;
                }
            }
            h
        })
        .collect();
    // SAFETY: every piece wrote each of its slots.
    unsafe { packed.set_len(n) };
    if n < SMALL_SORT {
        packed.sort_unstable();
    } else {
        let plan = bigvec::plan_from(&hists, digit.buckets());
        scatter_sort(&mut packed, ib, digit, plan, piece);
    }
    let mut perm = bigvec::with_capacity(n);
    packed
        .par_iter()
        .map(|&k| (k & mask) as u32)
        .collect_into_vec(&mut perm);
    perm
}

/// Whether the CPU has BMI2's `pdep` (one instruction for [`spread3`]).
fn has_bmi2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("bmi2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`hilbert_order`]'s sort keys of a run of points.
struct Keys {
    lo: [f32; 3],
    scale: f64,
    max: u32,
    /// The index bits.
    mask: u64,
    t3: &'static [[u16; 512]; 24],
    /// Table lookups (three levels each) that survive the truncation.
    steps: usize,
}

impl Keys {
    /// The keys of `pts`, points `base..` of the part, into `out`.
    #[inline(always)]
    fn write<const PDEP: bool>(&self, pts: &[[f32; 3]], out: &mut [MaybeUninit<u64>], base: u64) {
        let Keys { lo, scale, max, .. } = *self;
        let spread = |v: u32| -> u64 {
            #[cfg(target_arch = "x86_64")]
            if PDEP {
                // SAFETY: PDEP is only set where the CPU has BMI2 (`write_bmi2`).
                return unsafe {
                    std::arch::x86_64::_pdep_u64(u64::from(v) & 0x1f_ffff, 0x1249_2492_4924_9249)
                };
            }
            spread3(v)
        };
        let quantize = |p: &[f32; 3]| {
            // Written out: `[0, 1, 2].map` is not always inlined, and this runs
            // for every point.
            let q = |a: usize| (((p[a] - lo[a]) as f64 * scale) as u32).min(max);
            spread(q(0)) | (spread(q(1)) << 1) | (spread(q(2)) << 2)
        };
        // The 63-bit key moved up to bit 63, the index in the low bits.
        let pack = |h: u64, i: usize| ((h << 1) & !self.mask) | (base + i as u64);
        // Eight keys in lockstep: each key's table walk is a chain of dependent
        // loads, and eight chains keep the core busy.
        const LANES: usize = 8;
        let whole = pts.len() / LANES * LANES;
        for (g, (o, p)) in out[..whole]
            .chunks_exact_mut(LANES)
            .zip(pts[..whole].chunks_exact(LANES))
            .enumerate()
        {
            let m: [u64; LANES] = std::array::from_fn(|j| quantize(&p[j]));
            let h = hilbert_top_lanes(self.t3, m, self.steps);
            for j in 0..LANES {
                o[j].write(pack(h[j], g * LANES + j));
            }
        }
        for i in whole..pts.len() {
            let h = hilbert_top_lanes(self.t3, [quantize(&pts[i])], self.steps);
            out[i].write(pack(h[0], i));
        }
    }

    /// [`Keys::write`] with `pdep` (measured: the keys' share of the sort
    /// falls by a quarter).
    ///
    /// # Safety
    /// The CPU must have BMI2.
    #[cfg_attr(target_arch = "x86_64", target_feature(enable = "bmi2"))]
    unsafe fn write_bmi2(&self, pts: &[[f32; 3]], out: &mut [MaybeUninit<u64>], base: u64) {
        self.write::<true>(pts, out, base)
    }
}

/// [`hilbert_key_top`] of `L` Morton codes at once (`steps` lookups of three
/// levels each), their table walks interleaved.
#[inline(always)]
fn hilbert_top_lanes<const L: usize>(t3: &[[u16; 512]; 24], m: [u64; L], steps: usize) -> [u64; L] {
    let mut h = [0u64; L];
    let mut state = [0usize; L];
    for step in 0..steps {
        let shift = 54 - 9 * step;
        for j in 0..L {
            let s = t3[state[j]][((m[j] >> shift) & 511) as usize];
            h[j] = (h[j] << 9) | (s & 511) as u64;
            state[j] = (s >> 9) as usize;
        }
    }
    h.map(|h| h << (9 * (KEY_BITS as usize / 3 - steps)))
}

/// The Hilbert index of `q` with only its `levels` most significant levels
/// computed (rounded up to a multiple of three); the rest are zero.
#[inline]
pub fn hilbert_key_top(q: [u32; 3], levels: u32) -> u64 {
    let t3 = hilbert_table3();
    let m = spread3(q[0]) | (spread3(q[1]) << 1) | (spread3(q[2]) << 2);
    let steps = levels.div_ceil(3).min(KEY_BITS / 3) as i32;
    let mut h = 0u64;
    let mut state = 0usize;
    for step in 0..steps {
        let s = t3[state][((m >> (54 - 9 * step)) & 511) as usize];
        h = (h << 9) | (s & 511) as u64;
        state = (s >> 9) as usize;
    }
    h << (9 * (KEY_BITS as i32 / 3 - steps))
}

/// Digit width of the sort's scatter passes.
const RADIX_BITS: u32 = 11;

/// Below this many keys a comparison sort is quicker.
const SMALL_SORT: usize = 1 << 16;

/// The most significant digit of a sort: the `top`-bit bucket of key `k` is
/// `(k - base) >> shift`.
#[derive(Clone, Copy)]
struct Digit {
    base: u64,
    shift: u32,
    top: u32,
}

impl Digit {
    /// The top [`RADIX_BITS`] of the whole key, whose low `low_bits` are an index:
    /// what [`hilbert_order`] counts while making its keys (a Hilbert key's
    /// first levels vary over the cube, so no base is needed to spread them).
    fn top(low_bits: u32) -> Digit {
        let top = RADIX_BITS.min(64 - low_bits);
        Digit {
            base: 0,
            shift: 64 - top,
            top,
        }
    }

    fn buckets(self) -> usize {
        1 << self.top
    }

    #[inline(always)]
    fn bucket(self, k: u64) -> usize {
        ((k - self.base) >> self.shift) as usize
    }
}

/// Keys per piece of a parallel scatter of `n`.
fn scatter_piece(n: usize) -> usize {
    n.div_ceil(rayon::current_num_threads() * 4).max(1 << 14)
}

/// Sorts `v` ascending, given that its low `low_bits` bits are unique and already
/// ascending in the current order (they are the element's index), so only the
/// bits above them need sorting: a parallel most-significant-digit scatter, then
/// each bucket sorted in cache by stable least-significant-digit passes.
pub fn sort_indexed(v: &mut Vec<u64>, low_bits: u32) {
    let n = v.len();
    if n < SMALL_SORT {
        v.sort_unstable();
        return;
    }
    let (kmin, kmax) = v
        .par_iter()
        .with_min_len(1 << 16)
        .fold(|| (u64::MAX, 0u64), |(a, b), &k| (a.min(k), b.max(k)))
        .reduce(|| (u64::MAX, 0u64), |x, y| (x.0.min(y.0), x.1.max(y.1)));
    // The base keeps whole keys: subtracting it never borrows from the index bits.
    let kmin = kmin & !((1u64 << low_bits) - 1);
    let key_bits = 64 - ((kmax - kmin) >> low_bits).leading_zeros();
    if key_bits == 0 {
        return; // one key: the indices are already in order
    }

    let top = key_bits.min(RADIX_BITS);
    let digit = Digit {
        base: kmin,
        shift: low_bits + key_bits - top,
        top,
    };
    // Histograms per chunk, then each chunk's start in each bucket.
    let chunk = scatter_piece(n);
    let plan = bigvec::scatter_plan(v, chunk, digit.buckets(), |&k| digit.bucket(k));
    scatter_sort(v, low_bits, digit, plan, chunk);
}

/// The rest of [`sort_indexed`]: `v` scattered by `digit` into buckets as `plan`
/// says (from [`bigvec::scatter_plan`] over pieces of `chunk`), then each bucket
/// sorted in cache on the bits between `low_bits` and the digit.
fn scatter_sort(
    v: &mut Vec<u64>,
    low_bits: u32,
    digit: Digit,
    (mut starts, bounds): (Vec<Vec<usize>>, Vec<usize>),
    chunk: usize,
) {
    let n = v.len();
    let bucket = |k: u64| digit.bucket(k);
    let mut out: Vec<u64> = bigvec::with_capacity(n);
    let dst = bigvec::Shared(out.as_mut_ptr());
    v.par_chunks(chunk)
        .zip(starts.par_iter_mut())
        .for_each(|(c, fill)| {
            for &k in c {
                let b = bucket(k);
                // SAFETY: chunk c owns slots starts[c][b].. of bucket b, sized by
                // its own histogram, and no two chunks' ranges overlap.
                unsafe { *dst.at(fill[b]) = k };
                fill[b] += 1;
            }
        });
    // SAFETY: the scatter wrote every one of the n slots exactly once.
    unsafe { out.set_len(n) };

    let mut slices: Vec<&mut [u64]> = Vec::with_capacity(digit.buckets());
    let mut rest = out.as_mut_slice();
    for b in 0..digit.buckets() {
        let (head, tail) = rest.split_at_mut(bounds[b + 1] - bounds[b]);
        slices.push(head);
        rest = tail;
    }
    let rest_bits = digit.shift.saturating_sub(low_bits);
    slices.par_iter_mut().for_each_init(Vec::new, |scratch, s| {
        lsd_sort(s, scratch, digit.base, low_bits, rest_bits)
    });
    *v = out;
}

/// Stable sort of `s` by bits `low..low + bits` of `k - base` (digit passes of at
/// most `RADIX_BITS`), ping-ponging through `scratch`.
fn lsd_sort(s: &mut [u64], scratch: &mut Vec<u64>, base: u64, low: u32, bits: u32) {
    if s.len() < 2 || bits == 0 {
        return;
    }
    if s.len() <= 64 {
        s.sort_unstable();
        return;
    }
    scratch.clear();
    scratch.resize(s.len(), 0);
    let passes = bits.div_ceil(RADIX_BITS);
    let width = bits.div_ceil(passes);
    let mut counts = vec![0usize; 1 << width];
    let mut in_s = true;
    for p in 0..passes {
        let shift = low + p * width;
        let w = width.min(low + bits - shift);
        let mask = (1u64 << w) - 1;
        let (src, dst): (&[u64], &mut [u64]) = if in_s {
            (&*s, scratch.as_mut_slice())
        } else {
            (scratch.as_slice(), &mut *s)
        };
        counts.iter_mut().for_each(|c| *c = 0);
        for &k in src {
            counts[(((k - base) >> shift) & mask) as usize] += 1;
        }
        let mut at = 0;
        for c in counts.iter_mut() {
            let k = *c;
            *c = at;
            at += k;
        }
        for &k in src {
            let d = (((k - base) >> shift) & mask) as usize;
            dst[counts[d]] = k;
            counts[d] += 1;
        }
        in_s = !in_s;
    }
    if !in_s {
        s.copy_from_slice(scratch);
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
        let mut r = crate::rng::Rng::new(3);
        for _ in 0..10_000 {
            let q = [0, 1, 2].map(|_| (r.next_u64() & 0x1f_ffff) as u32);
            assert_eq!(hilbert_key(q), single(q));
        }
    }

    #[test]
    fn sort_matches_std() {
        // Keys of several spreads (full range, narrow, one outlier, all equal)
        // above a 20-bit index.
        let spreads: [fn(u64) -> u64; 5] = [
            |h| h >> 20,
            |h| 1_000_003 + (h >> 36),
            |h| h >> 50,
            |h| if h % 1000 == 0 { 1 << 43 } else { h >> 58 },
            |_| 77,
        ];
        for (s, f) in spreads.iter().enumerate() {
            for n in [1000usize, 70_000, 300_000] {
                let mut v: Vec<u64> = (0..n as u64)
                    .map(|i| (f(i.wrapping_mul(0x9E37_79B9_7F4A_7C15)) << 20) | i)
                    .collect();
                let mut w = v.clone();
                w.sort();
                sort_indexed(&mut v, 20);
                assert!(v == w, "spread {s}, n {n}");
            }
        }
    }

    #[test]
    fn truncated_key_is_the_full_key_top() {
        let mut r = crate::rng::Rng::new(5);
        for _ in 0..10_000 {
            let q = [0, 1, 2].map(|_| (r.next_u64() & 0x1f_ffff) as u32);
            for levels in [1u32, 9, 13, 14, 15, 21] {
                let keep = 9 * levels.div_ceil(3);
                let full = hilbert_key(q) >> (63 - keep);
                assert_eq!(hilbert_key_top(q, levels) >> (63 - keep), full);
                assert_eq!(hilbert_key_top(q, levels) & ((1 << (63 - keep)) - 1), 0);
            }
        }
    }

    #[test]
    fn lockstep_keys_match_single_keys() {
        let mut r = crate::rng::Rng::new(6);
        for levels in [1u32, 9, 13, 14, 21] {
            let steps = levels.div_ceil(3).min(KEY_BITS / 3) as usize;
            for _ in 0..1000 {
                let qs: [[u32; 3]; 8] =
                    std::array::from_fn(|_| [0, 1, 2].map(|_| (r.next_u64() & 0x1f_ffff) as u32));
                let m = qs.map(|q| spread3(q[0]) | (spread3(q[1]) << 1) | (spread3(q[2]) << 2));
                let h = hilbert_top_lanes(hilbert_table3(), m, steps);
                for j in 0..8 {
                    assert_eq!(h[j], hilbert_key_top(qs[j], levels));
                }
            }
        }
    }

    /// The keys made with `pdep` (where the CPU has it) are the portable ones.
    #[test]
    fn keys_with_pdep_are_the_portable_keys() {
        let mut r = crate::rng::Rng::new(11);
        let pts: Vec<[f32; 3]> = (0..10_007)
            .map(|_| {
                [
                    r.f64() as f32 * 300.0 - 7.0,
                    r.f64() as f32 * 90.0,
                    r.f64() as f32,
                ]
            })
            .collect();
        let keys = Keys {
            lo: [-7.0, 0.0, 0.0],
            scale: ((1u32 << KEY_BITS) - 1) as f64 / 300.0,
            max: (1 << KEY_BITS) - 1,
            mask: (1 << 14) - 1,
            t3: hilbert_table3(),
            steps: 5,
        };
        let run = |pdep: bool| {
            let mut out = vec![MaybeUninit::new(0u64); pts.len()];
            if pdep {
                // SAFETY: only where the CPU has BMI2.
                unsafe { keys.write_bmi2(&pts, &mut out, 3) };
            } else {
                keys.write::<false>(&pts, &mut out, 3);
            }
            out.iter()
                .map(|k| {
                    // SAFETY: the key writers initialise every slot of `out`.
                    unsafe { k.assume_init() }
                })
                .collect::<Vec<u64>>()
        };
        let portable = run(false);
        // Spot check against the single-key function.
        let q = |p: &[f32; 3]| [0, 1, 2].map(|a| ((p[a] - keys.lo[a]) as f64 * keys.scale) as u32);
        let h = hilbert_key_top(q(&pts[5]), 15);
        assert_eq!(portable[5], ((h << 1) & !keys.mask) | 8);
        assert!(has_bmi2() || !cfg!(target_arch = "x86_64") || std::env::var_os("CI").is_none());
        if has_bmi2() {
            assert_eq!(run(true), portable);
        }
    }

    #[test]
    fn hilbert_order_is_a_local_permutation() {
        let mut r = crate::rng::Rng::new(9);
        let pos: Vec<[f32; 3]> = (0..100_000)
            .map(|_| {
                [
                    r.f64() as f32 * 100.0,
                    r.f64() as f32 * 50.0,
                    r.f64() as f32,
                ]
            })
            .collect();
        let order = hilbert_order(Positions::Held(&pos), [0.0; 3], [100.0, 50.0, 1.0]);
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
}
