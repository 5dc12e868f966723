//! Against `fixtures/autzen_trim.copc.laz` (written by `copc_converter`).

use super::*;
use std::sync::atomic::{AtomicUsize, Ordering};

fn fixture() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/autzen_trim.copc.laz")
}

/// A source over bytes in memory that counts its reads.
struct Counted {
    bytes: Vec<u8>,
    reads: AtomicUsize,
}

impl ByteSource for Counted {
    fn name(&self) -> String {
        "mem.copc.laz".into()
    }
    fn read_prefix(&self, max: u64) -> std::io::Result<Vec<u8>> {
        self.reads.fetch_add(1, Ordering::Relaxed);
        Ok(self.bytes[..(max as usize).min(self.bytes.len())].to_vec())
    }
    fn size(&self) -> std::io::Result<u64> {
        Ok(self.bytes.len() as u64)
    }
    fn read_ranges(&self, ranges: &[Range<u64>]) -> std::io::Result<Vec<Vec<u8>>> {
        self.reads.fetch_add(ranges.len(), Ordering::Relaxed);
        ranges
            .iter()
            .map(|r| {
                self.bytes
                    .get(r.start as usize..r.end as usize)
                    .map(<[u8]>::to_vec)
                    .ok_or_else(|| std::io::Error::other(format!("range {r:?} outside")))
            })
            .collect()
    }
}

fn counted(bytes: Vec<u8>) -> Arc<Counted> {
    Arc::new(Counted {
        bytes,
        reads: AtomicUsize::new(0),
    })
}

fn open_bytes(bytes: Vec<u8>) -> Result<Copc> {
    Copc::open(counted(bytes))
}

#[test]
fn opens_in_two_reads_and_every_node_decompresses_inside_its_cube() {
    let src = counted(std::fs::read(fixture()).unwrap());
    let c = Copc::open(src.clone()).unwrap();
    assert_eq!(
        src.reads.load(Ordering::Relaxed),
        2,
        "header, then the root page"
    );
    assert_eq!(c.header.points, 110_000);
    assert_eq!((c.header.format, c.header.version), (7, (1, 4)));
    let nodes = c.all_nodes().unwrap();
    assert_eq!(
        nodes.iter().map(|e| u64::from(e.points)).sum::<u64>(),
        110_000
    );
    assert_eq!(nodes[0].key, Key::ROOT);
    let chunks = c.fetch(&nodes).unwrap();
    let stride = usize::from(c.header.record_len);
    for (e, chunk) in nodes.iter().zip(&chunks) {
        let rec = c
            .decompress(e, chunk, laz::DecompressionSelection::all())
            .unwrap();
        assert_eq!(rec.len(), stride * e.points as usize);
        let (lo, hi) = e.key.bounds(&c.info);
        for r in rec.chunks_exact(stride) {
            for a in 0..3 {
                let v = c.header.scale[a] * f64::from(i32_at(r, 4 * a)) + c.header.offset[a];
                let eps = c.header.scale[a];
                assert!(v >= lo[a] - eps && v <= hi[a] + eps, "{e:?} axis {a}: {v}");
            }
        }
    }
    // A walk that keeps only one octant's cube reads fewer nodes.
    let (lo, _) = Key::ROOT.bounds(&c.info);
    let corner = c.nodes_where(&|b: &Cube| b.0 == lo, i32::MAX).unwrap();
    assert!(corner.len() < nodes.len() && corner[0].key == Key::ROOT);
}

/// The bytes of the fixture with `patch` applied at `at`.
fn patched(at: usize, patch: &[u8]) -> Vec<u8> {
    let mut b = std::fs::read(fixture()).unwrap();
    b[at..at + patch.len()].copy_from_slice(patch);
    b
}

#[test]
fn a_las_file_is_not_copc_and_says_where() {
    // The LAZ it was made from: LAS 1.2.
    let laz = std::fs::read(fixture().with_file_name("autzen_trim.laz")).unwrap();
    let e = open_bytes(laz).unwrap_err();
    assert_eq!((e.kind, e.offset), (Kind::NotCopc, Some(24)), "{e}");
    // A LAS 1.4 file whose first VLR is not COPC's (as if renamed .copc.laz).
    let e = open_bytes(patched(377, b"notcopc\0")).unwrap_err();
    assert_eq!((e.kind, e.offset), (Kind::NotCopc, Some(375)), "{e}");
    assert!(e.to_string().contains("mem.copc.laz: byte 375: "), "{e}");
    let e = open_bytes(b"PK\x03\x04 a zip".to_vec()).unwrap_err();
    assert_eq!(e.kind, Kind::NotCopc);
}

#[test]
fn broken_hierarchy_and_chunks_are_named_by_byte() {
    let good = open_bytes(std::fs::read(fixture()).unwrap()).unwrap();
    let (root_at, root_size) = (good.info.root_hier_offset, good.info.root_hier_size);
    // A root page cut short by 8 bytes: not whole entries.
    let e = open_bytes(patched(
        INFO_OFFSET as usize + 48,
        &(root_size - 8).to_le_bytes(),
    ))
    .unwrap_err();
    assert_eq!((e.kind, e.offset), (Kind::Corrupt, Some(root_at)), "{e}");
    // A root page said to run past the file's end.
    let e = open_bytes(patched(
        INFO_OFFSET as usize + 48,
        &(1u64 << 40).to_le_bytes(),
    ))
    .unwrap_err();
    assert!(e.to_string().contains("past the file's end"), "{e}");
    // A file cut inside its hierarchy (the page is at its end).
    let mut cut = std::fs::read(fixture()).unwrap();
    cut.truncate(root_at as usize + 16);
    assert_eq!(open_bytes(cut).unwrap_err().kind, Kind::Corrupt);
    // The root entry's point count one more than its chunk holds.
    let root = good.root();
    let entry_at = (root_at..root_at + root_size)
        .step_by(ENTRY_SIZE as usize)
        .find(|&a| {
            let b = &std::fs::read(fixture()).unwrap()[a as usize..a as usize + 16];
            b.iter().all(|&c| c == 0)
        })
        .unwrap();
    let c = open_bytes(patched(
        entry_at as usize + 28,
        &(root.points + 1).to_le_bytes(),
    ))
    .unwrap();
    let r = c.root();
    let chunk = c.fetch(&[r]).unwrap().remove(0);
    let e = c
        .decompress(&r, &chunk, laz::DecompressionSelection::all())
        .unwrap_err();
    assert_eq!((e.kind, e.offset), (Kind::Corrupt, Some(r.offset)), "{e}");
    assert!(e.to_string().contains("the hierarchy says"), "{e}");
    // Garbage in a chunk: an error, never a panic.
    let mut junk = chunk.clone();
    for b in junk.iter_mut().skip(40) {
        *b = b.wrapping_mul(31).wrapping_add(7);
    }
    let _ = good.decompress(&root, &junk, laz::DecompressionSelection::all());
}

/// laspy's `simple_with_page.copc.laz` keeps its hierarchy in two pages: the
/// nodes known after opening are the root page's, the rest only once a walk
/// reads the second page, which adds no read of the first.
#[test]
fn known_nodes_are_those_of_the_pages_read() {
    let path = fixture().with_file_name("laspy/simple_with_page.copc.laz");
    let src = counted(std::fs::read(path).unwrap());
    let c = Copc::open(src.clone()).unwrap();
    let first = c.known_nodes();
    assert_eq!(c.pages(), (1, 1));
    let all = c.all_nodes().unwrap();
    assert_eq!(c.pages(), (2, 0));
    assert!(first.len() < all.len(), "{} of {}", first.len(), all.len());
    assert_eq!(c.known_nodes().len(), all.len());
    let total: u64 = all.iter().map(|e| u64::from(e.points)).sum();
    assert_eq!(total, 1065);
    assert_eq!(
        src.reads.load(Ordering::Relaxed),
        3,
        "header, root page, second page"
    );
}
