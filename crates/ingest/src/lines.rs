//! The parallel line engine shared by the text reader and the ASCII PLY reader:
//! column layouts, the number parser, windows of whole lines cut into pieces that
//! rayon parses in parallel, and chunking.
//!
//! * Columns are separated by runs of spaces, tabs, commas or semicolons; `\r` is
//!   a separator too, so `\r\n` line endings need no special case.
//! * Lines starting with `#` or `//` (after optional blanks) and blank lines are
//!   skipped (and counted, so line numbers stay exact).
//! * Numbers: a fast path for plain decimals that gives the same bits as a full
//!   parser (`parse_number`), `fast_float2::parse_partial` for the rest.
//! * A window is about `chunk_points` lines (estimated from the bytes per line
//!   seen so far), cut at line boundaries into pieces for rayon; each piece
//!   counts its lines, so the line number of an invalid line is exact whatever
//!   the piece it falls in. No allocation per line.
//! * Chunks never exceed `chunk_points`: when a window holds more points, the
//!   rest is cut into chunks delivered next.

use crate::bigvec;
use std::mem::MaybeUninit;
use std::path::PathBuf;

use rayon::prelude::*;

use super::color::ColorNormalizer;
use super::error::IngestError;
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
    /// Each attribute's offset (values are stored relative to it; see
    /// [`super::attribute_offset`]), zero until [`Layout::decide_offsets`].
    pub offsets: Vec<f64>,
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
                            pcimg_core::text::sanitize(other)
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
        let offsets = vec![0.0; attr_names.len()];
        Ok(Layout {
            roles,
            attr_names,
            offsets,
        })
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
            offsets: Vec::new(),
        })
    }

    pub(crate) fn ncols(&self) -> usize {
        self.roles.len()
    }

    /// Decides the attributes' offsets from the first point lines of `data` (up
    /// to [`super::OFFSET_SAMPLE`] of them and `max_lines`; lines that are not
    /// points are passed).
    pub(crate) fn decide_offsets(&mut self, data: &[u8], max_lines: u64) {
        let mut seen: Vec<Vec<f64>> = vec![Vec::new(); self.attr_names.len()];
        let mut vals = Vec::with_capacity(self.ncols());
        let lines = (super::OFFSET_SAMPLE as u64).min(max_lines) as usize;
        for line in data.split(|&c| c == b'\n').take(lines) {
            vals.clear();
            let mut rest = line;
            loop {
                let skip = rest.iter().position(|&c| !is_sep(c)).unwrap_or(rest.len());
                rest = &rest[skip..];
                if rest.is_empty() {
                    break;
                }
                match parse_number(rest) {
                    Some((v, used)) if used > 0 => {
                        vals.push(v);
                        rest = &rest[used..];
                    }
                    _ => break,
                }
            }
            if vals.len() != self.ncols() || !rest.is_empty() {
                continue;
            }
            for (c, role) in self.roles.iter().enumerate() {
                if let Role::Attr(a) = *role {
                    seen[a].push(vals[c]);
                }
            }
        }
        self.offsets = seen
            .iter_mut()
            .zip(&self.attr_names)
            .map(|(v, name)| super::attribute_offset(v, name == "gps_time"))
            .collect();
    }
}

impl Layout {
    /// The decimals the first point lines of `data` (up to
    /// [`super::OFFSET_SAMPLE`] of them) write each coordinate with: the most
    /// on each axis, `None` when a coordinate uses an exponent or more than 9
    /// decimals (no lattice to keep). A file whose later lines carry more
    /// decimals is caught by the store, which keeps a lattice only when every
    /// point lies on it.
    pub(crate) fn coordinate_decimals(&self, data: &[u8]) -> Option<[u32; 3]> {
        let mut most = [0u32; 3];
        let mut seen = 0usize;
        for line in data.split(|&c| c == b'\n').take(super::OFFSET_SAMPLE) {
            let fields: Vec<&[u8]> = line
                .split(|&c| is_sep(c))
                .filter(|f| !f.is_empty())
                .collect();
            if fields.len() != self.ncols() || parse_number(fields[0]).is_none() {
                continue;
            }
            for (f, role) in fields.iter().zip(&self.roles) {
                let axis = match role {
                    Role::X => 0,
                    Role::Y => 1,
                    Role::Z => 2,
                    _ => continue,
                };
                if f.iter().any(|&c| c == b'e' || c == b'E') {
                    return None;
                }
                let d = f.iter().position(|&c| c == b'.').map_or(0, |p| {
                    f[p + 1..].iter().take_while(|c| c.is_ascii_digit()).count()
                });
                if d > 9 {
                    return None;
                }
                most[axis] = most[axis].max(d as u32);
            }
            seen += 1;
        }
        (seen > 0).then_some(most)
    }
}

#[inline(always)]
pub(crate) fn is_sep(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b',' | b';' | b'\r')
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
pub(crate) fn parse_number(s: &[u8]) -> Option<(f64, usize)> {
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
    /// Two delimiters (`,` or `;`) in a row: a column left empty.
    EmptyField,
    /// A blank or comment line where every line is an item (ASCII PLY).
    NotAnItem,
}

impl LineFault {
    fn message(self, ncols: usize) -> String {
        match self {
            LineFault::NotANumber => "not a number".into(),
            LineFault::Columns(found) => format!("expected {ncols} columns, found {found}"),
            LineFault::NonFinite => "coordinate is not finite (NaN or infinity)".into(),
            LineFault::EmptyField => "a column is empty (two delimiters in a row)".into(),
            LineFault::NotAnItem => {
                "a blank or comment line where the header declares a vertex (PLY has one \
                 vertex a line)"
                    .into()
            }
        }
    }
}

/// The result of parsing one piece of a window.
#[derive(Default)]
struct Piece {
    /// Points written at the start of the piece's output slices.
    points: usize,
    /// Lines consumed (complete or not) up to the end of the piece or the error.
    lines: u64,
    skipped: u64,
    /// Points that the piece's PTS count lines declare.
    declared: u64,
    /// First invalid line when not skipping: (0-based line index within the piece,
    /// fault, byte range of the line within the piece).
    error: Option<(u64, LineFault, usize, usize)>,
}

/// Where one piece's points go: its slots of the window's columns, at least one
/// per line of the piece.
struct Out<'a> {
    x: &'a mut [MaybeUninit<f64>],
    y: &'a mut [MaybeUninit<f64>],
    z: &'a mut [MaybeUninit<f64>],
    attrs: Vec<&'a mut [MaybeUninit<f32>]>,
}

/// Lines in `buf`, counting a last line without its newline: an upper bound of
/// the points it holds.
fn count_lines(buf: &[u8]) -> usize {
    let newlines = memchr::memchr_iter(b'\n', buf).count();
    newlines + usize::from(buf.last().is_some_and(|&c| c != b'\n'))
}

/// Parses the lines of `buf` (which ends at a line boundary or at the end of data)
/// into `out`, which has a slot for every line. With `items` (ASCII PLY, whose
/// header counts the vertex lines) a blank or comment line is an error even when
/// skipping invalid lines: passed over, it would take a vertex's place in the count.
fn parse_piece(
    buf: &[u8],
    layout: &Layout,
    skip_invalid: bool,
    allow_count_lines: bool,
    items: bool,
    out: &mut Out,
) -> Piece {
    let ncols = layout.ncols();
    let mut p = Piece::default();
    let mut k = 0usize; // next output slot
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
        let comment = c == b'#' || (c == b'/' && i + 1 < n && buf[i + 1] == b'/');
        if items && (c == b'\n' || comment) {
            let end = memchr::memchr(b'\n', &buf[line_start..]).map_or(n, |k| line_start + k);
            p.error = Some((p.lines, LineFault::NotAnItem, line_start, end));
            break;
        }
        if c == b'\n' {
            p.lines += 1;
            i += 1;
            continue;
        }
        if comment {
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
            let mut delimiters = 0u32;
            while i < n && is_sep(buf[i]) {
                delimiters += matches!(buf[i], b',' | b';') as u32;
                i += 1;
            }
            if delimiters > 1 {
                fault = Some(LineFault::EmptyField);
                break;
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
                p.declared = p.declared.saturating_add(vals[0] as u64);
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
                    // (An attribute written for a line that turns out invalid is
                    // overwritten by the next point.)
                    Role::Attr(a) => {
                        out.attrs[a][k].write((vals[c] - layout.offsets[a]) as f32);
                    }
                    Role::Skip => {}
                }
            }
            if xyz.iter().all(|v| v.is_finite()) {
                out.x[k].write(xyz[0]);
                out.y[k].write(xyz[1]);
                out.z[k].write(xyz[2]);
                k += 1;
                if i < n {
                    i += 1; // the newline
                }
                p.lines += 1;
                continue;
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
        break;
    }
    p.points = k;
    p
}

/// Splits the first `total` slots of `v`'s spare capacity into pieces of `sizes`.
fn split_spare<'a, T>(v: &'a mut Vec<T>, sizes: &[usize]) -> Vec<&'a mut [MaybeUninit<T>]> {
    let total: usize = sizes.iter().sum();
    let mut rest = &mut v.spare_capacity_mut()[..total];
    sizes
        .iter()
        .map(|&len| {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(len);
            rest = b;
            a
        })
        .collect()
}

/// Closes the gaps that pieces with fewer points than lines left: moves each
/// piece's points right after the previous piece's and sets the length.
/// `slots`: each piece's slot count; `points`: the points it wrote.
fn close_gaps<T: Copy>(v: &mut Vec<T>, slots: &[usize], points: &[usize]) {
    let mut from = 0usize;
    let mut to = 0usize;
    let base = v.as_mut_ptr();
    for (&s, &p) in slots.iter().zip(points) {
        if from != to && p > 0 {
            // SAFETY: the `p` initialized values at `from` move down to `to`
            // (< from), inside the capacity; `copy` allows overlap.
            unsafe { std::ptr::copy(base.add(from), base.add(to), p) };
        }
        from += s;
        to += p;
    }
    // SAFETY: slots 0..to now hold initialized values (the pieces' points).
    unsafe { v.set_len(to) };
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
    /// For ASCII PLY: the elements after the vertex element (name, lines, and
    /// which of its properties are lists), checked to be whole once the vertices
    /// are read (a file cut short there is an error).
    pub after: Vec<(String, u64, Vec<bool>)>,
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
    /// Sampling (text only, see [`LineEngine::sample_rest`]): each window is read
    /// from pieces spread over a stretch this many times its size.
    pub sample: Option<u64>,
    /// PTS: the points that the file's count lines declare (the first, then those
    /// of the scans it concatenates), when it starts with one; a full read that
    /// finds fewer is an error (a file cut at a line's end).
    pub declared: Option<u64>,
    /// Point lines read so far (points and skipped lines), in a full read.
    pub point_lines: u64,
}

/// One parsed window or set of pieces.
struct Parsed {
    /// The points, or None if there were none.
    cols: Option<PointColumns>,
    /// Lines consumed.
    lines: u64,
    /// Lines skipped as invalid.
    skipped: u64,
    /// Points that count lines among them declare.
    declared: u64,
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

/// Whether an ASCII PLY item line holds every value of its element's properties
/// (`lists[k]`: property k is a list, whose first value counts its items).
fn item_is_whole(line: &[u8], lists: &[bool]) -> bool {
    let mut toks = line
        .split(|c| c.is_ascii_whitespace())
        .filter(|t| !t.is_empty());
    for &list in lists {
        let Some(t) = toks.next() else { return false };
        if list {
            let n = std::str::from_utf8(t)
                .ok()
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| *v >= 0.0 && v.fract() == 0.0);
            let Some(n) = n else { return false };
            if toks.by_ref().take(n as usize).count() < n as usize {
                return false;
            }
        }
    }
    true
}

impl LineEngine {
    /// From here on, parse only about one line in `every`: each window is made of
    /// pieces spread evenly over a stretch `every` windows long, their malformed
    /// lines skipped (a full pass that follows reports them; line numbers are not
    /// kept from here on). Returns false, changing nothing, for a PLY vertex
    /// section, whose end is found by counting lines.
    pub(crate) fn sample_rest(&mut self, every: u64) -> bool {
        if self.lines_left.is_some() || every < 2 {
            return false;
        }
        self.sample = Some(every);
        true
    }

    /// One sampled window (see [`LineEngine::sample_rest`]) from `pos`.
    fn next_sampled(
        &mut self,
        data: &[u8],
        end: usize,
        every: u64,
    ) -> Result<Option<PointColumns>, IngestError> {
        let line_end = |at: usize| -> usize {
            if at >= end {
                return end;
            }
            match memchr::memchr(b'\n', &data[at..end]) {
                Some(k) => at + k + 1,
                None => end,
            }
        };
        while self.pos < end {
            let target = ((self.chunk_points as f64) * self.bytes_per_line).clamp(1.0, 1e15);
            // Many small pieces, each at a random place in its slot: a stretch of
            // `every` windows is `pieces` slots, each read for `1 / every` of it
            // (at least a line). The last stretch may hold fewer slots.
            let pieces = rayon::current_num_threads().max(1) * 32;
            let slot = ((target * every as f64 / pieces as f64) as usize).max(1);
            let piece_len = (slot / every as usize).max(1);
            let stretch_end = line_end(self.pos.saturating_add(slot.saturating_mul(pieces)));
            let mut ranges: Vec<&[u8]> = Vec::with_capacity(pieces);
            let mut prev = self.pos;
            for j in 0..(stretch_end - self.pos).div_ceil(slot) {
                let jitter = super::mix((self.pos + j) as u64) as usize % (slot - piece_len + 1);
                let guess = (self.pos + slot * j + jitter).min(stretch_end);
                // Each piece starts at a line start and ends at a line end, after
                // the previous piece.
                let start = if guess == self.pos {
                    self.pos
                } else {
                    line_end(guess - 1)
                }
                .max(prev);
                let stop = line_end(start + piece_len - 1).min(stretch_end);
                if stop > start {
                    ranges.push(&data[start..stop]);
                    prev = stop;
                }
            }
            let parsed: usize = ranges.iter().map(|r| r.len()).sum();
            let Parsed { cols, lines, .. } = self.parse_ranges(&ranges, true)?;
            self.pos = stretch_end;
            if lines > 0 {
                self.bytes_per_line = (parsed as f64 / lines as f64).max(1.0);
            }
            if let Some(mut cols) = cols {
                self.colors.apply(&mut cols);
                return Ok(Some(cols));
            }
        }
        Ok(None)
    }

    /// Checks (once) that the lines of the elements after the vertex element are
    /// all there.
    fn check_after(&mut self, data: &[u8], end: usize) -> Result<(), IngestError> {
        let after = std::mem::take(&mut self.after);
        let wanted: u64 = after.iter().map(|(_, n, _)| n).sum();
        if wanted == 0 {
            return Ok(());
        }
        // Lines with something on them (a blank line is not an item).
        let rest = &data[self.pos.min(end)..end];
        let mut have = 0u64;
        let mut last: &[u8] = b"";
        for l in rest
            .split(|&c| c == b'\n')
            .filter(|l| !l.trim_ascii().is_empty())
            .take(wanted as usize)
        {
            have += 1;
            last = l;
        }
        // The file ends on the line after its last one (counted for errors only).
        let lines = || {
            memchr::memchr_iter(b'\n', rest).count() as u64
                + rest.last().is_some_and(|&c| c != b'\n') as u64
        };
        if have >= wanted {
            // Every line is there; the last could still be cut inside (a file
            // cut short mid-line): it must hold its element's values.
            let Some((name, _, lists)) = after.iter().rev().find(|(_, n, _)| *n > 0) else {
                return Ok(());
            };
            if item_is_whole(last, lists) {
                return Ok(());
            }
            return Err(IngestError::line(
                &self.path,
                self.line + lines(),
                format!(
                    "truncated file: the last line of element '{}' ends before the values \
                     its properties declare",
                    pcimg_core::text::sanitize(name)
                ),
                last,
            ));
        }
        let mut before = 0;
        let (name, _, _) = after
            .iter()
            .find(|(_, n, _)| {
                before += n;
                before > have
            })
            .unwrap_or(&after[after.len() - 1]);
        Err(IngestError::line(
            &self.path,
            self.line + lines(),
            format!(
                "truncated file: the file ends inside element '{}' ({} of the {} lines \
                 the header declares after the vertices are missing)",
                pcimg_core::text::sanitize(name),
                wanted - have,
                wanted
            ),
            b"",
        ))
    }

    pub(crate) fn next_chunk(&mut self, data: &[u8]) -> Result<Option<PointColumns>, IngestError> {
        let end = self.end.min(data.len());
        if let Some(p) = self.pending.pop_front() {
            return Ok(Some(p));
        }
        if let Some(every) = self.sample {
            return self.next_sampled(data, end, every);
        }
        loop {
            if self.lines_left == Some(0) {
                self.check_after(data, end)?;
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
                if let Some(d) = self.declared.filter(|&d| self.point_lines < d) {
                    return Err(IngestError::line(
                        &self.path,
                        self.line,
                        format!(
                            "the file ends after {} of the {} points its count line(s) \
                             declare (truncated?); to read what is there, correct the \
                             count line(s)",
                            pcimg_core::text::count(self.point_lines),
                            pcimg_core::text::count(d)
                        ),
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
            let Parsed {
                cols,
                lines,
                skipped,
                declared,
            } = self.parse_window(&data[self.pos..win_end])?;
            self.pos = win_end;
            self.point_lines += cols.as_ref().map_or(0, |c| c.len() as u64) + skipped;
            if let Some(d) = self.declared.as_mut() {
                *d = d.saturating_add(declared);
            }
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

    /// Parses one window of whole lines.
    fn parse_window(&self, w: &[u8]) -> Result<Parsed, IngestError> {
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
        let ranges: Vec<&[u8]> = bounds.windows(2).map(|b| &w[b[0]..b[1]]).collect();
        self.parse_ranges(&ranges, self.skip_invalid)
    }

    /// Parses `ranges` (each whole lines, in order, the first starting at line
    /// `self.line`) in parallel into one set of columns.
    fn parse_ranges(&self, ranges: &[&[u8]], skip: bool) -> Result<Parsed, IngestError> {
        let layout = &self.layout;
        let count = self.allow_count_lines;
        let items = self.lines_left.is_some();
        // A slot per line, so the pieces parse straight into the window's columns.
        let slots: Vec<usize> = ranges.par_iter().map(|r| count_lines(r)).collect();
        let total_slots: usize = slots.iter().sum();
        let nattr = layout.attr_names.len();
        let mut x: Vec<f64> = bigvec::with_capacity(total_slots);
        let mut y: Vec<f64> = bigvec::with_capacity(total_slots);
        let mut z: Vec<f64> = bigvec::with_capacity(total_slots);
        let mut attrs: Vec<Vec<f32>> = (0..nattr)
            .map(|_| bigvec::with_capacity(total_slots))
            .collect();
        let pieces: Vec<Piece> = {
            let mut xs = split_spare(&mut x, &slots).into_iter();
            let mut ys = split_spare(&mut y, &slots).into_iter();
            let mut zs = split_spare(&mut z, &slots).into_iter();
            let mut per_attr: Vec<_> = attrs
                .iter_mut()
                .map(|a| split_spare(a, &slots).into_iter())
                .collect();
            let outs: Vec<Out> = (0..ranges.len())
                .map(|_| Out {
                    x: xs.next().unwrap_or_default(),
                    y: ys.next().unwrap_or_default(),
                    z: zs.next().unwrap_or_default(),
                    attrs: per_attr
                        .iter_mut()
                        .map(|a| a.next().unwrap_or_default())
                        .collect(),
                })
                .collect();
            ranges
                .par_iter()
                .zip(outs)
                .map(|(r, mut o)| parse_piece(r, layout, skip, count, items, &mut o))
                .collect()
        };
        let mut lines = 0u64;
        let mut skipped = 0u64;
        let declared = pieces
            .iter()
            .fold(0u64, |a, p| a.saturating_add(p.declared));
        for (k, p) in pieces.iter().enumerate() {
            if let Some((idx, fault, s, e)) = p.error {
                return Err(IngestError::line(
                    &self.path,
                    self.line + lines + idx,
                    fault.message(layout.ncols()),
                    &ranges[k][s..e],
                ));
            }
            lines += p.lines;
            skipped += p.skipped;
        }
        let points: Vec<usize> = pieces.iter().map(|p| p.points).collect();
        if points.iter().sum::<usize>() == 0 {
            return Ok(Parsed {
                cols: None,
                lines,
                skipped,
                declared,
            });
        }
        close_gaps(&mut x, &slots, &points);
        close_gaps(&mut y, &slots, &points);
        close_gaps(&mut z, &slots, &points);
        for a in &mut attrs {
            close_gaps(a, &slots, &points);
        }
        let cols = PointColumns {
            x,
            y,
            z,
            attributes: layout
                .attr_names
                .iter()
                .zip(attrs)
                .zip(&layout.offsets)
                .map(|((n, values), &offset)| Attribute {
                    name: n.clone(),
                    offset,
                    values,
                })
                .collect(),
        };
        Ok(Parsed {
            cols: Some(cols),
            lines,
            skipped,
            declared,
        })
    }
}

/// A reader of line-oriented points (text files, ASCII PLY vertex lines): the
/// memory map, the line engine over it, and the consumed-page release.
pub(crate) struct LineReader {
    pub(crate) info: super::SourceInfo,
    pub(crate) map: std::sync::Arc<memmap2::Mmap>,
    pub(crate) engine: LineEngine,
    pub(crate) released: usize,
    /// Reading ahead of the parsers while every line is read.
    ahead: super::ahead::Ahead,
    /// Bytes the last chunk took (how far ahead to read).
    last_chunk: usize,
}

impl LineReader {
    pub(crate) fn new(info: super::SourceInfo, map: memmap2::Mmap, engine: LineEngine) -> Self {
        let map = std::sync::Arc::new(map);
        let ahead = super::ahead::Ahead::new(map.clone(), engine.pos as u64, map.len() as u64);
        LineReader {
            info,
            map,
            engine,
            released: 0,
            ahead,
            last_chunk: 0,
        }
    }
}

impl super::PointReader for LineReader {
    fn info(&self) -> &super::SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        // This chunk and the next are asked for while this one is parsed (the
        // first chunk's size is not known: 8 MiB). Pages read ahead are mapped,
        // so they count in the resident size: the span follows the chunks,
        // which the memory budget sizes.
        let from = self.engine.pos;
        self.ahead
            .want((from + 2 * self.last_chunk.max(4 << 20)) as u64);
        let r = self.engine.next_chunk(&self.map);
        self.last_chunk = self.engine.pos.saturating_sub(from);
        super::release_consumed(&self.map, &mut self.released, self.engine.pos);
        r
    }

    fn bytes_done(&self) -> u64 {
        self.engine.pos as u64
    }

    fn skipped(&self) -> u64 {
        self.engine.skipped
    }

    fn clamped_colours(&self) -> u64 {
        self.engine
            .colors
            .clamped()
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    fn sample_rest(&mut self, every: u64) -> bool {
        let sampling = self.engine.sample_rest(every);
        // Sampled windows are sparse: reading everything ahead would be waste.
        if sampling {
            self.ahead.stop();
        }
        sampling
    }
}

#[cfg(test)]
mod tests {
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
}
