//! PLY point clouds: the header parser, the plan of where each vertex property
//! goes, and `open`, which hands the vertices to the ASCII reader (`ascii.rs`) or
//! the fixed-stride binary reader, little- and big-endian (`binary.rs`).
//!
//! * The `vertex` element (or, failing that, a `point` element) gives the points:
//!   it must have scalar `x`, `y`, `z` properties of any type; every other scalar
//!   property becomes an attribute named by [`super::canonical_names`] (so `red`,
//!   `diffuse_red` → `red`, `scalar_intensity` → `intensity`, others lower-cased).
//! * Other elements (faces, edges...) are skipped: in binary files those before
//!   the vertex element are skipped by size (item by item when they have list
//!   properties); those after it are only checked to be whole. In ASCII files the lines of the
//!   elements before the vertex element are skipped and only the vertex lines are
//!   parsed, with the parallel line engine (`ingest::lines`) that the text reader uses.
//! * Binary vertices are read by a fixed-stride decoder over the memory map with a
//!   precomputed byte offset per property, byte-swapped for big-endian, in
//!   parallel over each window with rayon.
//! * A file shorter than its header declares is an error naming the byte offset
//!   (binary) or the line (ASCII), also when it ends inside the elements after the
//!   vertices (checked once the vertices are read: binary items walked, list
//!   lengths included; ASCII lines counted, and the last one's values, list
//!   lengths included, so a file cut inside its last line is caught too).

mod ascii;
mod binary;

use std::path::Path;

use super::color::is_color;
use super::error::IngestError;
use super::lines::{Layout, Role};
use super::{PointReader, ReadOptions, SourceInfo, canonical_names};

/// A PLY scalar type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    pub fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    pub(crate) fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decodes the value at the start of `b` (which must hold `size()` bytes;
    /// shorter input reads as 0).
    #[inline(always)]
    fn decode<const BE: bool>(self, b: &[u8]) -> f64 {
        macro_rules! rd {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = match b.get(..$n) {
                    Some(s) => s.try_into().unwrap_or([0; $n]),
                    None => [0; $n],
                };
                if BE {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Scalar::I8 => b.first().map_or(0.0, |&v| v as i8 as f64),
            Scalar::U8 => b.first().map_or(0.0, |&v| v as f64),
            Scalar::I16 => rd!(i16, 2),
            Scalar::U16 => rd!(u16, 2),
            Scalar::I32 => rd!(i32, 4),
            Scalar::U32 => rd!(u32, 4),
            Scalar::F32 => rd!(f32, 4),
            Scalar::F64 => rd!(f64, 8),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Property {
    pub name: String,
    pub kind: PropKind,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Element {
    pub name: String,
    pub count: u64,
    pub props: Vec<Property>,
}

impl Element {
    /// The record size when every property is scalar.
    fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                PropKind::Scalar(s) => Some(s.size()),
                PropKind::List { .. } => None,
            })
            .sum()
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub encoding: Encoding,
    pub elements: Vec<Element>,
    /// Bytes up to and including the `end_header` line.
    pub len: usize,
    /// Lines in the header.
    pub lines: u64,
}

/// Longest header accepted.
const MAX_HEADER: usize = 16 << 20;

/// Parses a PLY header at the start of `data`.
pub(crate) fn parse_header(path: &Path, data: &[u8]) -> Result<Header, IngestError> {
    let mut pos = 0usize;
    let mut line_no = 0u64;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let limit = data.len().min(MAX_HEADER);
    loop {
        if pos >= limit {
            return Err(IngestError::format(
                path,
                format!(
                    "PLY header has no 'end_header' line within the first {} bytes",
                    limit
                ),
            ));
        }
        let end = memchr::memchr(b'\n', &data[pos..limit]).map_or(limit, |k| pos + k);
        let raw = &data[pos..end];
        line_no += 1;
        pos = (end + 1).min(data.len());
        let line = String::from_utf8_lossy(raw);
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        let bad = |msg: &str| IngestError::line(path, line_no, msg.to_string(), raw);
        if line_no == 1 {
            if words.first() != Some(&"ply") {
                return Err(bad("not a PLY file (first line must be 'ply')"));
            }
            continue;
        }
        match words.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                encoding = Some(match words.get(1).copied() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::BinaryLe,
                    Some("binary_big_endian") => Encoding::BinaryBe,
                    _ => return Err(bad("unknown PLY format")),
                });
            }
            Some("element") => {
                let (Some(name), Some(count)) = (words.get(1), words.get(2)) else {
                    return Err(bad("element line needs a name and a count"));
                };
                let count: u64 = count
                    .parse()
                    .map_err(|_| bad("element count is not a non-negative integer"))?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(bad("property before any element"));
                };
                let prop = if words.get(1) == Some(&"list") {
                    let (Some(c), Some(i), Some(n)) = (
                        words.get(2).and_then(|s| Scalar::parse(s)),
                        words.get(3).and_then(|s| Scalar::parse(s)),
                        words.get(4),
                    ) else {
                        return Err(bad("bad list property"));
                    };
                    if c.is_float() {
                        return Err(bad("list count type must be an integer type"));
                    }
                    Property {
                        name: n.to_string(),
                        kind: PropKind::List { count: c, item: i },
                    }
                } else {
                    let (Some(t), Some(n)) =
                        (words.get(1).and_then(|s| Scalar::parse(s)), words.get(2))
                    else {
                        return Err(bad("bad property (unknown type or missing name)"));
                    };
                    Property {
                        name: n.to_string(),
                        kind: PropKind::Scalar(t),
                    }
                };
                el.props.push(prop);
            }
            Some("end_header") => break,
            Some(_) => return Err(bad("unexpected line in PLY header")),
        }
    }
    let Some(encoding) = encoding else {
        return Err(IngestError::format(path, "PLY header has no 'format' line"));
    };
    Ok(Header {
        encoding,
        elements,
        len: pos,
        lines: line_no,
    })
}

/// Where each vertex property goes.
#[derive(Debug, Clone)]
struct VertexPlan {
    element: usize,
    layout: Layout,
    /// Per property: byte offset in the record, type, destination.
    fields: Vec<(usize, Scalar, Role)>,
    stride: usize,
    float_color: bool,
    /// Every colour property is `uchar`: already 0–255, nothing to normalize.
    u8_color: bool,
}

fn plan_vertex(path: &Path, h: &Header) -> Result<VertexPlan, IngestError> {
    let element = h
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .or_else(|| h.elements.iter().position(|e| e.name == "point"))
        .ok_or_else(|| IngestError::format(path, "PLY file has no 'vertex' element"))?;
    let el = &h.elements[element];
    let mut names = Vec::new();
    let mut fields = Vec::new();
    let mut off = 0usize;
    let mut float_color = false;
    let mut u8_color = true;
    let canonical = canonical_names(&el.props.iter().map(|p| &p.name).collect::<Vec<_>>());
    for (p, canonical) in el.props.iter().zip(canonical) {
        let PropKind::Scalar(s) = p.kind else {
            return Err(IngestError::format(
                path,
                format!(
                    "list property '{}' in the vertex element is not supported",
                    pcimg_core::text::sanitize(&p.name)
                ),
            ));
        };
        let mut name = canonical;
        if names.contains(&name) {
            name = p.name.to_ascii_lowercase();
        }
        if is_color(&name) {
            float_color |= s.is_float();
            u8_color &= s == Scalar::U8;
        }
        names.push(name);
        fields.push((off, s, Role::Skip));
        off += s.size();
    }
    let layout = Layout::from_names(&names)
        .map_err(|m| IngestError::format(path, format!("PLY vertex element: {m}")))?;
    for (f, r) in fields.iter_mut().zip(&layout.roles) {
        f.2 = *r;
    }
    Ok(VertexPlan {
        element,
        layout,
        fields,
        stride: off,
        float_color,
        u8_color,
    })
}

/// Opens a PLY file (ASCII or binary).
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    let map = super::map_file(path)?;
    let header = parse_header(path, &map)?;
    let plan = plan_vertex(path, &header)?;
    let count = header.elements[plan.element].count;
    let format = match header.encoding {
        Encoding::Ascii => "ply-ascii",
        Encoding::BinaryLe => "ply-binary-le",
        Encoding::BinaryBe => "ply-binary-be",
    };
    let info = SourceInfo {
        path: path.to_path_buf(),
        format: format.into(),
        declared_points: Some(count),
        declared_bounds: None,
        crs_wkt: None,
        attribute_names: plan.layout.attr_names.clone(),
        file_bytes: map.len() as u64,
        notes: Vec::new(),
        metadata: Vec::new(),
        coordinate_step: None,
        coordinate_lattice: None,
    };
    if header.encoding == Encoding::Ascii {
        return ascii::open(path, opts, map, &header, plan, info);
    }
    binary::open(path, opts, map, &header, plan, info)
}

#[cfg(test)]
mod tests {
    use super::super::{ReadOptions, open, read_all};
    use crate::points::PointColumns;
    use std::path::PathBuf;

    /// Test points: (x, y, z, red, intensity-as-u16, label-as-i32).
    fn points(n: usize) -> Vec<(f64, f64, f64, u8, u16, i32)> {
        (0..n)
            .map(|i| {
                (
                    i as f64 * 0.5,
                    -(i as f64) * 0.25,
                    1000.0 + i as f64,
                    (i % 256) as u8,
                    (i * 7 % 65536) as u16,
                    i as i32 - 50,
                )
            })
            .collect()
    }

    /// Writes a PLY with a face element before the vertex element (1 face) and
    /// another after it; `double` picks the coordinate type.
    fn write_ply(
        dir: &tempfile::TempDir,
        name: &str,
        enc: &str,
        double: bool,
        n: usize,
    ) -> PathBuf {
        let t = if double { "double" } else { "float" };
        let mut out = format!(
            "ply\nformat {enc} 1.0\ncomment test\nelement face 1\nproperty list uchar int vertex_indices\n\
             element vertex {n}\nproperty {t} x\nproperty {t} y\nproperty {t} z\nproperty uchar red\n\
             property ushort Intensity\nproperty int label\nelement edge 2\nproperty int a\nproperty int b\nend_header\n"
        )
        .into_bytes();
        let pts = points(n);
        let be = enc == "binary_big_endian";
        macro_rules! put {
            ($v:expr) => {
                if be {
                    out.extend_from_slice(&$v.to_be_bytes())
                } else {
                    out.extend_from_slice(&$v.to_le_bytes())
                }
            };
        }
        if enc == "ascii" {
            out.extend_from_slice(b"3 0 1 2\n");
            for p in &pts {
                out.extend_from_slice(
                    format!("{} {} {} {} {} {}\n", p.0, p.1, p.2, p.3, p.4, p.5).as_bytes(),
                );
            }
            out.extend_from_slice(b"0 1\n1 2\n");
        } else {
            out.push(3);
            for k in 0..3i32 {
                put!(k);
            }
            for p in &pts {
                if double {
                    put!(p.0);
                    put!(p.1);
                    put!(p.2);
                } else {
                    put!(p.0 as f32);
                    put!(p.1 as f32);
                    put!(p.2 as f32);
                }
                out.push(p.3);
                put!(p.4);
                put!(p.5);
            }
            for k in 0..4i32 {
                put!(k);
            }
        }
        let p = dir.path().join(name);
        std::fs::write(&p, out).unwrap();
        p
    }

    fn check(c: &PointColumns, n: usize) {
        let pts = points(n);
        assert_eq!(c.len(), n);
        for (i, p) in pts.iter().enumerate() {
            assert_eq!((c.x[i], c.y[i], c.z[i]), (p.0, p.1, p.2), "point {i}");
            assert_eq!(c.attributes[0].values[i], p.3 as f32);
            assert_eq!(c.attributes[1].values[i], p.4 as f32);
            assert_eq!(c.attributes[2].values[i], p.5 as f32);
        }
    }

    #[test]
    fn all_encodings_and_types() {
        let d = tempfile::tempdir().unwrap();
        let n = 5000;
        for (enc, fmt) in [
            ("ascii", "ply-ascii"),
            ("binary_little_endian", "ply-binary-le"),
            ("binary_big_endian", "ply-binary-be"),
        ] {
            for double in [false, true] {
                let p = write_ply(&d, &format!("{enc}{double}.ply"), enc, double, n);
                let (info, c, _) = read_all(&p, &ReadOptions::default()).unwrap();
                assert_eq!(info.format, fmt);
                assert_eq!(info.declared_points, Some(n as u64));
                assert_eq!(info.attribute_names, ["red", "intensity", "label"]);
                check(&c, n);
                // Tiny chunks give the same points.
                let opts = ReadOptions {
                    chunk_points: 97,
                    ..Default::default()
                };
                let mut r = open(&p, &opts).unwrap();
                let mut all = c.empty_like();
                while let Some(ch) = r.next_chunk().unwrap() {
                    assert!(ch.len() <= 97);
                    all.append(&ch).unwrap();
                }
                assert_eq!(all, c, "{enc} double={double}");
            }
        }
    }

    #[test]
    fn truncated_binary_names_byte_offset() {
        let d = tempfile::tempdir().unwrap();
        let p = write_ply(&d, "t.ply", "binary_little_endian", false, 100);
        let data = std::fs::read(&p).unwrap();
        let header_len = data.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        for keep in [header_len + 5, header_len + 13 + 21 * 50 + 3] {
            let q = d.path().join("cut.ply");
            std::fs::write(&q, &data[..keep]).unwrap();
            let e = read_all(&q, &ReadOptions::default()).unwrap_err();
            assert_eq!(e.byte_offset(), Some(keep as u64));
            let s = e.to_string();
            assert!(s.contains("cut.ply") && s.contains("truncated"), "{s}");
        }
        // Truncated ASCII: fewer vertex lines than declared.
        let p = write_ply(&d, "a.ply", "ascii", false, 100);
        let text = std::fs::read_to_string(&p).unwrap();
        let cut = text.find("\n10 ").unwrap() + 1;
        let q = d.path().join("acut.ply");
        std::fs::write(&q, &text[..cut]).unwrap();
        let s = read_all(&q, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(s.contains("acut.ply") && s.contains("line"), "{s}");
    }

    /// A large attribute (a double GPS time) is stored relative to an offset, in
    /// binary and ASCII files alike.
    #[test]
    fn large_attributes_get_an_offset() {
        let d = tempfile::tempdir().unwrap();
        let times: Vec<f64> = (0..50).map(|i| 3.0e8 + 0.000123 + i as f64 * 0.5).collect();
        let head = "ply\nformat binary_little_endian 1.0\nelement vertex 50\nproperty float x\n\
                    property float y\nproperty float z\nproperty double gps_time\nend_header\n";
        let mut bin = head.as_bytes().to_vec();
        let mut ascii = head.replace("binary_little_endian", "ascii");
        for t in &times {
            for v in [1f32, 2.0, 3.0] {
                bin.extend_from_slice(&v.to_le_bytes());
            }
            bin.extend_from_slice(&t.to_le_bytes());
            ascii.push_str(&format!("1 2 3 {t:.6}\n"));
        }
        for (name, body) in [("b.ply", bin), ("a.ply", ascii.into_bytes())] {
            let p = d.path().join(name);
            std::fs::write(&p, body).unwrap();
            let (_, c, _) = read_all(&p, &ReadOptions::default()).unwrap();
            let a = &c.attributes[0];
            assert_eq!(a.offset, 3.0e8 + 13.0, "{name}");
            for (v, t) in a.values.iter().zip(&times) {
                assert!((a.offset + *v as f64 - t).abs() < 1e-5, "{name}");
            }
        }
    }

    /// A blank or comment line among ASCII vertices is an error, even when skipping
    /// invalid lines: counted as a vertex, it pushed the last vertex out unseen.
    #[test]
    fn blank_lines_among_ascii_vertices_are_errors() {
        let d = tempfile::tempdir().unwrap();
        let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                    property float z\nend_header\n";
        for (name, body) in [
            ("blank.ply", "1 2 3\n\n4 5 6\n7 8 9\n"),
            ("hash.ply", "1 2 3\n# c\n4 5 6\n7 8 9\n"),
        ] {
            let p = d.path().join(name);
            std::fs::write(&p, format!("{head}{body}")).unwrap();
            for skip_invalid in [false, true] {
                let opts = ReadOptions {
                    skip_invalid,
                    ..Default::default()
                };
                let e = read_all(&p, &opts).unwrap_err().to_string();
                assert!(
                    e.contains(&format!("{name}: line 9: a blank or comment line")),
                    "{e}"
                );
            }
        }
    }

    /// A file cut short inside the element after the vertices (here two edges) is
    /// truncated too, though its vertices are whole; a last line without its
    /// newline is not a cut.
    #[test]
    fn truncated_after_the_vertices() {
        let d = tempfile::tempdir().unwrap();
        let p = write_ply(&d, "b.ply", "binary_big_endian", false, 100);
        let data = std::fs::read(&p).unwrap();
        let q = d.path().join("bcut.ply");
        std::fs::write(&q, &data[..data.len() - 3]).unwrap();
        let e = read_all(&q, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.byte_offset(), Some(data.len() as u64 - 3));
        assert!(e.to_string().contains("inside element 'edge'"), "{e}");
        let p = write_ply(&d, "a.ply", "ascii", false, 100);
        let text = std::fs::read_to_string(&p).unwrap();
        let q = d.path().join("acut.ply");
        std::fs::write(&q, text.strip_suffix("1 2\n").unwrap()).unwrap();
        let e = read_all(&q, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        // Header (16 lines), one face, 100 vertices, one edge: line 119 is missing.
        assert!(
            e.contains("acut.ply: line 119") && e.contains("'edge' (1 of the 2"),
            "{e}"
        );
        std::fs::write(&q, text.strip_suffix('\n').unwrap()).unwrap();
        assert_eq!(read_all(&q, &ReadOptions::default()).unwrap().1.len(), 100);
        // A blank line is not an item.
        std::fs::write(&q, text.replace("1 2\n", "\n")).unwrap();
        let e = read_all(&q, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("'edge' (1 of the 2"), "{e}");
        // Cut inside the last line: its values are counted too.
        std::fs::write(&q, text.strip_suffix("2\n").unwrap()).unwrap();
        let e = read_all(&q, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("last line of element 'edge'"), "{e}");
        let faces = |tail: &str| {
            format!(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                 property float y\nproperty float z\nelement face 2\n\
                 property list uchar int vertex_indices\nproperty uchar flag\nend_header\n\
                 0 0 0\n1 0 0\n0 1 0\n3 0 1 2 7\n{tail}"
            )
        };
        for (tail, whole) in [
            ("4 0 1 2 0 9\n", true),
            ("4 0 1 2 0 9", true),
            ("4 0 1 2 0 9 \n\n", true),
            ("4 0 1 2 0", false),
            ("4 0 1 2", false),
            ("4", false),
        ] {
            std::fs::write(&q, faces(tail)).unwrap();
            let r = read_all(&q, &ReadOptions::default());
            assert_eq!(r.is_ok(), whole, "{tail:?}");
            if let Err(e) = r {
                assert!(e.to_string().contains("'face' ends before"), "{e}");
            }
        }
    }

    #[test]
    fn bad_headers_and_lines() {
        let d = tempfile::tempdir().unwrap();
        let cases: &[(&str, &[u8])] = &[
            ("nomagic.ply", b"plx\nformat ascii 1.0\nend_header\n"),
            ("noend.ply", b"ply\nformat ascii 1.0\nelement vertex 1\n"),
            ("noformat.ply", b"ply\nelement vertex 0\nproperty float x\nend_header\n"),
            ("badtype.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n1\n"),
            ("novertex.ply", b"ply\nformat ascii 1.0\nelement face 0\nend_header\n"),
            ("noz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n"),
            ("count.ply", b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n"),
            ("listv.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty list uchar int f\nend_header\n"),
            ("huge.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty double x\nproperty double y\nproperty double z\nend_header\n"),
            ("empty.ply", b""),
        ];
        for (name, body) in cases {
            let p = d.path().join(name);
            std::fs::write(&p, body).unwrap();
            let e = read_all(&p, &ReadOptions::default())
                .unwrap_err()
                .to_string();
            assert!(e.contains(name), "{e}");
        }
        let p = d.path().join("badline.ply");
        std::fs::write(
            &p,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 five 6\n7 8 9\n",
        )
        .unwrap();
        let e = read_all(&p, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.line_number(), Some(9), "{e}");
        let opts = ReadOptions {
            skip_invalid: true,
            ..Default::default()
        };
        let (_, c, skipped) = read_all(&p, &opts).unwrap();
        assert_eq!((c.len(), skipped), (2, 1));
    }

    #[test]
    fn binary_non_finite_vertices() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("nan.ply");
        let mut body = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
        let hl = body.len();
        for v in [
            1.0f32,
            2.0,
            3.0,
            f32::NAN,
            5.0,
            6.0,
            7.0,
            8.0,
            f32::INFINITY,
        ] {
            body.extend_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&p, &body).unwrap();
        let e = read_all(&p, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.byte_offset(), Some(hl as u64 + 12));
        assert!(e.to_string().contains("vertex 1"), "{e}");
        let opts = ReadOptions {
            skip_invalid: true,
            ..Default::default()
        };
        let (_, c, skipped) = read_all(&p, &opts).unwrap();
        assert_eq!((c.x.clone(), skipped), (vec![1.0], 2));
    }

    #[test]
    fn zero_vertices_is_an_empty_cloud() {
        let d = tempfile::tempdir().unwrap();
        for f in ["ascii", "binary_little_endian"] {
            let p = d.path().join(format!("{f}.ply"));
            std::fs::write(
                &p,
                format!("ply\nformat {f} 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n"),
            )
            .unwrap();
            let mut r = open(&p, &ReadOptions::default()).unwrap();
            assert_eq!(r.info().declared_points, Some(0));
            assert!(r.next_chunk().unwrap().is_none());
        }
    }

    #[test]
    fn float_colour_is_scaled() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("fc.ply");
        std::fs::write(
            &p,
            "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
             property float r\nproperty float g\nproperty float b\nend_header\n0 0 0 1 0.5 0\n1 1 1 0 0 1\n",
        )
        .unwrap();
        let (info, c, _) = read_all(&p, &ReadOptions::default()).unwrap();
        assert_eq!(info.attribute_names, ["red", "green", "blue"]);
        assert_eq!(c.attributes[0].values, [255.0, 0.0]);
        assert_eq!(c.attributes[1].values, [127.5, 0.0]);
    }
}
