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
//!   single-integer lines (PTS files that concatenate scans) are skipped too;
//! * column layout, unless given by [`ReadOptions::columns`]: 3 → x y z,
//!   4 → x y z intensity, 6 → x y z r g b, 7 → x y z intensity r g b (the PTS
//!   convention), otherwise x y z col3 col4 ... (0-based column index);
//! * every data line must have exactly the detected number of columns; a line
//!   that does not, a token that is not a number, or a NaN/infinite coordinate
//!   makes the line invalid: an error naming the line, or skipped and counted with
//!   [`ReadOptions::skip_invalid`].
//!
//! Speed: the file is memory-mapped; each chunk is a window of whole lines, cut
//! into pieces at line boundaries that rayon parses in parallel with
//! `fast_float2::parse_partial`, with no allocation per line. Each piece counts
//! its lines, so error line numbers are exact.

use std::path::{Path, PathBuf};

use memmap2::Mmap;
use rayon::prelude::*;

use super::color::ColorNormalizer;
use super::error::IngestError;
use super::{PointReader, ReadOptions, SourceInfo, canonical_name};
use crate::points::{Attribute, PointColumns};

/// What one column of a line holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Role {
    X,
    Y,
    Z,
    Attr(usize),
    Skip,
}

/// The columns of a line.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Layout {
    pub roles: Vec<Role>,
    pub attr_names: Vec<String>,
}

impl Layout {
    /// Builds a layout from column names (already canonical, `_` = skip).
    /// Errors (as a message) unless x, y and z each appear once.
    pub(crate) fn from_names(names: &[String]) -> Result<Layout, String> {
        let mut roles = Vec::with_capacity(names.len());
        let mut attr_names: Vec<String> = Vec::new();
        let mut seen = [false; 3];
        for n in names {
            let role = match n.as_str() {
                "x" | "y" | "z" => {
                    let a = (n.as_bytes()[0] - b'x') as usize;
                    if seen[a] {
                        return Err(format!("column '{n}' appears twice"));
                    }
                    seen[a] = true;
                    [Role::X, Role::Y, Role::Z][a]
                }
                "_" | "" => Role::Skip,
                other => {
                    if attr_names.iter().any(|a| a == other) {
                        return Err(format!(
                            "column '{}' appears twice",
                            crate::text::sanitize(other)
                        ));
                    }
                    attr_names.push(other.to_string());
                    Role::Attr(attr_names.len() - 1)
                }
            };
            roles.push(role);
        }
        if !seen.iter().all(|&s| s) {
            return Err("the columns must include x, y and z".into());
        }
        Ok(Layout { roles, attr_names })
    }

    /// The default layout for `n` columns (n ≥ 3).
    pub(crate) fn positional(n: usize) -> Layout {
        let names: Vec<String> = match n {
            3 => vec!["x", "y", "z"].into_iter().map(String::from).collect(),
            4 => ["x", "y", "z", "intensity"].map(String::from).to_vec(),
            6 => ["x", "y", "z", "red", "green", "blue"]
                .map(String::from)
                .to_vec(),
            7 => ["x", "y", "z", "intensity", "red", "green", "blue"]
                .map(String::from)
                .to_vec(),
            _ => (0..n)
                .map(|i| match i {
                    0 => "x".to_string(),
                    1 => "y".to_string(),
                    2 => "z".to_string(),
                    i => format!("col{i}"),
                })
                .collect(),
        };
        // Positional names are distinct and contain x y z.
        Layout::from_names(&names).unwrap_or(Layout {
            roles: vec![Role::X, Role::Y, Role::Z],
            attr_names: Vec::new(),
        })
    }

    fn ncols(&self) -> usize {
        self.roles.len()
    }
}

#[inline(always)]
fn is_sep(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b',' | b';' | b'\r')
}

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

/// Powers of ten that are exact in `f64`.
const POW10: [f64; 16] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
];

const POW10_INT: [u64; 16] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
];

/// Parses a number at the start of `s`: returns the value and the bytes used.
///
/// Fast path for plain decimals (`-12.345`, at most 15 significant digits, no
/// exponent): the digits form an exact integer `m < 2^53` and the value is
/// `m / 10^k` with `10^k` exact, which IEEE division rounds correctly (Clinger's
/// fast path), so the result equals a full parser's. Everything else (exponents,
/// long mantissas, `nan`, `inf`) goes to `fast_float2::parse_partial`.
#[inline(always)]
fn parse_number(s: &[u8]) -> Option<(f64, usize)> {
    let mut i = 0;
    let neg = match s.first() {
        Some(b'-') => {
            i = 1;
            true
        }
        Some(b'+') => {
            i = 1;
            false
        }
        _ => false,
    };
    // Integer and fraction digits accumulate separately (two short independent
    // dependency chains instead of one long one).
    let mut mi: u64 = 0;
    let int_start = i;
    while let Some(&c) = s.get(i) {
        let d = c.wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        mi = mi.wrapping_mul(10).wrapping_add(d as u64);
        i += 1;
    }
    let mut digits = i - int_start;
    let mut frac = 0;
    let mut mf: u64 = 0;
    if s.get(i) == Some(&b'.') {
        i += 1;
        let fs = i;
        while let Some(&c) = s.get(i) {
            let d = c.wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            mf = mf.wrapping_mul(10).wrapping_add(d as u64);
            i += 1;
        }
        frac = i - fs;
        digits += frac;
    }
    let exp_follows = matches!(s.get(i), Some(b'e' | b'E'));
    if digits == 0 || digits > 15 || exp_follows {
        return match fast_float2::parse_partial::<f64, _>(s) {
            Ok((v, used)) => Some((v, used)),
            Err(_) => None,
        };
    }
    // m < 10^15 fits in i64, whose conversion to f64 is one instruction.
    let v = if frac == 0 {
        mi as i64 as f64
    } else {
        let m = mi.wrapping_mul(POW10_INT[frac]).wrapping_add(mf);
        m as i64 as f64 / POW10[frac]
    };
    Some((if neg { -v } else { v }, i))
}

/// How a line failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LineFault {
    NotANumber,
    Columns(usize),
    NonFinite,
}

impl LineFault {
    fn message(self, ncols: usize) -> String {
        match self {
            LineFault::NotANumber => "not a number".into(),
            LineFault::Columns(found) => format!("expected {ncols} columns, found {found}"),
            LineFault::NonFinite => "coordinate is not finite (NaN or infinity)".into(),
        }
    }
}

/// The result of parsing one piece of a window.
#[derive(Default)]
struct Piece {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    attrs: Vec<Vec<f32>>,
    /// Lines consumed (complete or not) up to the end of the piece or the error.
    lines: u64,
    skipped: u64,
    /// First invalid line when not skipping: (0-based line index within the piece,
    /// fault, byte range of the line within the piece).
    error: Option<(u64, LineFault, usize, usize)>,
}

/// Parses the lines of `buf` (which ends at a line boundary or at the end of data).
fn parse_piece(
    buf: &[u8],
    layout: &Layout,
    skip_invalid: bool,
    allow_count_lines: bool,
    est_points: usize,
) -> Piece {
    let ncols = layout.ncols();
    let nattr = layout.attr_names.len();
    let mut p = Piece {
        x: super::column_with_capacity(est_points),
        y: super::column_with_capacity(est_points),
        z: super::column_with_capacity(est_points),
        attrs: (0..nattr)
            .map(|_| super::column_with_capacity(est_points))
            .collect(),
        ..Default::default()
    };
    let mut vals = vec![0f64; ncols];
    let n = buf.len();
    let mut i = 0usize;
    while i < n {
        let line_start = i;
        while i < n && matches!(buf[i], b' ' | b'\t' | b'\r') {
            i += 1;
        }
        if i >= n {
            break;
        }
        let c = buf[i];
        if c == b'\n' {
            p.lines += 1;
            i += 1;
            continue;
        }
        if c == b'#' || (c == b'/' && i + 1 < n && buf[i + 1] == b'/') {
            i = match memchr::memchr(b'\n', &buf[i..]) {
                Some(k) => i + k + 1,
                None => n,
            };
            p.lines += 1;
            continue;
        }
        // Parse the tokens of the line.
        let mut col = 0usize;
        let mut fault = None;
        loop {
            match parse_number(&buf[i..]) {
                Some((v, used)) => {
                    if col < ncols {
                        vals[col] = v;
                    }
                    col += 1;
                    i += used;
                }
                None => {
                    fault = Some(LineFault::NotANumber);
                    break;
                }
            }
            let before = i;
            while i < n && is_sep(buf[i]) {
                i += 1;
            }
            if i >= n || buf[i] == b'\n' {
                break;
            }
            if i == before {
                // Garbage glued to a number ("1.5abc").
                fault = Some(LineFault::NotANumber);
                break;
            }
        }
        if fault.is_none() && col != ncols {
            if allow_count_lines && col == 1 && vals[0].fract() == 0.0 && vals[0] >= 0.0 {
                // A PTS scan's point-count line.
                if i < n {
                    i += 1;
                }
                p.lines += 1;
                continue;
            }
            fault = Some(LineFault::Columns(col));
        }
        if fault.is_none() {
            let mut xyz = [0f64; 3];
            for (c, role) in layout.roles.iter().enumerate() {
                match *role {
                    Role::X => xyz[0] = vals[c],
                    Role::Y => xyz[1] = vals[c],
                    Role::Z => xyz[2] = vals[c],
                    Role::Attr(a) => p.attrs[a].push(vals[c] as f32),
                    Role::Skip => {}
                }
            }
            if xyz.iter().all(|v| v.is_finite()) {
                p.x.push(xyz[0]);
                p.y.push(xyz[1]);
                p.z.push(xyz[2]);
                if i < n {
                    i += 1; // the newline
                }
                p.lines += 1;
                continue;
            }
            // Undo the attributes pushed for this line.
            for a in &mut p.attrs {
                a.truncate(p.x.len());
            }
            fault = Some(LineFault::NonFinite);
        }
        // Invalid line.
        let line_end = match memchr::memchr(b'\n', &buf[line_start..]) {
            Some(k) => line_start + k,
            None => n,
        };
        if skip_invalid {
            p.skipped += 1;
            p.lines += 1;
            i = (line_end + 1).min(n);
            continue;
        }
        if let Some(f) = fault {
            p.error = Some((p.lines, f, line_start, line_end));
        }
        return p;
    }
    p
}

/// Concatenates slices, copying them in parallel into their places.
fn concat_par<T: Copy + Default + Send + Sync>(parts: &[&[T]]) -> Vec<T> {
    if parts.len() == 1 {
        return parts[0].to_vec();
    }
    let total = parts.iter().map(|p| p.len()).sum();
    let mut out = super::zeroed_column(total);
    let mut dests = Vec::with_capacity(parts.len());
    let mut rest = &mut out[..];
    for p in parts {
        let (a, b) = rest.split_at_mut(p.len());
        dests.push(a);
        rest = b;
    }
    dests
        .into_par_iter()
        .zip(parts.par_iter())
        .for_each(|(d, s)| d.copy_from_slice(s));
    out
}

/// Average bytes per line over the first 64 KiB from `start` (at least 1): the
/// first window's size estimate.
pub(crate) fn sample_bytes_per_line(data: &[u8], start: usize) -> f64 {
    let start = start.min(data.len());
    let sample = &data[start..data.len().min(start + (64 << 10))];
    let lines = memchr::memchr_iter(b'\n', sample).count().max(1);
    (sample.len() as f64 / lines as f64).max(1.0)
}

/// Smallest piece worth a rayon task, in bytes.
const MIN_PIECE_BYTES: usize = 256 << 10;

/// Reads lines of a memory-mapped region in windows, parsing each window in
/// parallel. Shared by the text reader and the ASCII PLY reader.
pub(crate) struct LineEngine {
    pub path: PathBuf,
    pub layout: Layout,
    /// Next byte to read.
    pub pos: usize,
    /// End of the data.
    pub end: usize,
    /// 1-based number of the line that starts at `pos`.
    pub line: u64,
    /// For ASCII PLY: vertex lines still to read.
    pub lines_left: Option<u64>,
    pub skip_invalid: bool,
    pub allow_count_lines: bool,
    pub chunk_points: usize,
    /// Estimated bytes per line, refined after each window.
    pub bytes_per_line: f64,
    pub skipped: u64,
    pub colors: ColorNormalizer,
    /// Points parsed beyond `chunk_points` in the last window, as chunks of
    /// `chunk_points`, delivered next.
    pub pending: std::collections::VecDeque<PointColumns>,
}

/// Cuts `cols` into chunks of at most `n` points (`n` ≥ 1), in order, copying
/// each point at most once.
fn cut_chunks(mut cols: PointColumns, n: usize) -> Vec<PointColumns> {
    let mut tails = Vec::new();
    while cols.len() > n {
        let at = (cols.len() - 1) / n * n;
        tails.push(PointColumns {
            x: cols.x.split_off(at),
            y: cols.y.split_off(at),
            z: cols.z.split_off(at),
            attributes: cols
                .attributes
                .iter_mut()
                .map(|a| Attribute {
                    name: a.name.clone(),
                    offset: a.offset,
                    values: a.values.split_off(at),
                })
                .collect(),
        });
    }
    tails.push(cols);
    tails.reverse();
    tails
}

impl LineEngine {
    pub(crate) fn next_chunk(&mut self, data: &[u8]) -> Result<Option<PointColumns>, IngestError> {
        let end = self.end.min(data.len());
        if let Some(p) = self.pending.pop_front() {
            return Ok(Some(p));
        }
        loop {
            if self.lines_left == Some(0) {
                return Ok(None);
            }
            if self.pos >= end {
                if let Some(left) = self.lines_left {
                    return Err(IngestError::line(
                        &self.path,
                        self.line,
                        format!("the file ends {left} vertex line(s) early (truncated?)"),
                        b"",
                    ));
                }
                return Ok(None);
            }
            let target =
                ((self.chunk_points as f64) * self.bytes_per_line).clamp(1.0, 1e15) as usize;
            let mut win_end = self.pos.saturating_add(target).min(end);
            if win_end < end {
                win_end = match memchr::memchr(b'\n', &data[win_end..end]) {
                    Some(k) => win_end + k + 1,
                    None => end,
                };
            }
            if let Some(left) = self.lines_left {
                let w = &data[self.pos..win_end];
                if let Some(k) =
                    memchr::memchr_iter(b'\n', w).nth((left - 1).min(usize::MAX as u64) as usize)
                {
                    win_end = self.pos + k + 1;
                }
            }
            let win_len = win_end - self.pos;
            let (cols, lines, skipped) = self.parse_window(&data[self.pos..win_end])?;
            self.pos = win_end;
            self.line += lines;
            self.skipped += skipped;
            if let Some(left) = self.lines_left.as_mut() {
                *left = left.saturating_sub(lines);
            }
            if lines > 0 {
                self.bytes_per_line = (win_len as f64 / lines as f64).max(1.0);
            }
            if let Some(mut cols) = cols {
                self.colors.apply(&mut cols);
                if cols.len() > self.chunk_points {
                    self.pending.extend(cut_chunks(cols, self.chunk_points));
                    return Ok(self.pending.pop_front());
                }
                return Ok(Some(cols));
            }
        }
    }

    /// Parses one window of whole lines: (points or None if the window had none,
    /// lines consumed, lines skipped).
    fn parse_window(&self, w: &[u8]) -> Result<(Option<PointColumns>, u64, u64), IngestError> {
        // Cut the window into pieces at line boundaries.
        let threads = rayon::current_num_threads().max(1);
        let max_pieces = if threads == 1 { 1 } else { threads * 4 };
        let npieces = (w.len() / MIN_PIECE_BYTES).clamp(1, max_pieces);
        let mut bounds = Vec::with_capacity(npieces + 1);
        bounds.push(0usize);
        for k in 1..npieces {
            let guess = w.len() * k / npieces;
            let prev = *bounds.last().unwrap_or(&0);
            if guess <= prev {
                continue;
            }
            let b = match memchr::memchr(b'\n', &w[guess..]) {
                Some(j) => guess + j + 1,
                None => w.len(),
            };
            if b < w.len() && b > prev {
                bounds.push(b);
            }
        }
        bounds.push(w.len());
        let est = |len: usize| ((len as f64 / self.bytes_per_line) * 1.05) as usize + 16;
        let layout = &self.layout;
        let (skip, count) = (self.skip_invalid, self.allow_count_lines);
        let mut pieces: Vec<Piece> = bounds
            .par_windows(2)
            .map(|b| parse_piece(&w[b[0]..b[1]], layout, skip, count, est(b[1] - b[0])))
            .collect();
        let mut lines = 0u64;
        let mut skipped = 0u64;
        for (k, p) in pieces.iter().enumerate() {
            if let Some((idx, fault, s, e)) = p.error {
                let base = bounds[k];
                return Err(IngestError::line(
                    &self.path,
                    self.line + lines + idx,
                    fault.message(layout.ncols()),
                    &w[base + s..base + e],
                ));
            }
            lines += p.lines;
            skipped += p.skipped;
        }
        let total: usize = pieces.iter().map(|p| p.x.len()).sum();
        if total == 0 {
            return Ok((None, lines, skipped));
        }
        if pieces.len() == 1
            && let Some(p) = pieces.pop()
        {
            // One piece: its columns are the chunk, no copy.
            let cols = PointColumns {
                x: p.x,
                y: p.y,
                z: p.z,
                attributes: layout
                    .attr_names
                    .iter()
                    .zip(p.attrs)
                    .map(|(n, v)| Attribute::new(n.clone(), v))
                    .collect(),
            };
            return Ok((Some(cols), lines, skipped));
        }
        let part = |f: fn(&Piece) -> &[f64]| -> Vec<&[f64]> { pieces.iter().map(f).collect() };
        let (x, (y, z)) = rayon::join(
            || concat_par(&part(|p| &p.x)),
            || {
                rayon::join(
                    || concat_par(&part(|p| &p.y)),
                    || concat_par(&part(|p| &p.z)),
                )
            },
        );
        let attributes = layout
            .attr_names
            .par_iter()
            .enumerate()
            .map(|(k, n)| {
                let parts: Vec<&[f32]> = pieces.iter().map(|p| &p.attrs[k][..]).collect();
                Attribute::new(n.clone(), concat_par(&parts))
            })
            .collect();
        let cols = PointColumns {
            x,
            y,
            z,
            attributes,
        };
        Ok((Some(cols), lines, skipped))
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
    tokens(strip_comment_marker(line))
        .map(|t| {
            let s = String::from_utf8_lossy(t);
            let s = s.trim_matches(|c| c == '"' || c == '\'' || c == '/' || c == '#');
            canonical_name(s)
        })
        .collect()
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
            if !numeric {
                if !seen_content {
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
                }
                break;
            }
        }
        pos = next;
        line_no += 1;
    }
    pre
}

/// Reader for text point clouds.
pub struct TextReader {
    info: SourceInfo,
    map: Mmap,
    engine: LineEngine,
    released: usize,
}

impl TextReader {
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<TextReader, IngestError> {
        let map = super::map_file(path)?;
        let data: &[u8] = &map;
        let start = if data.starts_with(b"\xEF\xBB\xBF") {
            3
        } else {
            0
        };
        let pre = scan_preamble(data, start);
        let Some((ncols, first_line, (fs, fe))) = pre.first_data else {
            return Err(IngestError::format(
                path,
                "no point lines found (the file holds only comments, a header or blank lines)",
            ));
        };
        let first_text = &data[fs..fe];
        let layout = if let Some(spec) = &opts.columns {
            let names: Vec<String> = tokens(spec.as_bytes())
                .map(|t| canonical_name(&String::from_utf8_lossy(t)))
                .collect();
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
                Some(h) if h.len() == ncols && has_xyz(h) => {
                    Layout::from_names(h).unwrap_or_else(|_| Layout::positional(ncols))
                }
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
        let engine = LineEngine {
            path: path.to_path_buf(),
            layout: layout.clone(),
            pos: pre.data_start,
            end: data.len(),
            line: pre.data_line,
            lines_left: None,
            skip_invalid: opts.skip_invalid,
            allow_count_lines: ext_pts || pre.count.is_some(),
            chunk_points: opts.chunk_points,
            bytes_per_line: sample_bytes_per_line(data, pre.data_start),
            skipped: 0,
            colors: ColorNormalizer::new(false),
            pending: Default::default(),
        };
        let info = SourceInfo {
            path: path.to_path_buf(),
            format: "text".into(),
            declared_points: pre.count,
            crs_wkt: None,
            attribute_names: layout.attr_names.clone(),
            file_bytes: data.len() as u64,
        };
        Ok(TextReader {
            info,
            map,
            engine,
            released: 0,
        })
    }
}

impl PointReader for TextReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        let r = self.engine.next_chunk(&self.map);
        super::release_consumed(&self.map, &mut self.released, self.engine.pos);
        r
    }

    fn bytes_done(&self) -> u64 {
        self.engine.pos as u64
    }

    fn skipped(&self) -> u64 {
        self.engine.skipped
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
    fn fast_decimal_path_matches_fast_float() {
        use super::parse_number;
        let mut seed = 0x2545F4914F6CDD1Du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let mut cases: Vec<String> = [
            "0",
            "-0",
            "+1",
            "1.",
            ".5",
            "-.5",
            "123456789012345",
            "1234567890123456",
            "0.000000000000001",
            "9007199254740993",
            "1e5",
            "-2.5E-3",
            "nan",
            "inf",
            "-infinity",
            "636123.456",
            "00000000000000000012.5",
            "99999999999999999999999",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        for _ in 0..20_000 {
            let r = next();
            let int = r % 10_000_000;
            let frac_digits = (r >> 40) % 12;
            let frac = (r >> 20) % 10u64.pow(frac_digits as u32).max(1);
            let sign = if r & 1 == 1 { "-" } else { "" };
            cases.push(if frac_digits == 0 {
                format!("{sign}{int}")
            } else {
                format!("{sign}{int}.{frac:0w$}", w = frac_digits as usize)
            });
        }
        for c in &cases {
            for tail in ["", " 7", ",8", "\n"] {
                let s = format!("{c}{tail}");
                let got = parse_number(s.as_bytes());
                let want = fast_float2::parse_partial::<f64, _>(s.as_bytes()).ok();
                match (got, want) {
                    (Some((a, n)), Some((b, m))) => {
                        assert_eq!(n, m, "{s:?}");
                        assert!(
                            a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                            "{s:?}: {a} vs {b}"
                        );
                    }
                    (None, None) => {}
                    (g, w) => panic!("{s:?}: {g:?} vs {w:?}"),
                }
            }
        }
        for bad in ["", "-", "+", ".", "x", "-.", "e5"] {
            assert!(parse_number(bad.as_bytes()).is_none(), "{bad:?}");
        }
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
