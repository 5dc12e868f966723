//! PCD point clouds (PCL's format, versions 0.5–0.7): the header (`header.rs`),
//! the plan of where each field goes, and the reader, which takes its points
//! from `DATA ascii` lines (`ascii.rs`), fixed-stride `binary` records over the
//! memory map (`binary.rs`) or `binary_compressed` columns (`compressed.rs`,
//! streamed through LZF cursors, `lzf.rs`).
//!
//! * Fields: `x y z` (any type, COUNT 1) are the coordinates; `rgb`/`rgba` (four
//!   bytes, TYPE F or U) are unpacked into `red green blue` (0–255); every other
//!   field is a band named by [`super::canonical_names`]. A field with COUNT n
//!   (up to [`MAX_COUNT`]) gives bands `name_0` … `name_{n-1}`; wider ones
//!   (feature histograms) and PCL's `_` padding are skipped, the summary says which.
//! * `VIEWPOINT` is kept in the part's metadata (`VIEWPOINT` item); the points
//!   stay as stored, as PCL's own tools show them.
//! * Points with a NaN (or infinite) coordinate, the empty slots of organized
//!   clouds, are left out and counted ([`PointReader::left_out`]).
//! * A file shorter than its header declares, more data than `POINTS`, `POINTS`
//!   other than `WIDTH × HEIGHT`, compressed sizes that do not add up or an
//!   unknown type are errors naming the file and the header line or byte offset.
//!
//! Why not the `pcd-rs` crate: it yields each point as a vector of per-field
//! vectors (allocations per point), decompresses `binary_compressed` whole, and
//! has no way to leave out NaN slots or report byte offsets; this reader decodes
//! binary records like the PLY reader, at memory speed.

mod ascii;
mod binary;
mod compressed;
mod decode;
pub mod header;
pub mod lzf;

use std::path::Path;
use std::sync::Arc;

use self::decode::{Elem, Out, Role, Val};
use self::header::{Data, Header, Ty};
use super::color::ColorNormalizer;
use super::error::IngestError;
use super::{PointReader, ReadOptions, SourceInfo, canonical_names};
use crate::bigvec;
use crate::points::{Attribute, PointColumns};

/// Widest field (COUNT) read as bands; wider ones are skipped.
pub const MAX_COUNT: usize = 16;

/// Where a reader takes its points from.
enum Source {
    Ascii(ascii::Ascii),
    Binary(binary::Binary),
    Compressed(compressed::Compressed),
}

impl Source {
    /// Fills `out` with the points from `first` on (always the next ones).
    fn fill<A: Val>(
        &mut self,
        first: u64,
        out: Out<'_, A>,
        elems: &[Elem],
        offsets: &[f64],
    ) -> Result<(), IngestError> {
        match self {
            Source::Ascii(s) => s.fill(out, elems, offsets),
            Source::Binary(s) => s.fill(first, out, elems, offsets),
            Source::Compressed(s) => s.fill(out, elems, offsets),
        }
    }

    /// Checks what follows the last point.
    fn finish(&mut self) -> Result<(), IngestError> {
        match self {
            Source::Ascii(s) => s.finish(),
            Source::Binary(s) => s.finish(),
            Source::Compressed(_) => Ok(()),
        }
    }

    /// A copy positioned where `self` is (for the offset sample), once `self`
    /// is ready to read.
    fn ready_copy(&mut self) -> Result<Source, IngestError> {
        Ok(match self {
            Source::Ascii(s) => Source::Ascii(s.clone()),
            Source::Binary(s) => Source::Binary(s.clone()),
            Source::Compressed(s) => Source::Compressed(s.ready_copy()?),
        })
    }

    fn bytes_done(&self, done: u64, points: u64) -> u64 {
        match self {
            Source::Ascii(s) => s.bytes_done(),
            Source::Binary(s) => s.bytes_done(done),
            Source::Compressed(s) => s.bytes_done(done, points),
        }
    }
}

/// The elements of every field, the attribute names and the notes on what is
/// skipped.
struct Plan {
    elems: Vec<Elem>,
    names: Vec<String>,
    notes: Vec<String>,
    /// `Some(float)` when colour comes from separate red/green/blue fields.
    colour_fields: Option<bool>,
}

fn plan(path: &Path, h: &Header) -> Result<Plan, IngestError> {
    let mut elems = Vec::new();
    let mut raw: Vec<String> = Vec::new();
    let mut rgb_at = Vec::new();
    let mut notes = Vec::new();
    let mut off = 0;
    let mut xyz = [false; 3];
    for (f, field) in h.fields.iter().enumerate() {
        let name = field.name.to_ascii_lowercase();
        let size = field.ty.size();
        let mut push = |within: usize, role: Role| {
            elems.push(Elem {
                field: f,
                off: off + within,
                within,
                ty: field.ty,
                role,
            })
        };
        let coord = match name.as_str() {
            "x" => Some(0),
            "y" => Some(1),
            "z" => Some(2),
            _ => None,
        };
        if let Some(c) = coord {
            if field.count != 1 || xyz[c] {
                return Err(IngestError::format(
                    path,
                    format!("field '{name}' must appear once with COUNT 1"),
                ));
            }
            xyz[c] = true;
            push(0, [Role::X, Role::Y, Role::Z][c]);
        } else if (name == "rgb" || name == "rgba") && size == 4 && field.count == 1 {
            rgb_at.push(raw.len());
            push(0, Role::Rgb(raw.len()));
            raw.extend(["red", "green", "blue"].map(String::from));
        } else if name == "_" || name.is_empty() {
            for j in 0..field.count {
                push(j * size, Role::Skip);
            }
        } else if field.count > MAX_COUNT {
            notes.push(format!(
                "field '{}' ({} values a point) skipped: wider than {MAX_COUNT}",
                pcimg_core::text::sanitize(&name),
                field.count
            ));
            for j in 0..field.count {
                push(j * size, Role::Skip);
            }
        } else {
            for j in 0..field.count {
                push(j * size, Role::Attr(raw.len()));
                raw.push(if field.count == 1 {
                    name.clone()
                } else {
                    format!("{name}_{j}")
                });
            }
        }
        off += field.bytes();
    }
    if xyz != [true; 3] {
        return Err(IngestError::format(
            path,
            "the PCD file has no x, y and z fields",
        ));
    }
    let mut names = canonical_names(&raw);
    // Unpacked colour keeps its names whatever canonical_names made of the rest.
    for &a in &rgb_at {
        names[a..a + 3].clone_from_slice(&["red", "green", "blue"].map(String::from));
    }
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(IngestError::format(
                path,
                format!(
                    "two fields give the band '{}'",
                    pcimg_core::text::sanitize(n)
                ),
            ));
        }
    }
    // Colour from separate fields is scaled like any other reader's.
    let colour_fields = elems.iter().find_map(|e| match e.role {
        Role::Attr(a) if super::color::is_color(&names[a]) => Some(e.ty.is_float()),
        _ => None,
    });
    Ok(Plan {
        elems,
        names,
        notes,
        colour_fields,
    })
}

/// Opens a PCD file.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    let map = Arc::new(super::map_file(path)?);
    let header = header::parse(path, &map)?;
    let plan = plan(path, &header)?;
    let source = match header.data {
        Data::Ascii => Source::Ascii(ascii::Ascii::new(path, map.clone(), &header)),
        Data::Binary => Source::Binary(binary::Binary::new(path, map.clone(), &header)?),
        Data::Compressed => {
            Source::Compressed(compressed::Compressed::new(path, map.clone(), &header)?)
        }
    };
    let mut metadata = Vec::new();
    if let Some(v) = header.viewpoint {
        metadata.push((
            crate::points::key::VIEWPOINT.to_string(),
            v.map(|c| c.to_string()).join(" "),
        ));
    }
    let encoding = match header.data {
        Data::Ascii => "ascii",
        Data::Binary => "binary",
        Data::Compressed => "binary_compressed",
    };
    let info = SourceInfo {
        path: path.to_path_buf(),
        format: format!(
            "pcd {} {encoding}",
            pcimg_core::text::sanitize(&header.version)
        ),
        declared_points: Some(header.points),
        declared_bounds: None,
        crs_wkt: None,
        attribute_names: plan.names.clone(),
        file_bytes: map.len() as u64,
        notes: plan.notes.clone(),
        metadata,
        coordinate_step: None,
        coordinate_lattice: None,
    };
    // Offsets only matter for values f32 cannot hold near 65536 and beyond.
    let wide = plan.elems.iter().any(|e| {
        matches!(e.role, Role::Attr(_))
            && matches!(e.ty, Ty::F8 | Ty::I4 | Ty::U4 | Ty::I8 | Ty::U8)
    });
    Ok(Box::new(PcdReader {
        info,
        points: header.points,
        offsets: if wide {
            None
        } else {
            Some(vec![0.0; plan.names.len()])
        },
        plan,
        source,
        done: 0,
        chunk_points: opts.chunk_points.max(1),
        left_out: 0,
        colours: None,
        finished: false,
    }))
}

/// The reader of one PCD file.
struct PcdReader {
    info: SourceInfo,
    points: u64,
    plan: Plan,
    /// Each attribute's offset, chosen from the first points before the first chunk.
    offsets: Option<Vec<f64>>,
    source: Source,
    done: u64,
    chunk_points: usize,
    left_out: u64,
    colours: Option<ColorNormalizer>,
    finished: bool,
}

/// Zeroed columns for `n` points, `attrs` of them besides x y z.
fn columns<A: Val>(n: usize, attrs: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<Vec<A>>) {
    (
        bigvec::zeroed(n),
        bigvec::zeroed(n),
        bigvec::zeroed(n),
        (0..attrs).map(|_| bigvec::zeroed(n)).collect(),
    )
}

impl PcdReader {
    /// The attribute offsets, from the first points (read by a copy of the source).
    fn choose_offsets(&mut self) -> Result<Vec<f64>, IngestError> {
        let n = self.points.min(super::OFFSET_SAMPLE as u64) as usize;
        let (mut x, mut y, mut z, mut attrs) = columns::<f64>(n, self.plan.names.len());
        let out = Out {
            x: &mut x,
            y: &mut y,
            z: &mut z,
            attrs: attrs.iter_mut().map(|a| a.as_mut_slice()).collect(),
        };
        let zero = vec![0.0; self.plan.names.len()];
        self.source
            .ready_copy()?
            .fill(0, out, &self.plan.elems, &zero)?;
        Ok(attrs
            .iter_mut()
            .zip(&self.plan.names)
            .map(|(v, name)| super::attribute_offset(v, name == "gps_time"))
            .collect())
    }
}

impl PointReader for PcdReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        loop {
            if self.done >= self.points {
                if !self.finished {
                    self.finished = true;
                    self.source.finish()?;
                }
                return Ok(None);
            }
            let offsets = match &self.offsets {
                Some(o) => o.clone(),
                None => {
                    let o = self.choose_offsets()?;
                    self.offsets = Some(o.clone());
                    o
                }
            };
            let n = (self.points - self.done).min(self.chunk_points as u64) as usize;
            let (mut x, mut y, mut z, mut attrs) = columns::<f32>(n, self.plan.names.len());
            let out = Out {
                x: &mut x,
                y: &mut y,
                z: &mut z,
                attrs: attrs.iter_mut().map(|a| a.as_mut_slice()).collect(),
            };
            self.source
                .fill(self.done, out, &self.plan.elems, &offsets)?;
            self.done += n as u64;
            let mut cols = PointColumns {
                x,
                y,
                z,
                attributes: attrs
                    .into_iter()
                    .zip(&self.plan.names)
                    .zip(&offsets)
                    .map(|((values, name), &offset)| Attribute {
                        name: name.clone(),
                        offset,
                        values,
                    })
                    .collect(),
            };
            self.left_out += cols.drop_non_finite();
            if cols.is_empty() {
                continue;
            }
            if let Some(float) = self.plan.colour_fields {
                self.colours
                    .get_or_insert_with(|| ColorNormalizer::new(float))
                    .apply(&mut cols);
            }
            return Ok(Some(cols));
        }
    }

    fn bytes_done(&self) -> u64 {
        self.source
            .bytes_done(self.done, self.points)
            .min(self.info.file_bytes)
    }

    fn skipped(&self) -> u64 {
        0
    }

    fn left_out(&self) -> u64 {
        self.left_out
    }

    fn clamped_colours(&self) -> u64 {
        self.colours.as_ref().map_or(0, |c| {
            c.clamped().load(std::sync::atomic::Ordering::Relaxed)
        })
    }
}
