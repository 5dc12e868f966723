//! `DATA binary`: fixed-stride little-endian records after the header, decoded
//! straight from the memory map in parallel (as the binary PLY reader does), the
//! pages behind the reader released as it goes.

use super::decode::{self, Elem, Out, Val};
use super::header::Header;
use crate::error::IngestError;
use memmap2::Mmap;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Clone)]
pub struct Binary {
    path: PathBuf,
    map: Arc<Mmap>,
    start: usize,
    stride: usize,
    points: u64,
    released: usize,
}

impl Binary {
    /// Checks that the file holds the records the header declares.
    pub fn new(path: &Path, map: Arc<Mmap>, h: &Header) -> Result<Binary, IngestError> {
        let stride = h.stride();
        let end = h
            .points
            .checked_mul(stride as u64)
            .and_then(|b| b.checked_add(h.len as u64));
        let len = map.len() as u64;
        match end {
            Some(end) if end <= len => {
                if len - end >= stride as u64 {
                    return Err(IngestError::binary(
                        path,
                        end,
                        format!(
                            "{} bytes follow the {} points the header declares (POINTS, line {}): \
                             the header understates the points",
                            len - end,
                            h.points,
                            h.points_line
                        ),
                    ));
                }
            }
            _ => {
                let whole = len.saturating_sub(h.len as u64) / stride.max(1) as u64;
                return Err(IngestError::binary(
                    path,
                    len,
                    format!(
                        "truncated file: the header declares {} points of {stride} bytes from \
                         byte {}, but the file ends after {whole} whole points",
                        h.points, h.len
                    ),
                ));
            }
        }
        Ok(Binary {
            path: path.to_path_buf(),
            map,
            start: h.len,
            stride,
            points: h.points,
            released: 0,
        })
    }

    pub fn fill<A: Val>(
        &mut self,
        first: u64,
        out: Out<'_, A>,
        elems: &[Elem],
        offsets: &[f64],
    ) -> Result<(), IngestError> {
        let n = out.len();
        let from = self.start + first as usize * self.stride;
        let stride = self.stride;
        let Some(data) = self.map.get(from..from + n * stride) else {
            return Err(IngestError::binary(
                &self.path,
                from as u64,
                "truncated file: point data ends early",
            ));
        };
        decode::split(out, decode::task_points(n))
            .into_par_iter()
            .for_each(|(at, mut out)| {
                let recs = &data[at * stride..(at + out.len()) * stride];
                for e in elems {
                    decode::element(recs, stride, e.off, e, &mut out, offsets);
                }
            });
        crate::release_consumed(&self.map, &mut self.released, from + n * stride);
        Ok(())
    }

    /// Nothing to check: `new` checked the length.
    pub fn finish(&mut self) -> Result<(), IngestError> {
        Ok(())
    }

    pub fn bytes_done(&self, done: u64) -> u64 {
        if done >= self.points {
            self.map.len() as u64
        } else {
            self.start as u64 + done * self.stride as u64
        }
    }
}
