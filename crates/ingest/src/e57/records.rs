//! One scan's binary section (ASTM E2807's compressed vector) decoded straight
//! from the memory map into a column of values per record.
//!
//! Our own decoder, not the `e57` crate's raw reader, because that one was the
//! E57 conversion's bottleneck (issue 42): it copies every 1 KiB page, queues
//! each value as an enum in a `VecDeque`, and allocates a `Vec` per point; with
//! it an E57 file converted at a third of LAS's speed. This one checks the same
//! things (each page's CRC-32C, the section and packet headers, the bytestream
//! count and lengths, that the packets hold every record) and unpacks each value
//! with one unaligned load. The crate still parses the header and the XML
//! section; `tests` below decode files of every record type both ways and
//! compare every value bit for bit.

use e57::{PointCloud, RecordDataType};

/// Physical page size of every E57 file, and the logical bytes in a page (the
/// last four hold its checksum).
const PAGE: u64 = 1024;
const DATA: u64 = PAGE - 4;

/// A decoding failure: the physical byte offset and what was wrong.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Fault {
    pub offset: u64,
    pub message: String,
}

fn fault<T>(offset: u64, message: impl Into<String>) -> Result<T, Fault> {
    Err(Fault {
        offset,
        message: message.into(),
    })
}

fn physical(logical: u64) -> u64 {
    logical / DATA * PAGE + logical % DATA
}

fn logical(physical: u64) -> u64 {
    physical / PAGE * DATA + (physical % PAGE).min(DATA)
}

/// The file's logical bytes, page checksums checked as pages are first read.
struct Paged<'a> {
    map: &'a [u8],
    /// Pages `checked.0..checked.1` have been checked.
    checked: (u64, u64),
}

impl<'a> Paged<'a> {
    fn new(map: &'a [u8]) -> Paged<'a> {
        Paged {
            map,
            checked: (0, 0),
        }
    }

    fn check(&mut self, page: u64) -> Result<(), Fault> {
        if page >= self.checked.0 && page < self.checked.1 {
            return Ok(());
        }
        let at = page * PAGE;
        let Some(bytes) = self.map.get(at as usize..(at + PAGE) as usize) else {
            return fault(at.min(self.map.len() as u64), "the file ends inside a page");
        };
        let (data, sum) = bytes.split_at(DATA as usize);
        // Big-endian, as every E57 writer stores it.
        if crc32c::crc32c(data).to_be_bytes() != sum {
            return fault(at, format!("the checksum of page {page} does not match"));
        }
        self.checked = if page == self.checked.1 {
            (self.checked.0, page + 1)
        } else {
            (page, page + 1)
        };
        Ok(())
    }

    /// Copies the logical bytes from `at` into `out`.
    fn read(&mut self, mut at: u64, mut out: &mut [u8]) -> Result<(), Fault> {
        while !out.is_empty() {
            let page = at / DATA;
            self.check(page)?;
            let within = at % DATA;
            let n = ((DATA - within) as usize).min(out.len());
            let from = (page * PAGE + within) as usize;
            out[..n].copy_from_slice(&self.map[from..from + n]);
            out = &mut out[n..];
            at += n as u64;
        }
        Ok(())
    }

    /// Appends `n` logical bytes from `at` to `out`.
    fn append(&mut self, at: u64, n: usize, out: &mut Vec<u8>) -> Result<(), Fault> {
        let start = out.len();
        out.resize(start + n, 0);
        self.read(at, &mut out[start..])
    }
}

/// How a record's values are stored.
#[derive(Debug, Clone, Copy)]
enum Kind {
    Single,
    Double,
    /// `min + bits` as an integer.
    Integer {
        min: i64,
    },
    /// `(min + bits) * scale + offset`.
    Scaled {
        min: i64,
        scale: f64,
        offset: f64,
    },
    /// Zero bits: every value is this one.
    Constant(f64),
}

/// One record's bytestream and the values unpacked from it so far.
struct Stream {
    kind: Kind,
    bits: u32,
    /// Unconsumed bytes, then 16 zero bytes so that loads may run over.
    bytes: Vec<u8>,
    /// Bytes of `bytes` that are data.
    len: usize,
    /// Bit position in `bytes` of the next value.
    bit: usize,
    values: Vec<f64>,
    /// Values of `values` already handed out.
    taken: usize,
}

const PAD: usize = 16;

impl Stream {
    fn new(dt: &RecordDataType) -> Stream {
        let int_bits = |min: i64, max: i64| {
            let range = max as i128 - min as i128;
            if range > 0 { range.ilog2() + 1 } else { 0 }
        };
        let (kind, bits) = match *dt {
            RecordDataType::Single { .. } => (Kind::Single, 32),
            RecordDataType::Double { .. } => (Kind::Double, 64),
            RecordDataType::Integer { min, max } => match int_bits(min, max) {
                0 => (Kind::Constant(min as f64), 0),
                b => (Kind::Integer { min }, b),
            },
            RecordDataType::ScaledInteger {
                min,
                max,
                scale,
                offset,
            } => match int_bits(min, max) {
                0 => (Kind::Constant(min as f64 * scale + offset), 0),
                b => (Kind::Scaled { min, scale, offset }, b),
            },
        };
        Stream {
            kind,
            bits,
            bytes: vec![0; PAD],
            len: 0,
            bit: 0,
            values: Vec::new(),
            taken: 0,
        }
    }

    fn available(&self) -> usize {
        self.values.len() - self.taken
    }

    /// Unpacks every whole value in the bytes held.
    fn unpack(&mut self) {
        let bits = self.bits as usize;
        if bits == 0 {
            return;
        }
        let n = (self.len * 8 - self.bit) / bits;
        self.values.reserve(n);
        let mask = if bits == 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        };
        let mut bit = self.bit;
        let b = &self.bytes;
        for _ in 0..n {
            let (byte, shift) = (bit / 8, (bit % 8) as u32);
            let raw = if shift as usize + bits <= 64 {
                let w = u64::from_le_bytes(b[byte..byte + 8].try_into().unwrap());
                (w >> shift) & mask
            } else {
                let w = u128::from_le_bytes(b[byte..byte + 16].try_into().unwrap());
                (w >> shift) as u64 & mask
            };
            bit += bits;
            let v = match self.kind {
                Kind::Single => f32::from_bits(raw as u32) as f64,
                Kind::Double => f64::from_bits(raw),
                Kind::Integer { min } => (raw as i128 + min as i128) as i64 as f64,
                Kind::Scaled { min, scale, offset } => {
                    (raw as i128 + min as i128) as i64 as f64 * scale + offset
                }
                Kind::Constant(c) => c,
            };
            self.values.push(v);
        }
        // Keep the partial byte (and the padding).
        let consumed = bit / 8;
        self.bytes.drain(..consumed);
        self.len -= consumed;
        self.bit = bit % 8;
    }

    /// Adds `n` bytes of the stream from logical offset `at`.
    fn append(&mut self, paged: &mut Paged<'_>, at: u64, n: usize) -> Result<(), Fault> {
        self.bytes.truncate(self.len);
        paged.append(at, n, &mut self.bytes)?;
        self.len += n;
        self.bytes.resize(self.len + PAD, 0);
        Ok(())
    }

    /// Drops the values handed out.
    fn compact(&mut self) {
        if self.taken > 0 {
            self.values.drain(..self.taken);
            self.taken = 0;
        }
    }
}

/// The records of one scan, packet by packet.
pub(crate) struct Records<'a> {
    paged: Paged<'a>,
    streams: Vec<Stream>,
    /// Logical offset of the next packet, and of the section's end.
    next: u64,
    end: u64,
    /// Records not yet handed out.
    left: u64,
    /// Records ready: each stream holds at least this many (constant ones any).
    ready: usize,
}

impl<'a> Records<'a> {
    /// The binary section of `pc` in the file `map`.
    pub fn new(map: &'a [u8], pc: &PointCloud) -> Result<Records<'a>, Fault> {
        let mut paged = Paged::new(map);
        let start = pc.file_offset;
        if start % PAGE >= DATA {
            return fault(start, "the scan's binary section starts inside a checksum");
        }
        let at = logical(start);
        let mut head = [0u8; 32];
        paged.read(at, &mut head)?;
        let word = |i: usize| u64::from_le_bytes(head[i..i + 8].try_into().unwrap());
        if head[0] != 1 {
            return fault(start, "not a compressed vector section (its id is not 1)");
        }
        let (length, data) = (word(8), word(16));
        let file_logical = logical(map.len() as u64);
        let end = at.saturating_add(length);
        if end > file_logical || length < 32 {
            return fault(
                start,
                format!("the binary section's length ({length} bytes) does not fit the file"),
            );
        }
        let next = logical(data);
        if data % PAGE >= DATA || next < at + 32 || next > end {
            return fault(
                start,
                format!("the first data packet's offset ({data}) is outside the section"),
            );
        }
        Ok(Records {
            paged,
            streams: pc
                .prototype
                .iter()
                .map(|r| Stream::new(&r.data_type))
                .collect(),
            next,
            end,
            left: pc.records,
            ready: 0,
        })
    }

    /// Decodes packets until some records are ready; how many (0: all were
    /// handed out). Hand them out with [`Records::values`], then [`Records::take`].
    pub fn fill(&mut self) -> Result<usize, Fault> {
        let constants = self
            .streams
            .iter()
            .all(|s| matches!(s.kind, Kind::Constant(_)));
        while self.ready == 0 && self.left > 0 {
            if constants {
                // Every record of the prototype holds its one value in no
                // bytes: the records need no packet; a block at a time.
                self.ready = self.left.min(1 << 16) as usize;
                break;
            }
            self.packet()?;
            let mut ready = usize::MAX;
            for s in &self.streams {
                if !matches!(s.kind, Kind::Constant(_)) {
                    ready = ready.min(s.available());
                }
            }
            self.ready = (ready as u64).min(self.left) as usize;
        }
        Ok(self.ready)
    }

    /// The values of ready record `k` (below what [`Records::fill`] gave),
    /// one per record of the prototype, into `out`.
    #[inline]
    pub fn values(&self, k: usize, out: &mut [f64]) {
        for (o, s) in out.iter_mut().zip(&self.streams) {
            *o = match s.kind {
                Kind::Constant(c) => c,
                _ => s.values[s.taken + k],
            };
        }
    }

    /// Marks the ready records handed out.
    pub fn take(&mut self) {
        let n = self.ready;
        for s in &mut self.streams {
            if !matches!(s.kind, Kind::Constant(_)) {
                s.taken += n;
                s.compact();
            }
        }
        self.left -= n as u64;
        self.ready = 0;
    }

    /// Physical offset of the next packet (for progress and errors).
    pub fn offset(&self) -> u64 {
        physical(self.next)
    }

    /// Reads the next packet; data packets add to the streams.
    fn packet(&mut self) -> Result<(), Fault> {
        let at = self.next;
        let here = physical(at);
        if at + 4 > self.end {
            return fault(
                here,
                format!(
                    "the binary section ends with {} records still to read",
                    self.left
                ),
            );
        }
        let mut head = [0u8; 6];
        self.paged.read(at, &mut head[..4])?;
        let length = u16::from_le_bytes([head[2], head[3]]) as u64 + 1;
        if at + length > self.end {
            return fault(
                here,
                format!("a packet of {length} bytes runs past its section"),
            );
        }
        self.next = at + length;
        match head[0] {
            // Index and empty packets: skipped.
            0 | 2 => return Ok(()),
            1 => {}
            t => return fault(here, format!("unknown packet type {t}")),
        }
        self.paged.read(at + 4, &mut head[4..6])?;
        let count = u16::from_le_bytes([head[4], head[5]]) as usize;
        if count != self.streams.len() {
            return fault(
                here,
                format!(
                    "a data packet holds {count} bytestreams, the scan has {} records",
                    self.streams.len()
                ),
            );
        }
        let mut lengths = vec![0u8; 2 * count];
        self.paged.read(at + 6, &mut lengths)?;
        let mut pos = at + 6 + 2 * count as u64;
        for (i, s) in self.streams.iter_mut().enumerate() {
            let n = u16::from_le_bytes([lengths[2 * i], lengths[2 * i + 1]]) as usize;
            if pos + n as u64 > self.next {
                return fault(here, "a data packet's bytestreams run past the packet");
            }
            s.append(&mut self.paged, pos, n)?;
            s.unpack();
            pos += n as u64;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use e57::{E57Reader, E57Writer, Record, RecordName, RecordValue};

    fn fixture(name: &str) -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../fixtures")
            .join(name)
    }

    /// Every value of every scan of `path`, through the crate and through ours.
    fn both(path: &std::path::Path) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let mut reader = E57Reader::from_file(path).unwrap();
        let map = std::fs::read(path).unwrap();
        let (mut theirs, mut ours) = (Vec::new(), Vec::new());
        for pc in reader.pointclouds() {
            let types: Vec<_> = pc.prototype.iter().map(|r| r.data_type.clone()).collect();
            let mut t = Vec::new();
            for p in reader.pointcloud_raw(&pc).unwrap() {
                for (v, dt) in p.unwrap().iter().zip(&types) {
                    t.push(v.to_f64(dt).unwrap());
                }
            }
            let mut o = Vec::new();
            let mut rec = Records::new(&map, &pc).unwrap();
            let mut vals = vec![0.0; types.len()];
            while rec.fill().unwrap() > 0 {
                for k in 0..rec.ready {
                    rec.values(k, &mut vals);
                    o.extend_from_slice(&vals);
                }
                rec.take();
            }
            theirs.push(t);
            ours.push(o);
        }
        (theirs, ours)
    }

    fn same(path: &std::path::Path) {
        let (theirs, ours) = both(path);
        assert_eq!(theirs.len(), ours.len());
        for (t, o) in theirs.iter().zip(&ours) {
            assert_eq!(t.len(), o.len(), "{}", path.display());
            for (k, (a, b)) in t.iter().zip(o).enumerate() {
                assert!(
                    a.to_bits() == b.to_bits(),
                    "{}: value {k}: {a} against {b}",
                    path.display()
                );
            }
        }
    }

    #[test]
    fn every_fixture_decodes_as_the_crate_decodes_it() {
        for f in [
            "bunnyFloat.e57",
            "bunnyInt21.e57",
            "integer_intensity.e57",
            "las2e57_no_images_tag.e57",
            "tinyCartesianFloatRgb.e57",
            "tiny_pc_and_images.e57",
            "tiny_spherical.e57",
        ] {
            same(&fixture(f));
        }
    }

    /// Every record type and odd bit widths (1, 7, 13, 33, 58 and 63 bits,
    /// 32 and 64 as floats, and zero-bit constants), over many packets and two
    /// scans. (The crate cannot write 64-bit integer ranges.)
    #[test]
    fn every_record_type_and_width_decodes_as_the_crate_decodes_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("types.e57");
        let ranges: [(i64, i64); 8] = [
            (0, 1),
            (-3, 100),
            (-4096, 4095),
            (0, 1 << 32),
            (i64::MIN / 2, i64::MAX / 2),
            (0, 1 << 57),
            (5, 5),
            (-7, -7),
        ];
        let mut proto = vec![
            Record {
                name: RecordName::CartesianX,
                data_type: RecordDataType::F64,
            },
            Record {
                name: RecordName::CartesianY,
                data_type: RecordDataType::F32,
            },
            Record {
                name: RecordName::CartesianZ,
                data_type: RecordDataType::ScaledInteger {
                    min: -1_000_000,
                    max: 1_000_000,
                    scale: 0.001,
                    offset: 12.5,
                },
            },
        ];
        for (i, (min, max)) in ranges.iter().enumerate() {
            proto.push(Record {
                name: RecordName::Unknown {
                    namespace: "t".into(),
                    name: format!("r{i}"),
                },
                data_type: RecordDataType::Integer {
                    min: *min,
                    max: *max,
                },
            });
        }
        let mut w = E57Writer::from_file(&path, "records-test").unwrap();
        w.register_extension(e57::Extension {
            namespace: "t".into(),
            url: "https://example.com/t".into(),
        })
        .unwrap();
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for (scan, n) in [(0, 70_001u64), (1, 3)] {
            let mut pc = w
                .add_pointcloud(&format!("s{scan}"), proto.clone())
                .unwrap();
            for _ in 0..n {
                let mut values = vec![
                    RecordValue::Double(f64::from_bits(next() >> 2)),
                    RecordValue::Single(f32::from_bits((next() >> 34) as u32)),
                    RecordValue::ScaledInteger((next() % 2_000_001) as i64 - 1_000_000),
                ];
                for (min, max) in ranges {
                    let span = (max as i128 - min as i128 + 1) as u128;
                    let v = (min as i128 + (next() as u128 % span) as i128) as i64;
                    values.push(RecordValue::Integer(v));
                }
                pc.add_point(values).unwrap();
            }
            pc.finalize().unwrap();
        }
        w.finalize().unwrap();
        same(&path);
    }

    /// The physical end of `pc`'s binary section in `map`.
    fn section_end(map: &[u8], pc: &PointCloud) -> u64 {
        let mut head = [0u8; 32];
        Paged::new(map)
            .read(logical(pc.file_offset), &mut head)
            .unwrap();
        let length = u64::from_le_bytes(head[8..16].try_into().unwrap());
        physical(logical(pc.file_offset) + length)
    }

    fn decode_all(map: &[u8], pc: &PointCloud) -> Result<u64, Fault> {
        let mut rec = Records::new(map, pc)?;
        let mut n = 0;
        loop {
            let ready = rec.fill()?;
            if ready == 0 {
                return Ok(n);
            }
            n += ready as u64;
            rec.take();
        }
    }

    /// Coordinates that are all one value take no bytes, and a prototype of
    /// such records alone needs no packet at all (the crate cannot write one:
    /// here the file has a 1-bit record too, left out of the prototype read).
    #[test]
    fn records_of_one_value_take_no_bytes_and_every_record_is_given() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("constants.e57");
        let record = |name, min, max| Record {
            name,
            data_type: RecordDataType::Integer { min, max },
        };
        let proto = vec![
            record(RecordName::CartesianX, 5, 5),
            record(RecordName::CartesianY, -2, -2),
            record(RecordName::CartesianZ, 9, 9),
            record(RecordName::Intensity, 0, 1),
        ];
        let mut w = E57Writer::from_file(&path, "constants").unwrap();
        let mut pc = w.add_pointcloud("c", proto).unwrap();
        for i in 0..70_000 {
            let v = [5, -2, 9, i % 2].map(RecordValue::Integer).to_vec();
            pc.add_point(v).unwrap();
        }
        pc.finalize().unwrap();
        w.finalize().unwrap();
        same(&path);
        let reader = E57Reader::from_file(&path).unwrap();
        let map = std::fs::read(&path).unwrap();
        let mut pc = reader.pointclouds()[0].clone();
        pc.prototype.truncate(3);
        let mut rec = Records::new(&map, &pc).unwrap();
        let (mut n, mut vals) = (0, [0.0; 3]);
        while rec.fill().unwrap() > 0 {
            for k in 0..rec.ready {
                rec.values(k, &mut vals);
                assert_eq!(vals, [5.0, -2.0, 9.0]);
            }
            n += rec.ready;
            rec.take();
        }
        assert_eq!(n, 70_000);
    }

    #[test]
    fn a_bad_page_checksum_names_its_page() {
        let path = fixture("bunnyInt21.e57");
        let reader = E57Reader::from_file(&path).unwrap();
        let pc = &reader.pointclouds()[0];
        let mut map = std::fs::read(&path).unwrap();
        assert_eq!(decode_all(&map, pc), Ok(pc.records));
        let page = (pc.file_offset + section_end(&map, pc)) / 2 / PAGE;
        map[(page * PAGE + 100) as usize] ^= 0x10;
        let e = decode_all(&map, pc).unwrap_err();
        assert_eq!(e.offset, page * PAGE, "{e:?}");
        assert!(e.message.contains("checksum"), "{e:?}");
    }

    #[test]
    fn a_section_cut_short_is_an_error_not_a_panic() {
        let path = fixture("bunnyInt21.e57");
        let reader = E57Reader::from_file(&path).unwrap();
        let full = std::fs::read(&path).unwrap();
        let pc = &reader.pointclouds()[0];
        let (start, end) = (pc.file_offset, section_end(&full, pc));
        for cut in [0, start + 10, start + 1500, (start + end) / 2, end - 1] {
            let e = decode_all(&full[..cut as usize], pc).expect_err("a cut file decoded");
            assert!(e.offset <= cut, "cut {cut}: {e:?}");
        }
    }

    #[test]
    fn fewer_records_than_the_xml_declares_is_an_error() {
        let path = fixture("bunnyInt21.e57");
        let reader = E57Reader::from_file(&path).unwrap();
        let map = std::fs::read(&path).unwrap();
        let mut pc = reader.pointclouds()[0].clone();
        // (A stream's padding may hold a whole value more: count well beyond.)
        pc.records += 1000;
        let e = decode_all(&map, &pc).unwrap_err();
        assert!(e.message.contains("records still to read"), "{e:?}");
        // And more than declared are left alone.
        pc.records -= 1001;
        assert_eq!(decode_all(&map, &pc), Ok(pc.records));
    }
}
