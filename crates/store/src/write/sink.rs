//! The threads that write a part's uncompressed tiles: the rayon pool encodes
//! tiles and hands them (file offset, samples) to a [`TileSink`]; writer threads
//! of their own take them from its queue and write them, in runs of neighbours,
//! through a [`TileWriter`], while the pool encodes the next ones.
//!
//! Not from the workers: the kernel takes the file's lock for every buffered
//! write (ext4, XFS), so parallel buffered writes to one file only queue, and a
//! queued worker spins on the lock instead of encoding (a fifth of a LAS
//! conversion's CPU time in `perf`). Two writers while writes go direct: a direct
//! write waits for the disk, and two in flight reach its full rate (1.25 GB/s on
//! the VM against 0.9 for one at a time).

use crate::spec::TILE_BYTES;
use crate::write::out::{self, TileBuf, TileWriter};
use rayon::prelude::*;
use std::io;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::SyncSender;

/// Tiles and the file offsets they go to.
pub(crate) type Batch = Vec<(u64, TileBuf)>;

/// Where encoders send tiles while [`with_sink`]'s writers run.
pub struct TileSink<'a> {
    tx: SyncSender<Batch>,
    /// Set once a write failed: the encoders stop, the writers only drain.
    failed: &'a AtomicBool,
    cancelled: &'a (dyn Fn() -> bool + Sync),
    /// The first send refused (cancelled, or the writers stopped).
    refused: Mutex<Option<io::Error>>,
}

impl TileSink<'_> {
    /// Queues `batch` for the writers (blocks while the queue is full). Refused
    /// once the write was cancelled or a write failed; the refusal is also kept
    /// for [`with_sink`] to report.
    pub fn send(&self, batch: Batch) -> io::Result<()> {
        let refuse = |e: io::Error| {
            let kept = io::Error::new(e.kind(), e.to_string());
            let mut r = self.refused.lock().unwrap_or_else(|p| p.into_inner());
            r.get_or_insert(kept);
            Err(e)
        };
        if (self.cancelled)() {
            return refuse(io::ErrorKind::Interrupted.into());
        }
        if self.failed.load(Ordering::Relaxed) {
            // The writers' error is the one reported.
            return refuse(io::Error::other("the tile writers stopped"));
        }
        match self.tx.send(batch) {
            Ok(()) => Ok(()),
            Err(_) => refuse(io::Error::other("the tile writers stopped")),
        }
    }

    /// Whether sending is pointless now (cancelled, or a write failed), so an
    /// encoder can skip its work.
    pub fn stopped(&self) -> bool {
        (self.cancelled)() || self.failed.load(Ordering::Relaxed)
    }
}

/// Runs `body` with a [`TileSink`] whose tiles writer threads write through
/// `out`, then waits for the last tile to be written. Returns what `body`
/// returned, and the writing's outcome: the first write error, else the first
/// refused send (`Interrupted` when `cancelled` said so), else `Ok`.
pub fn with_sink<R>(
    out: &TileWriter,
    cancelled: &(dyn Fn() -> bool + Sync),
    body: impl FnOnce(&TileSink) -> R,
) -> (R, io::Result<()>) {
    const WRITERS: usize = 2;
    // Tiles a writer takes at once, so that neighbours in the file are written
    // together (16 band tiles: 4 MiB).
    const RUN_TILES: usize = 16;
    // Tiles in flight: a few per worker (256 KiB a band tile).
    let depth = 4 * rayon::current_num_threads();
    let (tx, rx) = std::sync::mpsc::sync_channel::<Batch>(depth);
    let rx = Mutex::new(rx);
    let failed = AtomicBool::new(false);
    // Set once every tile was sent.
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let writers: Vec<_> = (0..WRITERS)
            .map(|k| {
                let (rx, failed, done) = (&rx, &failed, &done);
                scope.spawn(move || -> io::Result<()> {
                    let mut error = None;
                    // Until every sender is gone: a writer that stopped receiving
                    // would leave the encoders blocked on a full queue for good.
                    loop {
                        // The second writer helps only with direct writes: two
                        // buffered writers only queue on the kernel's lock
                        // (measured 8% slower than one on a text conversion).
                        if k > 0 && !out.is_direct() {
                            if done.load(Ordering::Acquire) {
                                break; // the first writer drains the rest
                            }
                            std::thread::sleep(std::time::Duration::from_millis(1));
                            continue;
                        }
                        // The next batch and those already waiting, up to
                        // RUN_TILES tiles (the lock is held only to take them).
                        let mut batch = {
                            let rx = rx.lock().unwrap_or_else(|p| p.into_inner());
                            let Ok(mut batch) = rx.recv() else { break };
                            while batch.len() < RUN_TILES {
                                match rx.try_recv() {
                                    Ok(more) => batch.extend(more),
                                    Err(_) => break,
                                }
                            }
                            batch
                        };
                        if failed.load(Ordering::Relaxed) {
                            continue; // drained, not written
                        }
                        let wrote = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            // Tiles back to back in the file go in one write.
                            batch.sort_unstable_by_key(|(at, _)| *at);
                            for run in batch.chunk_by(|a, b| a.0 + TILE_BYTES == b.0) {
                                let tiles: Vec<&[f32]> = run.iter().map(|(_, v)| &v[..]).collect();
                                out.write_run(&tiles, run[0].0)?;
                            }
                            for (_, v) in batch {
                                out::recycle(v);
                            }
                            Ok(())
                        }))
                        .unwrap_or_else(|_| Err(io::Error::other("a tile writer panicked")));
                        if let Err(e) = wrote {
                            failed.store(true, Ordering::Relaxed);
                            error.get_or_insert(e);
                        }
                    }
                    error.map_or(Ok(()), Err)
                })
            })
            .collect();
        let sink = TileSink {
            tx,
            failed: &failed,
            cancelled,
            refused: Mutex::new(None),
        };
        let r = body(&sink);
        let TileSink { tx, refused, .. } = sink;
        // The last sender goes, so the writers end after the last tile; their own
        // errors are the ones to report.
        drop(tx);
        done.store(true, Ordering::Release);
        let mut written = Ok(());
        for w in writers {
            let r = w
                .join()
                .unwrap_or_else(|_| Err(io::Error::other("a tile writer panicked")));
            written = written.and(r);
        }
        let refused = refused.into_inner().unwrap_or_else(|p| p.into_inner());
        (r, written.and(refused.map_or(Ok(()), Err)))
    })
}

/// Writes the tiles that the parallel iterator `jobs` encodes (each job: tiles
/// and their file offsets) through a [`with_sink`].
pub fn write_tiles<J>(
    out: &TileWriter,
    cancelled: &(dyn Fn() -> bool + Sync),
    jobs: J,
) -> io::Result<()>
where
    J: ParallelIterator<Item = Batch>,
{
    let (sent, written) = with_sink(out, cancelled, |sink| {
        jobs.try_for_each(|batch| sink.send(batch))
    });
    written.and(sent)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::TILE_PIXELS;
    use crate::write::out::TileIo;
    use std::fs::File;

    const NEVER: &(dyn Fn() -> bool + Sync) = &|| false;

    /// Writes that fail (a file opened read-only) end the tile writing with the
    /// writers' error, however many tiles are still to come: the encoders must not
    /// block on a queue that nobody drains.
    #[test]
    fn failing_writes_end_the_tiles_with_their_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ro.bin");
        std::fs::write(&path, b"").unwrap();
        let ro = File::open(&path).unwrap();
        let out = TileWriter::new(&ro, &path, TileIo::Buffered);

        let jobs = (0..500u64)
            .into_par_iter()
            .map(|j| vec![(j * TILE_BYTES, TileBuf::filled(1.0))]);
        let e = write_tiles(&out, NEVER, jobs).unwrap_err();
        assert_ne!(e.to_string(), "the tile writers stopped", "{e}");
        assert_eq!(e.raw_os_error(), Some(libc::EBADF), "{e}");
        // And through a writable file every tile lands where it was sent.
        let rw = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        let out = TileWriter::new(&rw, &path, TileIo::Direct);
        let jobs = (0..40u64).into_par_iter().map(|j| {
            let mut t = TileBuf::filled(j as f32);
            t[1] = -(j as f32);
            vec![(j * TILE_BYTES, t)]
        });
        write_tiles(&out, NEVER, jobs).unwrap();
        drop(out);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 40 * TILE_PIXELS * 4);
        let v: &[f32] = bytemuck::cast_slice(&bytes);
        for (j, t) in v.chunks_exact(TILE_PIXELS).enumerate() {
            assert_eq!(
                (t[0], t[1], t[TILE_PIXELS - 1]),
                (j as f32, -(j as f32), j as f32)
            );
        }
    }

    /// Tiles are written in runs of neighbours (several jobs' tiles together, in
    /// any order they were sent): every tile lands at its own offset and the
    /// slots nobody wrote stay zero, through the page cache, around it, and in
    /// the adaptive mode.
    #[test]
    fn tiles_written_in_runs_land_at_their_offsets() {
        for mode in [TileIo::Buffered, TileIo::Direct, TileIo::Auto] {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("runs.bin");
            let f = File::create(&path).unwrap();
            let out = TileWriter::new(&f, &path, mode);
            // Job j sends slots 4j+2, 4j, 4j+1 (out of order); 4j+3 is left empty,
            // so runs are at most three tiles long.
            let jobs = (0..60u64).into_par_iter().map(|j| {
                [2, 0, 1]
                    .map(|k| {
                        let slot = 4 * j + k;
                        let mut t = TileBuf::filled(slot as f32 + 0.5);
                        t[7] = -(slot as f32);
                        (slot * TILE_BYTES, t)
                    })
                    .into_iter()
                    .collect::<Vec<_>>()
            });
            write_tiles(&out, NEVER, jobs).unwrap();
            drop(out);
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(bytes.len() as u64, (4 * 59 + 3) * TILE_BYTES, "{mode:?}");
            let v: &[f32] = bytemuck::cast_slice(&bytes);
            for (slot, t) in v.chunks_exact(TILE_PIXELS).enumerate() {
                let want = if slot % 4 == 3 {
                    (0.0, 0.0, 0.0)
                } else {
                    (slot as f32 + 0.5, -(slot as f32), slot as f32 + 0.5)
                };
                assert_eq!(
                    (t[0], t[7], t[TILE_PIXELS - 1]),
                    want,
                    "{mode:?} slot {slot}"
                );
            }
        }
    }

    /// A sink whose write was cancelled refuses what comes after, says so to the
    /// encoder and in the outcome, and what it took before is still written.
    #[test]
    fn a_cancelled_sink_refuses_and_reports_the_interruption() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.bin");
        let f = File::create(&path).unwrap();
        let out = TileWriter::new(&f, &path, TileIo::Buffered);
        let stop = AtomicBool::new(false);
        let cancelled = || stop.load(Ordering::Relaxed);
        let (sent, written) = with_sink(&out, &cancelled, |sink| {
            sink.send(vec![(0, TileBuf::filled(1.0))]).unwrap();
            assert!(!sink.stopped());
            stop.store(true, Ordering::Relaxed);
            assert!(sink.stopped());
            sink.send(vec![(TILE_BYTES, TileBuf::filled(2.0))])
        });
        assert_eq!(sent.unwrap_err().kind(), io::ErrorKind::Interrupted);
        assert_eq!(written.unwrap_err().kind(), io::ErrorKind::Interrupted);
        drop(out);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), TILE_PIXELS * 4);
        assert!(
            bytemuck::cast_slice::<u8, f32>(&bytes)
                .iter()
                .all(|&v| v == 1.0)
        );
    }
}
