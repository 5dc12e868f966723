//! Sanitizing text that came from files before it reaches a terminal.

/// Replaces control characters (C0, DEL, C1) with U+FFFD so that text taken from a
/// file (metadata, band names, paths) cannot drive the user's terminal.
pub fn sanitize(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_control() { '\u{FFFD}' } else { c })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn escapes_are_neutralized() {
        let s = super::sanitize("band\x1b]0;pwned\x07\u{9b}2J");
        assert!(!s.chars().any(|c| c.is_control()));
        assert!(s.starts_with("band"));
    }
}
