//! `DATA binary_compressed`: after the header, the compressed and uncompressed
//! sizes (u32 each), then one LZF stream of the fields stored column by column
//! (every point's values of the first field, then the second...). The stream is
//! walked once before the first points are read, which checks that its sizes add
//! up and leaves an LZF cursor at the start of each field's column; each chunk is
//! then decoded column by column in parallel, a few KiB of state each, so the
//! whole cloud is never in memory.

use super::decode::{self, Elem, Out, Val};
use super::header::Header;
use super::lzf::{Cursor, LzfError};
use crate::error::IngestError;
use memmap2::Mmap;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Clone)]
pub struct Compressed {
    path: PathBuf,
    map: Arc<Mmap>,
    /// Byte offset of the LZF stream.
    start: usize,
    compressed: usize,
    points: u64,
    /// Bytes of one point's values of each field.
    field_bytes: Vec<usize>,
    /// One cursor per field, at the next point's values; empty until the stream
    /// was walked.
    cursors: Vec<Cursor>,
    /// Per field, the map's pages released so far (below each cursor's input):
    /// the columns are read at once from as many places in the file, whose
    /// pages would otherwise all stay resident.
    released: Vec<usize>,
}

impl Compressed {
    /// Checks the two sizes against the header and the file.
    pub fn new(path: &Path, map: Arc<Mmap>, h: &Header) -> Result<Compressed, IngestError> {
        let at = h.len;
        let word = |o: usize| -> Result<u32, IngestError> {
            map.get(o..o + 4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .ok_or_else(|| {
                    IngestError::binary(
                        path,
                        map.len() as u64,
                        "truncated file: the compressed and uncompressed sizes are missing",
                    )
                })
        };
        let compressed = word(at)? as usize;
        let uncompressed = word(at + 4)? as u64;
        let expected = h.points.checked_mul(h.stride() as u64);
        if expected != Some(uncompressed) {
            return Err(IngestError::binary(
                path,
                at as u64 + 4,
                format!(
                    "the uncompressed size {uncompressed} differs from the {} points × {} bytes \
                     the header declares (POINTS, line {})",
                    h.points,
                    h.stride(),
                    h.points_line
                ),
            ));
        }
        let start = at + 8;
        if start + compressed > map.len() {
            return Err(IngestError::binary(
                path,
                map.len() as u64,
                format!(
                    "truncated file: the compressed size {compressed} (at byte {at}) runs past \
                     the end of the file"
                ),
            ));
        }
        Ok(Compressed {
            path: path.to_path_buf(),
            map,
            start,
            compressed,
            points: h.points,
            field_bytes: h.fields.iter().map(|f| f.bytes()).collect(),
            cursors: Vec::new(),
            released: Vec::new(),
        })
    }

    fn stream(&self) -> &[u8] {
        &self.map[self.start..self.start + self.compressed]
    }

    fn error(&self, e: LzfError) -> IngestError {
        IngestError::binary(
            &self.path,
            (self.start + e.at) as u64,
            format!("binary_compressed data: {}", e.msg),
        )
    }

    /// Walks the stream once: a cursor at the start of each column; checks the
    /// stream ends exactly after the declared uncompressed size.
    fn walk(&mut self) -> Result<(), IngestError> {
        if !self.cursors.is_empty() || self.field_bytes.is_empty() {
            return Ok(());
        }
        let src = self.stream();
        let mut c = Cursor::default();
        let mut scratch = vec![0u8; 1 << 20];
        let mut cursors = Vec::with_capacity(self.field_bytes.len());
        let mut walked = self.start;
        for &b in &self.field_bytes {
            cursors.push(c.clone());
            let mut left = self.points * b as u64;
            while left > 0 {
                let k = left.min(scratch.len() as u64) as usize;
                c.read(src, &mut scratch[..k]).map_err(|e| self.error(e))?;
                left -= k as u64;
                crate::release_consumed(&self.map, &mut walked, self.start + c.input_offset());
            }
        }
        if !c.at_end(src) {
            return Err(IngestError::binary(
                &self.path,
                (self.start + c.input_offset()) as u64,
                format!(
                    "binary_compressed data: the stream goes on after the declared uncompressed \
                     size ({} of {} compressed bytes used)",
                    c.input_offset(),
                    self.compressed
                ),
            ));
        }
        self.released = cursors
            .iter()
            .map(|c| self.start + c.input_offset())
            .collect();
        self.cursors = cursors;
        Ok(())
    }

    /// A copy at the same point, the stream walked.
    pub(crate) fn ready_copy(&mut self) -> Result<Compressed, IngestError> {
        self.walk()?;
        Ok(self.clone())
    }

    pub fn fill<A: Val>(
        &mut self,
        out: Out<'_, A>,
        elems: &[Elem],
        offsets: &[f64],
    ) -> Result<(), IngestError> {
        self.walk()?;
        let n = out.len();
        let src = &self.map[self.start..self.start + self.compressed];
        let mut bufs: Vec<Vec<u8>> = self.field_bytes.iter().map(|b| vec![0; n * b]).collect();
        self.cursors
            .par_iter_mut()
            .zip(bufs.par_iter_mut())
            .map(|(c, buf)| c.read(src, buf))
            .collect::<Result<Vec<()>, LzfError>>()
            .map_err(|e| {
                IngestError::binary(
                    &self.path,
                    (self.start + e.at) as u64,
                    format!("binary_compressed data: {}", e.msg),
                )
            })?;
        for (c, r) in self.cursors.iter().zip(&mut self.released) {
            crate::release_consumed(&self.map, r, self.start + c.input_offset());
        }
        let field_bytes = &self.field_bytes;
        decode::split(out, decode::task_points(n))
            .into_par_iter()
            .for_each(|(at, mut out)| {
                for e in elems {
                    let b = field_bytes[e.field];
                    let recs = &bufs[e.field][at * b..(at + out.len()) * b];
                    decode::element(recs, b, e.within, e, &mut out, offsets);
                }
            });
        Ok(())
    }

    pub fn bytes_done(&self, done: u64, points: u64) -> u64 {
        let part = self.compressed as u64 * done / points.max(1);
        self.start as u64 + part
    }
}
