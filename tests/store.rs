//! The image store end to end: write → read round trips (property-based), the
//! pyramid's invariants, the tile index, and bad files.

mod common;

use common::random_cloud;
use pcimg::points::PointColumns;
use pcimg::store::tiff::zorder::Geometry;
use pcimg::store::{Compression, Dataset, Part, TileIo, WriteOptions, write_part};
use proptest::prelude::*;
use std::collections::HashMap;
use std::path::Path;

/// What the writer promises to store for a source coordinate: `origin + f32(v - origin)`.
fn stored(v: f64, origin: f64) -> f64 {
    origin + (v - origin) as f32 as f64
}

/// Rows of (x, y, z as f64 bits, attributes as f32 bits) read from a level.
fn read_rows(part: &Part, level: usize) -> Vec<Vec<u64>> {
    let bands: Vec<usize> = (0..part.bands.len()).collect();
    let p = part.read_level(level, &bands).unwrap();
    (0..p.len())
        .map(|i| {
            (0..bands.len())
                .map(|b| {
                    if b < 3 {
                        (p.offsets[b] + p.columns[b][i] as f64).to_bits()
                    } else {
                        p.columns[b][i].to_bits() as u64
                    }
                })
                .collect()
        })
        .collect()
}

fn check_round_trip(pts: &PointColumns, compression: Compression) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("part.tif");
    let opts = WriteOptions {
        compression,
        source: Some("test.xyz".into()),
        ..Default::default()
    };
    let summary = write_part(&path, pts, &opts).unwrap();
    let part = Part::open(&path).unwrap();
    let n = pts.len();
    assert_eq!(part.meta.point_count, n as u64);
    let origin = part.meta.origin;
    assert_eq!(origin, summary.origin);

    // Level 0 holds exactly the input points, each within the stated precision.
    let mut expected: Vec<Vec<u64>> = (0..n)
        .map(|i| {
            let mut r = vec![
                stored(pts.x[i], origin[0]).to_bits(),
                stored(pts.y[i], origin[1]).to_bits(),
                stored(pts.z[i], origin[2]).to_bits(),
            ];
            r.extend(pts.attributes.iter().map(|a| a.values[i].to_bits() as u64));
            r
        })
        .collect();
    expected.sort();
    let got = common::multiset(read_rows(&part, 0));
    assert_eq!(got.len(), n);
    assert!(got == expected, "level 0 differs from the input");
    // Precision bound: half an f32 ulp of the largest coordinate offset.
    for i in 0..n {
        for (a, v) in [pts.x[i], pts.y[i], pts.z[i]].into_iter().enumerate() {
            let rel = (v - origin[a]).abs();
            let bound = rel * f32::EPSILON as f64 / 2.0 + 1e-9;
            assert!((stored(v, origin[a]) - v).abs() <= bound);
            assert!((stored(v, origin[a]) - v).abs() <= summary.max_quantization_error + 1e-12);
        }
    }

    // Each level holds the stated count and is a sub-multiset of the level below.
    let g = Geometry::for_points(n as u64);
    assert_eq!(part.levels.len(), g.levels());
    let mut below: HashMap<Vec<u64>, usize> = HashMap::new();
    for r in got {
        *below.entry(r).or_default() += 1;
    }
    for k in 0..part.levels.len() {
        let level = &part.levels[k];
        assert_eq!(level.points, Some(g.level_points(k)));
        assert!(level.indexed);
        let rows = read_rows(&part, k);
        assert_eq!(rows.len() as u64, g.level_points(k), "level {k}");
        let mut this: HashMap<Vec<u64>, usize> = HashMap::new();
        for r in rows {
            *this.entry(r).or_default() += 1;
        }
        for (r, c) in &this {
            assert!(
                below.get(r).copied().unwrap_or(0) >= *c,
                "level {k} is not a subset"
            );
        }
        // Tile index: counts add up and every point lies within its tile's bounds.
        let idx: u64 = level.tiles.iter().map(|t| t.points.unwrap() as u64).sum();
        assert_eq!(idx, g.level_points(k));
        for t in &level.tiles {
            let p = part.read_tiles(k, &[t.index], &[0, 1, 2]).unwrap();
            assert_eq!(p.len() as u32, t.points.unwrap());
            for i in 0..p.len() {
                for a in 0..3 {
                    let v = p.offsets[a] + p.columns[a][i] as f64;
                    assert!(v >= t.bounds.min[a] && v <= t.bounds.max[a]);
                }
            }
        }
        below = this;
    }
}

#[test]
fn round_trip_edge_sizes() {
    for n in [0usize, 1, 2, 3, 4, 5, 65_535, 65_536, 65_537] {
        check_round_trip(&random_cloud(n, n as u64, 7), Compression::None);
    }
}

#[test]
fn round_trip_compressed() {
    check_round_trip(&random_cloud(70_000, 3, 5), Compression::Deflate);
    check_round_trip(&random_cloud(70_000, 4, 0), Compression::Zstd);
}

#[test]
fn round_trip_four_levels() {
    // 4^8 * 17 points: a 2048 image with 4 levels, the last tile partial.
    check_round_trip(&random_cloud(1_114_112 + 17, 11, 3), Compression::None);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
    #[test]
    fn round_trip_random(
        n in prop_oneof![0usize..300, 65_530usize..65_542, 130_000usize..140_000],
        seed in any::<u64>(),
        dup in prop_oneof![Just(0usize), 2usize..10],
        comp in prop_oneof![
            Just(Compression::None),
            Just(Compression::Deflate),
            Just(Compression::Zstd),
            Just(Compression::Lerc),
            Just(Compression::LercDeflate),
            Just(Compression::LercZstd),
        ],
        lossy in prop_oneof![Just(0.0f64), 0.0005f64..0.05],
    ) {
        let pts = random_cloud(n, seed, dup);
        if comp.is_lerc() && lossy > 0.0 {
            check_lossy_round_trip(&pts, comp, lossy);
        } else {
            // (LERC at error 0 is lossless: the same exact check.)
            check_round_trip(&pts, comp);
        }
    }
}

/// A LERC part whose coordinates may move by `bound` (source units): every
/// level holds the stated count of the input's points, each found in the input
/// (attributes exact, the lossless ones) with its coordinates within the part's
/// stated error (which covers the codec's bound), and inside its tile's bounds
/// within that error too.
fn check_lossy_round_trip(pts: &PointColumns, compression: Compression, bound: f64) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("part.tif");
    let opts = WriteOptions {
        compression,
        coord_max_error: [bound; 3],
        ..Default::default()
    };
    let summary = write_part(&path, pts, &opts).unwrap();
    let part = Part::open(&path).unwrap();
    let n = pts.len();
    assert_eq!(part.meta.point_count, n as u64);
    let err = summary.max_quantization_error;
    assert!(
        err >= bound,
        "stated error {err} below the codec's bound {bound}"
    );
    // Input points by their attributes' bits (duplicates listed twice).
    let mut source: HashMap<Vec<u32>, Vec<[f64; 3]>> = HashMap::new();
    for i in 0..n {
        let key = pts
            .attributes
            .iter()
            .map(|a| a.values[i].to_bits())
            .collect();
        source
            .entry(key)
            .or_default()
            .push([pts.x[i], pts.y[i], pts.z[i]]);
    }
    let g = Geometry::for_points(n as u64);
    assert_eq!(part.levels.len(), g.levels());
    let bands: Vec<usize> = (0..part.bands.len()).collect();
    let mut worst = 0.0f64;
    for k in 0..part.levels.len() {
        let p = part.read_level(k, &bands).unwrap();
        assert_eq!(p.len() as u64, g.level_points(k), "level {k}");
        let mut left = source.clone();
        for i in 0..p.len() {
            let key: Vec<u32> = (3..bands.len())
                .map(|b| p.columns[b][i].to_bits())
                .collect();
            let xyz = [0, 1, 2].map(|a| p.offsets[a] + p.columns[a][i] as f64);
            let cands = left
                .get_mut(&key)
                .unwrap_or_else(|| panic!("level {k}: point {i}'s attributes are not an input's"));
            let dist = |c: &[f64; 3]| (0..3).map(|a| (c[a] - xyz[a]).abs()).fold(0.0, f64::max);
            let (j, d) = cands
                .iter()
                .enumerate()
                .map(|(j, c)| (j, dist(c)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or_else(|| panic!("level {k}: point {i} appears too often"));
            assert!(
                d <= err + 1e-9,
                "level {k}: point {i} moved {d} (bound {err})"
            );
            worst = worst.max(d);
            cands.swap_remove(j);
        }
        for t in &part.levels[k].tiles {
            let q = part.read_tiles(k, &[t.index], &[0, 1, 2]).unwrap();
            assert_eq!(q.len() as u32, t.points.unwrap());
            for i in 0..q.len() {
                for a in 0..3 {
                    let v = q.offsets[a] + q.columns[a][i] as f64;
                    assert!(v >= t.bounds.min[a] - err && v <= t.bounds.max[a] + err);
                }
            }
        }
    }
    // The codec did use its room (else this checks a lossless part), unless
    // the part is tiny.
    if n > 1000 {
        assert!(worst > f32::EPSILON as f64 * 1000.0, "worst error {worst}");
    }
}

/// A LERC tile with damaged bytes: reading it is an error naming the file and
/// the tile, never a panic and never silently wrong values.
#[test]
fn a_corrupt_lerc_tile_is_an_error_naming_the_file_and_tile() {
    let dir = tempfile::tempdir().unwrap();
    let c = random_cloud(5000, 21, 0);
    for compression in [
        Compression::Lerc,
        Compression::LercDeflate,
        Compression::LercZstd,
    ] {
        let path = dir.path().join(format!("{compression:?}.tif"));
        let opts = WriteOptions {
            compression,
            coord_max_error: [0.001; 3],
            ..Default::default()
        };
        write_part(&path, &c, &opts).unwrap();
        let good = std::fs::read(&path).unwrap();
        let mut tiff = tiff::decoder::Decoder::new(std::io::Cursor::new(&good)).unwrap();
        let offsets = tiff.get_tag_u64_vec(tiff::tags::Tag::TileOffsets).unwrap();
        let counts = tiff
            .get_tag_u64_vec(tiff::tags::Tag::TileByteCounts)
            .unwrap();
        // Band 1's (x's) first stored tile of level 0.
        let (at, len) = offsets
            .iter()
            .zip(&counts)
            .find(|(_, n)| **n > 16)
            .map(|(o, n)| (*o as usize, *n as usize))
            .unwrap();
        let mut rng = pcimg::synth::Rng::new(5);
        for round in 0..12 {
            let mut bad = good.clone();
            match round % 3 {
                // One flipped bit, past the blob's first bytes.
                0 => bad[at + 8 + (rng.next_u64() as usize % (len - 8))] ^= 1 << (round % 8),
                // A run of bytes overwritten.
                1 => {
                    let from = at + rng.next_u64() as usize % (len / 2);
                    bad[from..from + 8.min(len / 2)].fill(0xff);
                }
                // The tile's bytes zeroed.
                _ => bad[at..at + len].fill(0),
            }
            let broken = dir.path().join(format!("bad-{compression:?}-{round}.tif"));
            std::fs::write(&broken, &bad).unwrap();
            let r = std::panic::catch_unwind(|| {
                let part = Part::open(&broken)?;
                let bands: Vec<usize> = (0..part.bands.len()).collect();
                part.read_level(0, &bands).map(|p| p.columns)
            });
            let shown = broken.display().to_string();
            match r {
                Err(_) => panic!("{shown}: reading a corrupt LERC tile panicked"),
                Ok(Err(e)) => {
                    let e = e.to_string();
                    assert!(e.contains(&shown) && e.contains("tile"), "{e}");
                }
                // A change LERC's checksum cannot see (none: it covers the
                // blob) would read back other values: refused above.
                Ok(Ok(cols)) => {
                    let part = Part::open(&path).unwrap();
                    let bands: Vec<usize> = (0..part.bands.len()).collect();
                    let want = part.read_level(0, &bands).unwrap().columns;
                    panic!(
                        "{shown}: a corrupt tile read without an error ({})",
                        if cols == want {
                            "same values"
                        } else {
                            "other values"
                        }
                    );
                }
            }
        }
    }
}

/// Tiles written around the page cache (`O_DIRECT`), through it, and as `auto`
/// picks, give the same bytes, on the temporary directory's file system and on
/// tmpfs (`/dev/shm`, where a direct write may be refused and fall back); and the
/// direct file reads back whole.
#[test]
fn direct_and_buffered_writes_give_the_same_file() {
    // Three levels and a partial last tile; 4 bands.
    let c = random_cloud(300_000, 1, 7);
    let mut dirs = vec![tempfile::tempdir().unwrap()];
    if Path::new("/dev/shm").is_dir() {
        dirs.push(tempfile::tempdir_in("/dev/shm").unwrap());
    }
    for dir in &dirs {
        let bytes: Vec<Vec<u8>> = [TileIo::Direct, TileIo::Buffered, TileIo::Auto]
            .iter()
            .enumerate()
            .map(|(k, &io)| {
                let path = dir.path().join(format!("p{k}.tif"));
                let opts = WriteOptions {
                    io,
                    ..Default::default()
                };
                let s = write_part(&path, &c, &opts).unwrap();
                // (Direct only where the file system took it, and in auto once
                // the page cache proved slow: not asserted.)
                if io == TileIo::Buffered {
                    assert!(!s.direct, "{io:?} wrote around the page cache");
                }
                std::fs::read(&path).unwrap()
            })
            .collect();
        assert!(bytes[0] == bytes[1], "direct and buffered files differ");
        assert!(bytes[2] == bytes[1], "auto and buffered files differ");
        let part = Part::open(&dir.path().join("p0.tif")).unwrap();
        assert_eq!(part.meta.point_count, 300_000);
        assert_eq!(read_rows(&part, 0).len(), 300_000);
    }
    assert!(TileIo::parse("sideways").is_err());
}

/// Uncompressed parts write every level while the points are arranged (level 0
/// in the order the tiles were arranged, a coarser tile as soon as the tiles
/// below it are), all tile data before the first directory, and point each
/// image tile at its place; compressed parts encode the levels afterwards, in
/// image order. Both read back the same, level by level in image order, with
/// tiles that the coarse levels reorder.
#[test]
fn every_level_written_while_arranging_reads_as_a_compressed_part() {
    // 22 tiles and a partial one: levels 9..=11 of the layout move whole tiles.
    let c = random_cloud(22 * 65_536 + 1_234, 5, 0);
    let dir = tempfile::tempdir().unwrap();
    let parts: Vec<Part> = [Compression::None, Compression::Zstd]
        .iter()
        .map(|&compression| {
            let path = dir.path().join(format!("{compression:?}.tif"));
            let opts = WriteOptions {
                compression,
                ..Default::default()
            };
            write_part(&path, &c, &opts).unwrap();
            Part::open(&path).unwrap()
        })
        .collect();
    // The level-0 tiles are not stored in image order (else this proves nothing):
    // band 0's tile offsets (raster order in the TIFF) taken in Z-order.
    let file = std::fs::File::open(dir.path().join("None.tif")).unwrap();
    let mut tiff = tiff::decoder::Decoder::new(file).unwrap();
    let raster = tiff.get_tag_u64_vec(tiff::tags::Tag::TileOffsets).unwrap();
    let z: Vec<u64> = parts[0].levels[0]
        .tiles
        .iter()
        .map(|t| raster[t.index as usize])
        .collect();
    assert_eq!(z.len(), 23);
    assert!(!z.is_sorted(), "level 0's tiles are stored in image order");
    // Every level's tiles lie after the head (written head-first: the last
    // directory is at most a few KiB after byte 0), at whole disk blocks.
    let head = std::fs::read(dir.path().join("None.tif")).unwrap();
    let first_ifd = u64::from(u32::from_le_bytes(head[4..8].try_into().unwrap()));
    assert!(first_ifd < 64, "the first directory is at byte {first_ifd}");
    let mut levels = 0;
    loop {
        let offsets = tiff.get_tag_u64_vec(tiff::tags::Tag::TileOffsets).unwrap();
        let first = offsets.iter().filter(|&&o| o > 0).min().unwrap();
        assert!(*first >= 4096, "level {levels}: tile inside the head");
        assert!(offsets.iter().all(|o| o % 4096 == 0), "level {levels}");
        levels += 1;
        if !tiff.more_images() {
            break;
        }
        tiff.next_image().unwrap();
    }
    assert_eq!(levels, parts[0].levels.len());
    // (Zstd parts keep each tile's points in their own order, format version 2:
    // tile by tile, the same points.)
    for k in 0..parts[0].levels.len() {
        let bands: Vec<usize> = (0..parts[0].bands.len()).collect();
        let [a, b] = [0, 1].map(|p| parts[p].read_level(k, &bands).unwrap());
        assert_eq!(a.len(), b.len(), "level {k}");
        assert_eq!(a.tile_points, b.tile_points, "level {k}");
        let tiles = |p: &pcimg::store::Points| -> Vec<Vec<Vec<u32>>> {
            let mut start = 0;
            p.tile_points
                .iter()
                .map(|&n| {
                    let mut rows: Vec<Vec<u32>> = (start..start + n as usize)
                        .map(|i| p.columns.iter().map(|c| c[i].to_bits()).collect())
                        .collect();
                    rows.sort();
                    start += n as usize;
                    rows
                })
                .collect()
        };
        assert!(tiles(&a) == tiles(&b), "level {k}: a tile's points differ");
    }
}

#[test]
fn all_points_equal() {
    let mut c = random_cloud(1000, 1, 0);
    for i in 0..c.len() {
        c.x[i] = 637179.22;
        c.y[i] = 6010946.56;
        c.z[i] = 20.51;
    }
    check_round_trip(&c, Compression::None);
}

#[test]
fn levels_are_spatially_even() {
    // Level k of a uniform grid keeps points spread over the whole extent: every
    // 1/8 × 1/8 cell of the square has points at the coarsest level.
    let n = 512 * 512;
    let mut c = PointColumns::default();
    for i in 0..n {
        c.x.push((i % 512) as f64);
        c.y.push((i / 512) as f64);
        c.z.push(0.0);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.tif");
    write_part(&path, &c, &WriteOptions::default()).unwrap();
    let part = Part::open(&path).unwrap();
    let last = part.levels.len() - 1;
    let p = part.read_level(last, &[0, 1]).unwrap();
    let mut cells = [[0u32; 8]; 8];
    for i in 0..p.len() {
        let x = p.offsets[0] + p.columns[0][i] as f64;
        let y = p.offsets[1] + p.columns[1][i] as f64;
        cells[(x / 64.0) as usize][(y / 64.0) as usize] += 1;
    }
    let expected = p.len() as f64 / 64.0;
    for row in cells {
        for c in row {
            assert!((c as f64 - expected).abs() <= expected * 0.25, "{cells:?}");
        }
    }
}

#[test]
fn metadata_survives_and_dataset_directory_opens() {
    let dir = tempfile::tempdir().unwrap();
    let mut opts = WriteOptions {
        source: Some("scan \u{1b}[31mred.las".into()),
        crs: Some("EPSG:2992".into()),
        ..Default::default()
    };
    write_part(&dir.path().join("a.tif"), &random_cloud(100, 1, 0), &opts).unwrap();
    opts.source = Some("b.las".into());
    write_part(&dir.path().join("b.tif"), &random_cloud(50, 2, 0), &opts).unwrap();
    let ds = Dataset::open(dir.path()).unwrap();
    assert_eq!(ds.part_count(), 2);
    assert_eq!(ds.points(), 150);
    let p = &ds.parts().unwrap()[0];
    // Control characters are replaced when written (GDAL would print them).
    assert_eq!(p.meta.source.as_deref(), Some("scan \u{FFFD}[31mred.las"));
    assert_eq!(p.meta.crs.as_deref(), Some("EPSG:2992"));
    let names: Vec<&str> = p.bands.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, ["x", "y", "z", "intensity", "gps_time"]);
    assert_eq!(p.bands[4].offset, 3.1e8);
    assert!(ds.bounds().contains(&p.meta.bounds));
    // Band ranges (GDAL's STATISTICS_*) in source units: the attributes' exactly,
    // the coordinates' within the quantization bound.
    let cloud = random_cloud(100, 1, 0);
    for (k, a) in cloud.attributes.iter().enumerate() {
        let lo = a.values.iter().copied().fold(f32::INFINITY, f32::min) as f64 + a.offset;
        let hi = a.values.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64 + a.offset;
        let (got_lo, got_hi) = p.bands[3 + k].range.expect("a range");
        assert!(
            (got_lo - lo).abs() <= 1e-9 * lo.abs().max(1.0),
            "{} {got_lo} {lo}",
            a.name
        );
        assert!(
            (got_hi - hi).abs() <= 1e-9 * hi.abs().max(1.0),
            "{} {got_hi} {hi}",
            a.name
        );
    }
    let b = cloud.bounds();
    for k in 0..3 {
        let (lo, hi) = p.bands[k].range.expect("a range");
        let tol = p.meta.max_quantization_error.expect("a quantization bound") + 1e-9;
        assert!(
            (lo - b.min[k]).abs() <= tol && (hi - b.max[k]).abs() <= tol,
            "axis {k}"
        );
    }
    // Text output never carries the escape character from the metadata.
    let text = pcimg::cli::info::render_text(&pcimg::cli::info::report(&ds, true));
    assert!(!text.contains('\u{1b}'));
    assert!(text.contains("EPSG:2992"));
}

#[test]
fn nan_coordinates_are_refused_and_nothing_is_left() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = random_cloud(10, 1, 0);
    c.y[4] = f64::NAN;
    let path = dir.path().join("bad.tif");
    let e = write_part(&path, &c, &WriteOptions::default()).unwrap_err();
    assert!(e.to_string().contains("point 4"), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn a_cancelled_write_stops_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let c = random_cloud(100_000, 1, 0);
    let path = dir.path().join("part.tif");
    let cancel = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let opts = WriteOptions {
        cancel: Some(cancel.clone()),
        ..Default::default()
    };
    let e = write_part(&path, &c, &opts).unwrap_err();
    assert!(e.to_string().contains(pcimg::store::INTERRUPTED), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    cancel.store(false, std::sync::atomic::Ordering::Relaxed);
    write_part(&path, &c, &opts).unwrap();
}

// ---- bad files -----------------------------------------------------------------

fn good_file(dir: &Path) -> (std::path::PathBuf, Vec<u8>) {
    let path = dir.join("good.tif");
    write_part(&path, &random_cloud(70_000, 5, 0), &WriteOptions::default()).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    (path, bytes)
}

fn open_err(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    let e = Part::open(&p).unwrap_err().to_string();
    assert!(e.contains(name), "error does not name the file: {e}");
    e
}

fn replace_once(bytes: &mut [u8], from: &[u8], to: &[u8]) {
    assert_eq!(from.len(), to.len());
    let at = bytes
        .windows(from.len())
        .position(|w| w == from)
        .expect("pattern present");
    bytes[at..at + to.len()].copy_from_slice(to);
}

#[test]
fn truncated_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = good_file(dir.path());
    for cut in [
        0usize,
        1,
        7,
        8,
        100,
        bytes.len() / 3,
        bytes.len() - 20,
        bytes.len() - 1,
    ] {
        let e = open_err(dir.path(), "cut.tif", &bytes[..cut]);
        assert!(
            e.contains("truncated")
                || e.contains("empty")
                || e.contains("too short")
                || e.contains("past the end"),
            "cut at {cut}: {e}"
        );
    }
    // Every prefix fails cleanly (never panics), sampled.
    for cut in (0..bytes.len()).step_by(9_973) {
        assert!(Part::from_bytes(Path::new("x.tif"), bytes[..cut].to_vec()).is_err());
    }
}

#[test]
fn plain_rgb_tiff_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut buf).unwrap();
    enc.write_image::<tiff::encoder::colortype::RGB8>(4, 4, &[7u8; 48])
        .unwrap();
    let e = open_err(dir.path(), "photo.tif", buf.get_ref());
    assert!(e.contains("no GDAL_METADATA"), "{e}");
}

#[test]
fn missing_metadata_and_wrong_bands_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = good_file(dir.path());
    let mut b = bytes.clone();
    replace_once(&mut b, b"PCIMG_FORMAT", b"OTHER_FORMAT");
    let e = open_err(dir.path(), "nometa.tif", &b);
    assert!(e.contains("PCIMG_FORMAT"), "{e}");

    let mut b = bytes.clone();
    replace_once(&mut b, b"\"POINT_COUNT\"", b"\"POINT_COUNX\"");
    let e = open_err(dir.path(), "nocount.tif", &b);
    assert!(e.contains("POINT_COUNT is missing"), "{e}");

    let mut b = bytes.clone();
    replace_once(
        &mut b,
        b">x y z intensity gps_time<",
        b">x y z intensity_gps_time<",
    );
    let e = open_err(dir.path(), "bands.tif", &b);
    assert!(e.contains("lists 4 bands") && e.contains("has 5"), "{e}");

    let mut b = bytes.clone();
    replace_once(
        &mut b,
        b"role=\"description\">x<",
        b"role=\"description\">q<",
    );
    let e = open_err(dir.path(), "names.tif", &b);
    assert!(e.contains("expected 'x'"), "{e}");

    // Bounds that are not finite, or inverted: refused (they would cull all).
    for (name, value, want) in [
        (
            "nanbounds.tif",
            "nan nan nan",
            "BOUNDS_MIN is not three finite numbers",
        ),
        (
            "inverted.tif",
            "1e30 1e30 1e30",
            "BOUNDS_MIN lies above BOUNDS_MAX",
        ),
    ] {
        let mut b = bytes.clone();
        set_item(&mut b, "BOUNDS_MIN", value);
        let e = open_err(dir.path(), name, &b);
        assert!(e.contains(want), "{name}: {e}");
    }
}

/// Overwrites the value of metadata item `name` with `value`, padded with spaces
/// to the old value's length.
fn set_item(bytes: &mut [u8], name: &str, value: &str) {
    let key = format!("name=\"{name}\">");
    let at = bytes
        .windows(key.len())
        .position(|w| w == key.as_bytes())
        .expect("item present")
        + key.len();
    let len = bytes[at..].iter().position(|&c| c == b'<').unwrap();
    assert!(value.len() <= len, "{value} does not fit {len} bytes");
    let padded = format!("{value:len$}");
    bytes[at..at + len].copy_from_slice(padded.as_bytes());
}

#[test]
fn tile_offset_past_the_end_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (_, mut bytes) = good_file(dir.path());
    let t = pcimg::store::tiff::ifd::Tiff::parse(&bytes).unwrap();
    let entry = t.ifds[0].entries[&324];
    let at = entry.at as usize;
    let past = (bytes.len() as u32 + 100).to_le_bytes();
    bytes[at..at + 4].copy_from_slice(&past);
    let e = open_err(dir.path(), "offset.tif", &bytes);
    assert!(e.contains("past the end of the file"), "{e}");
}

#[test]
fn corrupt_compressed_tile_is_an_error_at_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("z.tif");
    let opts = WriteOptions {
        compression: Compression::Deflate,
        ..Default::default()
    };
    write_part(&path, &random_cloud(1000, 5, 0), &opts).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let t = pcimg::store::tiff::ifd::Tiff::parse(&bytes).unwrap();
    let off = t.uints(&bytes, &t.ifds[0], 324).unwrap().unwrap()[0] as usize;
    for b in &mut bytes[off..off + 16] {
        *b ^= 0x5a;
    }
    let part = Part::from_bytes(Path::new("z.tif"), bytes).unwrap();
    let e = part.read_level(0, &[0]).unwrap_err().to_string();
    assert!(e.contains("z.tif") && e.contains("corrupt"), "{e}");
}

#[test]
fn empty_directory_and_missing_path() {
    let dir = tempfile::tempdir().unwrap();
    let e = Dataset::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("no .tif parts"), "{e}");
    let e = Dataset::open(&dir.path().join("nope.tif"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.tif") && e.contains("cannot open"), "{e}");
}

#[test]
fn fuzz_regressions_stay_bounded() {
    // Inputs cargo fuzz found (fixtures/fuzz): each must give Ok or Err quickly,
    // never a panic or an unbounded allocation.
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/fuzz");
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let bytes = std::fs::read(&path).unwrap();
        let t = std::time::Instant::now();
        if let Ok(part) = Part::from_bytes(&path, bytes) {
            let bands: Vec<usize> = (0..part.bands.len()).collect();
            for level in 0..part.levels.len() {
                let _ = part.read_level(level, &bands);
            }
        }
        assert!(
            t.elapsed().as_secs() < 10,
            "{} took too long",
            path.display()
        );
    }
}

/// The paper's layout: level 0 reads back in input order, every level `k` is exactly
/// the input points at pixels (2^k·x, 2^k·y) of the row-major image, the tile index
/// counts and bounds what each tile holds.
fn check_paper_layout(pts: &PointColumns, compression: Compression) {
    use pcimg::store::{Layout, write::paper};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("paper.tif");
    let opts = WriteOptions {
        compression,
        layout: Layout::Paper,
        ..Default::default()
    };
    let summary = write_part(&path, pts, &opts).unwrap();
    let part = Part::open(&path).unwrap();
    assert_eq!(part.meta.layout, "paper");
    let n = pts.len() as u64;
    let g = Geometry::for_points(n);
    assert_eq!(part.levels.len(), g.levels());
    let origin = part.meta.origin;
    let all: Vec<usize> = (0..part.bands.len()).collect();
    for (k, level) in part.levels.iter().enumerate() {
        let want = paper::level_indices(n, k);
        assert_eq!(level.points, Some(want.len() as u64), "level {k}");
        assert_eq!(summary.level_points[k], want.len() as u64);
        let got = part.read_level(k, &all).unwrap();
        assert_eq!(got.len(), want.len(), "level {k}");
        for (j, &i) in want.iter().enumerate() {
            let i = i as usize;
            let xyz = [pts.x[i], pts.y[i], pts.z[i]];
            for a in 0..3 {
                assert_eq!(
                    got.offsets[a] + got.columns[a][j] as f64,
                    stored(xyz[a], origin[a]),
                    "level {k} point {j}"
                );
            }
            for (b, attr) in pts.attributes.iter().enumerate() {
                assert_eq!(got.columns[3 + b][j], attr.values[i]);
            }
        }
        // Tiles: counts as indexed, points inside the bounds, together the level.
        let mut from_tiles = 0;
        for t in &level.tiles {
            let p = part.read_tiles(k, &[t.index], &[0, 1, 2]).unwrap();
            assert_eq!(p.tile_points, [t.points.unwrap()]);
            from_tiles += p.len();
            for i in 0..p.len() {
                for a in 0..3 {
                    let v = p.offsets[a] + p.columns[a][i] as f64;
                    assert!(v >= t.bounds.min[a] && v <= t.bounds.max[a]);
                }
            }
        }
        assert_eq!(from_tiles, want.len());
    }
}

#[test]
fn paper_layout_is_row_major_with_a_strided_pyramid() {
    for n in [0usize, 1, 5, 65_537] {
        check_paper_layout(&random_cloud(n, n as u64, 3), Compression::None);
    }
    // 3 levels; rows of 1024 points, the last one partial.
    check_paper_layout(&random_cloud(300_001, 9, 0), Compression::None);
    check_paper_layout(&random_cloud(70_000, 2, 0), Compression::Deflate);
}

/// Points `from..to` of `pts` as a chunk of their own.
fn cut_range(
    pts: &pcimg::points::PointColumns,
    from: usize,
    to: usize,
) -> pcimg::points::PointColumns {
    let mut c = pts.empty_like();
    c.append_range(pts, from, to);
    c
}

/// A part written from several chunks (as `convert` hands over a reader's
/// windows) is byte for byte the part written from the joined columns; chunks
/// whose attributes differ are refused.
#[test]
fn chunks_write_the_same_part() {
    let pts = pcimg::synth::scene(150_000, 4);
    let cut = |from: usize, to: usize| cut_range(&pts, from, to);
    let chunks = vec![cut(0, 40_000), cut(40_000, 40_001), cut(40_001, 150_000)];
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.tif"), dir.path().join("b.tif"));
    let opts = WriteOptions::default();
    write_part(&a, &pts, &opts).unwrap();
    pcimg::store::write_part_chunks(&b, &chunks, &opts).unwrap();
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());

    let mut odd = chunks;
    odd[1].attributes[0].offset += 1.0;
    let e = pcimg::store::write_part_chunks(&b, &odd, &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("b.tif") && e.contains("offsets"), "{e}");
}

/// Bounds a caller already has save the writer a pass: the part is the same as
/// with bounds it computes itself, and points outside them (or not finite) are
/// refused with the point's index, leaving nothing behind.
#[test]
fn given_bounds_write_the_same_part_and_are_checked() {
    let pts = pcimg::synth::scene(100_000, 5);
    let cut = |from: usize, to: usize| cut_range(&pts, from, to);
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.tif"), dir.path().join("b.tif"));
    let opts = WriteOptions::default();
    write_part(&a, &pts, &opts).unwrap();
    let chunks = vec![cut(0, 30_000), cut(30_000, 100_000)];
    pcimg::store::write_part_owned(&b, chunks, Some(pts.bounds()), &opts).unwrap();
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
    // Two attributes from several owned chunks (interleaved, then gathered
    // into image order): the same part again.
    let many = random_cloud(100_000, 9, 4);
    write_part(&a, &many, &opts).unwrap();
    let chunks = vec![cut_range(&many, 0, 1), cut_range(&many, 1, 100_000)];
    pcimg::store::write_part_owned(&b, chunks, Some(many.bounds()), &opts).unwrap();
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());

    let c = dir.path().join("c.tif");
    let mut small = pts.bounds();
    small.max[1] -= 1.0;
    let e = pcimg::store::write_part_owned(&c, vec![pts.clone()], Some(small), &opts)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("c.tif") && e.contains("outside the bounds"),
        "{e}"
    );
    let mut bad = pts.clone();
    bad.z[77_777] = f64::NAN;
    let e = pcimg::store::write_part_owned(&c, vec![bad], Some(pts.bounds()), &opts)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("point 77777") && e.contains("not a finite"),
        "{e}"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(left.len(), 2, "only a.tif and b.tif: {left:?}");
}

/// Compressed parts written from every worker of the global rayon pool at once
/// (as the overview writes its nodes): a worker must not wait on encoding jobs
/// queued behind it on its own pool. Before the fix this hung with every
/// worker parked; the test fails after a minute instead of hanging.
#[test]
fn compressed_parts_written_from_every_rayon_worker_at_once_finish() {
    use rayon::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().to_path_buf();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let writers = rayon::current_num_threads() * 2;
        let r: Vec<u64> = (0..writers)
            .into_par_iter()
            .map(|k| {
                let opts = WriteOptions {
                    compression: if k % 2 == 0 {
                        Compression::Zstd
                    } else {
                        Compression::LercZstd
                    },
                    ..Default::default()
                };
                let path = root.join(format!("p{k}.tif"));
                write_part(&path, &random_cloud(150_000, k as u64, 2), &opts).unwrap();
                Part::open(&path).unwrap().meta.point_count
            })
            .collect();
        let _ = tx.send(r);
    });
    let counts = rx
        .recv_timeout(std::time::Duration::from_secs(90))
        .expect("parallel compressed writes did not finish: a deadlock");
    assert!(counts.iter().all(|&c| c == 150_000), "{counts:?}");
}
