//! Streaming LZF decoding (liblzf's format, which PCL's `binary_compressed` uses):
//! a [`Cursor`] decodes any stretch of the output without the whole of it in
//! memory, since a back reference reaches at most [`WINDOW`] bytes back. A cursor
//! is cloned where each field's column starts, so the columns of a chunk of
//! points are decoded side by side (and in parallel), a few KiB each.

/// The farthest back an LZF back reference reaches: `(31 << 8) + 255 + 1`.
pub const WINDOW: usize = 8192;
const MASK: usize = WINDOW - 1;

/// A malformed stream: what is wrong and the offset in the compressed data.
#[derive(Debug, Clone, PartialEq)]
pub struct LzfError {
    pub at: usize,
    pub msg: &'static str,
}

/// What the last instruction still has to produce.
#[derive(Debug, Clone, Copy)]
enum Pending {
    None,
    Literal(usize),
    Copy { left: usize, dist: usize },
}

/// A decoder positioned anywhere in an LZF stream: the input offset, the
/// unfinished instruction and the last [`WINDOW`] bytes produced.
#[derive(Clone)]
pub struct Cursor {
    ip: usize,
    produced: u64,
    pending: Pending,
    ring: Box<[u8]>,
}

impl Default for Cursor {
    fn default() -> Self {
        Cursor {
            ip: 0,
            produced: 0,
            pending: Pending::None,
            ring: vec![0; WINDOW].into_boxed_slice(),
        }
    }
}

impl Cursor {
    /// Bytes of output produced so far.
    pub fn produced(&self) -> u64 {
        self.produced
    }

    /// Offset of the next input byte.
    pub(crate) fn input_offset(&self) -> usize {
        self.ip
    }

    /// Whether the stream `src` is used up exactly: no input left, nothing pending.
    pub(crate) fn at_end(&self, src: &[u8]) -> bool {
        matches!(self.pending, Pending::None) && self.ip == src.len()
    }

    fn keep(&mut self, bytes: &[u8]) {
        // Only the last WINDOW bytes matter.
        let skip = bytes.len().saturating_sub(WINDOW);
        let at = (self.produced as usize + skip) & MASK;
        let bytes = &bytes[skip..];
        let first = bytes.len().min(WINDOW - at);
        self.ring[at..at + first].copy_from_slice(&bytes[..first]);
        self.ring[..bytes.len() - first].copy_from_slice(&bytes[first..]);
    }

    /// Fills `dst` with the next `dst.len()` bytes of the stream `src`.
    pub fn read(&mut self, src: &[u8], dst: &mut [u8]) -> Result<(), LzfError> {
        let mut o = 0;
        while o < dst.len() {
            match self.pending {
                Pending::Literal(left) => {
                    let k = left.min(dst.len() - o);
                    let s = src.get(self.ip..self.ip + k).ok_or(LzfError {
                        at: src.len(),
                        msg: "a literal run goes past the end of the compressed data",
                    })?;
                    dst[o..o + k].copy_from_slice(s);
                    self.keep(s);
                    self.produced += k as u64;
                    self.ip += k;
                    o += k;
                    self.pending = if left > k {
                        Pending::Literal(left - k)
                    } else {
                        Pending::None
                    };
                }
                Pending::Copy { left, dist } => {
                    let k = left.min(dst.len() - o);
                    for d in &mut dst[o..o + k] {
                        let p = self.produced as usize;
                        let b = self.ring[(p - dist) & MASK];
                        self.ring[p & MASK] = b;
                        *d = b;
                        self.produced += 1;
                    }
                    o += k;
                    self.pending = if left > k {
                        Pending::Copy {
                            left: left - k,
                            dist,
                        }
                    } else {
                        Pending::None
                    };
                }
                Pending::None => {
                    let at = self.ip;
                    let byte = |i: usize| {
                        src.get(i).copied().ok_or(LzfError {
                            at: src.len(),
                            msg: "the compressed data ends before the declared uncompressed size",
                        })
                    };
                    let ctrl = byte(at)? as usize;
                    if ctrl < 32 {
                        self.ip = at + 1;
                        self.pending = Pending::Literal(ctrl + 1);
                    } else {
                        let mut len = ctrl >> 5;
                        let mut i = at + 1;
                        if len == 7 {
                            len += byte(i)? as usize;
                            i += 1;
                        }
                        let dist = ((ctrl & 31) << 8) + byte(i)? as usize + 1;
                        if dist as u64 > self.produced {
                            return Err(LzfError {
                                at,
                                msg: "a back reference points before the start of the data",
                            });
                        }
                        self.ip = i + 1;
                        self.pending = Pending::Copy {
                            left: len + 2,
                            dist,
                        };
                    }
                }
            }
        }
        Ok(())
    }
}

/// LZF-compresses `input` (greedy, a hash of the next three bytes): for
/// writing `binary_compressed` PCD files (benchmarks, the fuzzer's seeds).
pub fn compress(input: &[u8]) -> Vec<u8> {
    const HLOG: u32 = 14;
    let mut out = Vec::with_capacity(input.len() / 2 + 16);
    let mut table = vec![0usize; 1 << HLOG];
    let mut lit_from = 0;
    let flush = |out: &mut Vec<u8>, lit: &[u8]| {
        for run in lit.chunks(32) {
            out.push((run.len() - 1) as u8);
            out.extend_from_slice(run);
        }
    };
    let mut i = 0;
    while i + 2 < input.len() {
        let v = u32::from_le_bytes([input[i], input[i + 1], input[i + 2], 0]);
        let h = (v.wrapping_mul(2_654_435_761) >> (32 - HLOG)) as usize;
        let cand = table[h];
        table[h] = i + 1;
        if cand > 0 {
            let r = cand - 1;
            let dist = i - r;
            if dist <= WINDOW && input[r..r + 3] == input[i..i + 3] {
                let max = (input.len() - i).min(264);
                let mut len = 3;
                while len < max && input[r + len] == input[i + len] {
                    len += 1;
                }
                flush(&mut out, &input[lit_from..i]);
                let (d, l) = (dist - 1, len - 2);
                if l < 7 {
                    out.push(((l << 5) | (d >> 8)) as u8);
                } else {
                    out.push(((7 << 5) | (d >> 8)) as u8);
                    out.push((l - 7) as u8);
                }
                out.push((d & 255) as u8);
                i += len;
                lit_from = i;
                continue;
            }
        }
        i += 1;
    }
    flush(&mut out, &input[lit_from..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A literal run of `b"abc"`, then a back reference copying 6 bytes from 3
    /// back (overlapping), then a literal `z`.
    const STREAM: &[u8] = &[2, b'a', b'b', b'c', (4 << 5), 2, 0, b'z'];

    #[test]
    fn decodes_whole_and_in_pieces() {
        let mut c = Cursor::default();
        let mut out = vec![0; 10];
        c.read(STREAM, &mut out).unwrap();
        assert_eq!(&out, b"abcabcabcz");
        assert!(c.at_end(STREAM));
        // One byte at a time, through the pending states.
        let mut c = Cursor::default();
        let mut got = Vec::new();
        for _ in 0..10 {
            let mut b = [0u8];
            c.read(STREAM, &mut b).unwrap();
            got.push(b[0]);
        }
        assert_eq!(&got, b"abcabcabcz");
        // A clone continues where its original stood.
        let mut c = Cursor::default();
        let mut head = [0u8; 4];
        c.read(STREAM, &mut head).unwrap();
        let mut d = c.clone();
        let mut tail = [0u8; 6];
        d.read(STREAM, &mut tail).unwrap();
        assert_eq!(&tail, b"bcabcz");
    }

    #[test]
    fn long_windows_wrap() {
        // 10,000 literal bytes in runs of 32, then a copy from 8,192 back.
        let data: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut src = Vec::new();
        for run in data.chunks(32) {
            src.push((run.len() - 1) as u8);
            src.extend_from_slice(run);
        }
        src.extend_from_slice(&[(1 << 5) | 31, 255]);
        let mut c = Cursor::default();
        let mut out = vec![0; 10_003];
        c.read(&src, &mut out).unwrap();
        assert_eq!(&out[..10_000], &data[..]);
        assert_eq!(&out[10_000..], &data[10_000 - 8192..10_000 - 8192 + 3]);
        assert!(c.at_end(&src));
    }

    #[test]
    fn compress_round_trips() {
        let mut data: Vec<u8> = (0..50_000u32).map(|i| (i / 7 % 13) as u8).collect();
        data.extend((0..20_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8));
        let z = compress(&data);
        assert!(z.len() < data.len());
        let mut c = Cursor::default();
        let mut out = vec![0; data.len()];
        c.read(&z, &mut out).unwrap();
        assert_eq!(out, data);
        assert!(c.at_end(&z));
        assert!(compress(b"").is_empty());
    }

    #[test]
    fn malformed_streams_are_errors() {
        let mut out = [0u8; 8];
        // A back reference with nothing before it.
        let e = Cursor::default()
            .read(&[(1 << 5), 0], &mut out)
            .unwrap_err();
        assert_eq!(e.at, 0);
        // A literal run cut short.
        assert!(Cursor::default().read(&[5, 1, 2], &mut out).is_err());
        // The stream ends before the output is full.
        assert!(Cursor::default().read(&[0, 1], &mut out).is_err());
    }
}
