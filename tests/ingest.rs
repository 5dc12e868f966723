//! The input readers against the real sample files in `fixtures/`.

mod common;

use std::path::{Path, PathBuf};

use pcimg::ingest::{self, ReadOptions};
use pcimg::points::PointColumns;

fn sample(name: &str) -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/")).join(name)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * b.abs().max(1.0)
}

#[test]
fn autzen_laz() {
    let p = sample("autzen_trim.laz");
    let (info, pts, skipped) = ingest::read_all(&p, &ReadOptions::default()).unwrap();
    assert_eq!(info.format, "laz 1.2");
    assert_eq!(info.declared_points, Some(110_000));
    assert_eq!(pts.len(), 110_000);
    assert_eq!(skipped, 0);
    pts.check_lengths().unwrap();
    let b = pts.bounds();
    let min = [636001.76, 848935.20, 406.26];
    let max = [637179.22, 849497.90, 520.51];
    for a in 0..3 {
        assert!(close(b.min[a], min[a]), "min {a}: {}", b.min[a]);
        assert!(close(b.max[a], max[a]), "max {a}: {}", b.max[a]);
    }
    assert_eq!(
        info.attribute_names,
        [
            "intensity",
            "return_number",
            "number_of_returns",
            "classification",
            "gps_time",
            "gps_time_lo",
            "gps_time_mid",
            "gps_time_hi",
            "red",
            "green",
            "blue",
            "scan_angle",
            "user_data",
            "point_source_id",
            "las_flags"
        ]
    );
    for c in ["red", "green", "blue"] {
        let v = common::attr(&pts, c);
        let mx = v.iter().cloned().fold(0.0f32, f32::max);
        assert!(mx <= 255.0 && mx > 1.0, "{c} max {mx}");
    }
    let crs = info.crs_wkt.expect("autzen has a CRS");
    assert!(!crs.is_empty());
    // GPS time keeps its precision through the offset.
    let t = pts
        .attributes
        .iter()
        .find(|a| a.name == "gps_time")
        .unwrap();
    // (The offset is the first times' median, a whole second: the stored values
    // are small, so f32 keeps fine steps.)
    assert!(t.offset > 0.0 && t.offset.fract() == 0.0);
    assert!(t.values.iter().take(4096).all(|v| v.abs() < 1e4));
}

#[test]
fn autzen_chunked_equals_whole() {
    let p = sample("autzen_trim.laz");
    let (_, whole, _) = ingest::read_all(&p, &ReadOptions::default()).unwrap();
    let opts = ReadOptions {
        chunk_points: 7_001,
        ..Default::default()
    };
    let mut r = ingest::open(&p, &opts).unwrap();
    let mut n = 0;
    let mut chunks = 0;
    let mut last_bytes = 0;
    while let Some(c) = r.next_chunk().unwrap() {
        assert!(c.len() <= 7_001);
        assert_eq!(c.x[..], whole.x[n..n + c.len()]);
        assert_eq!(c.z[..], whole.z[n..n + c.len()]);
        n += c.len();
        chunks += 1;
        assert!(r.bytes_done() >= last_bytes);
        last_bytes = r.bytes_done();
    }
    assert_eq!(n, 110_000);
    assert_eq!(chunks, 110_000usize.div_ceil(7_001));
    assert_eq!(r.bytes_done(), r.info().file_bytes);
}

#[test]
fn bunny_ascii_ply() {
    let p = sample("bun_zipper.ply");
    let (info, pts, _) = ingest::read_all(&p, &ReadOptions::default()).unwrap();
    assert_eq!(info.format, "ply-ascii");
    assert_eq!(info.declared_points, Some(35_947));
    assert_eq!(pts.len(), 35_947);
    assert_eq!(info.attribute_names, ["confidence", "intensity"]);
    let b = pts.bounds();
    assert!(b.extent().iter().all(|&e| e > 0.0 && e < 1.0), "{b:?}");
    // Chunked read gives the same points.
    let opts = ReadOptions {
        chunk_points: 1000,
        ..Default::default()
    };
    let (_, small, _) = ingest::read_all(&p, &opts).unwrap();
    assert_eq!(small, pts);
}

#[test]
fn cgal_binary_ply() {
    let p = sample("cgal_b9_training.ply");
    let (info, pts, _) = ingest::read_all(&p, &ReadOptions::default()).unwrap();
    assert_eq!(info.format, "ply-binary-le");
    assert_eq!(pts.len(), 22_300);
    assert_eq!(info.attribute_names, ["red", "green", "blue", "label"]);
    for c in ["red", "green", "blue"] {
        let v = common::attr(&pts, c);
        assert!(v.iter().all(|&x| (0.0..=255.0).contains(&x)));
        assert!(v.iter().any(|&x| x > 1.0));
    }
    assert!(pts.x.iter().all(|v| v.is_finite()));
    let opts = ReadOptions {
        chunk_points: 333,
        ..Default::default()
    };
    let (_, small, _) = ingest::read_all(&p, &opts).unwrap();
    assert_eq!(small, pts);
}

#[test]
fn truncated_laz_is_an_error() {
    let data = std::fs::read(sample("autzen_trim.laz")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for keep in [100, 2000, data.len() / 2, data.len() - 10] {
        let p = dir.path().join(format!("cut{keep}.laz"));
        std::fs::write(&p, &data[..keep]).unwrap();
        let r = ingest::read_all(&p, &ReadOptions::default());
        let e = r
            .err()
            .unwrap_or_else(|| panic!("no error for {keep} bytes"));
        let s = e.to_string();
        eprintln!("{s}");
        assert!(s.contains(&format!("cut{keep}.laz")), "{s}");
    }
}

/// A LAZ chunk table whose chunk count is corrupt, or a laszip VLR whose chunk
/// size or point size is, is refused before the `laz` crate reserves memory for that many chunks
/// or points (`benches/fuzz_inputs.rs` found a
/// count that made it ask for 47 GB and abort the process). The table's offset is
/// the first 8 bytes of the point data; its count is the table's second u32.
#[test]
fn corrupt_laz_chunk_count_or_size_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("s.laz");
    pcimg::synth::write_las(&src, 3000, 1).unwrap();
    let data = std::fs::read(&src).unwrap();
    let start = u32::from_le_bytes(data[96..100].try_into().unwrap()) as usize;
    let table = i64::from_le_bytes(data[start..start + 8].try_into().unwrap()) as usize;
    // The untouched file reads.
    assert_eq!(
        ingest::read_all(&src, &ReadOptions::default())
            .unwrap()
            .1
            .len(),
        3000
    );
    for count in [u32::MAX, 1 << 24, 5000] {
        let mut d = data.clone();
        d[table + 4..table + 8].copy_from_slice(&count.to_le_bytes());
        let p = dir.path().join(format!("count{count}.laz"));
        std::fs::write(&p, &d).unwrap();
        let e = ingest::read_all(&p, &ReadOptions::default())
            .err()
            .unwrap_or_else(|| panic!("no error for {count} chunks"));
        let s = e.to_string();
        assert!(s.contains(&format!("count{count}.laz")), "{s}");
        assert!(
            s.contains("chunk table") && s.contains(&count.to_string()),
            "{s}"
        );
    }
    // The laszip VLR's chunk size (its data's bytes 12..16): the `laz` crate
    // reserves a chunk's decoded points for the last chunk (a corrupt size asked
    // for 114 GB). The data follows the user id (16 bytes), record id, length
    // and description (32 bytes).
    let id = data
        .windows(14)
        .position(|w| w == b"laszip encoded")
        .unwrap();
    let size_at = id + 16 + 2 + 2 + 32 + 12;
    assert_eq!(
        u32::from_le_bytes(data[size_at..size_at + 4].try_into().unwrap()),
        50_000
    );
    for size in [1u32 << 23, 0xf300_c350] {
        let mut d = data.clone();
        d[size_at..size_at + 4].copy_from_slice(&size.to_le_bytes());
        let p = dir.path().join(format!("size{size}.laz"));
        std::fs::write(&p, &d).unwrap();
        let opts = ReadOptions {
            chunk_points: 7,
            ..Default::default()
        };
        let e = ingest::read_all(&p, &opts)
            .err()
            .unwrap_or_else(|| panic!("no error for chunks of {size} points"));
        let s = e.to_string();
        assert!(s.contains(&format!("size{size}.laz")), "{s}");
        assert!(
            s.contains("laszip VLR") && s.contains(&size.to_string()),
            "{s}"
        );
    }
    // The items' sizes (after their count, at the data's byte 32: type, size and
    // version, u16 each) must add up to the header's record length, as LASzip
    // requires; the `laz` crate decoded that many bytes a point, and panicked
    // (or misread) when they differ.
    let first_size = id + 16 + 2 + 2 + 32 + 34 + 2;
    assert_eq!(
        u16::from_le_bytes(data[first_size..first_size + 2].try_into().unwrap()),
        20
    );
    let mut d = data.clone();
    d[first_size..first_size + 2].copy_from_slice(&0u16.to_le_bytes());
    let p = dir.path().join("items.laz");
    std::fs::write(&p, &d).unwrap();
    let e = ingest::read_all(&p, &ReadOptions::default()).err().unwrap();
    let s = e.to_string();
    assert!(
        s.contains("items.laz") && s.contains("laszip VLR") && s.contains("bytes a point"),
        "{s}"
    );
}

/// A LAZ file that declares no points behind a corrupt chunk table: the decoder
/// reads the table whatever the point count, so it is checked all the same
/// (`bash bench/fuzz.sh` found one whose table listed 4,059,738,657 chunks: the
/// `laz` crate asked for 65 GB and aborted the process).
/// A case the fuzzer found (`fixtures/README.md`): fixed-size chunks that
/// hold fewer points than the header declares made the `laz` crate's
/// parallel decoder panic; it is an error naming the file.
#[test]
fn laz_whose_chunks_hold_fewer_points_than_declared_is_an_error() {
    let f =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/fuzz/laz-chunks-short-of-points.laz");
    let r = std::panic::catch_unwind(|| ingest::read_all(&f, &ReadOptions::default()));
    let Ok(Err(e)) = r else {
        panic!("not an error: {:?}", r.map(|r| r.map(|(_, p, _)| p.len())));
    };
    let s = e.to_string();
    assert!(s.contains("laz-chunks-short-of-points.laz"), "{s}");
    assert!(
        s.contains("chunk table lists 1 chunk(s) of 1 points, fewer than the 200 points"),
        "{s}"
    );
}

#[test]
fn laz_declaring_no_points_with_a_corrupt_chunk_table_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("s.laz");
    pcimg::synth::write_las(&src, 200, 2).unwrap();
    let mut d = std::fs::read(&src).unwrap();
    assert_eq!(&d[..4], b"LASF");
    let start = u32::from_le_bytes(d[96..100].try_into().unwrap()) as usize;
    let table = i64::from_le_bytes(d[start..start + 8].try_into().unwrap()) as usize;
    // No points: the legacy count (bytes 107..111) and, from LAS 1.4, the
    // 64-bit count (bytes 247..255).
    d[107..111].copy_from_slice(&0u32.to_le_bytes());
    if u16::from_le_bytes([d[94], d[95]]) >= 375 {
        d[247..255].copy_from_slice(&0u64.to_le_bytes());
    }
    let empty = dir.path().join("empty.laz");
    std::fs::write(&empty, &d).unwrap();
    // With its table intact, the file reads (as no points).
    let (_, pts, _) = ingest::read_all(&empty, &ReadOptions::default()).unwrap();
    assert_eq!(pts.len(), 0);
    d[table + 4..table + 8].copy_from_slice(&4_059_738_657u32.to_le_bytes());
    let bad = dir.path().join("bad.laz");
    std::fs::write(&bad, &d).unwrap();
    let Err(e) = ingest::read_all(&bad, &ReadOptions::default()) else {
        panic!("a corrupt chunk table is refused");
    };
    let s = e.to_string();
    assert!(s.contains("bad.laz"), "{s}");
    assert!(s.contains(&format!("byte offset {}", table + 4)), "{s}");
    assert!(s.contains("chunk table") && s.contains("4059738657"), "{s}");
}

/// Damaged copies of every sample (truncated, bytes overwritten in the header and
/// in the body) must give `Ok` or `Err`, never a panic or a hang.
#[test]
fn damaged_inputs_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut seed = 0x9E3779B97F4A7C15u64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let text: Vec<u8> = (0..2000)
        .flat_map(|i| format!("{i}.5 {} {} {}\n", i * 2, i % 7, i % 255).into_bytes())
        .collect();
    let samples: Vec<(&str, Vec<u8>)> = vec![
        ("laz", std::fs::read(sample("autzen_trim.laz")).unwrap()),
        ("ply", std::fs::read(sample("bun_zipper.ply")).unwrap()),
        (
            "ply",
            std::fs::read(sample("cgal_b9_training.ply")).unwrap(),
        ),
        ("xyz", text),
    ];
    let opts = ReadOptions {
        chunk_points: 50_000,
        ..Default::default()
    };
    let mut n = 0;
    for (ext, data) in &samples {
        for k in 0..24 {
            let mut d = data.clone();
            match k % 3 {
                0 => d.truncate(rnd() as usize % d.len()),
                1 => {
                    // Overwrite bytes in the first 400 (header).
                    for _ in 0..1 + k % 4 {
                        let i = rnd() as usize % d.len().min(400);
                        d[i] = rnd() as u8;
                    }
                }
                _ => {
                    for _ in 0..1 + k % 8 {
                        let i = rnd() as usize % d.len();
                        d[i] = rnd() as u8;
                    }
                }
            }
            let p = dir.path().join(format!("damaged{n}.{ext}"));
            n += 1;
            std::fs::write(&p, &d).unwrap();
            let r = std::panic::catch_unwind(|| ingest::read_all(&p, &opts).map(|r| r.1.len()));
            match r {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => assert!(e.to_string().contains(&format!("damaged{}", n - 1))),
                Err(_) => panic!("reading {} panicked", p.display()),
            }
        }
    }
}

mod random_bytes {
    use super::*;
    use proptest::prelude::*;

    fn read_bytes(name: &str, bytes: &[u8]) -> Result<usize, String> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let opts = ReadOptions {
            chunk_points: 7,
            skip_invalid: bytes.first().is_some_and(|b| b & 1 == 1),
            ..Default::default()
        };
        ingest::read_all(&p, &opts)
            .map(|r| r.1.len())
            .map_err(|e| e.to_string())
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        /// Arbitrary bytes in text form: an answer, never a panic.
        #[test]
        fn text_never_panics(lines in proptest::collection::vec("[-+0-9eE.,;# \\t/xyzna]{0,30}", 0..40)) {
            let body = lines.join("\n");
            if let Err(e) = read_bytes("r.xyz", body.as_bytes()) {
                prop_assert!(e.contains("r.xyz"));
            }
        }

        /// Arbitrary bytes after a PLY header start.
        #[test]
        fn ply_never_panics(tail in proptest::collection::vec(any::<u8>(), 0..300), fmt in 0..3usize) {
            let f = ["ascii", "binary_little_endian", "binary_big_endian"][fmt];
            let mut b = format!(
                "ply\nformat {f} 1.0\nelement vertex 3\nproperty float x\nproperty double y\nproperty short z\nproperty uchar red\nend_header\n"
            )
            .into_bytes();
            b.extend_from_slice(&tail);
            if let Err(e) = read_bytes("r.ply", &b) {
                prop_assert!(e.contains("r.ply"));
            }
        }
    }
}

/// After `sample_rest(every)`, text and LAS readers deliver about one point in
/// `every` of the rest, each a point of the file, whole (a line parsed from its
/// start, a record from its first byte), spread over the whole rest of the file.
#[test]
fn sampling_reads_an_even_subset_of_whole_points() {
    use pcimg::synth::Order;
    let dir = tempfile::tempdir().unwrap();
    let n = 400_000u64;
    let text = dir.path().join("s.xyz");
    let las = dir.path().join("s.las");
    pcimg::synth::write_text_in_order(&text, n, 9, Order::Scan).unwrap();
    pcimg::synth::write_las_in_order(&las, n, 9, Order::Scan).unwrap();
    for path in [&text, &las] {
        let opts = ReadOptions {
            chunk_points: 20_000,
            ..Default::default()
        };
        let (_, all, _) = ingest::read_all(path, &opts).unwrap();
        let key = |p: &PointColumns, i: usize| [p.x[i], p.y[i], p.z[i]].map(f64::to_bits);
        let index: std::collections::HashMap<[u64; 3], usize> =
            (0..all.len()).map(|i| (key(&all, i), i)).collect();
        let mut r = ingest::open(path, &opts).unwrap();
        let head = r.next_chunk().unwrap().unwrap().len();
        assert!(r.sample_rest(8), "{}", path.display());
        let mut got = Vec::new();
        while let Some(c) = r.next_chunk().unwrap() {
            for i in 0..c.len() {
                let k = index.get(&key(&c, i));
                assert!(k.is_some(), "{}: not a point of the file", path.display());
                got.push(*k.unwrap_or(&0));
            }
        }
        assert_eq!(r.bytes_done(), std::fs::metadata(path).unwrap().len());
        let rest = n as usize - head;
        let frac = got.len() as f64 / rest as f64;
        assert!((0.10..0.15).contains(&frac), "{}: {frac}", path.display());
        // In file order, and every tenth of the rest holds its share (within
        // one LAS window of 1024 records: about 4.7 windows a tenth here).
        assert!(got.windows(2).all(|w| w[0] < w[1]));
        let mut tenths = [0usize; 10];
        for &i in &got {
            tenths[(i - head) * 10 / rest] += 1;
        }
        let mean = got.len() as f64 / 10.0;
        assert!(
            tenths.iter().all(|&t| (t as f64 - mean).abs() < 0.3 * mean),
            "{}: {tenths:?}",
            path.display()
        );
    }
}

/// A LAZ reader samples by seeking: a piece of 50,000 points (one LAZ chunk) in
/// every slot of `every` pieces, each point one of the file's, in file order,
/// spread over the rest of the file; a chunk decoded before the request is
/// thinned to the same rate.
#[test]
fn laz_sampling_seeks_to_pieces_of_the_file() {
    use pcimg::synth::Order;
    let dir = tempfile::tempdir().unwrap();
    let n = 600_000usize;
    let laz_path = dir.path().join("s.laz");
    pcimg::synth::write_las_in_order(&laz_path, n as u64, 4, Order::Scan).unwrap();
    let opts = ReadOptions {
        chunk_points: 20_000,
        ..Default::default()
    };
    let (info, all, _) = ingest::read_all(&laz_path, &opts).unwrap();
    assert_eq!((info.format.as_str(), all.len()), ("laz 1.2", n));
    let key = |p: &PointColumns, i: usize| [p.x[i], p.y[i], p.z[i]].map(f64::to_bits);
    let index: std::collections::HashMap<[u64; 3], usize> =
        (0..n).map(|i| (key(&all, i), i)).collect();
    let mut r = ingest::open(&laz_path, &opts).unwrap();
    let head = r.next_chunk().unwrap().unwrap().len();
    assert!(r.sample_rest(3));
    let mut got = Vec::new();
    while let Some(c) = r.next_chunk().unwrap() {
        got.extend((0..c.len()).map(|i| index[&key(&c, i)]));
    }
    assert!(got.windows(2).all(|w| w[0] < w[1]), "not in file order");
    let rest = n - head;
    let frac = got.len() as f64 / rest as f64;
    assert!((0.25..0.42).contains(&frac), "{frac}");
    // Pieces in the first and the last third of the rest.
    assert!(got.iter().any(|&i| i < head + rest / 3));
    assert!(got.iter().any(|&i| i > head + 2 * rest / 3));
}
