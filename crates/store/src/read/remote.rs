//! Parts and datasets in object storage: a dataset opens with one request (its
//! index); a part's head is fetched on its first tile read, in one range where
//! the index records the head's length, otherwise (older parts, IFDs after the
//! tiles) as the TIFF header and IFDs by successive ranges.

// A slice of one range is a request for one range (`ensure`, `read_ranges`).
#![allow(clippy::single_range_in_vec_init)]
use crate::error::{Result, StoreError};
use crate::read::part::{Bytes, Part};
use crate::remote::RemoteFile;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

/// The first range read of a part whose head's length is unknown: the TIFF
/// header and, for a part laid out head-first, usually every IFD.
const FIRST_READ: u64 = 64 << 10;
/// Directories beyond this number are a corrupt chain (as `ifd.rs`).
const MAX_IFDS: usize = 256;

/// A file's bytes as far as fetched: a zeroed buffer of the file's size (pages
/// never written are never backed) and the ranges filled in.
struct Sparse<'a> {
    file: &'a RemoteFile,
    buf: Vec<u8>,
    have: Vec<Range<u64>>,
}

impl Sparse<'_> {
    /// Fetches those of `ranges` not held yet, in one concurrent batch.
    fn ensure(&mut self, ranges: &[Range<u64>]) -> std::result::Result<(), String> {
        let size = self.buf.len() as u64;
        let mut want = Vec::new();
        for r in ranges {
            if r.end > size || r.start > r.end {
                return Err(format!(
                    "needs bytes {}..{} but the object has {size} bytes (truncated?)",
                    r.start, r.end
                ));
            }
            if r.end > r.start
                && !self
                    .have
                    .iter()
                    .any(|h| h.start <= r.start && r.end <= h.end)
            {
                want.push(r.clone());
            }
        }
        if want.is_empty() {
            return Ok(());
        }
        let want = crate::remote::file::merge(&want, 0);
        let got = self.file.read_ranges(&want)?;
        for (r, b) in want.into_iter().zip(got) {
            self.buf[r.start as usize..r.end as usize].copy_from_slice(&b);
            self.have.push(r);
        }
        Ok(())
    }

    fn uint(&self, at: u64, n: usize, le: bool) -> u64 {
        let b = &self.buf[at as usize..at as usize + n];
        let mut v = 0u64;
        for i in 0..n {
            let byte = if le { b[n - 1 - i] } else { b[i] };
            v = (v << 8) | byte as u64;
        }
        v
    }

    /// Walks the IFD chain, fetching each directory and its out-of-line values.
    fn walk(&mut self) -> std::result::Result<(), String> {
        let size = self.buf.len() as u64;
        self.ensure(&[0..FIRST_READ.min(size)])?;
        if size < 8 {
            return Err("too short for a TIFF file".into());
        }
        let le = match &self.buf[..2] {
            b"II" => true,
            b"MM" => false,
            _ => return Err("not a TIFF file (no II or MM at byte 0)".into()),
        };
        let big = self.uint(2, 2, le) == 43;
        let (word, count_size, entry_size) = if big { (8, 8, 20) } else { (4, 2, 12) };
        let mut at = self.uint(if big { 8 } else { 4 }, word, le);
        for _ in 0..MAX_IFDS {
            if at == 0 {
                return Ok(());
            }
            self.ensure(&[at..at + count_size as u64])?;
            let n = self.uint(at, count_size, le);
            if n > 4096 {
                return Err(format!("IFD at byte {at} claims {n} entries"));
            }
            let end = at + count_size as u64 + n * entry_size + word as u64;
            self.ensure(&[at..end])?;
            let mut values = Vec::new();
            for e in 0..n {
                let p = at + count_size as u64 + e * entry_size;
                let typ = self.uint(p + 2, 2, le) as u16;
                let count = self.uint(p + 4, word, le);
                let unit = match typ {
                    1 | 2 | 6 | 7 => 1,
                    3 | 8 => 2,
                    4 | 9 | 11 | 13 => 4,
                    5 | 10 | 12 | 16 | 17 | 18 => 8,
                    _ => continue,
                };
                let bytes = count.saturating_mul(unit);
                if bytes > word as u64 {
                    let off = self.uint(p + 4 + word as u64, word, le);
                    values.push(off..off.saturating_add(bytes));
                }
            }
            self.ensure(&values)?;
            at = self.uint(end - word as u64, word, le);
        }
        Err(format!("more than {MAX_IFDS} IFDs"))
    }
}

impl Part {
    /// Opens a part in object storage: its head only (`head` bytes in one
    /// request; 0: the header and IFDs by successive ranges). `expect`: the size
    /// the dataset index records.
    pub fn open_remote(file: Arc<RemoteFile>, head: u64, expect: Option<u64>) -> Result<Part> {
        let url = file.url();
        let path = Path::new(&url);
        // Messages from the fetch already name the URL.
        let err = |m: String| {
            let m = m
                .strip_prefix(&format!("{url}: "))
                .map(str::to_string)
                .unwrap_or(m);
            StoreError::new(path, m)
        };
        // The first request tells the size (and pins the ETag). It must not
        // ask past the object's end (a server answers such a range with the
        // bytes there are, as it should, but the answer then differs from
        // the request): where no index gives the size, a HEAD request does.
        let first = if head > 0 { head } else { FIRST_READ };
        let known = match expect {
            Some(e) => e,
            None => file.size().map_err(StoreError::remote)?,
        };
        if known == 0 {
            return Err(err("file is empty".into()));
        }
        let first = first.min(known);
        let got = file
            .read_ranges(&[0..first.max(1)])
            .map_err(StoreError::remote)?;
        let size = file.seen().map_or(got[0].len() as u64, |s| s.0);
        if let Some(e) = expect
            && e != size
        {
            return Err(err(format!(
                "changed since the dataset was indexed ({size} bytes now, {e} then): upload the whole dataset again"
            )));
        }
        if size == 0 {
            return Err(err("file is empty".into()));
        }
        let mut sparse = Sparse {
            file: &file,
            buf: vec![0u8; size as usize],
            have: vec![0..got[0].len() as u64],
        };
        sparse.buf[..got[0].len()].copy_from_slice(&got[0]);
        if head == 0 || head > size {
            sparse.walk().map_err(err)?;
        }
        let mut part = Part::parse(path, Bytes::Owned(sparse.buf))?;
        part.remote = Some(file);
        Ok(part)
    }
}
