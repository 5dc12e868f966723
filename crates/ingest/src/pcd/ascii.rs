//! `DATA ascii`: one point a line, the values of every field's elements in
//! order, separated by spaces; errors name the line. Packed colour is written
//! as the float whose bits hold it (TYPE F) or as the integer (TYPE U).

use super::decode::{Elem, Out, Role, Val, unpack};
use super::header::{Header, Ty};
use crate::error::IngestError;
use memmap2::Mmap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Clone)]
pub struct Ascii {
    path: PathBuf,
    map: Arc<Mmap>,
    /// Byte offset of the next line.
    pos: usize,
    /// Number of the line before it (1-based).
    line: u64,
    points: u64,
    done: u64,
    points_line: u64,
}

impl Ascii {
    pub fn new(path: &Path, map: Arc<Mmap>, h: &Header) -> Ascii {
        Ascii {
            path: path.to_path_buf(),
            map,
            pos: h.len,
            line: h.data_line,
            points: h.points,
            done: 0,
            points_line: h.points_line,
        }
    }

    /// The next line that is not blank, with its number.
    fn next_line(&mut self) -> Option<(u64, &[u8])> {
        let map: &[u8] = &self.map;
        while self.pos < map.len() {
            let end = memchr::memchr(b'\n', &map[self.pos..]).map_or(map.len(), |i| self.pos + i);
            let text = &map[self.pos..end];
            self.pos = (end + 1).min(map.len());
            self.line += 1;
            if !text.trim_ascii().is_empty() {
                return Some((self.line, text));
            }
        }
        None
    }

    pub fn fill<A: Val>(
        &mut self,
        mut out: Out<'_, A>,
        elems: &[Elem],
        offsets: &[f64],
    ) -> Result<(), IngestError> {
        let path = self.path.clone();
        let (points, points_line) = (self.points, self.points_line);
        for i in 0..out.len() {
            let done = self.done;
            let Some((line, text)) = self.next_line() else {
                return Err(IngestError::line(
                    &path,
                    self.line + 1,
                    format!(
                        "the data ends after {done} points; the header declares {points} \
                         (POINTS, line {points_line})"
                    ),
                    b"",
                ));
            };
            let mut words = text
                .split(|b| b.is_ascii_whitespace())
                .filter(|w| !w.is_empty());
            for e in elems {
                let Some(w) = words.next() else {
                    return Err(IngestError::line(
                        &path,
                        line,
                        format!("expected {} values", elems.len()),
                        text,
                    ));
                };
                let bad = || IngestError::line(&path, line, "not a number", text);
                if let Role::Rgb(a) = e.role {
                    let bits = if e.ty == Ty::F4 {
                        fast_float2::parse::<f32, _>(w)
                            .map_err(|_| bad())?
                            .to_bits()
                    } else {
                        let v: f64 = fast_float2::parse(w).map_err(|_| bad())?;
                        v as i64 as u32
                    };
                    for (k, v) in unpack(bits).into_iter().enumerate() {
                        if let Some(col) = out.attrs.get_mut(a + k) {
                            col[i] = A::from_f64(v);
                        }
                    }
                    continue;
                }
                // A `F 4` value is the float32 nearest the text, as PCL reads it.
                let v: f64 = if e.ty == Ty::F4 {
                    fast_float2::parse::<f32, _>(w).map_err(|_| bad())? as f64
                } else {
                    fast_float2::parse(w).map_err(|_| bad())?
                };
                match e.role {
                    Role::X => out.x[i] = v,
                    Role::Y => out.y[i] = v,
                    Role::Z => out.z[i] = v,
                    Role::Attr(a) => {
                        let off = offsets.get(a).copied().unwrap_or(0.0);
                        if let Some(col) = out.attrs.get_mut(a) {
                            col[i] = A::from_f64(v - off);
                        }
                    }
                    Role::Rgb(_) | Role::Skip => {}
                }
            }
            if words.next().is_some() {
                return Err(IngestError::line(
                    &path,
                    line,
                    format!("more than the {} values of the FIELDS", elems.len()),
                    text,
                ));
            }
            self.done += 1;
        }
        Ok(())
    }

    /// Checks that no points follow the declared ones.
    pub fn finish(&mut self) -> Result<(), IngestError> {
        let (points, points_line) = (self.points, self.points_line);
        let path = self.path.clone();
        if let Some((line, text)) = self.next_line() {
            return Err(IngestError::line(
                &path,
                line,
                format!(
                    "more points than the {points} the header declares (POINTS, line {points_line})"
                ),
                text,
            ));
        }
        Ok(())
    }

    pub fn bytes_done(&self) -> u64 {
        self.pos as u64
    }
}
