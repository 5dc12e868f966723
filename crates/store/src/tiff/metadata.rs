//! The part's self-description: GDAL_METADATA XML (items GDAL shows, band names,
//! band offsets) and the binary tile index (per level, per tile: points and bounds)
//! that lets a reader cull tiles without reading pixels.

use crate::points::Bounds;
use crate::spec::{TILE_INDEX_MAGIC, TILE_INDEX_VERSION, key};
use base64::Engine;
use std::collections::BTreeMap;

/// One `<Item>` of GDAL_METADATA.
#[derive(Debug, Clone, PartialEq)]
pub struct Item {
    pub name: String,
    pub value: String,
    pub sample: Option<usize>,
    pub role: Option<String>,
    pub domain: Option<String>,
}

impl Item {
    pub fn dataset(name: &str, value: impl Into<String>) -> Item {
        Item {
            name: name.into(),
            value: value.into(),
            sample: None,
            role: None,
            domain: None,
        }
    }

    /// A band item without a role, as GDAL writes `STATISTICS_*`.
    pub(crate) fn band_stat(name: &str, sample: usize, value: impl Into<String>) -> Item {
        Item {
            name: name.into(),
            value: value.into(),
            sample: Some(sample),
            role: None,
            domain: None,
        }
    }

    pub fn band(name: &str, sample: usize, role: &str, value: impl Into<String>) -> Item {
        Item {
            name: name.into(),
            value: value.into(),
            sample: Some(sample),
            role: Some(role.into()),
            domain: None,
        }
    }
}

fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&apos;"),
            // TIFF ASCII holds 7-bit text only: control and non-ASCII characters
            // travel as numeric references (GDAL's XML parser decodes them).
            c if ((c as u32) < 0x20 && c != '\n' && c != '\t') || !c.is_ascii() => {
                o.push_str(&format!("&#{};", c as u32))
            }
            c => o.push(c),
        }
    }
    o
}

/// An item's value as GDAL writes it: control characters (but newline and tab)
/// replaced, so no reader's terminal is driven by them; then XML-escaped twice,
/// as GDAL does (once by `CPLEscapeString`, once by its XML writer).
fn escape_value(s: &str) -> String {
    let clean: String = s
        .chars()
        .map(|c| {
            if c.is_control() && c != '\n' && c != '\t' {
                '\u{FFFD}'
            } else {
                c
            }
        })
        .collect();
    escape(&escape(&clean))
}

/// An item's value as GDAL reads it: unescaped twice (files written with one
/// escape read the same, but for a literal entity in the text).
fn unescape_value(s: &str) -> String {
    unescape(&unescape(s))
}

fn unescape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(p) = rest.find('&') {
        o.push_str(&rest[..p]);
        rest = &rest[p..];
        let Some(end) = rest.find(';').filter(|&e| e <= 10) else {
            o.push('&');
            rest = &rest[1..];
            continue;
        };
        let ent = &rest[1..end];
        let c = match ent {
            "amp" => Some('&'),
            "lt" => Some('<'),
            "gt" => Some('>'),
            "quot" => Some('"'),
            "apos" => Some('\''),
            _ if ent.starts_with("#x") => u32::from_str_radix(&ent[2..], 16)
                .ok()
                .and_then(char::from_u32),
            _ if ent.starts_with('#') => ent[1..].parse().ok().and_then(char::from_u32),
            _ => None,
        };
        match c {
            Some(c) => {
                o.push(c);
                rest = &rest[end + 1..];
            }
            None => {
                o.push('&');
                rest = &rest[1..];
            }
        }
    }
    o.push_str(rest);
    o
}

/// Serializes items as GDAL writes them.
pub(crate) fn to_xml(items: &[Item]) -> String {
    let mut s = String::from("<GDALMetadata>\n");
    for it in items {
        s.push_str("  <Item name=\"");
        s.push_str(&escape(&it.name));
        s.push('"');
        if let Some(d) = &it.domain {
            s.push_str(&format!(" domain=\"{}\"", escape(d)));
        }
        if let Some(b) = it.sample {
            s.push_str(&format!(" sample=\"{b}\""));
        }
        if let Some(r) = &it.role {
            s.push_str(&format!(" role=\"{}\"", escape(r)));
        }
        s.push('>');
        s.push_str(&escape_value(&it.value));
        s.push_str("</Item>\n");
    }
    s.push_str("</GDALMetadata>\n");
    s
}

fn attr(tag: &str, name: &str) -> Option<String> {
    let pat = format!("{name}=");
    let mut search = tag;
    while let Some(p) = search.find(&pat) {
        // The attribute name must start the token.
        let before = search[..p].chars().last();
        let after = &search[p + pat.len()..];
        if before.is_some_and(|c| c.is_whitespace()) {
            let q = after.chars().next()?;
            if q == '"' || q == '\'' {
                let end = after[1..].find(q)?;
                return Some(unescape(&after[1..1 + end]));
            }
        }
        search = after;
    }
    None
}

/// Parses GDAL_METADATA XML leniently: every `<Item ...>value</Item>`.
pub(crate) fn from_xml(xml: &str) -> Result<Vec<Item>, String> {
    if !xml.contains("<GDALMetadata") {
        return Err("GDAL_METADATA is not a <GDALMetadata> document".into());
    }
    let mut items = Vec::new();
    let mut rest = xml;
    while let Some(p) = rest.find("<Item") {
        rest = &rest[p + 5..];
        let close = rest
            .find('>')
            .ok_or("unterminated <Item> in GDAL_METADATA")?;
        let tag = &rest[..close];
        rest = &rest[close + 1..];
        if tag.ends_with('/') {
            continue;
        }
        let end = rest
            .find("</Item>")
            .ok_or("missing </Item> in GDAL_METADATA")?;
        let value = unescape_value(&rest[..end]);
        rest = &rest[end + 7..];
        let name = attr(tag, "name").ok_or("an <Item> without a name in GDAL_METADATA")?;
        items.push(Item {
            name,
            value,
            sample: attr(tag, "sample").and_then(|s| s.parse().ok()),
            role: attr(tag, "role"),
            domain: attr(tag, "domain").filter(|d| !d.is_empty()),
        });
    }
    Ok(items)
}

/// Dataset-level items of the default domain, by name.
pub(crate) fn dataset_items(items: &[Item]) -> BTreeMap<String, String> {
    items
        .iter()
        .filter(|i| i.sample.is_none() && i.domain.is_none())
        .map(|i| (i.name.clone(), i.value.clone()))
        .collect()
}

/// Per-band item `name` without a role (as GDAL writes band statistics), by band.
pub(crate) fn band_named(items: &[Item], name: &str) -> BTreeMap<usize, String> {
    items
        .iter()
        .filter(|i| i.name == name && i.role.is_none() && i.domain.is_none())
        .filter_map(|i| i.sample.map(|s| (s, i.value.clone())))
        .collect()
}

/// Per-band item `name` with `role`, by band.
pub(crate) fn band_items(items: &[Item], role: &str) -> BTreeMap<usize, String> {
    items
        .iter()
        .filter_map(|i| match (i.sample, &i.role) {
            (Some(s), Some(r)) if r == role => Some((s, i.value.clone())),
            _ => None,
        })
        .collect()
}

/// `f64` values as text that parses back to the same bits.
pub(crate) fn f64s(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(" ")
}

pub(crate) fn parse_f64s(s: &str, n: usize, what: &str) -> Result<Vec<f64>, String> {
    let v: Result<Vec<f64>, _> = s.split_whitespace().map(str::parse).collect();
    match v {
        Ok(v) if v.len() == n => Ok(v),
        _ => Err(format!("metadata {what} is not {n} numbers: '{s}'")),
    }
}

/// [`key::CLASS_COUNTS`]'s value: `CODE:COUNT` pairs, codes ascending.
pub fn class_counts(counts: &[(u8, u64)]) -> String {
    counts
        .iter()
        .map(|(c, n)| format!("{c}:{n}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Parses [`key::CLASS_COUNTS`] (see [`class_counts`]).
pub(crate) fn parse_class_counts(s: &str) -> Result<Vec<(u8, u64)>, String> {
    let bad = || format!("metadata {} is not a list of CODE:COUNT", key::CLASS_COUNTS);
    let mut out: Vec<(u8, u64)> = s
        .split_whitespace()
        .map(|pair| {
            let (c, n) = pair.split_once(':').ok_or_else(bad)?;
            Ok((c.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?))
        })
        .collect::<Result<_, String>>()?;
    out.sort_unstable();
    out.dedup_by_key(|p| p.0);
    Ok(out)
}

/// Per-tile entry of the tile index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TileEntry {
    /// Raster index of the tile in its level (`row * across + col`).
    pub index: u32,
    pub points: u32,
    /// Bounds of all level-0 points the tile stands for, in source coordinates (the
    /// tile's own points lie inside; so do those of its finer descendants).
    pub bounds: Bounds,
}

/// The tile index of one level.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LevelIndex {
    pub size: u32,
    pub tile_size: u32,
    pub tiles: Vec<TileEntry>,
}

/// Encodes the index as base64 of a little-endian binary blob.
pub(crate) fn encode_tile_index(levels: &[LevelIndex]) -> String {
    let mut b = Vec::new();
    b.extend_from_slice(TILE_INDEX_MAGIC);
    b.extend_from_slice(&TILE_INDEX_VERSION.to_le_bytes());
    b.extend_from_slice(&(levels.len() as u32).to_le_bytes());
    for l in levels {
        b.extend_from_slice(&l.size.to_le_bytes());
        b.extend_from_slice(&l.tile_size.to_le_bytes());
        b.extend_from_slice(&(l.tiles.len() as u32).to_le_bytes());
        for t in &l.tiles {
            b.extend_from_slice(&t.index.to_le_bytes());
            b.extend_from_slice(&t.points.to_le_bytes());
            for v in t.bounds.min.iter().chain(&t.bounds.max) {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    base64::engine::general_purpose::STANDARD.encode(b)
}

pub(crate) fn decode_tile_index(s: &str) -> Result<Vec<LevelIndex>, String> {
    let b = base64::engine::general_purpose::STANDARD
        .decode(s.trim())
        .map_err(|e| format!("tile index is not base64: {e}"))?;
    let mut at = 0usize;
    let mut take = |n: usize| -> Result<&[u8], String> {
        let s = b
            .get(at..at + n)
            .ok_or_else(|| format!("tile index truncated at byte {at}"))?;
        at += n;
        Ok(s)
    };
    if take(4)? != TILE_INDEX_MAGIC {
        return Err("tile index has a wrong magic".into());
    }
    let u32_at = |s: &[u8]| u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
    let version = u32_at(take(4)?);
    if version != TILE_INDEX_VERSION {
        return Err(format!("tile index version {version} is not supported"));
    }
    let nlevels = u32_at(take(4)?) as usize;
    let mut levels = Vec::with_capacity(nlevels.min(64));
    for _ in 0..nlevels {
        let size = u32_at(take(4)?);
        let tile_size = u32_at(take(4)?);
        let ntiles = u32_at(take(4)?) as usize;
        let mut tiles = Vec::with_capacity(ntiles.min(1 << 20));
        for _ in 0..ntiles {
            let index = u32_at(take(4)?);
            let points = u32_at(take(4)?);
            let mut v = [0f64; 6];
            for x in &mut v {
                let s = take(8)?;
                *x = f64::from_le_bytes(s.try_into().map_err(|_| "tile index truncated")?);
            }
            tiles.push(TileEntry {
                index,
                points,
                bounds: Bounds {
                    min: [v[0], v[1], v[2]],
                    max: [v[3], v[4], v[5]],
                },
            });
        }
        levels.push(LevelIndex {
            size,
            tile_size,
            tiles,
        });
    }
    Ok(levels)
}

/// Name of the dataset item holding the format version.
pub(crate) fn is_pcimg(items: &BTreeMap<String, String>) -> bool {
    items.contains_key(key::FORMAT)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xml_round_trip_with_awkward_text() {
        let items = vec![
            Item::dataset("SOURCE", "a<b>&\"c\" 'd'.las"),
            Item::band("DESCRIPTION", 2, "description", "z"),
            Item {
                domain: Some("pcimg".into()),
                ..Item::dataset("TILE_INDEX", "QUJD")
            },
            Item::dataset("CTRL", "bell\x07 Zürich\nline"),
        ];
        let xml = to_xml(&items);
        // Escaped twice, as GDAL writes values: `&` is `&amp;amp;`.
        assert!(xml.contains("a&amp;lt;b&amp;gt;&amp;amp;"), "{xml}");
        let mut back = from_xml(&xml).unwrap();
        // Control characters but newline do not survive the write.
        assert_eq!(back[3].value, "bell\u{FFFD} Zürich\nline");
        back[3].value = items[3].value.clone();
        assert_eq!(back, items);
        // A value escaped once (files from before) reads the same.
        let once = "<GDALMetadata><Item name=\"S\">a&lt;b&amp;c</Item></GDALMetadata>";
        assert_eq!(from_xml(once).unwrap()[0].value, "a<b&c");
    }

    #[test]
    fn tile_index_round_trip_and_truncation() {
        let levels = vec![LevelIndex {
            size: 512,
            tile_size: 256,
            tiles: vec![TileEntry {
                index: 3,
                points: 17,
                bounds: Bounds {
                    min: [637179.22, 6010946.56, 20.51],
                    max: [637180.0, 6010947.0, 21.0],
                },
            }],
        }];
        let s = encode_tile_index(&levels);
        assert_eq!(decode_tile_index(&s).unwrap(), levels);
        let b = base64::engine::general_purpose::STANDARD
            .decode(&s)
            .unwrap();
        let cut = base64::engine::general_purpose::STANDARD.encode(&b[..b.len() - 3]);
        assert!(decode_tile_index(&cut).unwrap_err().contains("truncated"));
    }
}
