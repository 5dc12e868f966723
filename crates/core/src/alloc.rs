//! The process's allocator: the system allocator for ordinary blocks; large blocks
//! (columns, sort keys, permutations: 4 MiB and up) are mapped directly and, when
//! freed, kept in a bounded pool that the next large allocation takes from, instead
//! of going back to the kernel.
//!
//! A conversion frees and allocates gigabytes of such buffers in turn (the input's
//! f64 columns, then relative positions, sort keys, the permutation, sorted
//! positions; the same again for every part). Memory handed back to the kernel
//! comes back as fresh pages that must be faulted in and zeroed: on the 2-core VM
//! (whose balloon reports freed pages to the host at once) about 0.75 s of CPU per
//! GiB, against 0.02 s to touch memory the process already has.
//!
//! A pooled block is reused for a request it can hold (its tail stays pooled);
//! a larger request gets a fresh mapping into whose start pooled blocks are moved
//! with `mremap` (their pages come along), so only the remainder is fresh. Pooled
//! memory is always used before fresh memory is mapped, so resident memory stays
//! near the peak of live buffers; the pool holds at most [`pool_limit`] bytes (set
//! by `convert` from its memory budget). Linux only (`mremap`); elsewhere the
//! system allocator serves everything.
//!
//! Blocks under 4 MiB (a tile's samples, its compressed bytes, a small level's
//! columns) stay with glibc's `malloc`, told once, at the first allocation, to
//! serve them from its heap ([`tune_system`]): by default it maps each one over
//! 128 KiB afresh and hands freed heap back to the kernel past 128 KiB, so every
//! read of a small level faulted its buffers in again. Reading level 3 of the
//! 47.7 M-point benchmark (746 k points) went from 230-244 to 406-449 M points/s
//! with it (bench/RESULTS.md); a conversion is unchanged.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Blocks from this size on are mapped directly and pooled when freed.
const LARGE: usize = 4 << 20;
const PAGE: usize = 4096;
/// Pooled blocks at most (freed blocks beyond it go back to the kernel).
const SLOTS: usize = 128;
/// Free memory at the top of one of glibc's heaps it keeps rather than trims.
#[cfg(target_env = "gnu")]
const TRIM: usize = 32 << 20;
/// Whether [`tune_system`] has run.
static TUNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Tells glibc's `malloc` (which serves blocks under [`LARGE`]) to take them all
/// from its heaps, not from mappings of their own, and to keep up to [`TRIM`]
/// free at a heap's top: freed blocks are then reused warm instead of returning
/// to the kernel and coming back as fresh pages to fault in. Once per process,
/// at its first allocation; a no-op beyond glibc.
fn tune_system() {
    if TUNED.load(Ordering::Relaxed) || TUNED.swap(true, Ordering::Relaxed) {
        return;
    }
    #[cfg(target_env = "gnu")]
    // SAFETY: mallopt sets two of glibc's parameters; it allocates nothing and
    // touches no memory of ours. Fixing the map threshold also turns off glibc's
    // own adjustment of both.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LARGE as libc::c_int);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM as libc::c_int);
    }
}

struct Pool {
    /// (address, length in bytes), page-aligned.
    blocks: [(usize, usize); SLOTS],
    n: usize,
    bytes: usize,
}

static POOL: Mutex<Pool> = Mutex::new(Pool {
    blocks: [(0, 0); SLOTS],
    n: 0,
    bytes: 0,
});
static LIMIT: AtomicUsize = AtomicUsize::new(1 << 30);
/// Bytes of large blocks that came fresh from the kernel (not from the pool).
static FRESH: AtomicUsize = AtomicUsize::new(0);

/// Bytes of large blocks mapped fresh from the kernel so far (each page of them
/// is faulted in and zeroed on first touch); the rest came from the pool.
pub fn fresh_bytes() -> usize {
    FRESH.load(Ordering::Relaxed)
}

/// The most bytes the pool keeps (default 1 GiB); lowering it releases the excess.
pub fn set_pool_limit(bytes: usize) {
    let mut evicted = [(0usize, 0usize); SLOTS];
    let mut k = 0;
    {
        let mut p = lock();
        LIMIT.store(bytes, Ordering::Relaxed);
        while p.bytes > bytes && p.n > 0 {
            let last = p.n - 1;
            evicted[k] = p.remove(last);
            k += 1;
        }
    }
    for &(a, l) in &evicted[..k] {
        unmap(a, l);
    }
}

/// Returns every pooled block to the kernel.
pub fn release_pool() {
    let mut evicted = [(0usize, 0usize); SLOTS];
    let k = {
        let mut p = lock();
        let k = p.n;
        for i in (0..k).rev() {
            evicted[i] = p.remove(i);
        }
        k
    };
    for &(a, l) in &evicted[..k] {
        unmap(a, l);
    }
}

/// The pool's current limit in bytes.
pub fn pool_limit() -> usize {
    LIMIT.load(Ordering::Relaxed)
}

/// Bytes held in the pool now, and its limit.
#[cfg(test)]
fn pool_state() -> (usize, usize) {
    let p = lock();
    (p.bytes, LIMIT.load(Ordering::Relaxed))
}

fn lock() -> std::sync::MutexGuard<'static, Pool> {
    // The pool's invariants hold between statements, so a poisoned lock (a panic
    // elsewhere while holding it cannot happen: nothing inside panics) is usable.
    POOL.lock().unwrap_or_else(|e| e.into_inner())
}

impl Pool {
    fn remove(&mut self, i: usize) -> (usize, usize) {
        let b = self.blocks[i];
        self.n -= 1;
        self.blocks[i] = self.blocks[self.n];
        self.bytes -= b.1;
        b
    }
    /// Adds a block if the limit and the slots allow; false if not.
    fn push(&mut self, b: (usize, usize)) -> bool {
        if self.n == SLOTS || self.bytes + b.1 > LIMIT.load(Ordering::Relaxed) {
            return false;
        }
        self.blocks[self.n] = b;
        self.n += 1;
        self.bytes += b.1;
        true
    }
}

fn round(size: usize) -> usize {
    size.next_multiple_of(PAGE)
}

fn unmap(addr: usize, len: usize) {
    // SAFETY: (addr, len) is a page-aligned range this module mapped and that
    // nothing else references (it was freed or never handed out).
    unsafe {
        libc::munmap(addr as *mut libc::c_void, len);
    }
}

/// Fresh zeroed pages from the kernel, or null.
fn map(len: usize) -> *mut u8 {
    // SAFETY: an anonymous private mapping of `len` bytes; no existing memory is
    // affected.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            len,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
            -1,
            0,
        )
    };
    if p == libc::MAP_FAILED {
        std::ptr::null_mut()
    } else {
        p.cast()
    }
}

/// Resizes a block this module mapped (it may move), or null.
fn remap(addr: usize, old: usize, new: usize) -> *mut u8 {
    // SAFETY: (addr, old) is a whole mapping range of ours, owned by the caller;
    // MREMAP_MAYMOVE moves its pages (contents kept) if it cannot grow in place.
    let p = unsafe { libc::mremap(addr as *mut libc::c_void, old, new, libc::MREMAP_MAYMOVE) };
    if p == libc::MAP_FAILED {
        std::ptr::null_mut()
    } else {
        p.cast()
    }
}

/// Moves the pages of (addr, len), a range of ours, to `to` (replacing what is
/// mapped there); false if the kernel refuses.
fn move_to(addr: usize, len: usize, to: usize) -> bool {
    // SAFETY: (addr, len) is a pooled range no one references; `to..to + len` lies
    // in a fresh mapping of ours that nothing references yet. MREMAP_FIXED
    // replaces that part of it with the moved pages.
    let p = unsafe {
        libc::mremap(
            addr as *mut libc::c_void,
            len,
            len,
            libc::MREMAP_MAYMOVE | libc::MREMAP_FIXED,
            to as *mut libc::c_void,
        )
    };
    p != libc::MAP_FAILED
}

/// A large block of `len` (page-rounded) bytes and how many of its leading bytes
/// were used before (and may hold old data; the rest is fresh and zero).
fn take(len: usize) -> (*mut u8, usize) {
    let mut p = lock();
    // The smallest block that holds the request; its tail stays pooled.
    let fit = (0..p.n)
        .filter(|&i| p.blocks[i].1 >= len)
        .min_by_key(|&i| p.blocks[i].1);
    if let Some(i) = fit {
        let (addr, have) = p.remove(i);
        let tail = (addr + len, have - len);
        let spare = tail.1 > 0 && !p.push(tail);
        drop(p);
        if spare {
            unmap(tail.0, tail.1);
        }
        return (addr as *mut u8, len);
    }
    // Otherwise pooled blocks, largest first, moved one after another to the start
    // of a fresh mapping (their pages come along); the rest of it is fresh.
    let mut parts = [(0usize, 0usize); SLOTS];
    let (mut k, mut got) = (0, 0);
    while got < len && p.n > 0 {
        let i = (0..p.n).max_by_key(|&i| p.blocks[i].1).unwrap_or(0);
        parts[k] = p.remove(i);
        got += parts[k].1;
        k += 1;
    }
    drop(p);
    let mut base = map(len);
    if base.is_null() {
        // Out of address space or of kernel mappings (pooled blocks split by
        // reuse count against the process's map limit): give the whole pool
        // back to the kernel and try once more.
        release_pool();
        base = map(len);
    }
    let mut warm = 0;
    for &(addr, have) in &parts[..k] {
        // Only what fits: the last block's tail goes back to the pool.
        let m = have.min(len - warm);
        if base.is_null() || m == 0 || !move_to(addr, m, base as usize + warm) {
            give(addr, have);
            continue;
        }
        if m < have {
            give(addr + m, have - m);
        }
        warm += m;
    }
    if !base.is_null() {
        FRESH.fetch_add(len - warm, Ordering::Relaxed);
    }
    (base, warm)
}

/// Returns a large block to the pool, or to the kernel when the pool is full.
fn give(addr: usize, len: usize) {
    let kept = lock().push((addr, len));
    if !kept {
        unmap(addr, len);
    }
}

/// Whether a layout goes to the pool (large, and page alignment suffices).
fn is_large(size: usize, align: usize) -> bool {
    size >= LARGE && align <= PAGE
}

/// The system allocator with large blocks recycled (see the module comment).
pub struct Recycling;

// SAFETY: small layouts go to `System` unchanged; large ones get page-aligned
// mappings of at least their (page-rounded) size, owned by the caller until freed,
// and the pool hands a range to one caller at a time (under its lock).
unsafe impl GlobalAlloc for Recycling {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if !is_large(l.size(), l.align()) {
            tune_system();
            // SAFETY: forwarded with the caller's guarantees.
            return unsafe { System.alloc(l) };
        }
        take(round(l.size())).0
    }

    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        if !is_large(l.size(), l.align()) {
            tune_system();
            // SAFETY: forwarded with the caller's guarantees.
            return unsafe { System.alloc_zeroed(l) };
        }
        let (p, used) = take(round(l.size()));
        if !p.is_null() && used > 0 {
            // SAFETY: the first `used` bytes of the new block are ours to write.
            unsafe { std::ptr::write_bytes(p, 0, used.min(l.size())) };
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, l: Layout) {
        if !is_large(l.size(), l.align()) {
            // SAFETY: forwarded with the caller's guarantees.
            return unsafe { System.dealloc(ptr, l) };
        }
        give(ptr as usize, round(l.size()));
    }

    unsafe fn realloc(&self, ptr: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        let old_large = is_large(l.size(), l.align());
        let new_large = is_large(new_size, l.align());
        match (old_large, new_large) {
            // SAFETY: forwarded with the caller's guarantees.
            (false, false) => unsafe { System.realloc(ptr, l, new_size) },
            (true, true) => {
                // A block assembled from moved pieces spans several kernel
                // mappings, which mremap cannot resize: then copy.
                let q = remap(ptr as usize, round(l.size()), round(new_size));
                if !q.is_null() {
                    return q;
                }
                // SAFETY: as below.
                unsafe { self.realloc_by_copy(ptr, l, new_size) }
            }
            // SAFETY: forwarded with the caller's guarantees.
            _ => unsafe { self.realloc_by_copy(ptr, l, new_size) },
        }
    }
}

impl Recycling {
    /// A new block, the contents copied, the old block freed.
    ///
    /// # Safety
    /// As for [`GlobalAlloc::realloc`].
    unsafe fn realloc_by_copy(&self, ptr: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the layout with the new size is valid (the caller guarantees
        // it); the old block is valid for `l.size()` bytes.
        unsafe {
            let nl = Layout::from_size_align_unchecked(new_size, l.align());
            let q = self.alloc(nl);
            if !q.is_null() {
                std::ptr::copy_nonoverlapping(ptr, q, l.size().min(new_size));
                self.dealloc(ptr, l);
            }
            q
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// This crate's tests run under the allocator they test (the `pcimg` library
    /// installs it for the binary; a test binary of this crate alone would
    /// otherwise run on `System`).
    #[global_allocator]
    static UNDER_TEST: Recycling = Recycling;

    #[test]
    fn large_blocks_are_reused_and_keep_contents_when_grown() {
        // The test binary runs tests in parallel through the same allocator, so
        // only properties of this test's own blocks are checked.
        let mut a: Vec<u64> = Vec::with_capacity(2 << 20); // 16 MiB
        a.extend((0..2u64 << 20).map(|i| i * 3));
        a.extend((0..3u64 << 20).map(|i| i ^ 7)); // grows: mremap
        assert!((0..2u64 << 20).all(|i| a[i as usize] == i * 3));
        assert!((0..3u64 << 20).all(|i| a[(2 << 20) + i as usize] == i ^ 7));
        drop(a);
        // Zeroed large blocks are zero even when they reuse pooled memory.
        for _ in 0..3 {
            let z = vec![0u32; 5 << 20];
            assert!(z.iter().all(|&v| v == 0));
            let mut d = vec![0xffu8; 9 << 20];
            d[123] = 1;
            assert_eq!(d.iter().filter(|&&v| v == 0xff).count(), (9 << 20) - 1);
        }
        // Shrinking below the threshold copies into a small block.
        let mut s: Vec<u8> = vec![5; 6 << 20];
        s.truncate(1000);
        s.shrink_to_fit();
        assert!(s.iter().all(|&v| v == 5));
    }

    #[test]
    fn blocks_assembled_from_pieces_hold_and_grow() {
        for round in 0..4u64 {
            // Three freed 8 MiB blocks, then a 20 MiB request: pieces of them are
            // moved into one block (when no other test took them first).
            let pieces: Vec<Vec<u64>> = (0..3).map(|k| vec![k; 1 << 20]).collect();
            drop(pieces);
            let mut v: Vec<u64> = Vec::with_capacity(20 << 17);
            v.extend((0..20u64 << 17).map(|i| i.wrapping_mul(round + 11)));
            // Growing it: mremap, or a copy when it spans several mappings.
            v.reserve(40 << 17);
            v.extend((0..40u64 << 17).map(|i| !i));
            let (a, b) = v.split_at(20 << 17);
            assert!(
                a.iter()
                    .enumerate()
                    .all(|(i, &x)| x == (i as u64).wrapping_mul(round + 11))
            );
            assert!(b.iter().enumerate().all(|(i, &x)| x == !(i as u64)));
        }
    }

    #[cfg(target_env = "gnu")]
    #[test]
    fn blocks_under_the_pool_s_size_come_from_the_heap() {
        // glibc would map a 3 MiB block of its own (its first threshold is
        // 128 KiB); told by `tune_system`, it takes it from a heap. `hblks` counts
        // the blocks glibc has mapped; other tests' blocks of the same size are
        // heap blocks too, so the count cannot rise for them either.
        let mut b = vec![0u8; 1000];
        b[1] = 1;
        // SAFETY: mallinfo2 only reads glibc's counters.
        let before = unsafe { libc::mallinfo2() }.hblks;
        let blocks: Vec<Vec<u8>> = (0..4).map(|k| vec![k; 3 << 20]).collect();
        // SAFETY: as above.
        let during = unsafe { libc::mallinfo2() }.hblks;
        assert!(blocks.iter().enumerate().all(|(k, v)| v[12345] == k as u8));
        assert!(
            during < before + 4,
            "glibc mapped the 3 MiB blocks itself: {before} mapped blocks, then {during}"
        );
        assert!(TUNED.load(Ordering::Relaxed));
        drop(b);
    }

    #[test]
    fn the_pool_keeps_no_more_than_its_limit() {
        // Each freed block is pooled only while the total stays within the limit.
        for _ in 0..3 {
            let blocks: Vec<Vec<u8>> = (0..8).map(|_| vec![1u8; 64 << 20]).collect();
            drop(blocks);
            let (bytes, limit) = pool_state();
            assert!(bytes <= limit, "{bytes} > {limit}");
        }
    }
}
