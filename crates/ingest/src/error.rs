//! `IngestError`: the one error type of the input readers.
//!
//! Every message names the file, and where the problem sits in it: the line number
//! for line-oriented inputs (text, ASCII PLY) or the byte offset for binary inputs
//! (binary PLY, LAS/LAZ). Text taken from the file is sanitized (control characters
//! replaced) and truncated, so an error message can be printed to a terminal safely.

use std::path::{Path, PathBuf};

/// Longest excerpt of file content shown in an error message, in characters.
pub const EXCERPT_CHARS: usize = 80;

/// An error while detecting, opening or reading an input point cloud.
#[derive(Debug, thiserror::Error)]
pub enum IngestError {
    /// The operating system refused an operation (open, stat, map, read).
    // The OS error is part of the message, not a `source`: the CLI prints the
    // whole chain, and it would appear twice.
    #[error("{}: {what}: {error}", show_path(path))]
    Io {
        path: PathBuf,
        what: String,
        error: std::io::Error,
    },
    /// A line of a line-oriented input could not be read.
    #[error("{}: line {line}: {msg}{}", show_path(path), quoted(text))]
    Line {
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        msg: String,
        /// The offending line, sanitized and truncated.
        text: String,
    },
    /// A problem at a byte position of a binary input.
    #[error("{}: byte offset {offset}: {msg}", show_path(path))]
    Binary {
        path: PathBuf,
        offset: u64,
        msg: String,
    },
    /// The file as a whole cannot be read: unknown format, empty file, bad options.
    #[error("{}: {msg}", show_path(path))]
    Format { path: PathBuf, msg: String },
    /// A text input's columns cannot be named from the file alone (its header
    /// disagrees with its lines, names a column twice, or it has more columns than
    /// a part stores): the caller's column layout ([`crate::ReadOptions`]'s
    /// `columns`, where `_` skips a column) would.
    #[error("{}: {}{msg}{}", show_path(path), at_line(*line), quoted(text))]
    Columns {
        path: PathBuf,
        /// 1-based line number, where one line shows it.
        line: Option<u64>,
        msg: String,
        /// That line, sanitized and truncated (empty without a line).
        text: String,
    },
}

impl IngestError {
    pub(crate) fn io(path: &Path, what: impl Into<String>, source: std::io::Error) -> Self {
        IngestError::Io {
            path: path.to_path_buf(),
            what: what.into(),
            error: source,
        }
    }

    /// An error on line `line` (1-based) whose content is `text` (raw bytes).
    pub(crate) fn line(path: &Path, line: u64, msg: impl Into<String>, text: &[u8]) -> Self {
        IngestError::Line {
            path: path.to_path_buf(),
            line,
            msg: msg.into(),
            text: excerpt(text),
        }
    }

    pub(crate) fn binary(path: &Path, offset: u64, msg: impl Into<String>) -> Self {
        IngestError::Binary {
            path: path.to_path_buf(),
            offset,
            msg: msg.into(),
        }
    }

    pub(crate) fn format(path: &Path, msg: impl Into<String>) -> Self {
        IngestError::Format {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// A text input's columns that need naming; `at`: the line that shows it.
    pub(crate) fn columns(path: &Path, at: Option<(u64, &[u8])>, msg: impl Into<String>) -> Self {
        IngestError::Columns {
            path: path.to_path_buf(),
            line: at.map(|a| a.0),
            msg: msg.into(),
            text: at.map(|a| excerpt(a.1)).unwrap_or_default(),
        }
    }

    /// The 1-based line number, for line errors.
    pub fn line_number(&self) -> Option<u64> {
        match self {
            IngestError::Line { line, .. } => Some(*line),
            IngestError::Columns { line, .. } => *line,
            _ => None,
        }
    }

    /// The byte offset, for binary errors.
    pub fn byte_offset(&self) -> Option<u64> {
        match self {
            IngestError::Binary { offset, .. } => Some(*offset),
            _ => None,
        }
    }
}

/// `line N: `, or nothing.
fn at_line(line: Option<u64>) -> String {
    line.map(|l| format!("line {l}: ")).unwrap_or_default()
}

/// `: "text"`, or nothing for no text (an error at the end of the file).
fn quoted(text: &str) -> String {
    if text.is_empty() {
        String::new()
    } else {
        format!(": \"{text}\"")
    }
}

pub(crate) fn show_path(p: &Path) -> String {
    pcimg_core::text::sanitize(&p.display().to_string())
}

/// Sanitized, truncated excerpt of raw file bytes (lossy UTF-8, line ending removed,
/// control characters replaced, at most [`EXCERPT_CHARS`] characters plus "…").
pub(crate) fn excerpt(raw: &[u8]) -> String {
    let cut = &raw[..raw.len().min(EXCERPT_CHARS * 4)];
    let s = String::from_utf8_lossy(cut);
    let s = s.trim_end_matches(['\n', '\r']);
    // (Tabs separate columns: shown as a space, not as a replaced control.)
    let mut out: String = s
        .chars()
        .take(EXCERPT_CHARS)
        .map(|c| if c == '\t' { ' ' } else { c })
        .collect();
    let truncated = s.chars().count() > EXCERPT_CHARS || cut.len() < raw.len();
    out = pcimg_core::text::sanitize(&out);
    if truncated {
        out.push('…');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn excerpt_sanitizes_and_truncates() {
        let long = vec![b'a'; 500];
        let e = excerpt(&long);
        assert_eq!(e.chars().count(), EXCERPT_CHARS + 1);
        assert!(e.ends_with('…'));
        let e = excerpt(b"1 2 \x1b[2J3\r\n");
        assert!(!e.chars().any(|c| c.is_control()));
        assert_eq!(excerpt(b"1\t2\t3\n"), "1 2 3");
        assert!(e.starts_with("1 2 "));
    }

    #[test]
    fn display_names_file_and_line() {
        let e = IngestError::line(Path::new("/tmp/a.xyz"), 7, "bad number", b"1 2 x\n");
        let s = e.to_string();
        assert!(s.contains("/tmp/a.xyz") && s.contains("line 7") && s.contains("1 2 x"));
        let e = IngestError::binary(Path::new("b.ply"), 1234, "truncated");
        assert!(e.to_string().contains("byte offset 1234"));
    }
}
