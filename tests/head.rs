//! Parts are written head-first: every directory, tile offset and byte count
//! array and the metadata before the first tile, and the head's length recorded
//! in the part's summary and the dataset index. A part in the older layout
//! (directories after the tiles) still opens and reads the same.

mod common;

use common::tiffwalk::Walk;
use pcimg::store::dataset::index::{entry_of, head_of};
use pcimg::store::{Compression, Part, WriteOptions, write_part};

fn levels_of(p: &Part) -> Vec<Vec<Vec<u32>>> {
    (0..p.levels.len())
        .map(|k| {
            let bands: Vec<usize> = (0..p.bands.len()).collect();
            let l = p.read_level(k, &bands).unwrap();
            l.columns
                .iter()
                .map(|c| c.iter().map(|v| v.to_bits()).collect())
                .collect()
        })
        .collect()
}

#[test]
fn every_directory_and_value_lies_before_the_first_tile() {
    let dir = tempfile::tempdir().unwrap();
    // 5 tiles and a partial one: three levels.
    let c = common::random_cloud(5 * 65_536 + 777, 9, 0);
    for compression in [Compression::None, Compression::Zstd, Compression::Deflate] {
        for big in [false, true] {
            let path = dir.path().join(format!("{compression:?}{big}.tif"));
            let opts = WriteOptions {
                compression,
                force_bigtiff: big,
                source: Some("a \"quoted\" & <odd> source.las".into()),
                ..Default::default()
            };
            let s = write_part(&path, &c, &opts).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            let w = Walk::new(&bytes);
            let what = format!("{compression:?} bigtiff={big}");
            assert_eq!(w.big, big, "{what}");
            // 3 levels: a directory each, with its tile offsets, byte counts
            // and (level 0) the metadata among the values.
            assert!(w.structures.len() > 3 * 4, "{what}");
            assert!(w.tiles.len() >= 5 * 5, "{what}");
            let (head, first) = (w.head_end(), w.first_tile());
            assert!(
                head <= first,
                "{what}: head ends at {head}, a tile starts at {first}"
            );
            assert_eq!(s.head, head, "{what}: the summary's head");
            assert_eq!(head_of(&path).unwrap(), head, "{what}");
            let part = Part::open(&path).unwrap();
            assert_eq!(entry_of(&part, "x.tif").unwrap().head, head, "{what}");
            assert_eq!(s.bytes, bytes.len() as u64, "{what}");
            if compression == Compression::None {
                assert_eq!(first % 4096, 0, "{what}: tiles on disk blocks");
            } else {
                // Compressed tiles follow the head closely.
                assert!(first - head < 8, "{what}: {head}..{first}");
            }
        }
    }
}

#[test]
fn a_part_in_the_older_layout_still_opens() {
    let dir = tempfile::tempdir().unwrap();
    let c = common::random_cloud(2 * 65_536 + 5, 3, 0);
    for compression in [Compression::None, Compression::Zstd] {
        let new = dir.path().join(format!("{compression:?}.tif"));
        let opts = WriteOptions {
            compression,
            ..Default::default()
        };
        write_part(&new, &c, &opts).unwrap();
        let bytes = std::fs::read(&new).unwrap();
        let old_bytes = Walk::new(&bytes).to_old_layout(&bytes);
        let old = dir.path().join(format!("{compression:?}-old.tif"));
        std::fs::write(&old, &old_bytes).unwrap();
        // The rewrite is the older layout: directories after the tiles.
        let w = Walk::new(&old_bytes);
        assert!(w.structures.iter().all(|s| s.0 > w.first_tile()));
        assert_eq!(head_of(&old).unwrap(), 0);
        let (a, b) = (Part::open(&new).unwrap(), Part::open(&old).unwrap());
        assert_eq!(entry_of(&b, "old.tif").unwrap().head, 0);
        assert_eq!(a.meta.point_count, b.meta.point_count);
        assert!(levels_of(&a) == levels_of(&b), "{compression:?}");
    }
}
