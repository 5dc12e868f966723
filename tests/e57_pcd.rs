//! PCD and E57 inputs (issue 28) against reference facts: the PCL tutorial
//! files and the `e57` crate's test data in `fixtures/` (counts and bounds
//! checked with an independent decoder, or the files' own declared bounds),
//! synthetic files of known points, bad inputs, and the part's metadata.

mod common;

use pcimg::convert::{self, Quiet};
use pcimg::ingest::{self, ReadOptions};
use pcimg::points::PointColumns;
use pcimg::store::Dataset;
use pcimg::synth_formats::{PcdData, write_e57, write_pcd};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// Every point of `path` read in chunks of `chunk` points, the reader's info
/// and its count of points left out.
fn read(path: &Path, chunk: usize) -> (ingest::SourceInfo, PointColumns, u64) {
    let opts = ReadOptions {
        chunk_points: chunk,
        ..Default::default()
    };
    let mut r = ingest::open(path, &opts).unwrap();
    let mut all: Option<PointColumns> = None;
    while let Some(c) = r.next_chunk().unwrap() {
        match &mut all {
            Some(a) => a.append(&c).unwrap(),
            None => all = Some(c),
        }
    }
    let all = all.unwrap_or_default();
    (r.info().clone(), all, r.left_out())
}

fn read_err(path: &Path) -> ingest::IngestError {
    let opts = ReadOptions {
        chunk_points: 1000,
        ..Default::default()
    };
    match ingest::read_all(path, &opts) {
        Ok((_, p, _)) => panic!("{} read {} points", path.display(), p.len()),
        Err(e) => {
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
            e
        }
    }
}

fn range(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        })
}

#[test]
fn pcd_ascii_lamppost() {
    let (info, p, left) = read(&fixture("lamppost.pcd"), 1 << 20);
    assert_eq!(info.format, "pcd 0.7 ascii");
    assert_eq!((p.len(), left), (1771, 0));
    assert!(p.attributes.is_empty());
    assert_eq!(range(&p.x), (-11.171875, -9.765625));
    assert_eq!(range(&p.z), (-5.447998f32 as f64, 0.46699905f32 as f64));
    assert_eq!(
        info.metadata,
        [("VIEWPOINT".to_string(), "0 0 0 1 0 0 0".to_string())]
    );
}

#[test]
fn pcd_compressed_rgba() {
    let (info, p, left) = read(&fixture("milk.pcd"), 1 << 20);
    assert_eq!(info.format, "pcd 0.7 binary_compressed");
    assert_eq!((p.len(), left), (12575, 0));
    assert_eq!(info.attribute_names, ["red", "green", "blue"]);
    // Every rgba value is 0x000000ff (read with an independent LZF decoder).
    assert!(common::attr(&p, "blue").iter().all(|&b| b == 255.0));
    assert!(common::attr(&p, "red").iter().all(|&r| r == 0.0));
    assert_eq!(range(&p.x), (0.17866219580173492, 0.32538360357284546));
    assert_eq!(range(&p.z), (-0.8268151879310608, -0.6361504197120667));
    // The first point, and its coordinates as float32.
    assert_eq!(p.x[0], 0.18544159829616547);
}

#[test]
fn pcd_organized_nan_slots_are_left_out_and_counted() {
    let name = fixture("milk_cartoon_all_small_clorox.pcd");
    let (_, whole, left) = read(&name, 1 << 20);
    assert_eq!((whole.len(), left), (241_407, 65_793));
    assert_eq!(range(&whole.x), (-1.0607999563217163, 1.152493953704834));
    assert_eq!(range(&whole.z), (-2.062999963760376, -0.5009999871253967));
    let red = common::attr(&whole, "red");
    assert_eq!(red.iter().fold(0f32, |m, &v| m.max(v)), 254.0);
    // The first slot with a measurement is slot 10,814: colour (88, 85, 68).
    assert_eq!(
        (
            red[0],
            common::attr(&whole, "green")[0],
            common::attr(&whole, "blue")[0]
        ),
        (88.0, 85.0, 68.0)
    );
    assert_eq!(whole.x[0], 0.9656456708908081);
    // Small chunks cross the LZF cursors' pieces: the same points.
    let (_, chunked, left) = read(&name, 999);
    assert_eq!(left, 65_793);
    assert_eq!(chunked, whole);
}

#[test]
fn pcd_encodings_agree_with_the_points_written() {
    let dir = tempfile::tempdir().unwrap();
    let n = 20_000;
    let mut got = Vec::new();
    for (name, data) in [
        ("a.pcd", PcdData::Ascii),
        ("b.pcd", PcdData::Binary),
        ("z.pcd", PcdData::Compressed),
    ] {
        let p = dir.path().join(name);
        write_pcd(&p, n, 5, data).unwrap();
        let (info, pts, left) = read(&p, 3_001);
        assert_eq!(info.attribute_names, ["intensity", "red", "green", "blue"]);
        assert_eq!((pts.len(), left), (n as usize, 0));
        got.push(pts);
    }
    assert_eq!(got[0], got[1]);
    assert_eq!(got[1], got[2]);
    // Grey colour from intensity, and the scene's local coordinates.
    let p = &got[1];
    let inten = common::attr(p, "intensity");
    assert!((0..p.len()).all(|i| common::attr(p, "red")[i] == inten[i].clamp(0.0, 255.0).trunc()));
    let (lo, hi) = range(&p.x);
    assert!(lo >= 0.0 && hi <= 410.0 && hi - lo > 300.0, "{lo} {hi}");
}

/// A header with `FIELDS x y z`, `F 4` each, `points` declared, then `data`.
fn pcd(points: &str, data_kind: &str, data: &[u8]) -> Vec<u8> {
    let mut v = format!(
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n{points}\nDATA {data_kind}\n"
    )
    .into_bytes();
    v.extend_from_slice(data);
    v
}

fn floats(n: usize) -> Vec<u8> {
    (0..n * 3).flat_map(|i| (i as f32).to_le_bytes()).collect()
}

#[test]
fn bad_pcd_inputs_name_the_line_or_byte_offset() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    // Truncated binary data: the offset is the end of the file.
    let b = pcd("WIDTH 10\nHEIGHT 1\nPOINTS 10", "binary", &floats(9));
    let e = read_err(&write("trunc.pcd", &b));
    assert_eq!(e.byte_offset(), Some(b.len() as u64), "{e}");
    assert!(e.to_string().contains("truncated"), "{e}");
    // POINTS other than WIDTH × HEIGHT: the POINTS line.
    let e = read_err(&write(
        "lie.pcd",
        &pcd("WIDTH 5\nHEIGHT 2\nPOINTS 11", "binary", &floats(11)),
    ));
    assert_eq!(e.line_number(), Some(8), "{e}");
    // POINTS (and WIDTH) understating the data.
    let e = read_err(&write(
        "under.pcd",
        &pcd("WIDTH 8\nHEIGHT 1\nPOINTS 8", "binary", &floats(10)),
    ));
    assert!(e.to_string().contains("understates"), "{e}");
    // An unknown type.
    let bad = String::from_utf8(pcd("WIDTH 1\nPOINTS 1", "ascii", b"1 2 3\n"))
        .unwrap()
        .replace("TYPE F F F", "TYPE F F Q");
    let e = read_err(&write("type.pcd", bad.as_bytes()));
    assert_eq!(e.line_number(), Some(4), "{e}");
    assert!(e.to_string().contains("unknown field type"), "{e}");
    // ASCII data shorter or longer than POINTS.
    let e = read_err(&write(
        "short.pcd",
        &pcd("WIDTH 3\nPOINTS 3", "ascii", b"1 2 3\n4 5 6\n"),
    ));
    assert!(e.to_string().contains("ends after 2 points"), "{e}");
    let e = read_err(&write(
        "long.pcd",
        &pcd("WIDTH 1\nPOINTS 1", "ascii", b"1 2 3\n4 5 6\n"),
    ));
    assert_eq!(e.line_number(), Some(10), "{e}");
    let e = read_err(&write(
        "word.pcd",
        &pcd("WIDTH 1\nPOINTS 1", "ascii", b"1 two 3\n"),
    ));
    assert_eq!(e.line_number(), Some(9), "{e}");
    // binary_compressed: sizes that do not add up.
    let raw = floats(4);
    let z = pcimg::ingest::pcd::lzf::compress(&raw);
    let body = |c: u32, u: u32, z: &[u8]| {
        let mut v = c.to_le_bytes().to_vec();
        v.extend(u.to_le_bytes());
        v.extend_from_slice(z);
        v
    };
    let head = "WIDTH 4\nHEIGHT 1\nPOINTS 4";
    let good = pcd(head, "binary_compressed", &body(z.len() as u32, 48, &z));
    let (_, p, _) = ingest::read_all(&write("good.pcd", &good), &ReadOptions::default()).unwrap();
    // Column by column: x 0-3, y 4-7, z 8-11.
    assert_eq!(p.z, [8.0, 9.0, 10.0, 11.0]);
    let at = (good.len() - z.len() - 8) as u64;
    let e = read_err(&write(
        "usize.pcd",
        &pcd(head, "binary_compressed", &body(z.len() as u32, 44, &z)),
    ));
    assert_eq!(e.byte_offset(), Some(at + 4), "{e}");
    let e = read_err(&write(
        "csize.pcd",
        &pcd(head, "binary_compressed", &body(z.len() as u32 + 9, 48, &z)),
    ));
    assert!(e.to_string().contains("runs past"), "{e}");
    let mut extra = z.clone();
    extra.extend([0, 7]);
    let e = read_err(&write(
        "more.pcd",
        &pcd(
            head,
            "binary_compressed",
            &body(extra.len() as u32, 48, &extra),
        ),
    ));
    assert!(e.to_string().contains("goes on after"), "{e}");
    // A back reference before the start of the data.
    let bad = [1u8 << 5, 0];
    let e = read_err(&write(
        "ref.pcd",
        &pcd(head, "binary_compressed", &body(2, 48, &bad)),
    ));
    assert_eq!(e.byte_offset(), Some(at + 8), "{e}");
}

#[test]
fn e57_bunny_float_and_scaled_integer() {
    let (info, f, left) = read(&fixture("bunnyFloat.e57"), 7_000);
    assert_eq!((f.len(), left), (30_571, 0));
    assert_eq!(info.declared_points, Some(30_571));
    let (_, i, _) = read(&fixture("bunnyInt21.e57"), 1 << 20);
    assert_eq!(i.len(), 30_571);
    // The files' declared cartesianBounds.
    let want = [
        (-0.094689, 0.061009),
        (0.040011, 0.187321),
        (-0.061873, 0.058799),
    ];
    for p in [&f, &i] {
        for (axis, (lo, hi)) in [&p.x, &p.y, &p.z].into_iter().zip(want) {
            let (a, b) = range(axis);
            assert!((a - lo).abs() < 1e-6 && (b - hi).abs() < 1e-6, "{a} {b}");
        }
    }
    // The same points in the same order: 21-bit integers are within a step.
    let worst = (0..f.len())
        .map(|k| {
            (f.x[k] - i.x[k])
                .abs()
                .max((f.y[k] - i.y[k]).abs())
                .max((f.z[k] - i.z[k]).abs())
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "{worst}");
}

#[test]
fn e57_colour_spherical_and_intensity() {
    let (info, p, _) = read(&fixture("tinyCartesianFloatRgb.e57"), 1 << 20);
    assert_eq!(p.len(), 2090);
    assert_eq!(info.attribute_names, ["red", "green", "blue"]);
    // The e57 crate's test of the declared bounds.
    let (lo, hi) = range(&p.x);
    assert!((lo - -9.779529571533203).abs() < 1e-9 && (hi - -6.774238109588623).abs() < 1e-9);
    let (lo, hi) = range(&p.z);
    assert!((lo - 295.5246887207031).abs() < 1e-9 && (hi - 298.53216552734375).abs() < 1e-9);
    let red = common::attr(&p, "red");
    assert!(red.iter().all(|v| (0.0..=255.0).contains(v)) && red.iter().any(|&v| v > 100.0));
    // 360 records, the odd ones a direction only: left out.
    let (_, s, left) = read(&fixture("tiny_spherical.e57"), 50);
    assert_eq!((s.len(), left), (180, 180));
    assert!((s.x[0] - 1.0).abs() < 1e-12 && s.y[0].abs() < 1e-12 && s.z[0].abs() < 1e-12);
    // Integer intensity from 0 to its declared maximum, normalised to 0 and 1.
    let (_, q, _) = read(&fixture("integer_intensity.e57"), 10);
    assert_eq!(common::attr(&q, "intensity"), [0.0, 1.0]);
}

#[test]
fn e57_bad_checksum_and_truncation_are_errors() {
    let e = read_err(&fixture("corrupt_crc.e57"));
    let s = e.to_string();
    assert!(
        s.contains("checksum") && e.byte_offset() == Some(33 * 1024),
        "{s}"
    );
    let dir = tempfile::tempdir().unwrap();
    let data = std::fs::read(fixture("bunnyInt21.e57")).unwrap();
    for cut in [100, 4096, data.len() / 2, data.len() - 1] {
        let p = dir.path().join(format!("cut{cut}.e57"));
        std::fs::write(&p, &data[..cut]).unwrap();
        assert!(read_err(&p).byte_offset().is_some());
    }
}

#[test]
fn e57_scans_land_in_one_frame_with_a_scan_band() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("three.e57");
    let n = 3000;
    write_e57(&p, n, 9, true, 3).unwrap();
    let (info, got, left) = read(&p, 700);
    assert_eq!((got.len(), left), (3000, 0));
    assert_eq!(
        info.attribute_names,
        ["intensity", "red", "green", "blue", "scan"]
    );
    // The same points as the PCD writer's (local frame, as f32), each scan's
    // pose undone: within the 1 mm of the scaled integers.
    let pcd = dir.path().join("same.pcd");
    write_pcd(&pcd, n, 9, PcdData::Binary).unwrap();
    let (_, want, _) = read(&pcd, 1 << 20);
    let worst = (0..3000)
        .map(|k| {
            (got.x[k] - want.x[k])
                .abs()
                .max((got.y[k] - want.y[k]).abs())
        })
        .fold(0.0, f64::max);
    assert!(worst < 1.5e-3, "{worst}");
    let scan = common::attr(&got, "scan");
    assert_eq!((scan[0], scan[1500], scan[2999]), (0.0, 1.0, 2.0));
    // Intensity normalised to its limits (0-255).
    let (a, b) = (
        common::attr(&got, "intensity"),
        common::attr(&want, "intensity"),
    );
    assert!((0..3000).all(|k| (a[k] - b[k].clamp(0.0, 255.0).trunc() / 255.0).abs() < 1e-6));
    let scans: serde_json::Value = serde_json::from_str(&info.metadata[0].1).unwrap();
    assert_eq!(scans.as_array().unwrap().len(), 3);
    assert_eq!(scans[2]["translation"], serde_json::json!([20.0, 0.0, 0.0]));
    assert_eq!(scans[1]["name"], "scan 1");
}

#[test]
fn converted_parts_keep_scans_and_viewpoint_and_info_shows_them() {
    let dir = tempfile::tempdir().unwrap();
    let e57 = dir.path().join("two.e57");
    write_e57(&e57, 300_000, 3, false, 2).unwrap();
    // A small budget: several parts, every point kept.
    let out = dir.path().join("out");
    let s = convert::convert(
        &e57,
        &common::convert_options(out.clone(), 24 << 20),
        &Quiet,
    )
    .unwrap();
    assert_eq!(s.points, 300_000);
    assert!(s.parts.len() > 1, "{}", s.parts.len());
    let ds = Dataset::open(&out).unwrap();
    let meta = &ds.parts().unwrap()[0].meta;
    assert_eq!(meta.from_source[0].0, "SCANS");
    let text = pcimg::cli::info::render_text(&pcimg::cli::info::report(&ds, false));
    assert!(
        text.contains("scans    2") && text.contains("scan 1"),
        "{text}"
    );
    // PCD: the viewpoint; NaN slots counted in the summary.
    let out = dir.path().join("milk.tif");
    let s = convert::convert(
        &fixture("milk_cartoon_all_small_clorox.pcd"),
        &common::convert_options(out.clone(), 1 << 30),
        &Quiet,
    )
    .unwrap();
    assert_eq!((s.points, s.left_out), (241_407, 65_793));
    let ds = Dataset::open(&out).unwrap();
    let text = pcimg::cli::info::render_text(&pcimg::cli::info::report(&ds, false));
    assert!(text.contains("viewpoint 0 0 0 1 0 0 0"), "{text}");
    // Embedded images are said to be skipped.
    let out = dir.path().join("img.tif");
    let s = convert::convert(
        &fixture("tiny_pc_and_images.e57"),
        &common::convert_options(out, 1 << 30),
        &Quiet,
    )
    .unwrap();
    assert!(
        s.notes
            .iter()
            .any(|n| n.contains("4 embedded image(s) skipped")),
        "{:?}",
        s.notes
    );
}

#[test]
fn a_failed_conversion_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    for (name, from) in [("c.e57", "corrupt_crc.e57"), ("t.pcd", "milk.pcd")] {
        let input = dir.path().join(name);
        let mut data = std::fs::read(fixture(from)).unwrap();
        if name.ends_with("pcd") {
            data.truncate(2000);
        }
        std::fs::write(&input, data).unwrap();
        let out = dir.path().join(format!("{name}.out"));
        assert!(
            convert::convert(
                &input,
                &common::convert_options(out.clone(), 1 << 30),
                &Quiet
            )
            .is_err()
        );
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left.len(), 1 + usize::from(name == "t.pcd"), "{left:?}");
    }
}

/// Scaled-integer coordinates in one frame are a lattice (issue 40: "choose the
/// coordinate lattice from the data"): `bunnyInt21.e57` (21-bit integers) and a
/// one-scan file of 1 mm integers keep theirs exactly through a conversion, each
/// point read back the source's lattice point. Floats, and scans turned by
/// their poses (a lattice at an angle to the file's axes), have none.
#[test]
fn e57_scaled_integers_in_one_frame_are_a_lattice_kept_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one.e57");
    write_e57(&one, 20_000, 4, true, 1).unwrap();
    let turned = dir.path().join("turned.e57");
    write_e57(&turned, 3000, 4, true, 3).unwrap();
    let floats = dir.path().join("floats.e57");
    write_e57(&floats, 3000, 4, false, 1).unwrap();
    for p in [&turned, &floats, &fixture("bunnyFloat.e57")] {
        let (info, _, _) = read(p, 1 << 20);
        assert!(info.coordinate_lattice.is_none(), "{}", p.display());
    }
    for (p, step) in [(fixture("bunnyInt21.e57"), 1e-6), (one, 1e-3)] {
        let (info, src, _) = read(&p, 1 << 20);
        let l = info.coordinate_lattice.expect("a lattice");
        assert_eq!(l.step, [step; 3], "{}", p.display());
        let out = dir.path().join(format!(
            "{}.pcimg",
            p.file_stem().unwrap().to_string_lossy()
        ));
        let o = common::cli::pcimg()
            .args(["convert", p.to_str().unwrap(), "-o", out.to_str().unwrap()])
            .output()
            .unwrap();
        let said = common::cli::ok(&o, "convert");
        assert!(
            said.contains("every part's coordinates kept exactly on the input's lattice"),
            "{said}"
        );
        let ds = Dataset::open(&out).unwrap();
        let mut got = Vec::new();
        for part in ds.parts().unwrap() {
            assert_eq!(part.meta.lattice, Some(l));
            let pts = part.read_level(0, &[0, 1, 2]).unwrap();
            for i in 0..pts.len() {
                got.push([0, 1, 2].map(|a| {
                    let v = pts.offsets[a] + pts.columns[a][i] as f64;
                    ((v - l.origin[a]) / l.step[a]).round() as i64
                }));
            }
        }
        let mut want: Vec<[i64; 3]> = (0..src.len())
            .map(|i| {
                let v = [src.x[i], src.y[i], src.z[i]];
                [0, 1, 2].map(|a| ((v[a] - l.origin[a]) / l.step[a]).round() as i64)
            })
            .collect();
        got.sort_unstable();
        want.sort_unstable();
        assert_eq!(got, want, "{}", p.display());
    }
}
