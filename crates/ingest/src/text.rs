//! Text point clouds (`.xyz .txt .csv .asc .pts`) and the parallel line engine that
//! also reads ASCII PLY vertex lines.
//!
//! Format accepted:
//! * one point per line; columns separated by runs of spaces, tabs, commas or
//!   semicolons (so `1,,2` reads as two columns: an empty CSV field is not a value);
//!   `\r\n` line endings and a UTF-8 byte-order mark are accepted;
//! * comment lines start with `#` or `//` (after optional blanks); blank lines are
//!   ignored; a comment just before the data whose names include x, y and z (as
//!   CloudCompare writes `//X,Y,Z,R,G,B`) is used as the header;
//! * an optional header line: the first non-comment line when it holds a
//!   non-numeric token; its names label the columns (`x y z intensity r g b`,
//!   `red green blue`, ...). Without x/y/z among the names the first three columns
//!   are the coordinates;
//! * PTS: a first line holding a single integer is the point count; later
//!   single-integer lines (PTS files that concatenate scans) are skipped too, and
//!   counted: a file that holds fewer points than its count lines declare is an
//!   error (cut short at a line's end; more points are read);
//! * column layout, unless given by [`ReadOptions::columns`]: 3 → x y z,
//!   4 → x y z intensity, 6 → x y z r g b, 7 → x y z intensity r g b (the PTS
//!   convention), otherwise x y z col3 col4 ... (0-based column index);
//! * every data line must have exactly the detected number of columns; a line
//!   that does not, a token that is not a number, or a NaN/infinite coordinate
//!   makes the line invalid: an error naming the line, or skipped and counted with
//!   [`ReadOptions::skip_invalid`].
//!
//! Speed: the file is memory-mapped and read by the parallel line engine of
//! `ingest::lines`; pages already consumed are released as the reader advances.

use std::path::Path;

use super::color::ColorNormalizer;
use super::error::IngestError;
use super::lines::{Layout, LineEngine, LineReader, is_sep, sample_bytes_per_line};
use super::{ReadOptions, SourceInfo, canonical_names};

/// Splits a line into tokens (separators as in the data).
fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|&c| is_sep(c) || c == b'\n')
        .filter(|t| !t.is_empty())
}

/// Parses a whole token as a number.
fn token_number(t: &[u8]) -> Option<f64> {
    match fast_float2::parse_partial::<f64, _>(t) {
        Ok((v, used)) if used == t.len() => Some(v),
        _ => None,
    }
}

/// What the first lines of a text file say.
#[derive(Debug, Default)]
struct Preamble {
    /// Byte where the engine starts (after a header or count line).
    data_start: usize,
    /// 1-based line number at `data_start`.
    data_line: u64,
    header: Option<Vec<String>>,
    /// The header is the last comment line before the data (`# x y z i`), which
    /// may be a remark rather than a header: ignored when it does not fit.
    header_is_comment: bool,
    count: Option<u64>,
    /// Token count, 1-based line number and bytes of the first data line.
    first_data: Option<(usize, u64, (usize, usize))>,
}

fn strip_comment_marker(line: &[u8]) -> &[u8] {
    let t = line.trim_ascii_start();
    if let Some(r) = t.strip_prefix(b"//") {
        r
    } else if let Some(r) = t.strip_prefix(b"#") {
        r
    } else {
        t
    }
}

fn header_names(line: &[u8]) -> Vec<String> {
    let line = strip_comment_marker(line);
    let clean = |t: &[u8]| {
        let s = String::from_utf8_lossy(t);
        let s = s
            .trim()
            .trim_matches(|c| c == '"' || c == '\'' || c == '/' || c == '#');
        // A name with spaces inside ("my col" in a CSV) becomes one word.
        s.split_whitespace().collect::<Vec<_>>().join("_")
    };
    // A header with commas or semicolons is split on them only, so names may
    // hold spaces; otherwise on any separator.
    let raw: Vec<String> = if line.iter().any(|&b| b == b',' || b == b';') {
        // (Not inside double quotes: `"area (1,000 m2)"` is one name.)
        let mut quoted = false;
        line.split(|&b| {
            quoted ^= b == b'"';
            !quoted && (b == b',' || b == b';')
        })
        .map(clean)
        .filter(|n| !n.is_empty())
        .collect()
    } else {
        tokens(line).map(clean).collect()
    };
    canonical_names(&raw)
}

/// Whether a line's numbers are written with decimal commas ("1,5 2,25 -3,0"):
/// whitespace separates at least three fields, each digits, one comma, digits; or
/// whitespace or semicolons separate fields of which one is ("1,5;2,25;-3,0",
/// "637000,123 6010900,456 20,030 96").
fn decimal_commas(line: &[u8]) -> bool {
    let fields: Vec<&[u8]> = line
        .split(|c| c.is_ascii_whitespace())
        .filter(|f| !f.is_empty())
        .collect();
    let decimal = |f: &[u8]| {
        let f = f.strip_prefix(b"-").unwrap_or(f);
        let mut halves = f.split(|&c| c == b',');
        let digits =
            |h: Option<&[u8]>| h.is_some_and(|h| !h.is_empty() && h.iter().all(u8::is_ascii_digit));
        digits(halves.next()) && digits(halves.next()) && halves.next().is_none()
    };
    // Fields apart from commas: when they are several, a comma inside one
    // ("1,5 2,25" or "1,5;2,25") is a decimal comma, not a separator.
    let parts: Vec<&[u8]> = line
        .split(|&c| c.is_ascii_whitespace() || c == b';')
        .filter(|f| !f.is_empty())
        .collect();
    // Commas next to blanks ("10,20, 30,40") separate fields.
    let spaced = line.windows(2).any(|w| {
        (w[0] == b',' && w[1].is_ascii_whitespace()) || (w[1] == b',' && w[0].is_ascii_whitespace())
    });
    (fields.len() >= 3 && fields.iter().all(|f| decimal(f)))
        || (!spaced && parts.len() >= 2 && parts.iter().any(|f| decimal(f)))
}

/// Whether two commas or semicolons follow each other with only blanks between
/// them (`1,2,,4`): an empty field.
fn has_empty_field(line: &[u8]) -> bool {
    let mut delimiters = 0;
    for &c in line {
        match c {
            b',' | b';' => {
                delimiters += 1;
                if delimiters > 1 {
                    return true;
                }
            }
            b' ' | b'\t' | b'\r' => {}
            _ => delimiters = 0,
        }
    }
    false
}

fn has_xyz(names: &[String]) -> bool {
    ["x", "y", "z"].iter().all(|c| names.iter().any(|n| n == c))
}

/// Scans the first lines: header, PTS count line, first data line.
fn scan_preamble(data: &[u8], start: usize) -> Preamble {
    let mut pre = Preamble {
        data_start: start,
        data_line: 1,
        ..Default::default()
    };
    let mut pos = start;
    let mut line_no = 1u64;
    let mut seen_content = false;
    let mut last_comment: Option<Vec<String>> = None;
    while pos < data.len() {
        let end = memchr::memchr(b'\n', &data[pos..]).map_or(data.len(), |k| pos + k);
        let line = &data[pos..end];
        let next = (end + 1).min(data.len());
        let t = line.trim_ascii();
        if t.is_empty() {
        } else if t.starts_with(b"#") || t.starts_with(b"//") {
            let names = header_names(t);
            last_comment = if has_xyz(&names) { Some(names) } else { None };
        } else {
            let toks: Vec<&[u8]> = tokens(t).collect();
            let numeric = toks.iter().all(|t| token_number(t).is_some());
            // A line that starts with a number is a point line, a bad one if the
            // rest is not numbers ("1,2,3 # note"): the engine reports it, rather
            // than it being taken for a header and its point lost.
            let starts_numeric = toks.first().is_some_and(|t| token_number(t).is_some());
            if !numeric {
                if !seen_content && !starts_numeric {
                    pre.header = Some(header_names(t));
                    pre.data_start = next;
                    pre.data_line = line_no + 1;
                    seen_content = true;
                } else {
                    // A bad first data line: the engine reports it.
                    pre.first_data = Some((toks.len(), line_no, (pos, end)));
                    break;
                }
            } else if toks.len() == 1
                && !seen_content
                && token_number(toks[0]).is_some_and(|v| v >= 0.0 && v.fract() == 0.0)
            {
                pre.count = token_number(toks[0]).map(|v| v as u64);
                pre.data_start = next;
                pre.data_line = line_no + 1;
                seen_content = true;
            } else {
                pre.first_data = Some((toks.len(), line_no, (pos, end)));
                if pre.header.is_none() {
                    pre.header = last_comment.take();
                    pre.header_is_comment = pre.header.is_some();
                }
                break;
            }
        }
        pos = next;
        line_no += 1;
    }
    pre
}

/// Reader for text point clouds (the line reader shared with ASCII PLY).
pub(crate) type TextReader = LineReader;

impl TextReader {
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<TextReader, IngestError> {
        let map = super::map_file(path)?;
        let data: &[u8] = &map;
        let start = if data.starts_with(b"\xEF\xBB\xBF") {
            3
        } else {
            0
        };
        // Lines ended by CR alone (classic Mac OS) would read as one long line.
        let head = &data[start..data.len().min(start + (1 << 20))];
        if !head.contains(&b'\n') && head.iter().filter(|&&c| c == b'\r').take(2).count() > 1 {
            return Err(IngestError::format(
                path,
                "lines end in a carriage return alone (classic Mac OS line ends); convert \
                 them first, e.g. tr '\\r' '\\n' < in > out",
            ));
        }
        let pre = scan_preamble(data, start);
        let Some((ncols, first_line, (fs, fe))) = pre.first_data else {
            return Err(IngestError::format(
                path,
                "no point lines found (the file holds only comments, a header or blank lines)",
            ));
        };
        let first_text = &data[fs..fe];
        if decimal_commas(first_text) {
            return Err(IngestError::line(
                path,
                first_line,
                "the numbers use decimal commas (1,5 for 1.5), which pcimg does not read: \
                 convert them to decimal points first",
                first_text,
            ));
        }
        let mut layout = if let Some(spec) = &opts.columns {
            let raw: Vec<String> = tokens(spec.as_bytes())
                .map(|t| String::from_utf8_lossy(t).into_owned())
                .collect();
            let names = canonical_names(&raw);
            let layout = Layout::from_names(&names).map_err(|m| {
                IngestError::format(path, format!("bad column layout '{}': {m}", spec))
            })?;
            if layout.ncols() != ncols {
                return Err(IngestError::line(
                    path,
                    first_line,
                    format!(
                        "the column layout names {} columns but the first point line has {ncols}",
                        layout.ncols()
                    ),
                    first_text,
                ));
            }
            layout
        } else {
            if ncols < 3 {
                return Err(IngestError::line(
                    path,
                    first_line,
                    format!("a point line needs at least 3 columns (x y z), found {ncols}"),
                    first_text,
                ));
            }
            match &pre.header {
                // A header that does not fit the lines would put values under the
                // wrong names (x and y swapped, colours invented): refused.
                Some(h) if h.len() != ncols && pre.header_is_comment => Layout::positional(ncols),
                // (An empty field miscounts the line: the engine reports it.)
                Some(h) if h.len() != ncols && !has_empty_field(first_text) => {
                    return Err(IngestError::columns(
                        path,
                        Some((first_line, first_text)),
                        format!(
                            "the header line names {} column(s) ({}) but the first point line \
                             has {ncols}",
                            h.len(),
                            pcimg_core::text::sanitize(&h.join(" "))
                        ),
                    ));
                }
                Some(h) if has_xyz(h) => Layout::from_names(h).map_err(|m| {
                    IngestError::columns(path, None, format!("the header line's columns: {m}"))
                })?,
                Some(h) if h.len() == ncols => {
                    let mut names: Vec<String> = vec!["x".into(), "y".into(), "z".into()];
                    names.extend(h[3..].iter().cloned());
                    Layout::from_names(&names).unwrap_or_else(|_| Layout::positional(ncols))
                }
                _ => Layout::positional(ncols),
            }
        };
        let ext_pts = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("pts"));
        layout.decide_offsets(&data[pre.data_start..], u64::MAX);
        // The lattice the coordinates are written on: 10^-decimals, from 0.
        let lattice = layout
            .coordinate_decimals(&data[pre.data_start..])
            .map(|d| crate::points::Lattice {
                step: d.map(|d| 10f64.powi(-(d as i32))),
                origin: [0.0; 3],
            });
        let engine = LineEngine {
            path: path.to_path_buf(),
            layout: layout.clone(),
            pos: pre.data_start,
            end: data.len(),
            line: pre.data_line,
            lines_left: None,
            after: Vec::new(),
            skip_invalid: opts.skip_invalid,
            allow_count_lines: ext_pts || pre.count.is_some(),
            chunk_points: opts.chunk_points,
            bytes_per_line: sample_bytes_per_line(data, pre.data_start),
            skipped: 0,
            colors: ColorNormalizer::new(false),
            pending: Default::default(),
            sample: None,
            declared: pre.count,
            point_lines: 0,
        };
        let info = SourceInfo {
            path: path.to_path_buf(),
            format: "text".into(),
            declared_points: pre.count,
            declared_bounds: None,
            crs_wkt: None,
            attribute_names: layout.attr_names.clone(),
            file_bytes: data.len() as u64,
            notes: Vec::new(),
            metadata: Vec::new(),
            coordinate_step: None,
            coordinate_lattice: lattice,
        };
        Ok(LineReader::new(info, map, engine))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{IngestError, ReadOptions, open, read_all};
    use crate::points::PointColumns;
    use std::path::PathBuf;

    fn write(dir: &tempfile::TempDir, name: &str, body: &str) -> PathBuf {
        let p = dir.path().join(name);
        std::fs::write(&p, body).unwrap();
        p
    }

    /// The coordinates' lattice is the decimals they are written with (the most
    /// on each axis, columns in any order); an exponent or more than nine
    /// decimals leaves none.
    #[test]
    fn coordinate_decimals_make_the_lattice() {
        let d = tempfile::tempdir().unwrap();
        let lattice = |name: &str, body: &str| {
            let p = write(&d, name, body);
            super::super::open(&p, &ReadOptions::default())
                .unwrap()
                .info()
                .coordinate_lattice
        };
        let l = lattice("a.xyz", "z,x,y,i\n1.5,2.25,3,7\n1.25,2.125,3,8\n").unwrap();
        assert_eq!((l.step, l.origin), ([0.001, 1.0, 0.01], [0.0; 3]));
        assert_eq!(lattice("b.xyz", "1 2 3\n1e3 2 3\n"), None);
        assert_eq!(lattice("c.xyz", "1.0123456789 2 3\n"), None);
    }

    /// Large attribute values (GPS times near 3e8) are stored relative to an
    /// offset, so f32 keeps their microseconds' millisecond; small ones are not.
    #[test]
    fn large_attributes_get_an_offset() {
        let d = tempfile::tempdir().unwrap();
        let mut body = String::from("X,Y,Z,GPS_Time,Classification\n");
        // An odd first time (0) does not decide the offset.
        body.push_str("1,2,3,0,2\n");
        for i in 0..100 {
            body.push_str(&format!(
                "1,2,3,{:.6},2\n",
                305002000.006393 + i as f64 * 0.25
            ));
        }
        let p = write(&d, "t.csv", &body);
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["gps_time", "classification"]);
        let (t, class) = (&c.attributes[0], &c.attributes[1]);
        assert_eq!((t.offset, class.offset), (305002000.0 + 12.0, 0.0));
        for i in 0..100 {
            let got = t.offset + t.values[i + 1] as f64;
            assert!(
                (got - (305002000.006393 + i as f64 * 0.25)).abs() < 1e-5,
                "{got}"
            );
        }
        // (The odd one is as far from the offset as f32 steps of 32 s allow.)
        assert!((t.offset + t.values[0] as f64).abs() <= 16.0);
    }

    /// Decimal commas are refused wherever a comma sits inside a field that other
    /// separators delimit; ordinary comma-separated lines are not mistaken for them.
    #[test]
    fn decimal_commas_are_refused_not_misread() {
        for line in [
            "1,5 2,25 -3,0",
            "637000,123 6010900,456 20,030 96",
            "1,5;2,25;-3,0",
            "1;2,5;3",
        ] {
            assert!(super::decimal_commas(line.as_bytes()), "{line}");
        }
        for line in [
            "1,2,3",
            "1.5,2.5,3.5",
            "1,2, 3",
            "1, 2, 3",
            "1;2;3",
            "1 2 3 4",
        ] {
            assert!(!super::decimal_commas(line.as_bytes()), "{line}");
        }
    }

    /// A header whose names do not match the columns is refused (it would put
    /// values under the wrong names); a comment that does not fit is ignored.
    #[test]
    fn headers_that_do_not_fit_the_columns() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "h.xyz", "y x z\n1 2 3 4 5 6 7\n");
        let e = read(&p, &ReadOptions::default()).unwrap_err().to_string();
        assert!(
            e.contains("h.xyz: line 2") && e.contains("names 3 column(s) (y x z)"),
            "{e}"
        );
        let opts = ReadOptions {
            columns: Some("y x z i r g b".into()),
            ..Default::default()
        };
        let (c, names, _) = read(&p, &opts).unwrap();
        assert_eq!((c.x[0], c.y[0], names.len()), (2.0, 1.0, 4));
        let p = write(&d, "c.xyz", "# x y z in metres\n1 2 3 4\n");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!((c.len(), names), (1, vec!["intensity".to_string()]));
        // A quoted name may hold a comma.
        let p = write(&d, "q.csv", "x,y,z,\"area (1,000 m2)\"\n1,2,3,4\n");
        let (_, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["area_(1,000_m2)"]);
        // A first line that starts with numbers is a point line, not a header:
        // its trailing note is reported, not its point lost.
        let p = write(&d, "note.csv", "1,2,3 # note\n4,5,6\n");
        let e = read(&p, &ReadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("note.csv: line 1: not a number"), "{e}");
        let p = write(&d, "dup.csv", "x,y,z,x\n1,2,3,4\n");
        let e = read(&p, &ReadOptions::default()).unwrap_err();
        assert!(
            e.to_string().contains("appears twice") && matches!(e, IngestError::Columns { .. }),
            "{e}"
        );
    }

    fn read(
        p: &std::path::Path,
        opts: &ReadOptions,
    ) -> Result<(PointColumns, Vec<String>, u64), IngestError> {
        read_all(p, opts).map(|(i, c, s)| (c, i.attribute_names, s))
    }

    fn attr<'a>(c: &'a PointColumns, n: &str) -> &'a [f32] {
        &c.attributes.iter().find(|a| a.name == n).unwrap().values
    }

    #[test]
    fn plain_xyz() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "a.xyz", "1 2 3\n4.5 -5e1 6\n\n7\t8\t9");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(c.x, vec![1.0, 4.5, 7.0]);
        assert_eq!(c.y, vec![2.0, -50.0, 8.0]);
        assert_eq!(c.z, vec![3.0, 6.0, 9.0]);
        assert!(names.is_empty());
    }

    #[test]
    fn layouts_by_column_count() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "a.txt", "1 2 3 10\n4 5 6 20\n");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["intensity"]);
        assert_eq!(attr(&c, "intensity"), [10.0, 20.0]);
        let p = write(&d, "b.txt", "1 2 3 10 20 30\n");
        assert_eq!(
            read(&p, &ReadOptions::default()).unwrap().1,
            ["red", "green", "blue"]
        );
        let p = write(&d, "c.pts", "2\n1 2 3 -5 10 20 30\n1 2 3 -6 40 50 60\r\n");
        let r = open(&p, &ReadOptions::default()).unwrap();
        assert_eq!(r.info().declared_points, Some(2));
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["intensity", "red", "green", "blue"]);
        assert_eq!(attr(&c, "intensity"), [-5.0, -6.0]);
        assert_eq!(attr(&c, "blue"), [30.0, 60.0]);
        let p = write(&d, "d.xyz", "1 2 3 4 5\n");
        assert_eq!(
            read(&p, &ReadOptions::default()).unwrap().1,
            ["col3", "col4"]
        );
    }

    #[test]
    fn header_comments_and_csv() {
        let d = tempfile::tempdir().unwrap();
        let p = write(
            &d,
            "a.csv",
            "# exported\n// by hand\nX,Y,Z,Intensity,R,G,B\n1,2,3,4,5,6,7\n# mid comment\n  \n8,9,10,11,12,13,14\n",
        );
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["intensity", "red", "green", "blue"]);
        assert_eq!(c.x, vec![1.0, 8.0]);
        assert_eq!(attr(&c, "green"), [6.0, 13.0]);
        // Header with another column order.
        let p = write(&d, "b.csv", "intensity;z;y;x\n1;2;3;4\n");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["intensity"]);
        assert_eq!((c.x[0], c.y[0], c.z[0]), (4.0, 3.0, 2.0));
        // CloudCompare-style commented header.
        let p = write(&d, "c.txt", "//X,Y,Z,R,G,B\n1,2,3,4,5,6\n");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["red", "green", "blue"]);
        assert_eq!(attr(&c, "red"), [4.0]);
        // Names with spaces in a CSV header stay one column each.
        let p = write(&d, "s.csv", "x, y, z, my col ,Point Source\n1,2,3,4,5\n");
        let (c, names, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(names, ["my_col", "point_source"]);
        assert_eq!(attr(&c, "point_source"), [5.0]);
        // Header without x y z names: first three are coordinates.
        let p = write(&d, "e.txt", "east north up amp\n1 2 3 4\n");
        assert_eq!(read(&p, &ReadOptions::default()).unwrap().1, ["amp"]);
    }

    #[test]
    fn columns_option_with_skip() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "a.txt", "h1 h2 h3 h4 h5\n9 1 2 3 77\n9 4 5 6 88\n");
        let opts = ReadOptions {
            columns: Some("_ x y z Classification".into()),
            ..Default::default()
        };
        let (c, names, _) = read(&p, &opts).unwrap();
        assert_eq!(names, ["classification"]);
        assert_eq!(c.x, vec![1.0, 4.0]);
        assert_eq!(attr(&c, "classification"), [77.0, 88.0]);
        let bad = ReadOptions {
            columns: Some("x y q".into()),
            ..Default::default()
        };
        let e = read(&p, &bad).unwrap_err().to_string();
        assert!(e.contains("x, y and z"), "{e}");
        let wrong = ReadOptions {
            columns: Some("x y z".into()),
            ..Default::default()
        };
        let e = read(&p, &wrong).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }

    #[test]
    fn malformed_line_names_file_line_and_text() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "bad.xyz", "# c\n1 2 3\n4 5 6\n7 8 oops\n10 11 12\n");
        let e = read(&p, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.line_number(), Some(4));
        let s = e.to_string();
        assert!(
            s.contains("bad.xyz") && s.contains("line 4") && s.contains("7 8 oops"),
            "{s}"
        );
        let p = write(&d, "cols.xyz", "1 2 3\n4 5\n");
        let s = read(&p, &ReadOptions::default()).unwrap_err().to_string();
        assert!(
            s.contains("line 2") && s.contains("expected 3 columns, found 2"),
            "{s}"
        );
        let p = write(&d, "glued.xyz", "1 2 3\n4 5 6abc\n");
        assert_eq!(
            read(&p, &ReadOptions::default()).unwrap_err().line_number(),
            Some(2)
        );
        let p = write(&d, "ctl.xyz", "1 2 3\n4 5 \x1b[2J\n");
        let s = read(&p, &ReadOptions::default()).unwrap_err().to_string();
        assert!(!s.chars().any(|c| c.is_control()), "{s:?}");
    }

    #[test]
    fn non_finite_coordinates_are_invalid() {
        let d = tempfile::tempdir().unwrap();
        for (i, bad) in ["nan 1 2", "1 inf 2", "1 2 -infinity", "1 2 1e400"]
            .iter()
            .enumerate()
        {
            let p = write(&d, &format!("n{i}.xyz"), &format!("1 2 3\n{bad}\n4 5 6\n"));
            let e = read(&p, &ReadOptions::default()).unwrap_err();
            assert_eq!(e.line_number(), Some(2), "{bad}");
            assert!(e.to_string().contains("not finite"));
            let opts = ReadOptions {
                skip_invalid: true,
                ..Default::default()
            };
            let (c, _, skipped) = read(&p, &opts).unwrap();
            assert_eq!((c.len(), skipped), (2, 1));
        }
        // NaN in an attribute is a value, not an invalid line.
        let p = write(&d, "attr.xyz", "1 2 3 nan\n");
        assert!(attr(&read(&p, &ReadOptions::default()).unwrap().0, "intensity")[0].is_nan());
    }

    /// A PTS file's count lines (the first, and one per concatenated scan) are
    /// checked against the points a full read finds: fewer is a truncated file.
    #[test]
    fn pts_count_lines_catch_truncation() {
        let d = tempfile::tempdir().unwrap();
        let ok = |name: &str, body: &str, n: usize| {
            let p = write(&d, name, body);
            let (c, _, _) = read(&p, &ReadOptions::default()).unwrap();
            assert_eq!(c.len(), n, "{body:?}");
        };
        ok("whole.pts", "2\n1 2 3\n4 5 6\n", 2);
        ok("scans.pts", "2\n1 2 3\n4 5 6\n1\n7 8 9\n", 3);
        // More points than declared: read (a count written before filtering).
        ok("more.pts", "1\n1 2 3\n4 5 6\n", 2);
        // No count line at the top: nothing to check.
        ok("none.pts", "1 2 3\n4 5 6\n", 2);
        let short = |name: &str, body: &str, msg: &str| {
            let p = write(&d, name, body);
            let e = read(&p, &ReadOptions::default()).unwrap_err().to_string();
            assert!(e.contains(msg) && e.contains(name), "{e}");
        };
        short("cut.pts", "3\n1 2 3\n4 5 6\n", "after 2 of the 3 points");
        short(
            "cut2.xyz",
            "2\n1 2 3\n4 5 6\n3\n7 8 9\n",
            "after 3 of the 5 points",
        );
        // A skipped invalid line still was a point line of the count.
        let p = write(&d, "skip.pts", "3\n1 2 3\nbad\n4 5 6\n");
        let opts = ReadOptions {
            skip_invalid: true,
            ..Default::default()
        };
        let (c, _, skipped) = read(&p, &opts).unwrap();
        assert_eq!((c.len(), skipped), (2, 1));
        // Long enough for several windows and pieces.
        let mut body = String::from("100000\n");
        for i in 0..99_999 {
            body.push_str(&format!("{i} 1 2\n"));
        }
        short("big.pts", &body, "after 99,999 of the 100,000 points");
    }

    #[test]
    fn skip_invalid_counts() {
        let d = tempfile::tempdir().unwrap();
        let p = write(
            &d,
            "s.xyz",
            "1 2 3 4\nx y z w\n5 6 7 8\n1 2\n9 10 11 12\n1 2 3 4 5\n",
        );
        let opts = ReadOptions {
            skip_invalid: true,
            ..Default::default()
        };
        let (c, _, skipped) = read(&p, &opts).unwrap();
        assert_eq!(c.x, vec![1.0, 5.0, 9.0]);
        assert_eq!(attr(&c, "intensity"), [4.0, 8.0, 12.0]);
        assert_eq!(skipped, 3);
    }

    #[test]
    fn empty_and_pointless_files() {
        let d = tempfile::tempdir().unwrap();
        for (name, body) in [
            ("e.xyz", ""),
            ("h.xyz", "x y z\n"),
            ("c.xyz", "# nothing\n\n"),
            ("two.xyz", "1 2\n3 4\n"),
        ] {
            let p = write(&d, name, body);
            let e = read(&p, &ReadOptions::default()).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
    }

    #[test]
    fn chunks_match_whole_and_line_numbers_stay_exact() {
        let d = tempfile::tempdir().unwrap();
        let mut body = String::from("x y z intensity\n");
        for i in 0..20_000 {
            if i % 997 == 0 {
                body.push_str("# comment\n");
            }
            body.push_str(&format!("{}.25 {} {} {}\n", i, i * 2, -i, i % 256));
        }
        let p = write(&d, "big.xyz", &body);
        let (whole, _, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(whole.len(), 20_000);
        let opts = ReadOptions {
            chunk_points: 777,
            ..Default::default()
        };
        let mut r = open(&p, &opts).unwrap();
        let mut all = whole.empty_like();
        let mut chunks = 0;
        while let Some(c) = r.next_chunk().unwrap() {
            assert!(!c.is_empty() && c.len() <= 777);
            all.append(&c).unwrap();
            chunks += 1;
        }
        assert!(chunks >= 20_000 / 777);
        assert_eq!(all, whole);
        assert_eq!(r.bytes_done(), body.len() as u64);
        // An error deep in a multi-piece window still gets its exact line number.
        let lines: Vec<&str> = body.lines().collect();
        let target = 15_000;
        let mut bad = lines.clone();
        bad[target - 1] = "1 2 three 4";
        let p = write(&d, "bad.xyz", &(bad.join("\n") + "\n"));
        for chunk in [usize::MAX / 2, 1000, 3] {
            let opts = ReadOptions {
                chunk_points: chunk,
                ..Default::default()
            };
            let e = read(&p, &opts).unwrap_err();
            assert_eq!(e.line_number(), Some(target as u64), "chunk {chunk}: {e}");
        }
    }

    /// A window of many pieces (several MB) where comment, blank and skipped lines
    /// leave pieces with fewer points than lines: the points close up in order.
    #[test]
    fn pieces_with_gaps_close_up() {
        let d = tempfile::tempdir().unwrap();
        let mut body = String::from("x y z intensity\n");
        let mut expect = Vec::new();
        for i in 0..150_000u32 {
            match i % 997 {
                0 => body.push_str("# a comment\n"),
                1 => body.push('\n'),
                2 => body.push_str("1 2 nan 4\n"),
                3 => body.push_str("1 2 x 4\n"),
                _ => {
                    body.push_str(&format!("{i} {} 0.5 {}\n", i % 1000, i % 7));
                    expect.push((i as f64, (i % 1000) as f64, (i % 7) as f32));
                }
            }
        }
        assert!(body.len() > 2 << 20, "several pieces");
        let p = write(&d, "gaps.xyz", &body);
        let opts = ReadOptions {
            skip_invalid: true,
            ..Default::default()
        };
        let (c, _, skipped) = read(&p, &opts).unwrap();
        assert_eq!(skipped, 2 * 150_000u64.div_ceil(997));
        assert_eq!(c.len(), expect.len());
        let got: Vec<(f64, f64, f32)> = (0..c.len())
            .map(|i| (c.x[i], c.y[i], attr(&c, "intensity")[i]))
            .collect();
        assert!(got == expect);
        assert!(c.z.iter().all(|&z| z == 0.5));
    }

    #[test]
    fn uneven_lines_still_give_bounded_chunks() {
        let d = tempfile::tempdir().unwrap();
        let mut body = String::new();
        for i in 0..2000 {
            body.push_str(&format!("{i}.000000000000 2.000000000000 3.000000000000\n"));
        }
        for i in 0..30_000 {
            body.push_str(&format!("{} 2 3\n", i % 10));
        }
        let p = write(&d, "uneven.xyz", &body);
        let (whole, _, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(whole.len(), 32_000);
        let opts = ReadOptions {
            chunk_points: 100,
            ..Default::default()
        };
        let mut r = open(&p, &opts).unwrap();
        let mut all = whole.empty_like();
        while let Some(c) = r.next_chunk().unwrap() {
            assert!(!c.is_empty() && c.len() <= 100);
            all.append(&c).unwrap();
        }
        assert_eq!(all, whole);
    }

    #[test]
    fn text_colour_scaling() {
        let d = tempfile::tempdir().unwrap();
        let p = write(&d, "c16.xyz", "1 2 3 65535 0 257\n");
        let (c, _, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(attr(&c, "red"), [255.0]);
        assert_eq!(attr(&c, "blue"), [1.0]);
        let p = write(&d, "cu.xyz", "1 2 3 1.0 0.5 0\n");
        let (c, _, _) = read(&p, &ReadOptions::default()).unwrap();
        assert_eq!(attr(&c, "red"), [255.0]);
        assert_eq!(attr(&c, "green"), [127.5]);
    }
}
