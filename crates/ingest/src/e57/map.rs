//! The memory map an E57 file is read through: `Read + Seek` for the `e57`
//! crate, with no system call per 1 KiB page (as a `BufReader` would make, since
//! the crate seeks before every page), the offset of the last read kept for
//! error messages, and the pages behind the reader released as it advances.

use memmap2::Mmap;
use std::io::{Read, Seek, SeekFrom};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Bytes read past a position before the pages below it are released (by
/// this cursor, and by the points' decoder in `mod.rs`).
pub(super) const KEEP: usize = 1 << 20;

pub(crate) struct MapCursor {
    map: Arc<Mmap>,
    pos: usize,
    released: usize,
    /// Byte offset where the last read began (shared with the reader for errors).
    pub last_read: Arc<AtomicU64>,
}

impl MapCursor {
    pub fn new(map: Arc<Mmap>) -> MapCursor {
        MapCursor {
            map,
            pos: 0,
            released: 0,
            last_read: Arc::new(AtomicU64::new(0)),
        }
    }
}

impl Read for MapCursor {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let start = self.pos.min(self.map.len());
        let n = buf.len().min(self.map.len() - start);
        buf[..n].copy_from_slice(&self.map[start..start + n]);
        self.last_read.store(start as u64, Ordering::Relaxed);
        self.pos = start + n;
        if self.pos < self.released {
            // Reading again below what was released: start over from here.
            self.released = start;
        } else if self.pos > self.released + KEEP {
            crate::release_consumed(&self.map, &mut self.released, self.pos - KEEP);
        }
        Ok(n)
    }
}

impl Seek for MapCursor {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let len = self.map.len() as i128;
        let at = match to {
            SeekFrom::Start(o) => o as i128,
            SeekFrom::End(d) => len + d as i128,
            SeekFrom::Current(d) => self.pos as i128 + d as i128,
        };
        if at < 0 || at > usize::MAX as i128 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "seek before the start of the file",
            ));
        }
        self.pos = at as usize;
        Ok(at as u64)
    }
}
