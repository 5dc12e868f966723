//! An independent walk over a little-endian TIFF/BigTIFF's directories (not
//! pcimg's parser): where each directory and out-of-line value lies, where the
//! tiles lie, and a rewrite of a head-first part into the older layout (every
//! directory and value after the tiles).

fn u(b: &[u8], at: u64, n: usize) -> u64 {
    let s = &b[at as usize..at as usize + n];
    let mut v = [0u8; 8];
    v[..n].copy_from_slice(s);
    u64::from_le_bytes(v)
}

fn type_size(t: u64) -> u64 {
    match t {
        1 | 2 | 6 | 7 => 1,
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        _ => 8,
    }
}

/// A pointer in the file: its place and width, and whether the value is an
/// offset to relocate.
pub struct Walk {
    pub big: bool,
    /// Byte ranges of the directories and out-of-line values.
    pub structures: Vec<(u64, u64)>,
    /// (offset, byte count) of every tile of every directory.
    pub tiles: Vec<(u64, u64)>,
    /// Places in the file holding an offset of a structure (header, next-IFD
    /// links, out-of-line value pointers), with their widths.
    pointers: Vec<(u64, usize)>,
}

impl Walk {
    pub fn new(b: &[u8]) -> Walk {
        assert_eq!(&b[..2], b"II", "little-endian expected");
        let big = u(b, 2, 2) == 43;
        let (psize, csize, esize) = if big { (8, 8, 20u64) } else { (4, 2, 12) };
        let first_at = if big { 8 } else { 4 };
        let mut pointers = vec![(first_at, psize)];
        let mut structures = Vec::new();
        let mut tiles = Vec::new();
        let mut next = u(b, first_at, psize);
        while next != 0 {
            let n = u(b, next, csize);
            let entries = next + csize as u64;
            let end = entries + n * esize + psize as u64;
            structures.push((next, end));
            let (mut offs, mut counts) = (Vec::new(), Vec::new());
            for k in 0..n {
                let e = entries + k * esize;
                let (tag, typ) = (u(b, e, 2), u(b, e + 2, 2));
                let count = u(b, e + 4, if big { 8 } else { 4 });
                let field = e + if big { 12 } else { 8 };
                let len = type_size(typ) * count;
                let at = if len <= psize as u64 {
                    field
                } else {
                    pointers.push((field, psize));
                    let at = u(b, field, psize);
                    structures.push((at, at + len));
                    at
                };
                let vals: Vec<u64> = (0..count)
                    .map(|i| u(b, at + i * type_size(typ), type_size(typ) as usize))
                    .collect();
                match tag {
                    324 => offs = vals,
                    325 => counts = vals,
                    _ => {}
                }
            }
            tiles.extend(offs.into_iter().zip(counts).filter(|t| t.1 > 0));
            pointers.push((end - psize as u64, psize));
            next = u(b, end - psize as u64, psize);
        }
        Walk {
            big,
            structures,
            tiles,
            pointers,
        }
    }

    /// The end of the furthest directory or value.
    pub fn head_end(&self) -> u64 {
        self.structures.iter().map(|s| s.1).max().unwrap()
    }

    pub fn first_tile(&self) -> u64 {
        self.tiles.iter().map(|t| t.0).min().unwrap()
    }

    /// The file rewritten in the older layout: the bytes `[header, head_end)`
    /// moved after the tiles, every pointer into them moved along, the old
    /// place zeroed.
    pub fn to_old_layout(&self, b: &[u8]) -> Vec<u8> {
        let header = if self.big { 16 } else { 8 };
        let head = self.head_end();
        let mut out = b.to_vec();
        while !out.len().is_multiple_of(8) {
            out.push(0);
        }
        let shift = out.len() as u64 - header;
        out.extend_from_slice(&b[header as usize..head as usize]);
        for &(at, w) in &self.pointers {
            let v = u(b, at, w);
            if v == 0 {
                continue;
            }
            let place = if at < header { at } else { at + shift };
            out[place as usize..place as usize + w]
                .copy_from_slice(&(v + shift).to_le_bytes()[..w]);
        }
        out[header as usize..head as usize].fill(0);
        out
    }
}
