//! The output file of a part as the TIFF encoder sees it: a buffered, seekable
//! writer that can leave a hole (a run of bytes the encoder counts but does not
//! write), which worker threads then fill with positioned writes (`pwrite`) in
//! parallel. Uncompressed tiles have known sizes, so a level's tile data is
//! reserved in one piece and both cores copy tiles into the page cache at once;
//! through the encoder alone one thread did all of that copying.

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

    /// A handle that makes the next `len` bytes written a hole (see [`Reserved`]).
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

/// Writes all of `data` at `offset` of `file` (callable from several threads).
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

/// `len` zero bytes that cost nothing until read: given to the encoder's
/// `write_data` while the [`Out`] below it has a hole of `len`, they advance the
/// encoder's offset without being read or written (an untouched anonymous
/// mapping: no memory is committed for it). Were the hole not set, the zeros would
/// simply be written.
pub fn untouched_zeros(len: u64) -> io::Result<memmap2::MmapMut> {
    let len = usize::try_from(len).map_err(|_| io::Error::other("reservation too large"))?;
    memmap2::MmapOptions::new().len(len.max(1)).map_anon()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    #[test]
    fn holes_are_skipped_and_filled_by_positioned_writes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let file = File::create(&path).unwrap();
        let mut o = Out::new(&file);
        o.write_all(b"head").unwrap();
        let hole = o.hole();
        hole.set(100_000);
        // Written in pieces, as the encoder does; none of it reaches the file.
        for _ in 0..4 {
            o.write_all(&[7u8; 25_000]).unwrap();
        }
        assert_eq!(hole.get(), 0);
        o.write_all(b"tail").unwrap();
        assert_eq!(o.stream_position().unwrap(), 100_008);
        o.seek(SeekFrom::Start(2)).unwrap();
        o.write_all(b"AD").unwrap();
        o.flush().unwrap();
        write_all_at(&file, &[1u8; 10], 4).unwrap();
        write_all_at(&file, &[2u8; 10], 99_994).unwrap();
        drop(o);
        let mut got = Vec::new();
        File::open(&path).unwrap().read_to_end(&mut got).unwrap();
        assert_eq!(got.len(), 100_008);
        assert_eq!(&got[..4], b"heAD");
        assert_eq!(&got[4..14], &[1u8; 10]);
        assert!(got[14..99_994].iter().all(|&b| b == 0));
        assert_eq!(&got[99_994..100_004], &[2u8; 10]);
        assert_eq!(&got[100_004..], b"tail");
    }
}
