//! A small, defensive TIFF/BigTIFF directory parser over a byte slice (the memory
//! map): header, IFD chain and tag values, every read bounds-checked, every error
//! naming the byte offset. Pixel data is not touched here. Also the writer of a
//! part's head ([`Head`]): the header and every directory with its values, laid
//! out before the tile data, so a reader fetches them in one range.

use std::collections::BTreeMap;

/// One directory entry: type, count and where its value lives.
#[derive(Debug, Clone, Copy)]
pub struct Entry {
    pub typ: u16,
    pub count: u64,
    /// Offset of the value in the file (inline values point into the entry itself).
    pub at: u64,
}

/// One image file directory.
#[derive(Debug, Clone)]
pub struct Ifd {
    pub offset: u64,
    pub entries: BTreeMap<u16, Entry>,
}

/// The parsed header and directories of a TIFF file.
#[derive(Debug, Clone)]
pub struct Tiff {
    pub little_endian: bool,
    pub big: bool,
    pub ifds: Vec<Ifd>,
}

fn type_size(t: u16) -> Option<u64> {
    Some(match t {
        1 | 2 | 6 | 7 => 1,
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 | 16 | 17 | 18 => 8,
        _ => return None,
    })
}

/// Directories beyond this number are treated as a corrupt chain.
const MAX_IFDS: usize = 256;

struct Bytes<'a> {
    data: &'a [u8],
    le: bool,
}

impl Bytes<'_> {
    fn get(&self, at: u64, n: u64) -> Result<&[u8], String> {
        let end = at.checked_add(n).ok_or("offset overflows")?;
        if end > self.data.len() as u64 {
            return Err(format!(
                "needs bytes {at}..{end} but the file has {} bytes (truncated?)",
                self.data.len()
            ));
        }
        Ok(&self.data[at as usize..end as usize])
    }
    fn u16(&self, at: u64) -> Result<u16, String> {
        let b = self.get(at, 2)?;
        Ok(if self.le {
            u16::from_le_bytes([b[0], b[1]])
        } else {
            u16::from_be_bytes([b[0], b[1]])
        })
    }
    fn u32(&self, at: u64) -> Result<u32, String> {
        let b: [u8; 4] = self.get(at, 4)?.try_into().map_err(|_| "short read")?;
        Ok(if self.le {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }
    fn u64(&self, at: u64) -> Result<u64, String> {
        let b: [u8; 8] = self.get(at, 8)?.try_into().map_err(|_| "short read")?;
        Ok(if self.le {
            u64::from_le_bytes(b)
        } else {
            u64::from_be_bytes(b)
        })
    }
}

impl Tiff {
    /// Parses the header and the chain of directories.
    pub fn parse(data: &[u8]) -> Result<Tiff, String> {
        if data.len() < 8 {
            return Err(format!(
                "file is {} bytes, too short to be a TIFF",
                data.len()
            ));
        }
        let le = match &data[..2] {
            b"II" => true,
            b"MM" => false,
            _ => return Err("not a TIFF file (no II/MM byte-order mark at byte 0)".into()),
        };
        let b = Bytes { data, le };
        let (big, mut next) = match b.u16(2)? {
            42 => (false, b.u32(4)? as u64),
            43 => {
                if b.u16(4)? != 8 {
                    return Err("BigTIFF header has an offset size other than 8 at byte 4".into());
                }
                (true, b.u64(8)?)
            }
            v => return Err(format!("not a TIFF file (version {v} at byte 2)")),
        };
        let mut ifds = Vec::new();
        while next != 0 {
            if ifds.len() >= MAX_IFDS {
                return Err(format!(
                    "more than {MAX_IFDS} directories: corrupt IFD chain"
                ));
            }
            if ifds.iter().any(|i: &Ifd| i.offset == next) {
                return Err(format!("IFD chain loops back to byte {next}"));
            }
            let at = next;
            let (n, entry_size, first) = if big {
                (b.u64(at)?, 20u64, at + 8)
            } else {
                (b.u16(at)? as u64, 12u64, at + 2)
            };
            if n > 4096 {
                return Err(format!("IFD at byte {at} claims {n} entries"));
            }
            let mut entries = BTreeMap::new();
            for k in 0..n {
                let e = first + k * entry_size;
                let tag = b.u16(e)?;
                let typ = b.u16(e + 2)?;
                let (count, value_at) = if big {
                    (b.u64(e + 4)?, e + 12)
                } else {
                    (b.u32(e + 4)? as u64, e + 8)
                };
                let Some(size) = type_size(typ) else {
                    continue; // Unknown types are skipped, as the TIFF spec asks.
                };
                let total = size
                    .checked_mul(count)
                    .ok_or_else(|| format!("tag {tag} at byte {e}: count {count} overflows"))?;
                let inline = if big { 8 } else { 4 };
                let at = if total <= inline {
                    value_at
                } else if big {
                    b.u64(value_at)?
                } else {
                    b.u32(value_at)? as u64
                };
                entries.insert(tag, Entry { typ, count, at });
            }
            let next_at = first + n * entry_size;
            next = if big {
                b.u64(next_at)?
            } else {
                b.u32(next_at)? as u64
            };
            ifds.push(Ifd {
                offset: at,
                entries,
            });
        }
        if ifds.is_empty() {
            return Err("the TIFF has no image directory".into());
        }
        Ok(Tiff {
            little_endian: le,
            big,
            ifds,
        })
    }

    /// Integer values of `tag` (BYTE, SHORT, LONG, LONG8, IFD types).
    pub fn uints(&self, data: &[u8], ifd: &Ifd, tag: u16) -> Result<Option<Vec<u64>>, String> {
        let Some(e) = ifd.entries.get(&tag) else {
            return Ok(None);
        };
        let b = Bytes {
            data,
            le: self.little_endian,
        };
        let size = type_size(e.typ).unwrap_or(1);
        b.get(e.at, size * e.count)
            .map_err(|m| format!("tag {tag} of the IFD at byte {}: {m}", ifd.offset))?;
        let mut v = Vec::with_capacity(e.count.min(1 << 24) as usize);
        for i in 0..e.count {
            let at = e.at + i * size;
            v.push(match e.typ {
                1 | 7 => data[at as usize] as u64,
                3 => b.u16(at)? as u64,
                4 | 13 => b.u32(at)? as u64,
                16 | 18 => b.u64(at)?,
                t => {
                    return Err(format!(
                        "tag {tag} of the IFD at byte {} has type {t}, not an integer type",
                        ifd.offset
                    ));
                }
            });
        }
        Ok(Some(v))
    }

    /// A single integer value of `tag`.
    pub fn uint(&self, data: &[u8], ifd: &Ifd, tag: u16) -> Result<Option<u64>, String> {
        Ok(self.uints(data, ifd, tag)?.and_then(|v| v.first().copied()))
    }

    /// ASCII value of `tag` (up to its first NUL), decoded lossily as UTF-8.
    pub fn ascii(&self, data: &[u8], ifd: &Ifd, tag: u16) -> Result<Option<String>, String> {
        let Some(e) = ifd.entries.get(&tag) else {
            return Ok(None);
        };
        if e.typ != 2 && e.typ != 1 && e.typ != 7 {
            return Err(format!(
                "tag {tag} of the IFD at byte {} is not text",
                ifd.offset
            ));
        }
        let b = Bytes {
            data,
            le: self.little_endian,
        };
        let raw = b
            .get(e.at, e.count)
            .map_err(|m| format!("tag {tag} of the IFD at byte {}: {m}", ifd.offset))?;
        let end = raw.iter().position(|&c| c == 0).unwrap_or(raw.len());
        Ok(Some(String::from_utf8_lossy(&raw[..end]).into_owned()))
    }
}

impl Tiff {
    /// Bytes from the start of the file to the end of the furthest directory or
    /// out-of-line tag value (the tiles' own bytes excluded): a reader that
    /// fetches `[0, head_len)` has every directory, tile index and metadata.
    pub fn head_len(&self) -> u64 {
        let (count_size, entry_size, next_size) = if self.big { (8, 20, 8) } else { (2, 12, 4) };
        let mut end = if self.big { 16 } else { 8 };
        for ifd in &self.ifds {
            let n = ifd.entries.len() as u64;
            end = end.max(ifd.offset + count_size + n * entry_size + next_size);
            for e in ifd.entries.values() {
                let size = type_size(e.typ).unwrap_or(1) * e.count;
                end = end.max(e.at + size);
            }
        }
        end
    }

    /// The smallest tile offset of any directory (`None`: no tile has bytes).
    pub fn first_tile(&self, data: &[u8]) -> Result<Option<u64>, String> {
        let mut first: Option<u64> = None;
        for ifd in &self.ifds {
            let offsets = self.uints(data, ifd, 324)?.unwrap_or_default();
            let counts = self.uints(data, ifd, 325)?.unwrap_or_default();
            for (o, c) in offsets.iter().zip(&counts) {
                if *c > 0 {
                    first = Some(first.map_or(*o, |f| f.min(*o)));
                }
            }
        }
        Ok(first)
    }

    /// The head's length when every directory and value lies before the first
    /// tile (a part written head-first), else 0 (an older part: directories
    /// after the tiles).
    pub(crate) fn head_first_len(&self, data: &[u8]) -> u64 {
        let head = self.head_len();
        match self.first_tile(data) {
            Ok(Some(first)) if head <= first => head,
            Ok(None) => head,
            _ => 0,
        }
    }
}

/// A tag value to write.
#[derive(Debug, Clone)]
pub enum Value {
    Short(Vec<u16>),
    Long(Vec<u32>),
    Long8(Vec<u64>),
    /// Text; the terminating NUL is added.
    Ascii(String),
}

impl Value {
    fn typ(&self) -> u16 {
        match self {
            Value::Short(_) => 3,
            Value::Long(_) => 4,
            Value::Long8(_) => 16,
            Value::Ascii(_) => 2,
        }
    }
    fn count(&self) -> u64 {
        match self {
            Value::Short(v) => v.len() as u64,
            Value::Long(v) => v.len() as u64,
            Value::Long8(v) => v.len() as u64,
            Value::Ascii(s) => s.len() as u64 + 1,
        }
    }
    fn bytes(&self) -> Vec<u8> {
        let mut b = Vec::new();
        match self {
            Value::Short(v) => v.iter().for_each(|x| b.extend_from_slice(&x.to_ne_bytes())),
            Value::Long(v) => v.iter().for_each(|x| b.extend_from_slice(&x.to_ne_bytes())),
            Value::Long8(v) => v.iter().for_each(|x| b.extend_from_slice(&x.to_ne_bytes())),
            Value::Ascii(s) => {
                b.extend_from_slice(s.as_bytes());
                b.push(0);
            }
        }
        b
    }
    fn len(&self) -> u64 {
        type_size(self.typ()).unwrap_or(1) * self.count()
    }
}

/// One directory to write: its entries (sorted by tag when written).
pub(crate) type Dir = Vec<(u16, Value)>;

/// The head of a TIFF or BigTIFF file in native byte order: the header, then
/// each directory followed by its out-of-line values (each at an 8-byte
/// boundary), the directories chained in order. Its length depends only on
/// the tags and their counts, so it can be sized before the tile offsets are
/// known and written once they are.
pub struct Head {
    pub big: bool,
    pub dirs: Vec<Dir>,
}

fn sorted(d: &Dir) -> Vec<&(u16, Value)> {
    let mut d: Vec<&(u16, Value)> = d.iter().collect();
    d.sort_by_key(|e| e.0);
    d
}

fn align8(v: u64) -> u64 {
    v.div_ceil(8) * 8
}

impl Head {
    fn sizes(&self) -> (u64, u64, u64, u64) {
        if self.big {
            (16, 8, 20, 8)
        } else {
            (8, 2, 12, 4)
        }
    }

    /// Bytes the head takes.
    pub fn len(&self) -> u64 {
        self.layout().1
    }

    /// Whether there is no directory (never written so).
    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }

    /// Offsets of each directory, and the head's end.
    fn layout(&self) -> (Vec<u64>, u64) {
        let (header, count, entry, next) = self.sizes();
        let inline = if self.big { 8 } else { 4 };
        let mut at = header;
        let mut starts = Vec::with_capacity(self.dirs.len());
        for d in &self.dirs {
            at = align8(at);
            starts.push(at);
            at += count + d.len() as u64 * entry + next;
            for (_, v) in sorted(d) {
                if v.len() > inline {
                    at = align8(at) + v.len();
                }
            }
        }
        (starts, at)
    }

    /// The head's bytes.
    pub(crate) fn to_bytes(&self) -> Vec<u8> {
        let (header, _, _, _) = self.sizes();
        let (starts, end) = self.layout();
        let inline = if self.big { 8 } else { 4 };
        let mut b = vec![0u8; end as usize];
        let le = cfg!(target_endian = "little");
        b[..2].copy_from_slice(if le { b"II" } else { b"MM" });
        let put = |b: &mut Vec<u8>, at: u64, v: &[u8]| {
            b[at as usize..at as usize + v.len()].copy_from_slice(v);
        };
        let first = starts.first().copied().unwrap_or(0);
        if self.big {
            put(&mut b, 2, &43u16.to_ne_bytes());
            put(&mut b, 4, &8u16.to_ne_bytes());
            put(&mut b, 8, &first.to_ne_bytes());
        } else {
            put(&mut b, 2, &42u16.to_ne_bytes());
            put(&mut b, 4, &(first as u32).to_ne_bytes());
        }
        debug_assert!(first >= header);
        for (k, d) in self.dirs.iter().enumerate() {
            let d = sorted(d);
            let mut at = starts[k];
            if self.big {
                put(&mut b, at, &(d.len() as u64).to_ne_bytes());
                at += 8;
            } else {
                put(&mut b, at, &(d.len() as u16).to_ne_bytes());
                at += 2;
            }
            let entries_at = at;
            let entry = if self.big { 20 } else { 12 };
            let mut value_at = entries_at + d.len() as u64 * entry + if self.big { 8 } else { 4 };
            for (i, (tag, v)) in d.iter().enumerate() {
                let e = entries_at + i as u64 * entry;
                put(&mut b, e, &tag.to_ne_bytes());
                put(&mut b, e + 2, &v.typ().to_ne_bytes());
                let bytes = v.bytes();
                let field = if self.big {
                    put(&mut b, e + 4, &v.count().to_ne_bytes());
                    e + 12
                } else {
                    put(&mut b, e + 4, &(v.count() as u32).to_ne_bytes());
                    e + 8
                };
                if v.len() <= inline {
                    put(&mut b, field, &bytes);
                } else {
                    value_at = align8(value_at);
                    if self.big {
                        put(&mut b, field, &value_at.to_ne_bytes());
                    } else {
                        put(&mut b, field, &(value_at as u32).to_ne_bytes());
                    }
                    put(&mut b, value_at, &bytes);
                    value_at += bytes.len() as u64;
                }
            }
            let next_at = entries_at + d.len() as u64 * entry;
            let next = starts.get(k + 1).copied().unwrap_or(0);
            if self.big {
                put(&mut b, next_at, &next.to_ne_bytes());
            } else {
                put(&mut b, next_at, &(next as u32).to_ne_bytes());
            }
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_garbage_without_panicking() {
        assert!(Tiff::parse(b"").is_err());
        assert!(Tiff::parse(b"GIF89a....").is_err());
        assert!(
            Tiff::parse(b"II*\0\xff\xff\xff\x7f")
                .unwrap_err()
                .contains("truncated")
        );
        // An IFD that points to itself.
        let mut f = b"II*\0\x08\0\0\0".to_vec();
        f.extend_from_slice(&0u16.to_le_bytes());
        f.extend_from_slice(&8u32.to_le_bytes());
        assert!(Tiff::parse(&f).unwrap_err().contains("loops"));
        // Every prefix of a small valid file fails cleanly.
        let mut g = b"II*\0\x08\0\0\0".to_vec();
        g.extend_from_slice(&1u16.to_le_bytes());
        g.extend_from_slice(&256u16.to_le_bytes());
        g.extend_from_slice(&4u16.to_le_bytes());
        g.extend_from_slice(&1u32.to_le_bytes());
        g.extend_from_slice(&512u32.to_le_bytes());
        g.extend_from_slice(&0u32.to_le_bytes());
        let t = Tiff::parse(&g).unwrap();
        assert_eq!(t.uint(&g, &t.ifds[0], 256).unwrap(), Some(512));
        for n in 0..g.len() {
            assert!(Tiff::parse(&g[..n]).is_err());
        }
    }
}
