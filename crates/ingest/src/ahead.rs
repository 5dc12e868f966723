//! Reading ahead of a reader that walks its memory-mapped input from start to
//! end: a thread of its own faults in the stretch after the one being decoded
//! (`madvise(MADV_POPULATE_READ)`, 16 MiB at a time: it waits for the disk, the
//! decoders do not), so the disk works while the cores decode. Without it an
//! input not in the page cache is read by the decoders' own page faults, the
//! disk idle while they decode and they idle while it reads.
//! (`posix_fadvise(WILLNEED)` was tried first: it returns at once and drops
//! what the device queue cannot take; of a 1.3 GB file asked for in 16 MiB
//! requests, 640 MiB were ever read.)

use memmap2::Mmap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Bytes faulted in at a time.
const STEP: u64 = 16 << 20;

/// Inputs of at most this many bytes are not read ahead.
const SMALL: u64 = 2 * STEP;

/// A read-ahead thread over one mapping; stopped when dropped.
pub struct ReadAhead {
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
}

struct Shared {
    /// Read ahead up to this byte offset.
    want: AtomicU64,
    stop: AtomicBool,
}

impl ReadAhead {
    /// Starts reading ahead in `map` from byte `start` up to `end` (at most the
    /// map's length), as far as [`ReadAhead::want`] asks. `None` where the
    /// system has no such advice (reading then goes on without it).
    pub fn start(map: Arc<Mmap>, start: u64, end: u64) -> Option<ReadAhead> {
        if !cfg!(target_os = "linux") {
            return None;
        }
        let end = end.min(map.len() as u64);
        let shared = Arc::new(Shared {
            want: AtomicU64::new(start),
            stop: AtomicBool::new(false),
        });
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name("read-ahead".into())
            .spawn(move || run(&map, &s, start, end))
            .ok()?;
        Some(ReadAhead {
            shared,
            thread: Some(thread),
        })
    }

    /// Asks for the file up to byte `upto` to be read (an offset below one asked
    /// for before changes nothing).
    pub fn want(&self, upto: u64) {
        self.shared.want.fetch_max(upto, Ordering::Relaxed);
        if let Some(t) = &self.thread {
            t.thread().unpark();
        }
    }
}

/// A [`ReadAhead`] started at the first [`Ahead::want`]: a reader opened only
/// for its header (several input files are, up front) starts no thread.
pub struct Ahead {
    map: Arc<Mmap>,
    start: u64,
    end: u64,
    state: State,
}

enum State {
    Idle,
    Running(ReadAhead),
    Off,
}

impl Ahead {
    /// Reading ahead in `map` from byte `start` up to `end`, once asked; not at
    /// all for a stretch of at most `SMALL` (a thread a file cost more than it
    /// saved on 500 files of 130 kB: 1.37-1.66 s against 1.10-1.17 s).
    pub fn new(map: Arc<Mmap>, start: u64, end: u64) -> Ahead {
        let small = end.saturating_sub(start) <= SMALL;
        Ahead {
            map,
            start,
            end,
            state: if small { State::Off } else { State::Idle },
        }
    }

    /// Asks for the file up to byte `upto` to be read (the thread starts now
    /// if it has not).
    pub fn want(&mut self, upto: u64) {
        if let State::Idle = self.state {
            self.state = match ReadAhead::start(self.map.clone(), self.start, self.end) {
                Some(r) => State::Running(r),
                None => State::Off,
            };
        }
        if let State::Running(r) = &self.state {
            r.want(upto);
        }
    }

    /// No more reading ahead (the reader samples from here on: its windows are
    /// sparse).
    pub fn stop(&mut self) {
        self.state = State::Off;
    }
}

impl Drop for ReadAhead {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

fn run(map: &Mmap, s: &Shared, start: u64, end: u64) {
    let mut at = start;
    while at < end && !s.stop.load(Ordering::Relaxed) {
        let want = s.want.load(Ordering::Relaxed).min(end);
        if at < want {
            let len = STEP.min(want - at);
            if !populate(map, at as usize, len as usize) {
                return; // not supported here: the decoders fault the pages in
            }
            at += len;
        } else {
            std::thread::park_timeout(std::time::Duration::from_millis(50));
        }
    }
}

/// Faults in `map[at..at + len]`, waiting for the disk, unless the page cache
/// holds all of it already (faulting in cached pages a page at a time costs more
/// CPU than the parsers' own faults, which map 16 pages each); false where the
/// system refuses the advice.
#[cfg(target_os = "linux")]
fn populate(map: &Mmap, at: usize, len: usize) -> bool {
    if cached(map, at, len) {
        return true;
    }
    map.advise_range(memmap2::Advice::PopulateRead, at, len)
        .is_ok()
}

/// Whether every page of `map[at..at + len]` is in the page cache (`mincore`).
#[cfg(target_os = "linux")]
fn cached(map: &Mmap, at: usize, len: usize) -> bool {
    const PAGE: usize = 4096;
    let start = (map.as_ptr() as usize + at) / PAGE * PAGE;
    let end = map.as_ptr() as usize + at + len;
    let mut v = vec![0u8; (end - start).div_ceil(PAGE)];
    // SAFETY: the range lies inside the mapping (rounded down to its page, which
    // the mapping starts on or after); `v` holds a byte for each page.
    let r = unsafe { libc::mincore(start as *mut libc::c_void, end - start, v.as_mut_ptr()) };
    r == 0 && v.iter().all(|b| b & 1 == 1)
}

#[cfg(not(target_os = "linux"))]
fn populate(_: &Mmap, _: usize, _: usize) -> bool {
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The thread reads as far as asked: pages the page cache had dropped are
    /// there afterwards, though nothing touched the map. It stops when dropped,
    /// even while waiting for more to be asked.
    #[test]
    fn reads_ahead_and_stops() {
        // (Under target/, on the disk: a tmpfs could not drop the pages. It is
        // made if the build went elsewhere, as with CARGO_TARGET_DIR.)
        let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target");
        std::fs::create_dir_all(&base).unwrap();
        let dir = tempfile::tempdir_in(&base).unwrap();
        let p = dir.path().join("f.bin");
        std::fs::write(&p, vec![7u8; 8 << 20]).unwrap();
        let f = std::fs::File::open(&p).unwrap();
        f.sync_all().unwrap();
        // SAFETY: a file of this test's own.
        let map = Arc::new(unsafe { Mmap::map(&f) }.unwrap());
        // Drop the file's clean pages from the page cache.
        {
            use std::os::unix::io::AsRawFd;
            // SAFETY: advice on an open descriptor.
            let r = unsafe { libc::posix_fadvise(f.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED) };
            assert_eq!(r, 0);
        }
        assert!(
            !cached(&map, 0, 4 << 20),
            "the test file's pages stayed cached"
        );
        let a = ReadAhead::start(map.clone(), 0, 8 << 20).expect("a read-ahead thread");
        a.want(4 << 20);
        a.want(1 << 20); // lower: no change
        assert_eq!(a.shared.want.load(Ordering::Relaxed), 4 << 20);
        let t = std::time::Instant::now();
        while !cached(&map, 0, 4 << 20) && t.elapsed() < std::time::Duration::from_secs(10) {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert!(
            cached(&map, 0, 4 << 20),
            "the first 4 MiB were not read ahead"
        );
        let t = std::time::Instant::now();
        drop(a);
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        assert_eq!(map[(4 << 20) - 1], 7);
    }
}
