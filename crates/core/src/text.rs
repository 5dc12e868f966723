//! Sanitizing text that came from files before it reaches a terminal.

/// Replaces control characters (C0, DEL, C1) with U+FFFD so that text taken from a
/// file (metadata, band names, paths) cannot drive the user's terminal.
pub fn sanitize(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_control() { '\u{FFFD}' } else { c })
        .collect()
}

/// Like [`sanitize`] but keeps line breaks and tabs, for multi-line messages.
pub fn sanitize_multiline(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_control() && c != '\n' && c != '\t' {
                '\u{FFFD}'
            } else {
                c
            }
        })
        .collect()
}

/// A byte count for people: `16.0 MiB`.
pub fn bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u < UNITS.len() - 1 {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// An integer with thousands separators: `1,234,567`.
pub fn count(n: u64) -> String {
    let s = n.to_string();
    let mut o = String::with_capacity(s.len() + s.len() / 3);
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            o.push(',');
        }
        o.push(c);
    }
    o
}

#[cfg(test)]
mod tests {
    #[test]
    fn escapes_are_neutralized() {
        let s = super::sanitize("band\x1b]0;pwned\x07\u{9b}2J");
        assert!(!s.chars().any(|c| c.is_control()));
        assert!(s.starts_with("band"));
        assert_eq!(super::sanitize_multiline("a\nb\x1b"), "a\nb\u{FFFD}");
    }

    #[test]
    fn numbers_for_people() {
        assert_eq!(super::count(1_234_567), "1,234,567");
        assert_eq!(super::count(12), "12");
        assert_eq!(super::bytes(512), "512 B");
        assert_eq!(super::bytes(3 << 20), "3.0 MiB");
    }
}
