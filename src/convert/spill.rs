//! Temporary per-region files of the spatial partitioning: points appended in input
//! order as fixed-size records (f64 x y z, then f32 attributes), read back whole
//! when the region becomes a part. The directory holding them is removed on drop:
//! on success, on error, and when Ctrl-C unwinds the conversion.

use crate::points::{Attribute, PointColumns};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A temporary directory that is removed with everything in it when dropped.
#[derive(Debug)]
pub struct TempDir {
    pub path: PathBuf,
}

impl TempDir {
    /// Creates `.<stem>.pcimg-tmp-<pid>` beside `near`.
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
        std::fs::create_dir_all(&path)?;
        Ok(TempDir { path })
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

/// Bytes of one record with `attributes` attribute columns.
pub fn record_size(attributes: usize) -> usize {
    24 + 4 * attributes
}

/// Appends points to one region file.
pub struct SpillWriter {
    pub path: PathBuf,
    out: BufWriter<File>,
    pub points: u64,
}

impl SpillWriter {
    pub fn create(path: PathBuf, buffer: usize) -> std::io::Result<SpillWriter> {
        let f = File::create(&path)?;
        Ok(SpillWriter {
            path,
            out: BufWriter::with_capacity(buffer.max(4096), f),
            points: 0,
        })
    }

    /// Appends point `i` of `c`.
    #[inline]
    pub fn push(&mut self, c: &PointColumns, i: usize) -> std::io::Result<()> {
        let mut rec = [0u8; 24 + 4 * 64];
        rec[0..8].copy_from_slice(&c.x[i].to_le_bytes());
        rec[8..16].copy_from_slice(&c.y[i].to_le_bytes());
        rec[16..24].copy_from_slice(&c.z[i].to_le_bytes());
        let mut at = 24;
        for a in &c.attributes {
            rec[at..at + 4].copy_from_slice(&a.values[i].to_le_bytes());
            at += 4;
        }
        self.points += 1;
        self.out.write_all(&rec[..at])
    }

    pub fn finish(mut self) -> std::io::Result<(PathBuf, u64)> {
        self.out.flush()?;
        Ok((self.path, self.points))
    }
}

/// Most attribute columns a spill record carries.
pub const MAX_ATTRIBUTES: usize = 64;

/// Reads a region file back into columns, with the attribute names and offsets of
/// `like`.
pub fn read_back(path: &Path, like: &PointColumns) -> std::io::Result<PointColumns> {
    let na = like.attributes.len();
    let rs = record_size(na);
    let bytes = std::fs::read(path)?;
    if bytes.len() % rs != 0 {
        return Err(std::io::Error::other(format!(
            "temporary file {} has a partial record",
            path.display()
        )));
    }
    let n = bytes.len() / rs;
    let f64_at = |r: &[u8], o: usize| {
        f64::from_le_bytes([
            r[o],
            r[o + 1],
            r[o + 2],
            r[o + 3],
            r[o + 4],
            r[o + 5],
            r[o + 6],
            r[o + 7],
        ])
    };
    let recs = || bytes.par_chunks_exact(rs);
    let x = recs().map(|r| f64_at(r, 0)).collect();
    let y = recs().map(|r| f64_at(r, 8)).collect();
    let z = recs().map(|r| f64_at(r, 16)).collect();
    let attributes = like
        .attributes
        .iter()
        .enumerate()
        .map(|(k, a)| Attribute {
            name: a.name.clone(),
            offset: a.offset,
            values: recs()
                .map(|r| {
                    let o = 24 + 4 * k;
                    f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]])
                })
                .collect(),
        })
        .collect();
    let c = PointColumns {
        x,
        y,
        z,
        attributes,
    };
    debug_assert_eq!(c.len(), n);
    Ok(c)
}
