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

/// `12.5 ms` as its number and its unit (lower case, trimmed); `None` where
/// it does not start with a number.
fn number_and_unit(s: &str) -> Option<(f64, String)> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    Some((num.parse().ok()?, unit.trim().to_ascii_lowercase()))
}

/// A span of time as people say it: `42 s`, `5 min`, `3 h`, `2 days`.
pub fn duration(d: std::time::Duration) -> String {
    let s = d.as_secs();
    match s {
        0..120 => format!("{s} s"),
        120..7200 => format!("{} min", s / 60),
        7200..172_800 => format!("{} h", s / 3600),
        _ => format!("{} days", s / 86_400),
    }
}

/// Parses a duration such as `30s`, `500ms`, `2m`, `1.5s` or `30` (seconds).
pub fn parse_duration(s: &str) -> Result<std::time::Duration, String> {
    let (v, unit) = number_and_unit(s)
        .ok_or_else(|| format!("'{s}' is not a duration (try 30s, 500ms or 2m)"))?;
    let secs = match unit.as_str() {
        "" | "s" | "sec" | "secs" => v,
        "ms" => v / 1000.0,
        "m" | "min" | "mins" => v * 60.0,
        "h" => v * 3600.0,
        u => {
            return Err(format!(
                "unknown time unit '{u}' in '{s}' (use ms, s, m or h)"
            ));
        }
    };
    if !secs.is_finite() || secs <= 0.0 || secs > 1e9 {
        return Err(format!("'{s}' is not a usable duration"));
    }
    Ok(std::time::Duration::from_secs_f64(secs))
}

/// Parses a size such as `256MiB`, `2G`, `1.5GiB`, `512M`, `1000000` (bytes).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let (v, unit) =
        number_and_unit(s).ok_or_else(|| format!("'{s}' is not a size (try 256MiB or 2G)"))?;
    let mult: f64 = match unit.as_str() {
        "" | "b" => 1.0,
        "k" | "kb" | "kib" => 1024.0,
        "m" | "mb" | "mib" => 1024.0 * 1024.0,
        "g" | "gb" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tb" | "tib" => 1024.0f64.powi(4),
        u => {
            return Err(format!(
                "unknown size unit '{u}' in '{s}' (use K, M, G or T)"
            ));
        }
    };
    let bytes = v * mult;
    if !bytes.is_finite() || bytes < 1.0 {
        return Err(format!("'{s}' is not a usable size"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod tests {
    #[test]
    fn sizes_parse() {
        use super::parse_size;
        assert_eq!(parse_size("256MiB").unwrap(), 256 << 20);
        assert_eq!(parse_size("2G").unwrap(), 2 << 30);
        assert_eq!(parse_size("1.5gb").unwrap(), 3 << 29);
        assert_eq!(parse_size("4096").unwrap(), 4096);
        assert!(parse_size("lots").is_err());
        assert!(parse_size("5 parsecs").is_err());
        assert!(parse_size("0").is_err());
    }

    #[test]
    fn durations_read_as_people_say_them() {
        use std::time::Duration as D;
        assert_eq!(super::duration(D::from_secs(42)), "42 s");
        assert_eq!(super::duration(D::from_secs(300)), "5 min");
        assert_eq!(super::duration(D::from_secs(3 * 3600 + 5)), "3 h");
        assert_eq!(super::duration(D::from_secs(5 * 86_400)), "5 days");
    }

    #[test]
    fn durations_parse() {
        use super::parse_duration;
        use std::time::Duration;
        assert_eq!(parse_duration("30").unwrap(), Duration::from_secs(30));
        assert_eq!(parse_duration("30s").unwrap(), Duration::from_secs(30));
        assert_eq!(parse_duration("250ms").unwrap(), Duration::from_millis(250));
        assert_eq!(parse_duration("1.5s").unwrap(), Duration::from_millis(1500));
        assert_eq!(parse_duration("2m").unwrap(), Duration::from_secs(120));
        assert!(parse_duration("soon").is_err());
        assert!(parse_duration("5 fortnights").is_err());
        assert!(parse_duration("0").is_err());
    }

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
