//! Temporary per-region files of the spatial partitioning: points appended in input
//! order as fixed-size records (x y z as f32 relative to the region's origin, then
//! the f32 attributes: the values the part will store, so 16 bytes a point with
//! one attribute), read back a block at a time when the region becomes a part.
//! The directory holding them is removed on drop:
//! on success, on error, and when Ctrl-C unwinds the conversion; a killed
//! conversion's, by the next run ([`sweep`]).

use crate::points::{Attribute, Bounds, PointColumns};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A temporary directory that is removed with everything in it when dropped.
#[derive(Debug)]
pub struct TempDir {
    pub path: PathBuf,
    /// The lock on [`LOCK_FILE`] inside, where the directory has one: while it
    /// is held the directory is in use (see [`stale`]).
    lock: Option<crate::disk::Lock>,
}

/// The lock file inside a temporary directory that other processes may find
/// (a cluster shard's, an upload's): held while the directory is in use.
pub const LOCK_FILE: &str = ".pcimg-lock";

impl TempDir {
    /// Creates `.<name>.<tag>-<pid>` beside `near` (the process id tells a
    /// later run whether the directory is a killed run's: see [`stale`]).
    pub fn beside(near: &Path, tag: &str) -> std::io::Result<TempDir> {
        let parent = near
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let name = near
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let path = parent.join(format!(".{name}.{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&path).map_err(|e| named(&path, e))?;
        Ok(TempDir { path, lock: None })
    }

    /// Creates the directory `path` with a held lock inside ([`LOCK_FILE`]):
    /// a run on another machine sharing the disk, which cannot ask whether
    /// this process lives, sees it in use until this process ends.
    pub fn locked(path: PathBuf) -> std::io::Result<TempDir> {
        std::fs::create_dir_all(&path).map_err(|e| named(&path, e))?;
        let mut dir = TempDir { path, lock: None };
        let lock = crate::disk::Lock::try_take(&dir.path.join(LOCK_FILE), false)
            .map_err(|e| named(&dir.path, e))?
            .map_err(|_| std::io::Error::other(format!("{}: in use", dir.path.display())))?;
        dir.lock = Some(lock);
        Ok(dir)
    }

    /// A directory made elsewhere, removed when dropped.
    pub fn adopt(path: PathBuf) -> TempDir {
        TempDir { path, lock: None }
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
        drop(self.lock.take());
    }
}

/// Whether the temporary directory or file at `path`, named with a process id
/// after `tag`, was left by a run that ended: its lock file (if it has one) is
/// held by no one, or else the process its name carries is gone.
pub fn stale(path: &Path, tag: &str) -> bool {
    let lock = path.join(LOCK_FILE);
    if lock.exists() {
        return !crate::disk::is_locked(&lock);
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    crate::disk::pid_after(&name, tag).is_some_and(|pid| !crate::disk::pid_alive(pid))
}

/// Removes the entries of `dir` whose names start with `prefix`, end with
/// `suffix` and carry a process id after `tag`, where [`stale`]: a killed
/// run's temporary files and directories. Returns what it removed.
pub fn sweep(dir: &Path, prefix: &str, tag: &str, suffix: &str) -> Vec<PathBuf> {
    let mut gone = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return gone;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if !name.starts_with(prefix)
            || !name.ends_with(suffix)
            || !name[prefix.len()..].contains(tag)
        {
            continue;
        }
        let path = e.path();
        if !stale(&path, tag) {
            continue;
        }
        let r = if e.file_type().is_ok_and(|t| t.is_dir()) {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if r.is_ok() {
            gone.push(path);
        }
    }
    gone
}

/// Bytes of one record with `attributes` attribute columns.
pub fn record_size(attributes: usize) -> usize {
    crate::store::packed_size(attributes)
}

/// An I/O error on a temporary file, naming it (the disk that fills up is the
/// one beside the output, which the user may not expect to need room).
fn named(path: &Path, e: std::io::Error) -> std::io::Error {
    named_needing(path, e, None)
}

/// As [`named`], where the room the temporary files need is known.
fn named_needing(path: &Path, e: std::io::Error, needed: Option<u64>) -> std::io::Error {
    let e = crate::disk::with_full_note(e, path, needed);
    std::io::Error::new(e.kind(), format!("temporary file {}: {e}", path.display()))
}

/// Appends points to one region file.
pub struct SpillWriter {
    pub path: PathBuf,
    out: BufWriter<File>,
    pub points: u64,
    /// Points the conversion spills in all (every region's file): with the
    /// record size, the room its temporary files need, said when the disk
    /// fills up.
    all_points: u64,
    /// That room, once a record's size is known.
    needed: Option<u64>,
}

impl SpillWriter {
    /// A region's file; `all_points`: the points of every region's file.
    pub fn create(path: PathBuf, buffer: usize, all_points: u64) -> std::io::Result<SpillWriter> {
        let f = File::create(&path).map_err(|e| named(&path, e))?;
        Ok(SpillWriter {
            path,
            out: BufWriter::with_capacity(buffer.max(4096), f),
            points: 0,
            all_points,
            needed: None,
        })
    }

    /// Appends `count` records already encoded (see [`records_by_region`]).
    pub fn push_records(&mut self, records: &[u8], count: u64) -> std::io::Result<()> {
        self.points += count;
        if let Some(record) = (records.len() as u64).checked_div(count) {
            self.needed = Some(record * self.all_points);
        }
        self.out
            .write_all(records)
            .map_err(|e| named_needing(&self.path, e, self.needed))
    }

    pub fn finish(mut self) -> std::io::Result<(PathBuf, u64)> {
        self.out
            .flush()
            .map_err(|e| named_needing(&self.path, e, self.needed))?;
        Ok((self.path, self.points))
    }
}

/// The records of `c`'s points grouped by region (`region[i]` < `origins.len()`),
/// in input order within each region, coordinates relative to the region's
/// origin, encoded in parallel (a counting sort); where each region's records
/// start (in records; `regions + 1` entries); and the bounds of each region's
/// points in `c`.
pub fn records_by_region(
    c: &PointColumns,
    region: &[u32],
    origins: &[[f64; 3]],
) -> (Vec<u8>, Vec<usize>, Vec<Bounds>) {
    let regions = origins.len();
    let n = c.len();
    let rs = record_size(c.attributes.len());
    let piece = n.div_ceil(rayon::current_num_threads() * 4).max(1 << 14);
    // Per piece and region: where the piece's first record goes.
    let (mut starts, bounds) = crate::bigvec::scatter_plan(region, piece, regions, |&r| r as usize);
    let mut out: Vec<u8> = crate::bigvec::with_capacity(n * rs);
    let dst = crate::bigvec::Shared(out.as_mut_ptr());
    let boxes = region
        .par_chunks(piece)
        .zip(starts.par_iter_mut())
        .enumerate()
        .map(|(p, (ids, fill))| {
            let mut boxes = vec![Bounds::EMPTY; regions];
            for (j, &r) in ids.iter().enumerate() {
                let i = p * piece + j;
                let slot = fill[r as usize];
                fill[r as usize] += 1;
                boxes[r as usize].extend([c.x[i], c.y[i], c.z[i]]);
                // SAFETY: piece p owns record slots starts[p][r].. of region r,
                // counted by its own histogram, so no two pieces write the same
                // bytes, and the n slots lie inside `out`'s capacity.
                let rec = unsafe { std::slice::from_raw_parts_mut(dst.at(slot * rs), rs) };
                let o = origins[r as usize];
                rec[0..4].copy_from_slice(&((c.x[i] - o[0]) as f32).to_le_bytes());
                rec[4..8].copy_from_slice(&((c.y[i] - o[1]) as f32).to_le_bytes());
                rec[8..12].copy_from_slice(&((c.z[i] - o[2]) as f32).to_le_bytes());
                for (k, a) in c.attributes.iter().enumerate() {
                    rec[12 + 4 * k..16 + 4 * k].copy_from_slice(&a.values[i].to_le_bytes());
                }
            }
            boxes
        })
        .reduce(
            || vec![Bounds::EMPTY; regions],
            |a, b| a.iter().zip(&b).map(|(a, b)| a.union(b)).collect(),
        );
    // SAFETY: every one of the n records was written above.
    unsafe { out.set_len(n * rs) };
    (out, bounds, boxes)
}

/// Reads a region file back a block of records at a time.
pub struct SpillReader {
    path: PathBuf,
    file: File,
    rs: usize,
    buf: Vec<u8>,
}

impl SpillReader {
    pub fn open(path: &Path, attributes: usize) -> std::io::Result<SpillReader> {
        Ok(SpillReader {
            path: path.to_path_buf(),
            file: File::open(path).map_err(|e| named(path, e))?,
            rs: record_size(attributes),
            buf: Vec::new(),
        })
    }

    /// The next block of at most `max` whole records (`None` at the end), as
    /// written: the packed records of [`crate::store::PartBuilder::push_packed`].
    pub fn next_records(&mut self, max: usize) -> std::io::Result<Option<&[u8]>> {
        use std::io::Read;
        let want = max.min(BLOCK_BYTES / self.rs).max(1) * self.rs;
        self.buf.resize(want, 0);
        let mut got = 0;
        while got < want {
            match self.file.read(&mut self.buf[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(named(&self.path, e)),
            }
        }
        if got % self.rs != 0 {
            return Err(std::io::Error::other(format!(
                "temporary file {} has a partial record",
                self.path.display()
            )));
        }
        Ok((got > 0).then(|| &self.buf[..got]))
    }

    /// The next block of at most `max` points (`None` at the end), coordinates
    /// made absolute again from the region's `origin` (exactly: the store, given
    /// the same origin, recovers the `f32` values the file holds), with the
    /// attribute names and offsets of `like`.
    pub fn next_block(
        &mut self,
        like: &PointColumns,
        max: usize,
        origin: [f64; 3],
    ) -> std::io::Result<Option<PointColumns>> {
        let rs = self.rs;
        Ok(self
            .next_records(max)?
            .map(|bytes| decode(bytes, rs, like, origin)))
    }
}

/// Bytes of records a [`SpillReader`] block holds at most (cache-sized, so the
/// columns decoded from them are still in cache when the caller uses them).
const BLOCK_BYTES: usize = 4 << 20;

/// Decodes whole records into columns named and offset like `like`'s.
fn decode(bytes: &[u8], rs: usize, like: &PointColumns, origin: [f64; 3]) -> PointColumns {
    let f32_at = |r: &[u8], o: usize| f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
    let recs = || bytes.par_chunks_exact(rs).with_min_len(1 << 13);
    let axis = |a: usize| -> Vec<f64> {
        recs()
            .map(|r| origin[a] + f64::from(f32_at(r, 4 * a)))
            .collect()
    };
    PointColumns {
        x: axis(0),
        y: axis(1),
        z: axis(2),
        attributes: like
            .attributes
            .iter()
            .enumerate()
            .map(|(k, a)| Attribute {
                name: a.name.clone(),
                offset: a.offset,
                values: recs().map(|r| f32_at(r, 12 + 4 * k)).collect(),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records grouped by region hold each region's points in input order, and a
    /// region file written from them reads back as those points, each within
    /// f32's rounding of its offset from the region's origin, and exactly the
    /// f32 offsets written.
    #[test]
    fn records_by_region_group_in_input_order() {
        let c = crate::synth::scene(70_001, 3);
        let regions = 5;
        let ids: Vec<u32> = (0..c.len())
            .map(|i| ((i * 7 + i / 1000) % regions) as u32)
            .collect();
        let origins: Vec<[f64; 3]> = (0..regions)
            .map(|r| [100.0 * r as f64, -50.0, 7.25])
            .collect();
        let (recs, starts, boxes) = records_by_region(&c, &ids, &origins);
        let rs = record_size(c.attributes.len());
        assert_eq!(recs.len(), c.len() * rs);
        assert_eq!((starts[0], starts[regions]), (0, c.len()));
        let dir = tempfile::tempdir().unwrap();
        for r in 0..regions {
            let mut w = SpillWriter::create(dir.path().join(format!("{r}")), 4096, 0).unwrap();
            let (a, b) = (starts[r], starts[r + 1]);
            w.push_records(&recs[a * rs..b * rs], (b - a) as u64)
                .unwrap();
            let (path, n) = w.finish().unwrap();
            // Read back in blocks of at most 1000 points.
            let mut blocks = SpillReader::open(&path, c.attributes.len()).unwrap();
            let mut back = c.empty_like();
            while let Some(b) = blocks.next_block(&c, 1000, origins[r]).unwrap() {
                assert!(!b.is_empty() && b.len() <= 1000);
                back.append_range(&b, 0, b.len());
            }
            let mine: Vec<usize> = (0..c.len()).filter(|&i| ids[i] as usize == r).collect();
            assert_eq!(n as usize, mine.len());
            let mut b = Bounds::EMPTY;
            for &i in &mine {
                b.extend([c.x[i], c.y[i], c.z[i]]);
            }
            assert_eq!(boxes[r], b);
            let o = origins[r];
            for (j, &i) in mine.iter().enumerate() {
                let got = [back.x[j], back.y[j], back.z[j]];
                let want = [c.x[i], c.y[i], c.z[i]];
                for a in 0..3 {
                    // The f32 offset comes back exactly; the point within its rounding.
                    assert_eq!((got[a] - o[a]) as f32, (want[a] - o[a]) as f32);
                    let ulp = ((want[a] - o[a]).abs() as f32 * f32::EPSILON) as f64;
                    assert!((got[a] - want[a]).abs() <= ulp, "{got:?} {want:?}");
                }
                for (ba, ca) in back.attributes.iter().zip(&c.attributes) {
                    assert_eq!(ba.values[j].to_bits(), ca.values[i].to_bits());
                }
            }
        }
    }

    /// What a sweep removes: a killed run's directory (its process gone, or
    /// its lock free), never one in use (a live process's, or one whose lock
    /// is held), nor names that do not match.
    #[test]
    fn a_sweep_removes_only_what_dead_runs_left() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // A process that has ended: its id is free.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let me = std::process::id();
        for n in [
            format!(".a.pcimg-out-{dead}"),
            format!(".a.pcimg-out-{me}"),
            format!(".b.pcimg-out-{dead}"),
            ".a.pcimg-out-x".to_string(),
        ] {
            std::fs::create_dir(d.join(n)).unwrap();
        }
        // Locked: in use whatever its name says; its lock free: left.
        let held = TempDir::locked(d.join(format!(".a.pcimg-out-{dead}-held"))).unwrap();
        let free = d.join(format!(".a.pcimg-out-{me}-free"));
        std::fs::create_dir(&free).unwrap();
        std::fs::write(free.join(LOCK_FILE), "1\n").unwrap();
        let mut gone = sweep(d, ".a.", "pcimg-out-", "");
        gone.sort();
        let mut want = vec![d.join(format!(".a.pcimg-out-{dead}")), free.clone()];
        want.sort();
        assert_eq!(gone, want);
        assert!(held.path.exists() && d.join(format!(".a.pcimg-out-{me}")).exists());
        assert!(d.join(format!(".b.pcimg-out-{dead}")).exists());
        let held_path = held.path.clone();
        drop(held);
        assert!(!held_path.exists());
    }

    /// Failures on temporary files name the file.
    #[test]
    fn errors_name_the_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-dir").join("region-00001.bin");
        let e = SpillWriter::create(missing.clone(), 4096, 0).err().unwrap();
        assert!(e.to_string().contains("temporary file"), "{e}");
        assert!(e.to_string().contains("region-00001.bin"), "{e}");
        let e = SpillReader::open(&missing, 1).err().unwrap();
        assert!(e.to_string().contains("region-00001.bin"), "{e}");
    }
}
