//! The memory budget: parsing sizes, reading available memory, and the paper's rule
//! that decides how many points one part (one image) may hold.

/// Parses a size such as `256MiB`, `2G`, `1.5GiB`, `512M`, `1000000` (bytes).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num
        .parse()
        .map_err(|_| format!("'{s}' is not a size (try 256MiB or 2G)"))?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
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

/// The smallest budget a conversion keeps to: below it, its fixed needs (the
/// region sample, the count grid, reader windows of at least 65,536 points) come
/// to more than the budget, so parts are sized to it but resident memory is not.
pub const MIN_KEPT: u64 = 64 << 20;

/// Memory the system reports as available (`MemAvailable` of /proc/meminfo).
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    text.lines()
        .find(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<u64>().ok())
        .map(|kb| kb * 1024)
}

/// The default budget: half the available memory, at least 256 MiB, at most 16 GiB
/// (more buys nothing but fewer, larger parts).
pub fn default_budget() -> u64 {
    let avail = available_memory().unwrap_or(4 << 30);
    (avail / 2).clamp(256 << 20, 16 << 30)
}

/// Resident bytes per point while a part is sorted and written with `attributes`
/// attribute bands: the source columns (f64 x y z, f32 attributes), relative
/// positions, packed sort keys and their scratch copy, the permutation, sorted
/// positions, and the output bands.
pub fn bytes_per_point(attributes: usize) -> u64 {
    let source = 24 + 4 * attributes as u64;
    let layout = 12 + 8 + 8 + 4 + 12;
    let bands = 4 * (3 + attributes as u64);
    source + layout + bands
}

/// Fixed overhead kept out of the budget: reader windows, tile buffers, allocator
/// slack.
pub const OVERHEAD: u64 = 48 << 20;

/// Points one part may hold under `budget` (the paper's rule: when parsed points
/// would exceed the budget, they become an image).
pub fn points_per_part(budget: u64, attributes: usize) -> u64 {
    let usable = budget.saturating_sub(OVERHEAD).max(16 << 20);
    (usable / bytes_per_point(attributes)).clamp(1 << 16, u32::MAX as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes() {
        assert_eq!(parse_size("256MiB").unwrap(), 256 << 20);
        assert_eq!(parse_size("2G").unwrap(), 2 << 30);
        assert_eq!(parse_size("1.5gb").unwrap(), 3 << 29);
        assert_eq!(parse_size("4096").unwrap(), 4096);
        assert!(parse_size("lots").is_err());
        assert!(parse_size("5 parsecs").is_err());
        assert!(parse_size("0").is_err());
    }

    #[test]
    fn budget_rule() {
        let n = points_per_part(256 << 20, 1);
        assert!(n > 1_000_000 && n < 4_000_000, "{n}");
        assert!(points_per_part(1 << 40, 0) <= u32::MAX as u64);
        assert!(default_budget() >= 256 << 20);
    }
}
