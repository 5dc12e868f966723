//! The PCD header (versions 0.5 to 0.7): its entries, checked against each other,
//! with every error naming the header line it comes from.

use crate::error::IngestError;
use std::path::Path;

/// Longest header read before giving up on finding `DATA`.
const MAX_HEADER: usize = 1 << 20;

/// A field's value type: `TYPE` (`I`, `U`, `F`) with its `SIZE`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ty {
    I1,
    U1,
    I2,
    U2,
    I4,
    U4,
    I8,
    U8,
    F4,
    F8,
}

impl Ty {
    fn of(t: &str, size: &str) -> Option<Ty> {
        Some(match (t, size) {
            ("I", "1") => Ty::I1,
            ("U", "1") => Ty::U1,
            ("I", "2") => Ty::I2,
            ("U", "2") => Ty::U2,
            ("I", "4") => Ty::I4,
            ("U", "4") => Ty::U4,
            ("I", "8") => Ty::I8,
            ("U", "8") => Ty::U8,
            ("F", "4") => Ty::F4,
            ("F", "8") => Ty::F8,
            _ => return None,
        })
    }

    pub fn size(self) -> usize {
        match self {
            Ty::I1 | Ty::U1 => 1,
            Ty::I2 | Ty::U2 => 2,
            Ty::I4 | Ty::U4 | Ty::F4 => 4,
            Ty::I8 | Ty::U8 | Ty::F8 => 8,
        }
    }

    pub(crate) fn is_float(self) -> bool {
        matches!(self, Ty::F4 | Ty::F8)
    }
}

/// How the points follow the header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Data {
    Ascii,
    Binary,
    Compressed,
}

/// One `FIELDS` entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub name: String,
    pub ty: Ty,
    pub count: usize,
}

impl Field {
    /// Bytes of one point's values of this field.
    pub fn bytes(&self) -> usize {
        self.ty.size() * self.count
    }
}

/// A parsed header.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub version: String,
    pub fields: Vec<Field>,
    pub width: u64,
    pub height: u64,
    pub points: u64,
    /// `tx ty tz qw qx qy qz`, when the header has a `VIEWPOINT`.
    pub viewpoint: Option<[f64; 7]>,
    pub data: Data,
    /// Byte offset of the first byte after the `DATA` line.
    pub len: usize,
    /// 1-based line number of the `DATA` line.
    pub data_line: u64,
    /// 1-based line number of the `POINTS` line (of `WIDTH` without one).
    pub points_line: u64,
}

impl Header {
    /// Bytes of one point (binary record).
    pub fn stride(&self) -> usize {
        self.fields.iter().map(Field::bytes).sum()
    }
}

/// Whether `bytes` start like a PCD file (a `# .PCD` comment or a `VERSION` line).
pub(crate) fn sniff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"# .PCD") || bytes.starts_with(b"VERSION")
}

/// Parses the header at the start of `data`.
pub fn parse(path: &Path, data: &[u8]) -> Result<Header, IngestError> {
    let mut pos = 0usize;
    let mut line_no = 0u64;
    let mut names: Option<(u64, Vec<String>)> = None;
    let mut sizes: Option<(u64, Vec<String>)> = None;
    let mut types: Option<(u64, Vec<String>)> = None;
    let mut counts: Option<(u64, Vec<String>)> = None;
    let mut version = String::from("0.7");
    let mut width = None;
    let mut width_line = 0;
    let mut height = None;
    let mut points: Option<(u64, u64)> = None;
    let mut viewpoint = None;
    let head = &data[..data.len().min(MAX_HEADER)];
    loop {
        if pos >= head.len() {
            return Err(IngestError::line(
                path,
                line_no,
                "the PCD header has no DATA line",
                b"",
            ));
        }
        let end = memchr::memchr(b'\n', &head[pos..]).map_or(head.len(), |i| pos + i + 1);
        let raw = &head[pos..end];
        pos = end;
        line_no += 1;
        let text = String::from_utf8_lossy(raw);
        let text = text.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let mut words = text.split_ascii_whitespace();
        let key = words.next().unwrap_or_default().to_ascii_uppercase();
        let rest: Vec<String> = words.map(str::to_string).collect();
        let err = |msg: String| IngestError::line(path, line_no, msg, raw);
        let one_number = |what: &str| -> Result<u64, IngestError> {
            match rest.as_slice() {
                [v] => v
                    .parse::<u64>()
                    .map_err(|_| err(format!("{what} must be a whole number"))),
                _ => Err(err(format!("{what} takes one number"))),
            }
        };
        match key.as_str() {
            "VERSION" => version = rest.first().cloned().unwrap_or_default(),
            "FIELDS" | "COLUMNS" => names = Some((line_no, rest)),
            "SIZE" => sizes = Some((line_no, rest)),
            "TYPE" => types = Some((line_no, rest)),
            "COUNT" => counts = Some((line_no, rest)),
            "WIDTH" => {
                width = Some(one_number("WIDTH")?);
                width_line = line_no;
            }
            "HEIGHT" => height = Some(one_number("HEIGHT")?),
            "POINTS" => points = Some((line_no, one_number("POINTS")?)),
            "VIEWPOINT" => {
                let v: Vec<f64> = rest.iter().filter_map(|w| w.parse().ok()).collect();
                let v: [f64; 7] = v
                    .try_into()
                    .map_err(|_| err("VIEWPOINT takes seven numbers".into()))?;
                viewpoint = Some(v);
            }
            "DATA" => {
                let data = match rest.first().map(|s| s.to_ascii_lowercase()).as_deref() {
                    Some("ascii") => Data::Ascii,
                    Some("binary") => Data::Binary,
                    Some("binary_compressed") => Data::Compressed,
                    _ => {
                        return Err(err("DATA must be ascii, binary or binary_compressed".into()));
                    }
                };
                let fields = fields(path, names, sizes, types, counts)?;
                let width = width.ok_or_else(|| err("the header has no WIDTH".into()))?;
                let height = height.unwrap_or(1);
                let slots = width.checked_mul(height);
                let points_line = points.map_or(width_line, |(l, _)| l);
                let points = match points {
                    Some((l, p)) => {
                        if slots != Some(p) {
                            return Err(IngestError::line(
                                path,
                                l,
                                format!(
                                    "POINTS {p} differs from WIDTH × HEIGHT = {width} × {height}"
                                ),
                                b"",
                            ));
                        }
                        p
                    }
                    None => slots.ok_or_else(|| err("WIDTH × HEIGHT is too large".into()))?,
                };
                return Ok(Header {
                    version,
                    fields,
                    width,
                    height,
                    points,
                    viewpoint,
                    data,
                    len: pos,
                    data_line: line_no,
                    points_line,
                });
            }
            _ => {
                return Err(err(format!(
                    "unknown PCD header entry '{}'",
                    pcimg_core::text::sanitize(&key)
                )));
            }
        }
    }
}

type Entry = Option<(u64, Vec<String>)>;

/// The fields from `FIELDS`, `SIZE`, `TYPE` and `COUNT` (each with its line).
fn fields(
    path: &Path,
    names: Entry,
    sizes: Entry,
    types: Entry,
    counts: Entry,
) -> Result<Vec<Field>, IngestError> {
    let missing = |what: &str| IngestError::format(path, format!("the PCD header has no {what}"));
    let (nl, names) = names.ok_or_else(|| missing("FIELDS"))?;
    let (sl, sizes) = sizes.ok_or_else(|| missing("SIZE"))?;
    let (tl, types) = types.ok_or_else(|| missing("TYPE"))?;
    let n = names.len();
    if n == 0 {
        return Err(IngestError::line(path, nl, "FIELDS names no field", b""));
    }
    let check = |line: u64, what: &str, len: usize| {
        if len == n {
            Ok(())
        } else {
            Err(IngestError::line(
                path,
                line,
                format!("{what} has {len} entries for {n} FIELDS"),
                b"",
            ))
        }
    };
    check(sl, "SIZE", sizes.len())?;
    check(tl, "TYPE", types.len())?;
    let counts = match counts {
        Some((cl, c)) => {
            check(cl, "COUNT", c.len())?;
            c.iter()
                .map(|c| match c.parse::<usize>() {
                    Ok(v) if (1..=1 << 16).contains(&v) => Ok(v),
                    _ => Err(IngestError::line(
                        path,
                        cl,
                        format!(
                            "COUNT '{}' is not a count from 1",
                            pcimg_core::text::sanitize(c)
                        ),
                        b"",
                    )),
                })
                .collect::<Result<Vec<_>, _>>()?
        }
        None => vec![1; n],
    };
    (0..n)
        .map(|i| {
            let ty = Ty::of(&types[i].to_ascii_uppercase(), &sizes[i]).ok_or_else(|| {
                IngestError::line(
                    path,
                    tl,
                    format!(
                        "field '{}': unknown field type {} of size {} (known: I and U of 1, 2, 4 \
                         or 8 bytes, F of 4 or 8)",
                        pcimg_core::text::sanitize(&names[i]),
                        pcimg_core::text::sanitize(&types[i]),
                        pcimg_core::text::sanitize(&sizes[i])
                    ),
                    b"",
                )
            })?;
            Ok(Field {
                name: names[i].clone(),
                ty,
                count: counts[i],
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n\
                        COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n";

    #[test]
    fn parses_a_header() {
        let h = parse(Path::new("a.pcd"), HEAD.as_bytes()).unwrap();
        assert_eq!(h.fields.len(), 4);
        assert_eq!(h.stride(), 16);
        assert_eq!(h.points, 2);
        assert_eq!(h.data, Data::Ascii);
        assert_eq!(h.len, HEAD.len());
        assert_eq!(h.data_line, 11);
        assert_eq!(h.viewpoint, Some([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]));
    }

    #[test]
    fn lies_and_unknowns_name_their_line() {
        let e = parse(
            Path::new("a.pcd"),
            HEAD.replace("POINTS 2", "POINTS 3").as_bytes(),
        )
        .unwrap_err();
        assert_eq!(e.line_number(), Some(10), "{e}");
        assert!(e.to_string().contains("WIDTH × HEIGHT"), "{e}");
        let e = parse(
            Path::new("a.pcd"),
            HEAD.replace("F F F F", "F F F X").as_bytes(),
        )
        .unwrap_err();
        assert_eq!(e.line_number(), Some(5), "{e}");
        assert!(e.to_string().contains("unknown field type"), "{e}");
        let e = parse(
            Path::new("a.pcd"),
            HEAD.replace("SIZE 4 4 4 4", "SIZE 4 4 4").as_bytes(),
        )
        .unwrap_err();
        assert_eq!(e.line_number(), Some(4), "{e}");
        let e = parse(Path::new("a.pcd"), b"VERSION 0.7\nFIELDS x\n").unwrap_err();
        assert!(e.to_string().contains("no DATA"), "{e}");
    }
}
