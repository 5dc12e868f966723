//! Large working buffers (tens to hundreds of MB of points) backed by transparent
//! huge pages where the kernel offers them (`madvise` mode, the usual default):
//! the first touch of a 4 KiB page costs a page fault, and a fresh 40 MB column
//! takes ten thousand of them; a 2 MiB page takes one fault for 512 of them.

/// Below this size the advice is not worth a system call.
const MIN_BYTES: usize = 4 << 20;

/// Above this size buffers keep ordinary pages. Measured on the 2-core VM (writing
/// 47.7 M points, `write_phases`): with the advice on every buffer (up to 573 MB)
/// the kernel spent 2.0–3.9 s of system time per write against 1.7–2.1 s without
/// it, and the Hilbert sort's 382 MB buffers took 1.5–2.0 s against 1.0–1.2 s;
/// at 10 M points (buffers up to 120 MB) the advice still wins.
const MAX_BYTES: usize = 256 << 20;

/// An empty vector with room for `n` elements whose memory the kernel is asked to
/// back with huge pages before anything touches it.
pub fn with_capacity<T>(n: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(n);
    advise_huge(&v);
    v
}

/// `n` default values (zeros) in huge-page-backed memory. Large zeroed buffers come
/// from the kernel already zero, so nothing is touched until the caller writes.
pub fn zeroed<T: Copy + Default>(n: usize) -> Vec<T> {
    let v = vec![T::default(); n];
    advise_huge(&v);
    v
}

#[cfg(target_os = "linux")]
fn advise_huge<T>(v: &Vec<T>) {
    let bytes = v.capacity() * std::mem::size_of::<T>();
    if !(MIN_BYTES..=MAX_BYTES).contains(&bytes) {
        return;
    }
    // madvise wants a page-aligned start: advise the whole pages inside the buffer.
    let page = 4096usize;
    let start = v.as_ptr() as usize;
    let aligned = start.next_multiple_of(page);
    let len = (start + bytes).saturating_sub(aligned) / page * page;
    if len > 0 {
        // SAFETY: the range lies inside the vector's own allocation; MADV_HUGEPAGE
        // only changes how the kernel backs it, never its contents. A failure (no
        // THP support) leaves ordinary pages, so the result is ignored.
        unsafe {
            libc::madvise(aligned as *mut libc::c_void, len, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge<T>(_: &Vec<T>) {}

/// How far ahead of a gather through an index list to prefetch: gathers of
/// points in curve order from input order miss the cache on nearly every read,
/// and prefetching the read this many steps ahead keeps a core's misses
/// overlapping (measured on the 2-core VM, 47.7 M points: the attribute gather
/// 0.40-0.60 s without, 0.25-0.28 s with).
pub const PREFETCH_AHEAD: usize = 24;

/// Asks the CPU to bring `v[i]` into the cache (a hint: nothing when `i` is out of
/// range or the target has no prefetch instruction).
#[inline(always)]
pub fn prefetch<T>(v: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < v.len() {
        // SAFETY: a prefetch never faults, and the address lies inside `v`.
        unsafe {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            _mm_prefetch::<_MM_HINT_T0>(v.as_ptr().add(i).cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (v, i);
}

/// A pointer into a buffer that a parallel scatter shares across threads, each
/// thread writing its own disjoint set of slots (the caller guarantees that).
#[derive(Clone, Copy)]
pub struct Shared<T>(pub *mut T);
// SAFETY: only addresses cross threads; every write through them is to slots the
// writing thread owns (the caller's contract).
unsafe impl<T> Send for Shared<T> {}
// SAFETY: as for Send: shared references hand out only the addresses.
unsafe impl<T> Sync for Shared<T> {}

impl<T> Shared<T> {
    /// The slot `i` (a method, so closures capture the whole `Shared`).
    pub fn at(self, i: usize) -> *mut T {
        self.0.wrapping_add(i)
    }
}

/// The plan of a parallel, stable counting sort of `items` into `buckets`: the
/// items cut into pieces of `piece`, each piece's first slot in each bucket
/// (`starts[p][b]`: pieces fill a bucket in order, so the scatter is stable), and
/// where each bucket begins (`bounds`, `buckets + 1` entries).
pub fn scatter_plan<T: Sync>(
    items: &[T],
    piece: usize,
    buckets: usize,
    bucket: impl Fn(&T) -> usize + Sync,
) -> (Vec<Vec<usize>>, Vec<usize>) {
    use rayon::prelude::*;
    let hists: Vec<Vec<u32>> = items
        .par_chunks(piece.max(1))
        .map(|c| {
            let mut h = vec![0u32; buckets];
            for k in c {
                h[bucket(k)] += 1;
            }
            h
        })
        .collect();
    plan_from(&hists, buckets)
}

/// [`scatter_plan`] from each piece's histogram (`hists[p][b]`: items of piece `p`
/// in bucket `b`).
pub fn plan_from(hists: &[Vec<u32>], buckets: usize) -> (Vec<Vec<usize>>, Vec<usize>) {
    let mut starts = vec![vec![0usize; buckets]; hists.len()];
    let mut bounds = vec![0usize; buckets + 1];
    let mut at = 0usize;
    for b in 0..buckets {
        bounds[b] = at;
        for (c, h) in hists.iter().enumerate() {
            starts[c][b] = at;
            at += h[b] as usize;
        }
    }
    bounds[buckets] = at;
    (starts, bounds)
}

#[cfg(test)]
mod tests {
    #[test]
    fn buffers_hold_what_was_asked() {
        let mut v: Vec<f32> = super::zeroed(3_000_000);
        assert_eq!(v.len(), 3_000_000);
        assert!(v.iter().all(|&x| x == 0.0));
        v[2_999_999] = 1.5;
        assert_eq!(v[2_999_999], 1.5);
        let w: Vec<u64> = super::with_capacity(10);
        assert!(w.capacity() >= 10 && w.is_empty());
    }
}
