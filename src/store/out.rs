//! The output file of a part as the TIFF encoder sees it: a buffered, seekable
//! writer that can leave a hole (a run of bytes the encoder counts but does not
//! write), which is then filled with positioned writes (`pwrite`). Uncompressed
//! tiles have known sizes, so a level's tile data is reserved as one hole: the
//! rayon pool encodes the tiles and one writer thread writes them into it
//! (`writer::write_tiles`), while the encoder's own thread goes on.

use std::cell::Cell;
use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::rc::Rc;

/// Bytes gathered before a write to the file (tags and small values).
const BUFFER: usize = 64 << 10;

/// A buffered writer over a file with positioned writes (no seek system calls).
pub struct Out<'f> {
    file: &'f File,
    buf: Vec<u8>,
    /// File position of `buf[0]`.
    at: u64,
    /// Bytes still to skip instead of writing (set through [`Out::hole`]).
    skip: Rc<Cell<u64>>,
}

impl<'f> Out<'f> {
    pub fn new(file: &'f File) -> Self {
        Out {
            file,
            buf: Vec::with_capacity(BUFFER),
            at: 0,
            skip: Rc::new(Cell::new(0)),
        }
    }

    /// The file, for positioned writes into holes.
    pub fn file(&self) -> &'f File {
        self.file
    }

    /// A handle that makes the next `len` bytes written a hole (see [`reserve`]).
    pub fn hole(&self) -> Rc<Cell<u64>> {
        self.skip.clone()
    }

    fn flush_buf(&mut self) -> io::Result<()> {
        if !self.buf.is_empty() {
            write_all_at(self.file, &self.buf, self.at)?;
            self.at += self.buf.len() as u64;
            self.buf.clear();
        }
        Ok(())
    }
}

impl Write for Out<'_> {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        let skip = self.skip.get();
        if skip > 0 {
            self.flush_buf()?;
            let k = skip.min(data.len() as u64);
            self.skip.set(skip - k);
            self.at += k;
            return Ok(k as usize);
        }
        if self.buf.len() + data.len() > BUFFER {
            self.flush_buf()?;
            if data.len() >= BUFFER {
                write_all_at(self.file, data, self.at)?;
                self.at += data.len() as u64;
                return Ok(data.len());
            }
        }
        self.buf.extend_from_slice(data);
        Ok(data.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.flush_buf()
    }
}

impl Seek for Out<'_> {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let here = self.at + self.buf.len() as u64;
        let target = match to {
            SeekFrom::Start(o) => o,
            SeekFrom::Current(d) => here.checked_add_signed(d).ok_or_else(bad_seek)?,
            SeekFrom::End(_) => return Err(io::Error::other("seek from the end unsupported")),
        };
        if target != here {
            self.flush_buf()?;
            self.at = target;
        }
        Ok(target)
    }
}

fn bad_seek() -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, "seek before the start")
}

/// Writes all of `data` at `offset` of `file` (callable from any thread).
pub fn write_all_at(file: &File, data: &[u8], offset: u64) -> io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.write_all_at(data, offset)
    }
    #[cfg(windows)]
    {
        use std::os::windows::fs::FileExt;
        let mut done = 0;
        while done < data.len() {
            let n = file.seek_write(&data[done..], offset + done as u64)?;
            if n == 0 {
                return Err(io::ErrorKind::WriteZero.into());
            }
            done += n;
        }
        Ok(())
    }
}

/// Zeros handed to the encoder for a hole: a zero-initialized static, so its pages
/// are never touched (the hole skips them unread).
static ZEROS: [u8; 1 << 20] = [0; 1 << 20];

/// Passes `len` zero bytes to `write` (the encoder's `write_data`) in pieces and
/// returns the offset of the first: with the [`Out`] below the encoder holding a
/// hole of `len`, this advances the encoder's offset without reading or writing
/// anything. Were the hole not set, the zeros would simply be written.
pub fn reserve<E>(len: u64, mut write: impl FnMut(&[u8]) -> Result<u64, E>) -> Result<u64, E> {
    let mut start = None;
    let mut left = len;
    loop {
        let k = left.min(ZEROS.len() as u64) as usize;
        let at = write(&ZEROS[..k])?;
        start.get_or_insert(at);
        left -= k as u64;
        if left == 0 {
            return Ok(start.unwrap_or(at));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    #[test]
    fn holes_are_skipped_and_filled_by_positioned_writes() {
        // A hole of three pieces (the zeros are 1 MiB), then a tail.
        const HOLE: u64 = (2 << 20) + 100_000;
        const END: u64 = 4 + HOLE + 4;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let file = File::create(&path).unwrap();
        let mut o = Out::new(&file);
        o.write_all(b"head").unwrap();
        let hole = o.hole();
        hole.set(HOLE);
        let mut pieces = 0;
        let start = reserve(HOLE, |piece| {
            pieces += 1;
            let at = o.stream_position()?;
            o.write_all(piece).map(|()| at)
        })
        .unwrap();
        assert_eq!((start, hole.get(), pieces), (4, 0, 3));
        o.write_all(b"tail").unwrap();
        assert_eq!(o.stream_position().unwrap(), END);
        o.seek(SeekFrom::Start(2)).unwrap();
        o.write_all(b"AD").unwrap();
        o.flush().unwrap();
        // The hole filled at both ends from positioned writes; its middle reads 0.
        write_all_at(&file, &[1u8; 10], 4).unwrap();
        write_all_at(&file, &[2u8; 10], 4 + HOLE - 10).unwrap();
        drop(o);
        let mut got = Vec::new();
        File::open(&path).unwrap().read_to_end(&mut got).unwrap();
        let (h, e) = ((4 + HOLE) as usize, END as usize);
        assert_eq!(got.len(), e);
        assert_eq!(&got[..4], b"heAD");
        assert_eq!(&got[4..14], &[1u8; 10]);
        assert!(got[14..h - 10].iter().all(|&b| b == 0));
        assert_eq!(&got[h - 10..h], &[2u8; 10]);
        assert_eq!(&got[h..], b"tail");
    }
}
