//! The output file of a part: a buffered, seekable writer with positioned writes
//! (`pwrite`), for compressed tiles streamed after the head; and the writers of
//! uncompressed tiles, whose sizes are known, so every level's tile data has its
//! place before it is encoded: the rayon pool encodes the tiles and writer
//! threads write them there (`writer::write_tiles`), through the page cache or
//! around it ([`TileWriter`], from aligned [`TileBuf`]s).

use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};

use crate::spec::TILE_PIXELS;

/// Bytes gathered before a write to the file (tags and small values).
const BUFFER: usize = 64 << 10;

/// A buffered writer over a file with positioned writes (no seek system calls).
pub struct Out<'f> {
    file: &'f File,
    buf: Vec<u8>,
    /// File position of `buf[0]`.
    at: u64,
}

impl<'f> Out<'f> {
    pub fn new(file: &'f File) -> Self {
        Out {
            file,
            buf: Vec::with_capacity(BUFFER),
            at: 0,
        }
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
pub(crate) fn write_all_at(file: &File, data: &[u8], offset: u64) -> io::Result<()> {
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

/// Alignment of tile data in the file and in memory for direct I/O (`O_DIRECT`
/// wants offsets, lengths and buffer addresses in whole logical blocks; 4 KiB
/// covers 512-byte and 4 KiB devices).
pub const DIRECT_ALIGN: usize = 4096;

/// One band of one tile: `TILE_PIXELS` samples in memory aligned to
/// [`DIRECT_ALIGN`], so the writer can hand it to the disk without a copy.
pub struct TileBuf {
    ptr: std::ptr::NonNull<f32>,
}

// SAFETY: a TileBuf owns its allocation outright, like a Vec<f32>.
unsafe impl Send for TileBuf {}
// SAFETY: as a Vec<f32>: a shared TileBuf is only read.
unsafe impl Sync for TileBuf {}

impl TileBuf {
    /// A tile whose every sample the caller will overwrite: a recycled buffer
    /// as it is (its old samples), or a fresh zeroed one; no fill.
    pub fn reused() -> TileBuf {
        if let Some(t) = FREE_TILES.lock().ok().and_then(|mut f| f.pop()) {
            return t;
        }
        let layout = Self::layout();
        // SAFETY: the layout has a non-zero size; zeroed memory is valid f32s.
        let raw = unsafe { std::alloc::alloc_zeroed(layout) } as *mut f32;
        let Some(ptr) = std::ptr::NonNull::new(raw) else {
            std::alloc::handle_alloc_error(layout)
        };
        TileBuf { ptr }
    }

    fn layout() -> std::alloc::Layout {
        // (Sizes are constants: TILE_PIXELS * 4 bytes, aligned to 4 KiB.)
        std::alloc::Layout::from_size_align(TILE_PIXELS * 4, DIRECT_ALIGN)
            .expect("a tile's layout is valid")
    }

    /// A buffer for a tile of `count` points: reused as it is where they fill
    /// every pixel, else NaN everywhere (pixels without a point).
    pub fn for_points(count: usize) -> TileBuf {
        if count == crate::spec::TILE_PIXELS {
            TileBuf::reused()
        } else {
            TileBuf::filled(f32::NAN)
        }
    }

    /// A tile of `v` everywhere: a recycled buffer when one is free.
    pub fn filled(v: f32) -> TileBuf {
        if let Some(mut t) = FREE_TILES.lock().ok().and_then(|mut f| f.pop()) {
            t.fill(v);
            return t;
        }
        {
            let layout = Self::layout();
            // SAFETY: the layout has a non-zero size.
            let raw = unsafe { std::alloc::alloc(layout) } as *mut f32;
            let Some(ptr) = std::ptr::NonNull::new(raw) else {
                std::alloc::handle_alloc_error(layout)
            };
            // SAFETY: the allocation holds TILE_PIXELS f32s; fill initializes them
            // (writing through the raw slice before any read).
            unsafe { std::slice::from_raw_parts_mut(raw, TILE_PIXELS) }.fill(v);
            TileBuf { ptr }
        }
    }
}

/// Tile buffers freed and kept for the next tiles (at most [`FREE_TILES_MAX`]):
/// a part's tiles are allocated and freed by the thousand, and fresh memory
/// costs page faults.
static FREE_TILES: std::sync::Mutex<Vec<TileBuf>> = std::sync::Mutex::new(Vec::new());
const FREE_TILES_MAX: usize = 64;

/// Returns `t` to the free list (or frees it when the list is full).
pub(crate) fn recycle(t: TileBuf) {
    if let Ok(mut f) = FREE_TILES.lock()
        && f.len() < FREE_TILES_MAX
    {
        f.push(t);
    }
}

impl std::ops::Deref for TileBuf {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        // SAFETY: TILE_PIXELS initialized f32s, owned by self.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), TILE_PIXELS) }
    }
}

impl std::ops::DerefMut for TileBuf {
    fn deref_mut(&mut self) -> &mut [f32] {
        // SAFETY: as above, borrowed mutably through self.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.as_ptr(), TILE_PIXELS) }
    }
}

impl Drop for TileBuf {
    fn drop(&mut self) {
        // SAFETY: allocated in `filled` with this layout.
        unsafe { std::alloc::dealloc(self.ptr.as_ptr() as *mut u8, Self::layout()) }
    }
}

/// How uncompressed tile data reaches the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TileIo {
    /// Through the page cache while it takes data faster than [`SLOW_CACHE`],
    /// then around it (see [`TileWriter`]).
    #[default]
    Auto,
    /// Around the page cache (`O_DIRECT`) where the file system allows.
    Direct,
    /// Through the page cache.
    Buffered,
}

impl TileIo {
    /// Parses `auto`, `direct` or `buffered` (the command line's `--io`).
    pub fn parse(s: &str) -> Result<TileIo, String> {
        match s {
            "auto" => Ok(TileIo::Auto),
            "direct" => Ok(TileIo::Direct),
            "buffered" => Ok(TileIo::Buffered),
            _ => Err(format!("'{s}': expected auto, direct or buffered")),
        }
    }
}

/// In [`TileIo::Auto`], buffered writes slower than this (bytes a second of
/// copying into the page cache) switch the process to direct writes. On the VM the
/// copy runs at 4.6 GB/s into pages freed moments ago and at 0.3-0.7 GB/s into
/// pages the host has taken back (as it has after any pause), where a direct write
/// runs at the disk's 1.25 GB/s with no CPU.
pub const SLOW_CACHE: f64 = 1.5e9;

/// Buffered bytes timed before [`TileIo::Auto`] judges the page cache.
const JUDGE_BYTES: u64 = 32 << 20;

/// Set once [`TileIo::Auto`] found the page cache slow: later parts start direct.
static CACHE_SLOW: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Writes tile data at aligned offsets, through the page cache or around it
/// (`O_DIRECT`, through a second handle, straight from the encoder's buffers to
/// the disk), as [`TileIo`] says. In `Auto` the buffered writes are timed and,
/// when the page cache proves slower than [`SLOW_CACHE`], the rest go direct (and
/// so do later parts'): a buffered write of 2 GiB costs 0.5 s of CPU into warm
/// pages and 5 s into pages the host took back. A direct write the file system
/// refuses falls back to buffered writes, for good.
pub struct TileWriter<'f> {
    buffered: &'f File,
    direct: Option<File>,
    mode: TileIo,
    /// Whether writes go direct now.
    going_direct: std::sync::atomic::AtomicBool,
    /// Buffered writes one at a time, timed: (bytes, seconds) since the last
    /// judgement. (The kernel serializes buffered writes to one file anyway.)
    timed: std::sync::Mutex<(u64, f64)>,
}

impl<'f> TileWriter<'f> {
    /// A writer for `buffered`, the file at `path`, in `mode`.
    pub fn new(buffered: &'f File, path: &std::path::Path, mode: TileIo) -> TileWriter<'f> {
        use std::sync::atomic::Ordering::Relaxed;
        let direct = match mode {
            TileIo::Buffered => None,
            _ => open_direct(path),
        };
        let start_direct = match mode {
            TileIo::Direct => true,
            TileIo::Auto => CACHE_SLOW.load(Relaxed),
            TileIo::Buffered => false,
        };
        TileWriter {
            going_direct: (start_direct && direct.is_some()).into(),
            buffered,
            direct,
            mode,
            timed: std::sync::Mutex::new((0, 0.0)),
        }
    }

    /// Whether tile data goes around the page cache now.
    pub(crate) fn is_direct(&self) -> bool {
        self.going_direct.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Writes `tile` at `offset` (a multiple of [`DIRECT_ALIGN`]; callable from
    /// several threads).
    pub fn write(&self, tile: &[f32], offset: u64) -> io::Result<()> {
        use std::sync::atomic::Ordering::Relaxed;
        let bytes: &[u8] = bytemuck::cast_slice(tile);
        if let Some(d) = self.direct_now() {
            let aligned = offset.is_multiple_of(DIRECT_ALIGN as u64)
                && bytes.len().is_multiple_of(DIRECT_ALIGN)
                && (bytes.as_ptr() as usize).is_multiple_of(DIRECT_ALIGN);
            if aligned {
                match write_all_at(d, bytes, offset) {
                    Ok(()) => return Ok(()),
                    Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                        self.going_direct.store(false, Relaxed);
                    }
                    Err(e) => return Err(e),
                }
            } else {
                return write_all_at(self.buffered, bytes, offset);
            }
        }
        if self.mode != TileIo::Auto || self.direct.is_none() {
            return write_all_at(self.buffered, bytes, offset);
        }
        let mut timed = self.timed.lock().unwrap_or_else(|p| p.into_inner());
        let t = std::time::Instant::now();
        write_all_at(self.buffered, bytes, offset)?;
        self.judge(&mut timed, bytes.len() as u64, t);
        Ok(())
    }

    /// Adds a buffered write of `bytes` begun at `since` to `timed`; once
    /// [`JUDGE_BYTES`] were timed, a page cache slower than [`SLOW_CACHE`] sends
    /// the rest of the process's tile data around it.
    fn judge(&self, timed: &mut (u64, f64), bytes: u64, since: std::time::Instant) {
        use std::sync::atomic::Ordering::Relaxed;
        timed.0 += bytes;
        timed.1 += since.elapsed().as_secs_f64();
        if timed.0 >= JUDGE_BYTES {
            if (timed.0 as f64) < SLOW_CACHE * timed.1 {
                CACHE_SLOW.store(true, Relaxed);
                self.going_direct.store(true, Relaxed);
            }
            *timed = (0, 0.0);
        }
    }

    /// Writes `tiles`, which lie back to back in the file from `offset` (a
    /// multiple of [`DIRECT_ALIGN`]), with one system call where it can: the
    /// disk takes 1.5 GB/s in 256 KiB direct writes and 2.0-2.2 GB/s in 1-4 MiB
    /// ones (`dd oflag=direct` on the VM).
    pub(crate) fn write_run(&self, tiles: &[&[f32]], offset: u64) -> io::Result<()> {
        use std::sync::atomic::Ordering::Relaxed;
        if tiles.len() < 2 {
            return tiles.first().map_or(Ok(()), |t| self.write(t, offset));
        }
        let timed = self.judging();
        let direct = self.direct_now();
        let file = direct.unwrap_or(self.buffered);
        // (Buffered writes in Auto are timed one at a time, as in `write`.)
        let mut lock = timed.then(|| self.timed.lock().unwrap_or_else(|p| p.into_inner()));
        let t = std::time::Instant::now();
        match write_vectored_all_at(file, tiles, offset) {
            Ok(()) => {}
            Err(e) if direct.is_some() && e.raw_os_error() == Some(libc::EINVAL) => {
                // The file system refuses direct writes: buffered from here on.
                self.going_direct.store(false, Relaxed);
                drop(lock);
                return self.write_run(tiles, offset);
            }
            Err(e) => return Err(e),
        }
        if let Some(timed) = lock.as_deref_mut() {
            let bytes: u64 = tiles.iter().map(|t| 4 * t.len() as u64).sum();
            self.judge(timed, bytes, t);
        }
        Ok(())
    }
}

impl<'f> TileWriter<'f> {
    /// The handle for direct writes, while tile data goes around the page cache.
    fn direct_now(&self) -> Option<&File> {
        self.direct.as_ref().filter(|_| self.is_direct())
    }

    /// Whether buffered writes are being timed (`Auto` with a direct handle,
    /// not yet direct).
    fn judging(&self) -> bool {
        self.mode == TileIo::Auto && self.direct.is_some() && !self.is_direct()
    }

    /// Sends the rest of the tile data through the page cache (a direct write
    /// the file system refused).
    fn stop_direct(&self) {
        self.going_direct
            .store(false, std::sync::atomic::Ordering::Relaxed);
    }
}

/// Bytes a [`StreamOut`] gathers for one direct write (the disk takes 1-4 MiB
/// writes fastest, [`TileWriter::write_run`]).
const STAGE: usize = 4 << 20;

/// Compressed tiles written one after another from a position (sizes known
/// only once encoded): through the page cache by an [`Out`], judged as
/// [`TileWriter`] judges it, and once that writer goes direct (a slow page
/// cache, or `--io direct`), from the next block boundary on around it, from
/// an aligned buffer of [`STAGE`] bytes, the last block padded with zeros (the caller sets the file's length
/// once all is written). As with uncompressed tiles: on the VM a copy into
/// pages the host took back runs at 0.3-0.7 GB/s, and writing a conversion's
/// compressed tiles that way took a writer thread's second of CPU from two
/// cores' encoding.
pub struct StreamOut<'f> {
    file: &'f File,
    tiles: &'f TileWriter<'f>,
    out: Out<'f>,
    /// While direct: the buffer, its bytes, and the file offset of its first
    /// (a multiple of [`DIRECT_ALIGN`]).
    stage: Option<(StageBuf, usize, u64)>,
}

/// [`STAGE`] bytes aligned to [`DIRECT_ALIGN`].
struct StageBuf(std::ptr::NonNull<u8>);

impl StageBuf {
    fn layout() -> std::alloc::Layout {
        std::alloc::Layout::from_size_align(STAGE, DIRECT_ALIGN).expect("a valid layout")
    }

    fn new() -> StageBuf {
        // SAFETY: the layout has a non-zero size; zeroed bytes are valid u8s.
        let raw = unsafe { std::alloc::alloc_zeroed(Self::layout()) };
        match std::ptr::NonNull::new(raw) {
            Some(p) => StageBuf(p),
            None => std::alloc::handle_alloc_error(Self::layout()),
        }
    }

    fn bytes(&mut self) -> &mut [u8] {
        // SAFETY: STAGE initialized bytes, owned by self.
        unsafe { std::slice::from_raw_parts_mut(self.0.as_ptr(), STAGE) }
    }
}

impl Drop for StageBuf {
    fn drop(&mut self) {
        // SAFETY: allocated in `new` with this layout.
        unsafe { std::alloc::dealloc(self.0.as_ptr(), Self::layout()) }
    }
}

impl<'f> StreamOut<'f> {
    /// A writer at `at` of `file` (whose tile writer is `tiles`).
    pub fn new(file: &'f File, tiles: &'f TileWriter<'f>, at: u64) -> io::Result<StreamOut<'f>> {
        let mut out = Out::new(file);
        out.seek(SeekFrom::Start(at))?;
        Ok(StreamOut {
            file,
            tiles,
            out,
            stage: None,
        })
    }

    fn position(&self) -> u64 {
        match &self.stage {
            Some((_, len, at)) => at + *len as u64,
            None => self.out.at + self.out.buf.len() as u64,
        }
    }

    /// Around the page cache from the next block boundary on: the bytes up
    /// to it still go through the page cache (so none is written twice).
    /// Writes the first of `data` that way and returns the rest.
    fn toward_direct<'d>(&mut self, data: &'d [u8]) -> io::Result<&'d [u8]> {
        let here = self.position();
        let to_boundary = (here.next_multiple_of(DIRECT_ALIGN as u64) - here) as usize;
        let now = to_boundary.min(data.len());
        self.out.write_all(&data[..now])?;
        if now == to_boundary {
            self.out.flush()?;
            self.stage = Some((StageBuf::new(), 0, here + now as u64));
        }
        Ok(&data[now..])
    }

    /// Writes the first `n` bytes of the buffer (a multiple of
    /// [`DIRECT_ALIGN`]) around the page cache, or through it if the file
    /// system refuses (and then every later byte too).
    fn write_stage(&mut self, n: usize) -> io::Result<()> {
        let Some((buf, len, at)) = self.stage.as_mut() else {
            return Ok(());
        };
        let direct = self.tiles.direct.as_ref();
        let res = match direct {
            Some(d) => write_all_at(d, &buf.bytes()[..n], *at),
            None => Err(io::Error::from_raw_os_error(libc::EINVAL)),
        };
        match res {
            Ok(()) => {
                let keep = *len - n;
                buf.bytes().copy_within(n..n + keep, 0);
                *len = keep;
                *at += n as u64;
                Ok(())
            }
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                // Refused: what the buffer holds, and the rest, buffered.
                self.tiles.stop_direct();
                let (mut buf, len, at) = self.stage.take().expect("staging");
                write_all_at(self.file, &buf.bytes()[..len], at)?;
                self.out.at = at + len as u64;
                Ok(())
            }
            Err(e) => Err(e),
        }
    }

    /// Writes what is left; the end of the data (the file may be longer by
    /// the padding of its last block: set its length to this).
    pub fn finish(&mut self) -> io::Result<u64> {
        let end = self.position();
        if let Some((buf, len, _)) = self.stage.as_mut() {
            let n = len.next_multiple_of(DIRECT_ALIGN);
            buf.bytes()[*len..n].fill(0);
            *len = n;
            self.write_stage(n)?;
        }
        self.out.flush()?;
        Ok(end)
    }
}

impl Write for StreamOut<'_> {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        let mut rest = data;
        if self.stage.is_none() {
            if self.tiles.direct_now().is_some() {
                rest = self.toward_direct(rest)?;
            } else if !self.tiles.judging() {
                self.out.write_all(rest)?;
                rest = &[];
            } else {
                let mut timed = self.tiles.timed.lock().unwrap_or_else(|p| p.into_inner());
                let t = std::time::Instant::now();
                self.out.write_all(rest)?;
                self.tiles.judge(&mut timed, rest.len() as u64, t);
                rest = &[];
            }
        }
        while !rest.is_empty() {
            let Some((buf, len, _)) = self.stage.as_mut() else {
                // Direct writes were refused: the rest buffered.
                self.out.write_all(rest)?;
                break;
            };
            let take = rest.len().min(STAGE - *len);
            buf.bytes()[*len..*len + take].copy_from_slice(&rest[..take]);
            *len += take;
            rest = &rest[take..];
            if *len == STAGE {
                self.write_stage(STAGE)?;
            }
        }
        Ok(data.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

impl Seek for StreamOut<'_> {
    /// Only where it stands (`stream_position`): the data goes in sequence.
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let here = self.position();
        match to {
            SeekFrom::Current(0) => Ok(here),
            SeekFrom::Start(o) if o == here => Ok(here),
            _ => Err(io::Error::other("a tile stream only goes forward")),
        }
    }
}

/// Writes the slices `parts`, back to back, at `offset` of `file` (`pwritev`;
/// what a short write leaves is written piece by piece).
#[cfg(unix)]
fn write_vectored_all_at(file: &File, parts: &[&[f32]], offset: u64) -> io::Result<()> {
    use std::os::unix::io::AsRawFd;
    let iov: Vec<libc::iovec> = parts
        .iter()
        .map(|p| libc::iovec {
            iov_base: p.as_ptr() as *mut libc::c_void,
            iov_len: std::mem::size_of_val(*p),
        })
        .collect();
    let total: usize = iov.iter().map(|v| v.iov_len).sum();
    let done = loop {
        // SAFETY: every iovec points at a live slice of its length, only read.
        let n = unsafe {
            libc::pwritev(
                file.as_raw_fd(),
                iov.as_ptr(),
                iov.len().min(libc::c_int::MAX as usize) as libc::c_int,
                offset as libc::off_t,
            )
        };
        if n >= 0 {
            break n as usize;
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    };
    if done == total {
        return Ok(());
    }
    if done == 0 {
        return Err(io::ErrorKind::WriteZero.into());
    }
    // A short write: the rest, slice by slice.
    let mut at = 0usize;
    for p in parts {
        let bytes: &[u8] = bytemuck::cast_slice(p);
        let end = at + bytes.len();
        if end > done {
            let skip = done.saturating_sub(at);
            write_all_at(file, &bytes[skip..], offset + (at + skip) as u64)?;
        }
        at = end;
    }
    Ok(())
}

#[cfg(not(unix))]
fn write_vectored_all_at(file: &File, parts: &[&[f32]], offset: u64) -> io::Result<()> {
    let mut at = offset;
    for p in parts {
        let bytes: &[u8] = bytemuck::cast_slice(p);
        write_all_at(file, bytes, at)?;
        at += bytes.len() as u64;
    }
    Ok(())
}

/// `path` opened for writing with `O_DIRECT`, if the system and file system allow.
#[cfg(target_os = "linux")]
fn open_direct(path: &std::path::Path) -> Option<File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .write(true)
        .custom_flags(libc::O_DIRECT)
        .open(path)
        .ok()
}

#[cfg(not(target_os = "linux"))]
fn open_direct(_: &std::path::Path) -> Option<File> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    /// Tiles streamed from an unaligned position land where they were
    /// written whatever the writer's mode (direct from the next block on, or
    /// buffered where the file system refuses direct writes), the head
    /// written last and the file cut to the data's end.
    #[test]
    fn streamed_tiles_land_in_sequence_in_every_mode() {
        let dir = tempfile::tempdir().unwrap();
        for mode in [TileIo::Direct, TileIo::Buffered, TileIo::Auto] {
            let path = dir.path().join(format!("{mode:?}.bin"));
            let file = File::create(&path).unwrap();
            let tiles = TileWriter::new(&file, &path, mode);
            let head = 1000u64;
            let mut want = vec![0u8; head as usize];
            let mut w = StreamOut::new(&file, &tiles, head).unwrap();
            let mut rng = crate::rng::Rng::new(5);
            // Pieces of every size around the block and the buffer.
            for n in [1usize, 3000, 4096, 5000, STAGE - 10, 20, STAGE + 7, 100] {
                let piece: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
                assert_eq!(w.stream_position().unwrap(), want.len() as u64);
                w.write_all(&piece).unwrap();
                want.extend(&piece);
            }
            let end = w.finish().unwrap();
            assert_eq!(end, want.len() as u64, "{mode:?}");
            write_all_at(&file, &[9u8; 1000], 0).unwrap();
            want[..1000].fill(9);
            file.set_len(end).unwrap();
            drop(file);
            assert!(std::fs::read(&path).unwrap() == want, "{mode:?}");
        }
    }

    #[test]
    fn writes_land_where_seeks_put_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let file = File::create(&path).unwrap();
        let mut o = Out::new(&file);
        o.seek(SeekFrom::Start(100)).unwrap();
        o.write_all(b"tile").unwrap();
        o.write_all(&vec![7u8; 2 * BUFFER]).unwrap();
        assert_eq!(o.stream_position().unwrap(), 104 + 2 * BUFFER as u64);
        o.flush().unwrap();
        write_all_at(&file, b"head", 0).unwrap();
        drop(o);
        let mut got = Vec::new();
        File::open(&path).unwrap().read_to_end(&mut got).unwrap();
        assert_eq!(got.len(), 104 + 2 * BUFFER);
        assert_eq!(&got[..4], b"head");
        assert!(got[4..100].iter().all(|&b| b == 0));
        assert_eq!(&got[100..104], b"tile");
        assert!(got[104..].iter().all(|&b| b == 7));
    }
}
