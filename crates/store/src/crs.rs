//! The linear unit of a coordinate reference system (WKT1, WKT2 or `EPSG:n`),
//! so that messages state distances in the dataset's own units (US feet for
//! many LAS files), never assumed metres.

/// A CRS's unit of length: its name as the CRS spells it and metres per unit.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LinearUnit {
    pub name: String,
    pub metres: f64,
}

/// A WKT node: keyword and arguments (quoted strings, numbers and words as
/// text; nested nodes).
#[derive(Debug)]
struct Node {
    keyword: String,
    texts: Vec<String>,
    children: Vec<Node>,
}

/// Parses one node at `s[*at..]`; `None` on malformed text (or nesting deeper
/// than 64).
fn parse(s: &[u8], at: &mut usize, depth: usize) -> Option<Node> {
    if depth > 64 {
        return None;
    }
    let skip_ws = |at: &mut usize| {
        while *at < s.len() && s[*at].is_ascii_whitespace() {
            *at += 1;
        }
    };
    skip_ws(at);
    let start = *at;
    while *at < s.len() && !matches!(s[*at], b',' | b'[' | b']' | b'(' | b')' | b'"') {
        *at += 1;
    }
    let keyword = String::from_utf8_lossy(&s[start..*at])
        .trim()
        .to_ascii_uppercase();
    skip_ws(at);
    let mut node = Node {
        keyword,
        texts: Vec::new(),
        children: Vec::new(),
    };
    if *at >= s.len() || !matches!(s[*at], b'[' | b'(') {
        return Some(node);
    }
    *at += 1;
    loop {
        skip_ws(at);
        let c = *s.get(*at)?;
        match c {
            b']' | b')' => {
                *at += 1;
                return Some(node);
            }
            b',' => *at += 1,
            b'"' => {
                *at += 1;
                let from = *at;
                // `""` inside a quoted string is a quote.
                while *at < s.len() && !(s[*at] == b'"' && s.get(*at + 1) != Some(&b'"')) {
                    *at += if s[*at] == b'"' { 2 } else { 1 };
                }
                node.texts.push(
                    String::from_utf8_lossy(&s[from..(*at).min(s.len())]).replace("\"\"", "\""),
                );
                *at += 1;
            }
            _ => {
                let from = *at;
                while *at < s.len() && !matches!(s[*at], b',' | b'[' | b']' | b'(' | b')' | b'"') {
                    *at += 1;
                }
                if *at < s.len() && matches!(s[*at], b'[' | b'(') {
                    *at = from;
                    node.children.push(parse(s, at, depth + 1)?);
                } else {
                    let word = String::from_utf8_lossy(&s[from..*at]);
                    node.texts.push(word.trim().to_string());
                }
            }
        }
    }
}

/// Keywords of a CRS whose coordinates are planar lengths.
const PROJECTED: [&str; 5] = ["PROJCS", "PROJCRS", "PROJECTEDCRS", "LOCAL_CS", "ENGCRS"];
/// Keywords of a geographic CRS (coordinates in angles).
const GEOGRAPHIC: [&str; 4] = ["GEOGCS", "GEOGCRS", "GEOGRAPHICCRS", "GEODCRS"];

fn unit_of(n: &Node) -> Option<LinearUnit> {
    let name = n.texts.first()?.clone();
    let metres: f64 = n.texts.get(1)?.parse().ok()?;
    (metres.is_finite() && metres > 0.0).then_some(LinearUnit { name, metres })
}

/// The unit of a horizontal CRS node: its own `UNIT`/`LENGTHUNIT`, or (WKT2)
/// one in its coordinate system's axes; not the ellipsoid's.
fn horizontal_unit(n: &Node) -> Option<LinearUnit> {
    let direct = n
        .children
        .iter()
        .find(|c| c.keyword == "UNIT" || c.keyword == "LENGTHUNIT")
        .and_then(unit_of);
    direct.or_else(|| {
        n.children
            .iter()
            .filter(|c| c.keyword == "AXIS")
            .flat_map(|a| &a.children)
            .find(|c| c.keyword == "LENGTHUNIT" || c.keyword == "UNIT")
            .and_then(unit_of)
    })
}

/// What the x and y coordinates of data in `crs` are measured in: a linear
/// unit, `Err("degree")`-like for a geographic CRS (the angle's unit name), or
/// `None` when the CRS does not say (an EPSG code alone, unparsable text).
pub(crate) fn linear_unit(crs: &str) -> Option<Result<LinearUnit, String>> {
    let s = crs.trim().as_bytes();
    let mut at = 0;
    let root = parse(s, &mut at, 0)?;
    let mut stack = vec![&root];
    while let Some(n) = stack.pop() {
        if PROJECTED.contains(&n.keyword.as_str()) {
            return horizontal_unit(n).map(Ok);
        }
        if GEOGRAPHIC.contains(&n.keyword.as_str()) {
            let angle = n
                .children
                .iter()
                .find(|c| c.keyword == "UNIT" || c.keyword == "ANGLEUNIT")
                .and_then(|c| c.texts.first().cloned())
                .unwrap_or_else(|| "degree".into());
            return Some(Err(angle));
        }
        // A compound CRS: its horizontal part first.
        if matches!(n.keyword.as_str(), "COMPD_CS" | "COMPOUNDCRS") {
            stack.extend(n.children.iter().rev());
        }
    }
    None
}

/// `e` (in the CRS's units) for a message: "0.0012 US survey foot (0.366 mm)",
/// "0.037 mm" for metres, "1.2e-8 degree", "0.0012 units" when unknown.
pub fn distance(e: f64, crs: Option<&str>) -> String {
    match crs.and_then(linear_unit) {
        Some(Ok(u)) if (u.metres - 1.0).abs() < 1e-12 => format!("{:.3} mm", e * 1000.0),
        Some(Ok(u)) => format!(
            "{} {} ({:.3} mm)",
            significant(e),
            crate::text::sanitize(&u.name),
            e * u.metres * 1000.0
        ),
        Some(Err(angle)) => format!("{} {}", significant(e), crate::text::sanitize(&angle)),
        None => format!(
            "{} units (the CRS's; metres: {:.3} mm)",
            significant(e),
            e * 1000.0
        ),
    }
}

/// The short symbol labels (a scale bar, a distance) give lengths of data in
/// `crs` in: `m` for metres, `ft` for international and US survey feet, `km`,
/// else the unit's name as the CRS spells it (sanitized); `°` for a geographic
/// CRS; `units` when there is no CRS or it does not say (an EPSG code alone):
/// never assumed metres.
pub fn unit_symbol(crs: Option<&str>) -> String {
    match crs.and_then(linear_unit) {
        Some(Ok(u)) => {
            let name = u.name.to_ascii_lowercase();
            let near = |m: f64| (u.metres / m - 1.0).abs() < 1e-5;
            if near(1.0) && ["metre", "meter", "m", "metres", "meters"].contains(&name.as_str()) {
                "m".into()
            } else if near(0.3048)
                && (name.contains("foot") || name.contains("feet") || name.starts_with("ft"))
            {
                "ft".into()
            } else if near(1000.0) && name.starts_with("kilomet") {
                "km".into()
            } else {
                crate::text::sanitize(&u.name)
            }
        }
        Some(Err(_)) => "°".into(),
        None => "units".into(),
    }
}

/// Four significant digits.
fn significant(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    if digits > 12 {
        format!("{v:.3e}")
    } else {
        format!("{v:.digits$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_of_wkt1_wkt2_compound_and_geographic_crs() {
        let feet = r#"COMPD_CS["NAD83(HARN) / Oregon GIC Lambert (ft) + NAVD88 height (ft)",
            PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)",
              GEOGCS["NAD83(HARN)",DATUM["NAD83_High_Accuracy_Reference_Network",
                SPHEROID["GRS 1980",6378137,298.257222101]],UNIT["degree",0.0174532925199433]],
              PROJECTION["Lambert_Conformal_Conic_2SP"],
              UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]],AXIS["Easting",EAST]],
            VERT_CS["NAVD88 height (ft)",VERT_DATUM["North American Vertical Datum 1988",2005],
              UNIT["foot",0.3048]]]"#;
        let u = linear_unit(feet).unwrap().unwrap();
        assert_eq!((u.name.as_str(), u.metres), ("foot", 0.3048));
        // WKT2: the ellipsoid's metre is not the CRS's unit.
        let wkt2 = r#"PROJCRS["NAD83 / Vermont (ftUS)",
            BASEGEOGCRS["NAD83",DATUM["North American Datum 1983",
              ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]]],
            CONVERSION["SPCS83 Vermont zone (US survey foot)",METHOD["Transverse Mercator"]],
            CS[Cartesian,2],
            AXIS["easting (X)",east,ORDER[1],LENGTHUNIT["US survey foot",0.304800609601219]],
            AXIS["northing (Y)",north,ORDER[2],LENGTHUNIT["US survey foot",0.304800609601219]]]"#;
        let u = linear_unit(wkt2).unwrap().unwrap();
        assert_eq!(u.name, "US survey foot");
        assert!((u.metres - 0.3048006).abs() < 1e-6);
        let utm = r#"PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",UNIT["degree",0.01745]],
            UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert_eq!(linear_unit(utm).unwrap().unwrap().metres, 1.0);
        assert_eq!(distance(0.000_25, Some(utm)), "0.250 mm");
        assert_eq!(distance(0.000_25, Some(feet)), "0.0002500 foot (0.076 mm)");
        let geo = r#"GEOGCS["WGS 84",DATUM["WGS_1984"],UNIT["degree",0.0174532925199433]]"#;
        assert_eq!(linear_unit(geo), Some(Err("degree".into())));
        assert_eq!(linear_unit("EPSG:2992"), None);
        assert!(distance(0.001, Some("EPSG:2992")).starts_with("0.001000 units"));
        assert!(distance(0.001, None).starts_with("0.001000 units"));
        // Malformed or hostile text: no unit, no panic.
        for bad in [
            "PROJCS[",
            "PROJCS[\"a\",UNIT[\"x\",-1]]",
            "[[[[",
            "\"",
            &"A[".repeat(500),
        ] {
            let _ = distance(1.0, Some(bad));
        }
        assert_eq!(linear_unit("PROJCS[\"a\",UNIT[\"x\",-1]]"), None);
    }

    #[test]
    fn unit_symbols_for_labels() {
        let utm = r#"PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",UNIT["degree",0.01745]],
            UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert_eq!(unit_symbol(Some(utm)), "m");
        let ft = r#"PROJCS["a",UNIT["foot",0.3048]]"#;
        assert_eq!(unit_symbol(Some(ft)), "ft");
        let us = r#"PROJCRS["NAD83 / Vermont (ftUS)",CS[Cartesian,2],
            AXIS["easting (X)",east,LENGTHUNIT["US survey foot",0.304800609601219]]]"#;
        assert_eq!(unit_symbol(Some(us)), "ft");
        let km = r#"PROJCS["a",UNIT["kilometre",1000]]"#;
        assert_eq!(unit_symbol(Some(km)), "km");
        let link = r#"PROJCS["a",UNIT["Clarke's link",0.201166195164]]"#;
        assert_eq!(unit_symbol(Some(link)), "Clarke's link");
        // A "metre" that is not one is named, not called m.
        let odd = r#"PROJCS["a",UNIT["metre",0.5]]"#;
        assert_eq!(unit_symbol(Some(odd)), "metre");
        let geo = r#"GEOGCS["WGS 84",UNIT["degree",0.0174532925199433]]"#;
        assert_eq!(unit_symbol(Some(geo)), "°");
        assert_eq!(unit_symbol(Some("EPSG:2992")), "units");
        assert_eq!(unit_symbol(None), "units");
        let evil = "PROJCS[\"a\",UNIT[\"x\x1b[2J\",2]]";
        assert!(!unit_symbol(Some(evil)).contains('\x1b'));
    }
}
