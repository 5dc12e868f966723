//! ASPRS LAS classification codes: their standard names (LAS 1.4 R15, table
//! 17) and the colours viewers conventionally give them (Potree, QGIS), plus
//! the per-class visibility mask that filters apply with one lookup a point.

use super::color::pack_rgb;

/// The standard name of class `code` (`"user 64"` above the ASPRS table,
/// `"reserved 23"` for unassigned codes).
pub fn name(code: u8) -> String {
    let s = match code {
        0 => "never classified",
        1 => "unclassified",
        2 => "ground",
        3 => "low vegetation",
        4 => "medium vegetation",
        5 => "high vegetation",
        6 => "building",
        7 => "low point (noise)",
        8 => "model key-point",
        9 => "water",
        10 => "rail",
        11 => "road surface",
        12 => "overlap",
        13 => "wire guard (shield)",
        14 => "wire conductor (phase)",
        15 => "transmission tower",
        16 => "wire-structure connector",
        17 => "bridge deck",
        18 => "high noise",
        19 => "overhead structure",
        20 => "ignored ground",
        21 => "snow",
        22 => "temporal exclusion",
        64.. => return format!("user {code}"),
        _ => return format!("reserved {code}"),
    };
    s.into()
}

/// The conventional colour of class `code`, packed as [`pack_rgb`] does.
pub const fn color(code: u8) -> u32 {
    match code {
        0 | 1 => pack_rgb(160, 160, 160),
        2 => pack_rgb(161, 82, 46),
        3 => pack_rgb(120, 220, 80),
        4 => pack_rgb(40, 180, 40),
        5 => pack_rgb(0, 110, 0),
        6 => pack_rgb(255, 170, 0),
        7 => pack_rgb(255, 0, 255),
        8 => pack_rgb(255, 0, 0),
        9 => pack_rgb(0, 100, 255),
        10 => pack_rgb(140, 90, 160),
        11 => pack_rgb(90, 90, 90),
        12 => pack_rgb(255, 255, 0),
        13 | 14 => pack_rgb(255, 255, 160),
        15 => pack_rgb(200, 200, 255),
        16 => pack_rgb(255, 140, 140),
        17 => pack_rgb(180, 140, 100),
        18 => pack_rgb(255, 60, 160),
        19 => pack_rgb(120, 200, 200),
        20 => pack_rgb(110, 60, 30),
        21 => pack_rgb(240, 250, 255),
        22 => pack_rgb(80, 80, 140),
        _ => pack_rgb(80, 160, 160),
    }
}

/// The class code of a stored `classification` value: a whole number 0..=255,
/// else `None` (such points match no class).
#[inline(always)]
pub fn code_of(v: f32) -> Option<u8> {
    crate::points::class_code(v)
}

/// Which classes are shown: one flag a code.
#[derive(Clone, PartialEq, Eq)]
pub struct ClassMask(pub [bool; 256]);

impl std::fmt::Debug for ClassMask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let shown: Vec<usize> = (0..256).filter(|&c| self.0[c]).collect();
        write!(f, "ClassMask{shown:?}")
    }
}

impl Default for ClassMask {
    fn default() -> Self {
        ClassMask([true; 256])
    }
}

impl ClassMask {
    /// Only `include` (every class when `None`), less `exclude`.
    pub fn new(include: Option<&[u8]>, exclude: &[u8]) -> ClassMask {
        let mut m = [include.is_none(); 256];
        for &c in include.unwrap_or(&[]) {
            m[c as usize] = true;
        }
        for &c in exclude {
            m[c as usize] = false;
        }
        ClassMask(m)
    }

    /// Whether every class is shown.
    pub fn all(&self) -> bool {
        self.0.iter().all(|&v| v)
    }

    pub fn shows(&self, code: u8) -> bool {
        self.0[code as usize]
    }

    pub fn set(&mut self, code: u8, shown: bool) {
        self.0[code as usize] = shown;
    }

    /// Whether a point with stored value `v` is shown (values that are not a
    /// code are shown only when every class is).
    #[inline(always)]
    pub(crate) fn shows_value(&self, v: f32) -> bool {
        match code_of(v) {
            Some(c) => self.0[c as usize],
            None => self.all(),
        }
    }
}

/// Parses a list of class codes such as `2,6` (`what` names the option in errors).
pub fn parse_list(s: &str, what: &str) -> Result<Vec<u8>, String> {
    s.split(',')
        .map(|t| {
            t.trim().parse::<u8>().map_err(|_| {
                format!("{what} '{s}': expected class codes 0 to 255 separated by commas, e.g. 2,6")
            })
        })
        .collect()
}

/// A colour column from a `classification` column.
pub(crate) fn colorize(values: &[f32]) -> Vec<u32> {
    values
        .iter()
        .map(|&v| code_of(v).map_or(color(255), color))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_colors_masks() {
        assert_eq!(name(2), "ground");
        assert_eq!(name(6), "building");
        assert_eq!(name(9), "water");
        assert_eq!(name(18), "high noise");
        assert_eq!(name(40), "reserved 40");
        assert_eq!(name(200), "user 200");
        assert_ne!(color(2), color(6));
        let m = ClassMask::new(Some(&[2, 6]), &[6]);
        assert!(m.shows(2) && !m.shows(6) && !m.shows(1));
        assert!(m.shows_value(2.0) && !m.shows_value(2.5) && !m.shows_value(-1.0));
        let m = ClassMask::new(None, &[7, 18]);
        assert!(m.shows(2) && !m.shows(7) && !m.shows(18) && !m.all());
        assert!(ClassMask::default().shows_value(f32::NAN));
        assert_eq!(parse_list("2, 6", "--classes").unwrap(), vec![2, 6]);
        assert!(parse_list("2,300", "--classes").is_err());
        assert!(parse_list("", "--classes").is_err());
        assert_eq!(colorize(&[2.0, 0.5]), vec![color(2), color(255)]);
    }
}
