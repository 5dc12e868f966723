//! Telling a terminal's answers to the probe's queries (XTVERSION, the kitty
//! graphics query, the cell-size report, DA1) apart from the keys a user typed
//! meanwhile, in whatever order and in whatever pieces they arrive.
//!
//! The scanner is incremental: [`Scanner::feed`] takes the bytes read so far and
//! leaves an unfinished escape sequence for the next read. Everything that is not
//! an answer we asked for is kept, byte for byte, as typed input, so the inspector
//! can act on it (see [`super::typed`]).

use serde::Serialize;

/// The kitty graphics query's image id: answers carrying another id are not ours.
pub(crate) const KITTY_QUERY_ID: u32 = 31;

/// The queries, in the order they are written, DA1 last: every terminal answers
/// DA1, and answers come in order, so once its answer is in all others have come.
pub fn queries() -> String {
    format!("\x1b[>0q\x1b_Gi={KITTY_QUERY_ID},s=1,v=1,a=q,t=d,f=24;AAAA\x1b\\\x1b[16t\x1b[c")
}

/// What the terminal answered.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Replies {
    /// XTVERSION's text (`kitty(0.35.2)`, `XTerm(379)`, `tmux 3.3a`…), sanitized.
    pub xtversion: Option<String>,
    /// The kitty graphics query: `OK`, or the terminal's error text.
    pub kitty: Option<String>,
    /// The cell size in pixels from `CSI 6 ; height ; width t`, as (width, height).
    pub cell_pixels: Option<(u32, u32)>,
    /// DA1's attributes (`CSI ? 62 ; 4 ; 22 c` → `[62, 4, 22]`).
    pub da1: Option<Vec<u16>>,
}

impl Replies {
    /// Whether the kitty graphics query was answered `OK`.
    pub(crate) fn kitty_ok(&self) -> bool {
        self.kitty.as_deref() == Some("OK")
    }

    /// Whether DA1 lists attribute 4 (sixel graphics).
    pub fn sixel(&self) -> bool {
        self.da1.as_ref().is_some_and(|a| a.contains(&4))
    }
}

/// Escape sequences longer than this are not answers: their bytes are input.
const LONGEST_REPLY: usize = 4096;

/// Splits a stream of bytes from the terminal into answers and typed input.
#[derive(Debug, Default)]
pub struct Scanner {
    pub replies: Replies,
    /// Bytes that were not answers (keys typed during the probe), in order.
    pub typed: Vec<u8>,
    /// Every answer recognised, raw, in order of arrival (for `pcimg doctor`).
    pub answers: Vec<Vec<u8>>,
    /// Whether DA1's answer (the fence) has arrived.
    pub fenced: bool,
    pending: Vec<u8>,
}

/// One step of the scan.
enum Step {
    /// An answer of this many bytes.
    Answer(usize),
    /// Input of this many bytes (a key, or an escape sequence we did not ask for).
    Input(usize),
    /// An escape sequence that is not complete yet.
    Incomplete,
}

impl Scanner {
    /// Adds `bytes` read from the terminal. Stops at DA1's answer: what follows it
    /// is typed input.
    pub fn feed(&mut self, bytes: &[u8]) {
        self.pending.extend_from_slice(bytes);
        let buf = std::mem::take(&mut self.pending);
        let mut i = 0;
        while i < buf.len() {
            if self.fenced {
                self.typed.extend_from_slice(&buf[i..]);
                i = buf.len();
                break;
            }
            match self.step(&buf[i..]) {
                Step::Answer(n) => {
                    self.answers.push(buf[i..i + n].to_vec());
                    i += n;
                }
                Step::Input(n) => {
                    self.typed.extend_from_slice(&buf[i..i + n]);
                    i += n;
                }
                Step::Incomplete => break,
            }
        }
        self.pending = buf[i..].to_vec();
    }

    /// Ends the scan: an unfinished sequence left over is typed input (a lone Esc).
    pub fn finish(&mut self) {
        let rest = std::mem::take(&mut self.pending);
        self.typed.extend_from_slice(&rest);
    }

    fn step(&mut self, b: &[u8]) -> Step {
        if b[0] != 0x1b {
            // Plain input up to the next escape.
            let n = b.iter().position(|&c| c == 0x1b).unwrap_or(b.len());
            return Step::Input(n);
        }
        let Some(&kind) = b.get(1) else {
            return Step::Incomplete;
        };
        let outcome = match kind {
            b'P' | b'_' | b']' => string_end(b, kind == b']'),
            b'[' => csi_end(b),
            _ => return Step::Input(1),
        };
        let Some(end) = outcome else {
            return if b.len() > LONGEST_REPLY {
                Step::Input(1)
            } else {
                Step::Incomplete
            };
        };
        let seq = &b[..end];
        if self.recognise(seq, kind) {
            Step::Answer(end)
        } else {
            Step::Input(end)
        }
    }

    /// Records `seq` when it answers one of our queries.
    fn recognise(&mut self, seq: &[u8], kind: u8) -> bool {
        match kind {
            b'P' => {
                let body = string_body(seq);
                if let Some(text) = body.strip_prefix(b">|") {
                    let text = String::from_utf8_lossy(text);
                    self.replies.xtversion = Some(crate::text::sanitize(&text));
                    return true;
                }
                false
            }
            b'_' => {
                let body = string_body(seq);
                let Some(rest) = body.strip_prefix(b"G") else {
                    return false;
                };
                let text = String::from_utf8_lossy(rest);
                let (keys, message) = text.split_once(';').unwrap_or((&text, ""));
                let ours = keys
                    .split(',')
                    .any(|kv| kv == format!("i={KITTY_QUERY_ID}"));
                if ours {
                    self.replies.kitty = Some(crate::text::sanitize(message));
                }
                ours
            }
            b'[' => {
                let params = &seq[2..seq.len() - 1];
                match seq[seq.len() - 1] {
                    b'c' if params.first() == Some(&b'?') => {
                        let attrs = numbers(&params[1..]);
                        self.replies.da1 = Some(attrs);
                        self.fenced = true;
                        true
                    }
                    b't' => match numbers(params).as_slice() {
                        [6, h, w] if *w > 0 && *h > 0 => {
                            self.replies.cell_pixels = Some((*w as u32, *h as u32));
                            true
                        }
                        _ => false,
                    },
                    _ => false,
                }
            }
            _ => false,
        }
    }
}

/// The end (exclusive) of a DCS, APC or OSC string that starts `b`: at ST
/// (`ESC \`), or for OSC also at BEL.
fn string_end(b: &[u8], bel_ends: bool) -> Option<usize> {
    let mut i = 2;
    while i < b.len() {
        match b[i] {
            0x07 if bel_ends => return Some(i + 1),
            0x1b => {
                return match b.get(i + 1) {
                    Some(b'\\') => Some(i + 2),
                    // An escape that does not end the string: the string was cut
                    // short (input, not an answer); it ends before this escape.
                    Some(_) => Some(i),
                    None => None,
                };
            }
            _ => i += 1,
        }
    }
    None
}

/// The text between a string sequence's introducer and its terminator.
fn string_body(seq: &[u8]) -> &[u8] {
    let end = if seq.ends_with(b"\x1b\\") {
        seq.len() - 2
    } else if seq.ends_with(b"\x07") {
        seq.len() - 1
    } else {
        seq.len()
    };
    &seq[2..end.max(2)]
}

/// The end (exclusive) of the CSI sequence that starts `b`: parameters and
/// intermediates, then one final byte.
fn csi_end(b: &[u8]) -> Option<usize> {
    for (i, &c) in b.iter().enumerate().skip(2) {
        match c {
            0x20..=0x3f => {}
            0x40..=0x7e => return Some(i + 1),
            // Not a CSI byte: what came so far was input.
            _ => return Some(i),
        }
    }
    None
}

/// The decimal numbers of a parameter string (`62;4;22` → `[62, 4, 22]`).
fn numbers(params: &[u8]) -> Vec<u16> {
    params
        .split(|&c| c == b';' || c == b':')
        .filter_map(|p| std::str::from_utf8(p).ok()?.parse().ok())
        .collect()
}

/// `bytes` as printable text: escapes and control bytes as `\e`, `\x07`…
/// (for `pcimg doctor`, which prints what the terminal sent).
pub fn escaped(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len() * 2);
    for &c in bytes {
        match c {
            0x1b => s.push_str("\\e"),
            b'\\' => s.push_str("\\\\"),
            0x20..=0x7e => s.push(c as char),
            _ => s.push_str(&format!("\\x{c:02x}")),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(chunks: &[&[u8]]) -> Scanner {
        let mut s = Scanner::default();
        for c in chunks {
            s.feed(c);
        }
        s.finish();
        s
    }

    #[test]
    fn answers_are_parsed_and_keys_kept_in_order() {
        let s = scan(&[
            b"j\x1bP>|kitty(0.35.2)\x1b\\\x1b_Gi=31;OK\x1b\\",
            b"k\x1b[6;20;10t\x1b[?62;4;22c",
            b"q",
        ]);
        assert_eq!(s.replies.xtversion.as_deref(), Some("kitty(0.35.2)"));
        assert!(s.replies.kitty_ok());
        assert_eq!(s.replies.cell_pixels, Some((10, 20)));
        assert_eq!(s.replies.da1, Some(vec![62, 4, 22]));
        assert!(s.replies.sixel() && s.fenced);
        assert_eq!(s.typed, b"jkq");
        assert_eq!(s.answers.len(), 4);
    }

    #[test]
    fn answers_split_across_reads_and_arrow_keys_are_input() {
        let all: &[u8] = b"\x1b[A\x1bP>|XTerm(379)\x1b\\\x1b[?63;1;2;4;6;9;15;16;22;28c";
        // Every split point gives the same result.
        for cut in 0..all.len() {
            let s = scan(&[&all[..cut], &all[cut..]]);
            assert_eq!(s.replies.xtversion.as_deref(), Some("XTerm(379)"), "{cut}");
            assert!(s.replies.sixel(), "{cut}");
            assert_eq!(s.typed, b"\x1b[A", "{cut}");
        }
    }

    #[test]
    fn a_kitty_error_and_other_ids_and_a_lone_escape() {
        let s = scan(&[b"\x1b_Gi=7;OK\x1b\\\x1b_Gi=31;ENOTSUPPORTED:no\x1b\\\x1b[?1;2c\x1b"]);
        assert_eq!(s.replies.kitty.as_deref(), Some("ENOTSUPPORTED:no"));
        assert!(!s.replies.kitty_ok() && !s.replies.sixel());
        // Another program's kitty answer is input; so is the Esc after the fence.
        assert_eq!(s.typed, b"\x1b_Gi=7;OK\x1b\\\x1b");
    }

    #[test]
    fn hostile_text_is_sanitized_and_junk_is_bounded() {
        let s = scan(&[b"\x1bP>|evil\x07\x9b2J\x1b\\"]);
        let v = s.replies.xtversion.unwrap();
        assert!(!v.contains('\x07') && !v.contains('\u{9b}'), "{v:?}");
        let mut junk = b"\x1bP".to_vec();
        junk.extend(std::iter::repeat_n(b'x', 5000));
        let s = scan(&[&junk]);
        assert_eq!(s.typed.len(), junk.len());
        assert_eq!(s.replies, Replies::default());
    }

    #[test]
    fn queries_end_with_da1() {
        let q = queries();
        assert!(q.starts_with("\x1b[>0q") && q.ends_with("\x1b[c"));
        assert_eq!(escaped(b"\x1b[c\x07\\"), "\\e[c\\x07\\\\");
    }
}
