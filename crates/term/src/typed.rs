//! Keys typed while the terminal was being probed, turned into the key events
//! crossterm would have read, so that nothing a user typed during start-up is lost.
//!
//! The probe reads every byte the terminal sends until DA1's answer; the keys among
//! them would otherwise be gone (crossterm reads only what is still unread). This
//! decodes what keyboards send in the modes the inspector uses: printable text
//! (UTF-8), control keys, and the common CSI / SS3 sequences for arrows, Home, End,
//! Page Up/Down, Insert, Delete and F1–F4.

use crossterm::event::{KeyCode, KeyEvent, KeyModifiers};

/// The key events in `bytes`, in order. Sequences not understood are dropped.
pub fn key_events(bytes: &[u8]) -> Vec<KeyEvent> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let (event, n) = one(&bytes[i..]);
        out.extend(event);
        i += n.max(1);
    }
    out
}

fn key(code: KeyCode, modifiers: KeyModifiers) -> Option<KeyEvent> {
    Some(KeyEvent::new(code, modifiers))
}

/// One key from the start of `b`, and how many bytes it took.
fn one(b: &[u8]) -> (Option<KeyEvent>, usize) {
    let none = KeyModifiers::NONE;
    match b[0] {
        0x1b => escape(b),
        b'\r' | b'\n' => (key(KeyCode::Enter, none), 1),
        b'\t' => (key(KeyCode::Tab, none), 1),
        0x7f | 0x08 => (key(KeyCode::Backspace, none), 1),
        0 => (key(KeyCode::Char(' '), KeyModifiers::CONTROL), 1),
        c @ 0x01..=0x1a => (
            key(KeyCode::Char((c - 1 + b'a') as char), KeyModifiers::CONTROL),
            1,
        ),
        0x1c..=0x1f => (None, 1),
        _ => {
            let len = utf8_len(b[0]);
            match b.get(..len).and_then(|s| std::str::from_utf8(s).ok()) {
                Some(s) => {
                    let c = s.chars().next().unwrap_or(' ');
                    let m = if c.is_uppercase() {
                        KeyModifiers::SHIFT
                    } else {
                        none
                    };
                    (key(KeyCode::Char(c), m), len)
                }
                None => (None, 1),
            }
        }
    }
}

fn utf8_len(first: u8) -> usize {
    match first {
        0xc0..=0xdf => 2,
        0xe0..=0xef => 3,
        0xf0..=0xf7 => 4,
        _ => 1,
    }
}

/// An escape sequence: Esc alone, Alt+key, CSI or SS3 keys.
fn escape(b: &[u8]) -> (Option<KeyEvent>, usize) {
    let none = KeyModifiers::NONE;
    match b.get(1) {
        None => (key(KeyCode::Esc, none), 1),
        Some(b'[') | Some(b'O') => {
            let end = b
                .iter()
                .enumerate()
                .skip(2)
                .find(|(_, c)| (0x40..=0x7e).contains(*c))
                .map(|(i, _)| i);
            let Some(end) = end else {
                return (None, b.len());
            };
            let params = std::str::from_utf8(&b[2..end]).unwrap_or("");
            let mut nums = params.split(';').map(|p| p.parse::<u8>().unwrap_or(1));
            let first = nums.next().unwrap_or(1);
            let modifiers = modifiers(nums.next().unwrap_or(1));
            let code = match b[end] {
                b'A' => Some(KeyCode::Up),
                b'B' => Some(KeyCode::Down),
                b'C' => Some(KeyCode::Right),
                b'D' => Some(KeyCode::Left),
                b'H' => Some(KeyCode::Home),
                b'F' => Some(KeyCode::End),
                b'P' => Some(KeyCode::F(1)),
                b'Q' => Some(KeyCode::F(2)),
                b'R' => Some(KeyCode::F(3)),
                b'S' => Some(KeyCode::F(4)),
                b'Z' => return (key(KeyCode::BackTab, KeyModifiers::SHIFT), end + 1),
                b'~' => match first {
                    1 | 7 => Some(KeyCode::Home),
                    2 => Some(KeyCode::Insert),
                    3 => Some(KeyCode::Delete),
                    4 | 8 => Some(KeyCode::End),
                    5 => Some(KeyCode::PageUp),
                    6 => Some(KeyCode::PageDown),
                    _ => None,
                },
                _ => None,
            };
            (code.and_then(|c| key(c, modifiers)), end + 1)
        }
        Some(&c) if c != 0x1b => {
            let (inner, n) = one(&b[1..]);
            (
                inner.map(|mut k| {
                    k.modifiers |= KeyModifiers::ALT;
                    k
                }),
                n + 1,
            )
        }
        Some(_) => (key(KeyCode::Esc, none), 1),
    }
}

/// xterm's modifier parameter (1 + shift + 2·alt + 4·ctrl).
fn modifiers(p: u8) -> KeyModifiers {
    let bits = p.saturating_sub(1);
    let mut m = KeyModifiers::NONE;
    if bits & 1 != 0 {
        m |= KeyModifiers::SHIFT;
    }
    if bits & 2 != 0 {
        m |= KeyModifiers::ALT;
    }
    if bits & 4 != 0 {
        m |= KeyModifiers::CONTROL;
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_typed_during_the_probe_decode() {
        let keys = key_events(b"jQ\x1b[A\x1bOB\x1b[5~\x1b[1;5C\x03\r\x1bx\x1b\xc3\xa9");
        let codes: Vec<(KeyCode, KeyModifiers)> =
            keys.iter().map(|k| (k.code, k.modifiers)).collect();
        let n = KeyModifiers::NONE;
        assert_eq!(
            codes,
            vec![
                (KeyCode::Char('j'), n),
                (KeyCode::Char('Q'), KeyModifiers::SHIFT),
                (KeyCode::Up, n),
                (KeyCode::Down, n),
                (KeyCode::PageUp, n),
                (KeyCode::Right, KeyModifiers::CONTROL),
                (KeyCode::Char('c'), KeyModifiers::CONTROL),
                (KeyCode::Enter, n),
                (KeyCode::Char('x'), KeyModifiers::ALT),
                (KeyCode::Char('é'), KeyModifiers::ALT),
            ]
        );
    }
}
