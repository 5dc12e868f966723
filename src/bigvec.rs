//! Large working buffers (tens to hundreds of MB of points) backed by transparent
//! huge pages where the kernel offers them (`madvise` mode, the usual default):
//! the first touch of a 4 KiB page costs a page fault, and a fresh 40 MB column
//! takes ten thousand of them; a 2 MiB page takes one fault for 512 of them.

/// Below this size the advice is not worth a system call.
const MIN_BYTES: usize = 4 << 20;

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
    if bytes < MIN_BYTES {
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
