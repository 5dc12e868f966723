//! `pcimg convert` end to end: every input format, the real samples in fixtures/, the
//! memory budget, partition modes, bad inputs, interruption, and the command line.

mod common;

use pcimg::convert::{self, Partition, Progress, Quiet};
use pcimg::ingest::ReadOptions;
use pcimg::store::{Compression, Dataset, Layout};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// Level-0 points of a dataset as (x, y, z) rounded to 0.1 mm, sorted.
fn dataset_points(path: &Path) -> Vec<[i64; 3]> {
    let ds = Dataset::open(path).unwrap();
    let mut all = Vec::new();
    for p in ds.parts().unwrap() {
        let pts = p.read_level(0, &[0, 1, 2]).unwrap();
        for i in 0..pts.len() {
            all.push(
                [0, 1, 2]
                    .map(|a| ((pts.offsets[a] + pts.columns[a][i] as f64) * 1e4).round() as i64),
            );
        }
    }
    all.sort();
    all
}

/// The points of an input file as (x, y, z) rounded to 0.1 mm, sorted.
fn file_points(path: &Path) -> Vec<[i64; 3]> {
    let (_, all, _) = pcimg::ingest::read_all(path, &ReadOptions::default()).unwrap();
    let mut v: Vec<[i64; 3]> = (0..all.len())
        .map(|i| [all.x[i], all.y[i], all.z[i]].map(|v| (v * 1e4).round() as i64))
        .collect();
    v.sort();
    v
}

/// The largest difference (in 0.1 mm) between matching points of two sorted
/// lists, which must be as long.
fn worst_offset(got: &[[i64; 3]], want: &[[i64; 3]]) -> i64 {
    assert_eq!(got.len(), want.len());
    got.iter()
        .zip(want)
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).max().unwrap_or(0))
        .max()
        .unwrap_or(0)
}

/// Parts do not overlap: each pair is separated on some axis.
fn assert_parts_disjoint(path: &Path) {
    let ds = Dataset::open(path).unwrap();
    let parts = ds.parts().unwrap();
    for (i, a) in parts.iter().enumerate() {
        for b in &parts[i + 1..] {
            let (a, b) = (a.meta.bounds, b.meta.bounds);
            assert!(
                (0..3).any(|k| a.max[k] <= b.min[k] || b.max[k] <= a.min[k]),
                "parts overlap: {a:?} {b:?}"
            );
        }
    }
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// LERC on a LAS input: coordinates within half the LAS scale by default
/// (`CODEC_MAX_ERROR`), and in fact back on the LAS lattice (within f32
/// rounding of the uncompressed part's values); every attribute, whole
/// numbers and GPS time alike, bit for bit; `--max-error` narrows the bound,
/// and a non-LAS input is lossless.
#[test]
fn lerc_gives_las_coordinates_back_on_their_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let part = |input: &str, name: &str, c: Compression, e: Option<f64>| {
        let out = dir.path().join(name);
        let o = convert::ConvertOptions {
            compression: c,
            max_error: e,
            ..common::convert_options(out.clone(), 1 << 30)
        };
        convert::convert(&fixture(input), &o, &Quiet).unwrap();
        pcimg::store::Part::open(&out).unwrap()
    };
    let plain = part("autzen_trim.laz", "none.tif", Compression::None, None);
    let lerc = part("autzen_trim.laz", "lerc.tif", Compression::LercZstd, None);
    assert_eq!(lerc.meta.codec_max_error, Some([0.005; 3]));
    assert!(lerc.meta.max_quantization_error.unwrap() > 0.005);
    assert!(
        lerc.file_bytes * 4 < plain.file_bytes,
        "LERC is far smaller"
    );
    // `info` states the bound in the data's own unit (autzen is in feet).
    let text = pcimg::cli::info::render_text(&pcimg::cli::info::report(
        &Dataset::open(&dir.path().join("lerc.tif")).unwrap(),
        false,
    ));
    let line = text
        .lines()
        .find(|l| l.contains("stored coordinates within"))
        .unwrap_or_else(|| panic!("{text}"));
    assert!(line.contains(" foot (") && line.contains(" mm)"), "{line}");
    let bands: Vec<usize> = (0..plain.bands.len()).collect();
    for level in 0..plain.levels.len() {
        let (a, b) = (
            plain.read_level(level, &bands).unwrap(),
            lerc.read_level(level, &bands).unwrap(),
        );
        assert_eq!(a.len(), b.len());
        for k in &bands {
            for (x, y) in a.columns[*k].iter().zip(&b.columns[*k]) {
                if *k < 3 {
                    // (f32 at ~600 ft from the origin: steps of 6e-5.)
                    assert!(
                        (x - y).abs() <= 1.3e-4,
                        "level {level} band {k}: {x} vs {y}"
                    );
                } else {
                    assert_eq!(x.to_bits(), y.to_bits(), "level {level} band {k}");
                }
            }
        }
    }
    let narrow = part(
        "autzen_trim.laz",
        "narrow.tif",
        Compression::Lerc,
        Some(0.001),
    );
    assert_eq!(narrow.meta.codec_max_error, Some([0.001; 3]));
    let ply = part("bun_zipper.ply", "bunny.tif", Compression::Lerc, None);
    assert_eq!(ply.meta.codec_max_error, Some([0.0; 3]));
    let ply_plain = part("bun_zipper.ply", "bunny-none.tif", Compression::None, None);
    let (a, b) = (
        ply_plain.read_level(0, &[0, 1, 2]).unwrap(),
        ply.read_level(0, &[0, 1, 2]).unwrap(),
    );
    assert!(a.columns == b.columns, "lossless without a lattice");
}

#[test]
fn real_samples_convert_with_reference_counts_and_bounds() {
    let dir = tempfile::tempdir().unwrap();
    type Case = (&'static str, u64, Option<([f64; 3], [f64; 3])>);
    let cases: [Case; 3] = [
        (
            "autzen_trim.laz",
            110_000,
            Some((
                [636001.76, 848935.20, 406.26],
                [637179.22, 849497.90, 520.51],
            )),
        ),
        ("bun_zipper.ply", 35_947, None),
        ("cgal_b9_training.ply", 22_300, None),
    ];
    for (name, n, bounds) in cases {
        let out = dir.path().join(format!("{name}.tif"));
        let s = convert::convert(
            &fixture(name),
            &common::convert_options(out.clone(), 1 << 30),
            &Quiet,
        )
        .unwrap();
        assert_eq!(s.points, n, "{name}");
        let ds = Dataset::open(&out).unwrap();
        assert_eq!(ds.points(), n);
        let p = &ds.parts().unwrap()[0];
        assert_eq!(p.meta.source.as_deref(), Some(name));
        if let Some((min, max)) = bounds {
            for a in 0..3 {
                assert!((p.meta.bounds.min[a] - min[a]).abs() < 1e-6, "{name} min");
                assert!((p.meta.bounds.max[a] - max[a]).abs() < 1e-6, "{name} max");
            }
            assert!(p.meta.crs.as_deref().is_some_and(|c| !c.is_empty()));
            let names: Vec<&str> = p.bands.iter().map(|b| b.name.as_str()).collect();
            for want in [
                "intensity",
                "red",
                "green",
                "blue",
                "classification",
                "gps_time",
            ] {
                assert!(names.contains(&want), "{want} in {names:?}");
            }
            // 8-bit colour stored in 16-bit fields stays 0-255.
            let red = p.band_index("red").unwrap();
            let v = p.read_level(0, &[red]).unwrap();
            let max = v.columns[0].iter().fold(0f32, |m, &x| m.max(x));
            assert!(max > 1.0 && max <= 255.0, "{max}");
        }
        assert_eq!(p.meta.max_quantization_error.map(|e| e < 1e-3), Some(true));
    }
}

#[test]
fn budget_far_below_input_gives_spatial_parts_with_every_point() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("scan.xyz");
    pcimg::synth::write_text(&input, 600_000, 3).unwrap();
    let out = dir.path().join("scan.pcimg");
    // 64 MiB: about 180 k points per part for 4 bands.
    let s = convert::convert(
        &input,
        &common::convert_options(out.clone(), 64 << 20),
        &Quiet,
    )
    .unwrap();
    assert_eq!(s.points, 600_000);
    assert!(s.parts.len() as u64 >= 600_000u64.div_ceil(s.points_per_part));
    assert!(s.parts.len() >= 3, "{} parts", s.parts.len());
    assert!(s.parts.iter().all(|p| p.points <= s.points_per_part));
    // Every point, exactly once.
    let pts = pcimg::synth::scene(600_000, 3);
    let mut want: Vec<[i64; 3]> = (0..pts.len())
        .map(|i| {
            [pts.x[i], pts.y[i], pts.z[i]]
                .map(|v| ((v * 1000.0).round() / 1000.0 * 1e4).round() as i64)
        })
        .collect();
    want.sort();
    let worst = worst_offset(&dataset_points(&out), &want);
    assert!(worst <= 1, "points differ by {worst} x 0.1 mm");
    assert_parts_disjoint(&out);
    // Regions written whole (none was split again) record their points' source
    // bounds, exactly.
    assert!(s.phases.iter().all(|(name, _)| name != "split"));
    let ds = Dataset::open(&out).unwrap();
    let got = ds
        .parts()
        .unwrap()
        .into_iter()
        .fold(pcimg::points::Bounds::EMPTY, |b, p| b.union(&p.meta.bounds));
    let (_, read, _) = pcimg::ingest::read_all(&input, &ReadOptions::default()).unwrap();
    assert_eq!(got, read.bounds());
    // No temporary files left beside the output.
    assert_eq!(entries(dir.path()), ["scan.pcimg", "scan.xyz"]);
}

/// Keeps the progress notes.
#[derive(Default)]
struct Notes(std::sync::Mutex<Vec<String>>);

impl Progress for Notes {
    fn phase(&self, _: &str, _: u64, _: &'static str) {}
    fn advance(&self, _: u64, _: u64) {}
    fn note(&self, msg: &str) {
        self.0.lock().unwrap().push(msg.to_string());
    }
}

/// A first pass that samples the input once it proves larger than one part
/// (forced here with a small `sample_points`) still places regions that hold every
/// point, within the budget and without overlap, for text, LAS and LAZ, in scan
/// order (a periodic layout, the case where evenly spaced samples would alias).
#[test]
fn sampled_first_pass_keeps_every_point_within_budget() {
    use pcimg::synth::Order;
    let dir = tempfile::tempdir().unwrap();
    let n = 600_000;
    let text = dir.path().join("scan.xyz");
    let las = dir.path().join("scan.las");
    pcimg::synth::write_text_in_order(&text, n, 5, Order::Scan).unwrap();
    pcimg::synth::write_las_in_order(&las, n, 5, Order::Scan).unwrap();
    let laz = dir.path().join("scan.laz");
    pcimg::synth::write_las_in_order(&laz, n, 5, Order::Scan).unwrap();
    for input in [&text, &las, &laz] {
        let whole = dir.path().join("whole.pcimg");
        let sampled = dir.path().join("sampled.pcimg");
        let s = convert::convert(
            input,
            &common::convert_options(whole.clone(), 64 << 20),
            &Quiet,
        )
        .unwrap();
        let mut o = common::convert_options(sampled.clone(), 64 << 20);
        o.sample_points = 20_000;
        let notes = Notes::default();
        let t = convert::convert(input, &o, &notes).unwrap();
        // The sample was taken (the region count is then an estimate).
        let notes = notes.0.into_inner().unwrap();
        assert!(
            notes
                .iter()
                .any(|l| l.starts_with("about ") && l.contains("regions")),
            "{notes:?}"
        );
        assert_eq!((s.points, t.points), (n, n), "{}", input.display());
        assert!(t.parts.iter().all(|p| p.points <= t.points_per_part));
        assert!(t.parts.len() >= 4, "{} parts", t.parts.len());
        // The same points, only grouped differently.
        assert_eq!(dataset_points(&sampled), dataset_points(&whole));
        assert_parts_disjoint(&sampled);
        std::fs::remove_dir_all(&whole).unwrap();
        std::fs::remove_dir_all(&sampled).unwrap();
    }
    // A malformed line the sample may skip is still reported, with its number,
    // by the pass that reads every line.
    let mut bytes = std::fs::read(&text).unwrap();
    let cut = bytes.len() * 9 / 10;
    let at = cut + bytes[cut..].iter().position(|&c| c == b'\n').unwrap() + 1;
    let line = bytes[..at].iter().filter(|&&c| c == b'\n').count() + 1;
    bytes.splice(at..at, b"1 2 oops 4\n".iter().copied());
    std::fs::write(&text, &bytes).unwrap();
    let mut o = common::convert_options(dir.path().join("bad.pcimg"), 64 << 20);
    o.sample_points = 20_000;
    let e = convert::convert(&text, &o, &Quiet).unwrap_err().to_string();
    assert!(e.contains(&format!("line {line}")), "{e}");
    o.read.skip_invalid = true;
    let t = convert::convert(&text, &o, &Quiet).unwrap();
    assert_eq!((t.points, t.skipped), (n, 1));
}

/// Regions the sample underestimates are split again, exactly, before they are
/// written; a spot denser than any grid resolves (here 250,000 copies of one
/// point) becomes parts in file order. No part exceeds the budget and every
/// point is stored once.
#[test]
fn underestimated_regions_are_split_within_budget() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("dense.xyz");
    pcimg::synth::write_text(&input, 400_000, 7).unwrap();
    let mut text = std::fs::read(&input).unwrap();
    for _ in 0..250_000 {
        text.extend_from_slice(b"100.5 200.25 30.125 7\n");
    }
    std::fs::write(&input, &text).unwrap();
    let out = dir.path().join("dense.pcimg");
    let mut o = common::convert_options(out.clone(), 64 << 20);
    // A tiny sample: its region estimates are far off.
    o.sample_points = 2_000;
    let s = convert::convert(&input, &o, &Quiet).unwrap();
    assert_eq!(s.points, 650_000);
    assert!(
        s.phases.iter().any(|(name, _)| name == "split"),
        "{:?}",
        s.phases
    );
    assert!(s.parts.iter().all(|p| p.points <= s.points_per_part));
    assert_eq!(s.parts.iter().map(|p| p.points).sum::<u64>(), 650_000);
    let worst = worst_offset(&dataset_points(&out), &file_points(&input));
    assert!(worst <= 1, "points differ by {worst} x 0.1 mm");
    assert_eq!(entries(dir.path()), ["dense.pcimg", "dense.xyz"]);
}

/// A point the sample missed, 40 km beyond the rest, lands in an edge region whose
/// box centre f32 cannot hold them to 1 mm from: the regions are spilled again
/// around their own centres, and every point is stored within 1 mm.
#[test]
fn points_far_outside_the_sample_are_kept_to_a_millimetre() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("far.xyz");
    let mut text = String::new();
    let n = 300_000;
    for i in 0..n {
        let (x, y) = ((i % 547) as f64 * 0.183, (i / 547) as f64 * 0.182);
        writeln!(text, "{x:.3} {y:.3} {:.3} 1", (i % 7) as f64 * 0.1).unwrap();
    }
    // The last line, which no sampled piece reaches here.
    text.push_str("40000.125 50.5 1.5 9\n");
    std::fs::write(&input, &text).unwrap();
    let out = dir.path().join("far.pcimg");
    let mut o = common::convert_options(out.clone(), 64 << 20);
    o.sample_points = 1;
    let notes = Notes::default();
    let s = convert::convert(&input, &o, &notes).unwrap();
    let notes = notes.0.into_inner().unwrap();
    assert!(
        notes.iter().any(|l| l.contains("partitioning again")),
        "{notes:?}"
    );
    assert_eq!(s.points, n + 1);
    assert!(
        s.max_quantization_error < 1e-3,
        "{}",
        s.max_quantization_error
    );
    let worst = worst_offset(&dataset_points(&out), &file_points(&input));
    assert!(worst <= 10, "a point moved {worst} x 0.1 mm");
}

#[test]
fn stream_partition_keeps_file_order() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("scan.las");
    pcimg::synth::write_las(&input, 300_000, 5).unwrap();
    let out = dir.path().join("stream");
    let mut o = common::convert_options(out.clone(), 56 << 20);
    o.partition = Partition::Stream;
    o.layout = Layout::Paper;
    let s = convert::convert(&input, &o, &Quiet).unwrap();
    assert_eq!(s.points, 300_000);
    assert!(s.parts.len() >= 2);
    // The pass over the input comes first in the timings, though parts were
    // written while it ran.
    assert_eq!(
        s.phases.first().map(|(n, _)| n.as_str()),
        Some("read"),
        "{:?}",
        s.phases
    );
    // Part k holds points [k * per_part, ...) of the file, in file order (paper layout).
    let ds = Dataset::open(&out).unwrap();
    let pts = pcimg::synth::scene(300_000, 5);
    let mut start = 0usize;
    for p in ds.parts().unwrap() {
        let got = p.read_level(0, &[0]).unwrap();
        for i in [0, got.len() / 2, got.len() - 1] {
            let x = got.offsets[0] + got.columns[0][i] as f64;
            assert!((x - pts.x[start + i]).abs() < 2e-3, "part point {i}");
        }
        start += got.len();
    }
    assert_eq!(start, 300_000);
}

#[test]
fn precision_is_refused_unless_allowed() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wide.xyz");
    std::fs::write(&input, "0 0 0\n100000 5 1\n50000 2 3\n").unwrap();
    let e = convert::convert(
        &input,
        &common::convert_options(dir.path().join("w.tif"), 1 << 30),
        &Quiet,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("100.0 km") && e.contains("--allow-lossy"), "{e}");
    assert!(
        e.contains("1.95 mm") && e.contains("a directory output"),
        "{e}"
    );
    let mut o = common::convert_options(dir.path().join("w.tif"), 1 << 30);
    o.allow_lossy = true;
    assert!(convert::convert(&input, &o, &Quiet).is_ok());
    // Stream parts follow the file: refused, pointing to spatial parts.
    let mut o = common::convert_options(dir.path().join("stream.pcimg"), 1 << 30);
    o.partition = Partition::Stream;
    let e = convert::convert(&input, &o, &Quiet)
        .unwrap_err()
        .to_string();
    assert!(e.contains("the default spatial partitioning"), "{e}");
}

/// Points that fit one part but lie in clusters 100 km apart become spatial
/// parts narrow enough for 1 mm, with no --allow-lossy, whether the input holds
/// one part's points or many.
#[test]
fn wide_inputs_become_parts_that_keep_a_millimetre() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().unwrap();
    for (n, memory) in [(5_000u32, 1u64 << 30), (400_000, 64 << 20)] {
        let input = dir.path().join(format!("clusters{n}.xyz"));
        let mut text = String::new();
        for i in 0..n {
            let x = 500_000.0 + if i % 2 == 0 { 0.0 } else { 100_000.0 } + (i % 97) as f64;
            writeln!(
                text,
                "{x:.3} {:.3} {:.3}",
                4_000_000.0 + (i % 89) as f64,
                i % 7
            )
            .unwrap();
        }
        std::fs::write(&input, &text).unwrap();
        let out = dir.path().join(format!("clusters{n}.pcimg"));
        let s = convert::convert(
            &input,
            &common::convert_options(out.clone(), memory),
            &Quiet,
        )
        .unwrap();
        assert!(s.parts.len() >= 2, "{n}: {} part(s)", s.parts.len());
        assert!(
            s.max_quantization_error < 1e-3,
            "{n}: {}",
            s.max_quantization_error
        );
        assert_eq!(s.points, n as u64);
        assert_eq!(
            worst_offset(&dataset_points(&out), &file_points(&input)),
            0,
            "{n}"
        );
        assert_parts_disjoint(&out);
    }
}

/// LAS tiles of one survey: the same scale, each its own round offset (whole
/// steps apart), converted together keep that one lattice exactly; a tile
/// whose offset is half a step off the others' has none in common.
#[test]
fn las_tiles_with_their_own_offsets_share_one_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let tile = |name: &str, offset: [f64; 3], at: f64| {
        let path = dir.path().join(name);
        let mut b = las::Builder::from((1, 2));
        b.point_format = las::point::Format::new(1).unwrap();
        let t = |o| las::Transform {
            scale: 0.01,
            offset: o,
        };
        b.transforms = las::Vector {
            x: t(offset[0]),
            y: t(offset[1]),
            z: t(offset[2]),
        };
        let mut w = las::Writer::from_path(&path, b.into_header().unwrap()).unwrap();
        for i in 0..5000u32 {
            w.write_point(las::Point {
                x: at + f64::from(i % 97) * 1.37 + f64::from(i % 13) * 0.01,
                y: 4_000_000.0 + f64::from(i % 89) * 0.73,
                z: 100.0 + f64::from(i % 7) * 0.11,
                gps_time: Some(f64::from(i)),
                ..Default::default()
            })
            .unwrap();
        }
        w.close().unwrap();
        path
    };
    let a = tile("a.las", [500_000.0, 4_000_000.0, 0.0], 500_100.0);
    let b = tile("b.las", [501_000.0, 4_000_000.0, 100.0], 501_100.0);
    let half = tile("c.las", [502_000.005, 4_000_000.0, 0.0], 502_100.0);
    let convert = |inputs: &[&Path], name: &str| {
        let out = dir.path().join(name);
        let o = common::cli::pcimg()
            .arg("convert")
            .args(inputs)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        (out, common::cli::ok(&o, "convert"))
    };
    let (out, said) = convert(&[&a, &b], "ab.pcimg");
    assert!(
        said.contains("every part's coordinates kept exactly on the input's lattice (steps 0.01"),
        "{said}"
    );
    for p in Dataset::open(&out).unwrap().parts().unwrap() {
        assert_eq!(p.meta.lattice.map(|l| l.step), Some([0.01; 3]));
    }
    let mut want = file_points(&a);
    want.extend(file_points(&b));
    want.sort();
    assert_eq!(dataset_points(&out), want);
    let (out, said) = convert(&[&a, &half], "ac.pcimg");
    assert!(
        !said.contains("kept exactly on the input's lattice"),
        "{said}"
    );
    for p in Dataset::open(&out).unwrap().parts().unwrap() {
        assert_eq!(p.meta.lattice, None);
    }
    // Tiles converted one by one (each part its own offset) and indexed
    // together: the overview above them keeps their common lattice, its points
    // the parts' lattice points.
    let sep = dir.path().join("sep");
    std::fs::create_dir(&sep).unwrap();
    for (t, name) in [(&a, "a.tif"), (&b, "b.tif")] {
        let o = common::cli::pcimg()
            .arg("convert")
            .arg(t)
            .arg("-o")
            .arg(sep.join(name))
            .output()
            .unwrap();
        common::cli::ok(&o, "convert a tile");
    }
    let o = common::cli::pcimg()
        .arg("index")
        .arg(&sep)
        .output()
        .unwrap();
    common::cli::ok(&o, "index");
    let mut nodes = Vec::new();
    let mut dirs = vec![sep.join("overview")];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|e| e == "tif") {
                nodes.push(p);
            }
        }
    }
    assert!(!nodes.is_empty());
    for n in &nodes {
        let node = pcimg::store::Part::open(n).unwrap();
        let l = node.meta.lattice.expect("the node on the tiles' lattice");
        assert_eq!(l.step, [0.01; 3]);
    }
}

/// An uncompressed LAS file that fits one part is first read for its extent
/// only (no columns); when its points lie in clusters 100 km apart it is read
/// again, whole, and partitioned into parts that keep 1 mm, every point kept.
#[test]
fn wide_las_fitting_one_part_is_read_again_and_partitioned() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("clusters.las");
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    let t = |o| las::Transform {
        scale: 0.001,
        offset: o,
    };
    b.transforms = las::Vector {
        x: t(500_000.0),
        y: t(4_000_000.0),
        z: t(0.0),
    };
    let mut w = las::Writer::from_path(&input, b.into_header().unwrap()).unwrap();
    let n = 20_000u32;
    for i in 0..n {
        w.write_point(las::Point {
            x: 500_000.0 + if i % 2 == 0 { 0.0 } else { 100_000.0 } + (i % 97) as f64,
            y: 4_000_000.0 + (i % 89) as f64,
            z: (i % 7) as f64,
            intensity: i as u16,
            gps_time: Some(f64::from(i)),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let out = dir.path().join("clusters.pcimg");
    let s = convert::convert(
        &input,
        &common::convert_options(out.clone(), 1 << 30),
        &Quiet,
    )
    .unwrap();
    assert!(s.parts.len() >= 2, "{} part(s)", s.parts.len());
    assert!(
        s.max_quantization_error < 1e-3,
        "{}",
        s.max_quantization_error
    );
    assert_eq!(s.points, u64::from(n));
    assert_eq!(worst_offset(&dataset_points(&out), &file_points(&input)), 0);
    assert_parts_disjoint(&out);
}

/// A LAS header's bounds only place the origin of a part collected while reading;
/// when they are wrong (200 km wide around 400 m of points, or 400 m of bounds
/// 20 km off, which f32 would keep to 1 mm but not to 0.01) the input is read
/// again and converted around its true centre, every point kept.
#[test]
fn wrong_header_bounds_are_not_trusted() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.las");
    pcimg::synth::write_las(&good, 50_000, 3).unwrap();
    let a = dir.path().join("a.tif");
    let sa = convert::convert(&good, &common::convert_options(a.clone(), 1 << 30), &Quiet).unwrap();
    // Max X (byte 179), Min X (187), Max Y (195) and Min Y (203) of the header.
    let header = std::fs::read(&good).unwrap();
    let at = |o: usize| f64::from_le_bytes(header[o..o + 8].try_into().unwrap());
    let wide = [(179, at(187) + 200_000.0)];
    let shifted = [179, 187, 195, 203].map(|o| (o, at(o) + 20_000.0));
    for (k, edits) in [&wide[..], &shifted[..]].into_iter().enumerate() {
        let mut bytes = header.clone();
        for &(o, v) in edits {
            bytes[o..o + 8].copy_from_slice(&v.to_le_bytes());
        }
        let bad = dir.path().join(format!("bad{k}.las"));
        std::fs::write(&bad, &bytes).unwrap();
        let b = dir.path().join(format!("b{k}.tif"));
        let sb =
            convert::convert(&bad, &common::convert_options(b.clone(), 1 << 30), &Quiet).unwrap();
        assert_eq!((sa.points, sb.points), (50_000, 50_000));
        assert_eq!(dataset_points(&a), dataset_points(&b));
        let part = &pcimg::store::Part::open(&b).unwrap();
        let centre = part.meta.bounds.center();
        assert!((0..3).all(|k| (part.meta.origin[k] - centre[k]).abs() < 1e-6));
        assert!(
            sb.max_quantization_error < 1e-5,
            "{}",
            sb.max_quantization_error
        );
    }
}

/// Text declares no bounds: a part is collected around its first window's centre.
/// When that is too far from the rest for f32 (30 km of points, the first window
/// at one end) the input is read again around the points' own centre.
#[test]
fn first_window_far_from_the_rest_is_read_again() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("long.xyz");
    let mut text = String::new();
    for i in 0..5000 {
        let x = if i < 1000 { 0.0 } else { 59_990.0 } + (i % 10) as f64;
        text.push_str(&format!("{x} {} {}\n", i % 7, i % 3));
    }
    std::fs::write(&input, text).unwrap();
    let out = dir.path().join("long.tif");
    let mut o = common::convert_options(out.clone(), 1 << 30);
    o.read.chunk_points = 1000;
    let s = convert::convert(&input, &o, &Quiet).unwrap();
    assert_eq!(s.points, 5000);
    let part = &pcimg::store::Part::open(&out).unwrap();
    assert!(
        (part.meta.origin[0] - 29_999.5).abs() < 1e-9,
        "{:?}",
        part.meta.origin
    );
    assert!(s.max_quantization_error < 1e-3);
    assert_eq!(dataset_points(&out).len(), 5000);
}

/// A progress sink that asks to stop after the first window, as Ctrl-C does.
struct StopAfterFirst(Arc<AtomicBool>);
impl Progress for StopAfterFirst {
    fn phase(&self, _: &str, _: u64, _: &'static str) {}
    fn advance(&self, _: u64, _: u64) {
        self.0.store(true, Ordering::Relaxed);
    }
    fn note(&self, _: &str) {}
}

#[test]
fn interrupted_conversion_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("scan.xyz");
    pcimg::synth::write_text(&input, 400_000, 1).unwrap();
    for partition in [Partition::Spatial, Partition::Stream] {
        let mut o = common::convert_options(dir.path().join("out"), 64 << 20);
        o.partition = partition;
        o.read.chunk_points = 50_000;
        let stop = StopAfterFirst(o.cancel.clone());
        let e = convert::convert(&input, &o, &stop).unwrap_err().to_string();
        assert!(e.contains("interrupted"), "{e}");
        assert_eq!(entries(dir.path()), ["scan.xyz"]);
    }
}

#[test]
fn bad_inputs_are_clear_errors_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("bad.xyz", b"1 2 3\n4 5 6\n7 oops 9\n".to_vec(), "line 3"),
        ("nan.xyz", b"1 2 3\n4 nan 6\n".to_vec(), "line 2"),
        ("empty.xyz", Vec::new(), "empty"),
        ("gap.csv", b"x,y,z,i,c\n1,2,3,,5\n".to_vec(), "line 2: a column is empty"),
        ("mac.xyz", b"1 2 3\r4 5 6\r".to_vec(), "carriage return alone"),
        ("comma.xyz", b"1,5 2,25 -3,0\n".to_vec(), "line 1: the numbers use decimal commas"),
        ("points.unknown", b"1 2 3\n".to_vec(), "unknown input format"),
        (
            "short.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00\x80\x3f".to_vec(),
            "byte offset",
        ),
        ("cut.laz", std::fs::read(fixture("autzen_trim.laz")).unwrap()[..20_000].to_vec(), "byte offset"),
    ];
    for (name, bytes, want) in cases {
        let input = d.join(name);
        std::fs::write(&input, &bytes).unwrap();
        let out = d.join(format!("{name}.out"));
        let e = convert::convert(
            &input,
            &common::convert_options(out.clone(), 1 << 30),
            &Quiet,
        )
        .expect_err(name)
        .to_string();
        assert!(
            e.contains(name),
            "{name}: error does not name the file: {e}"
        );
        assert!(e.contains(want), "{name}: {e}");
        assert!(!out.exists(), "{name}: output left behind");
        std::fs::remove_file(&input).unwrap();
        assert!(entries(d).is_empty(), "{name}: left {:?}", entries(d));
    }
    // skip_invalid skips and counts.
    let input = d.join("bad.xyz");
    std::fs::write(&input, b"1 2 3\n4 5 6\n7 oops 9\n10 11 12\n").unwrap();
    let mut o = common::convert_options(d.join("ok.tif"), 1 << 30);
    o.read.skip_invalid = true;
    let s = convert::convert(&input, &o, &Quiet).unwrap();
    assert_eq!((s.points, s.skipped), (3, 1));
    // An existing output is not replaced without force.
    let e = convert::convert(
        &input,
        &common::convert_options(d.join("ok.tif"), 1 << 30),
        &Quiet,
    )
    .unwrap_err();
    assert!(e.to_string().contains("--force"), "{e}");
}

/// `pcimg synth -n N -o DIR/NAME`, through the binary.
fn synth(dir: &Path, name: &str, n: u64) -> PathBuf {
    let path = dir.join(name);
    let st = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .args(["synth", "-n", &n.to_string(), "-o"])
        .arg(&path)
        .status()
        .unwrap();
    assert!(st.success());
    path
}

#[test]
fn a_closed_stderr_does_not_stop_a_conversion() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_pcimg");
    let input = synth(dir.path(), "s.xyz", 300_000);
    // A budget below 64 MiB prints a note on stderr first: its reader is gone.
    let out = dir.path().join("s.pcimg");
    let mut child = Command::new(exe)
        .args(["convert", "--memory", "8MiB", "-o"])
        .arg(&out)
        .arg(&input)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    assert!(child.wait().unwrap().success());
    let ds = pcimg::store::Dataset::open(&out).unwrap();
    assert_eq!(ds.points(), 300_000);
    assert_eq!(
        entries(dir.path()),
        ["s.pcimg", "s.xyz"],
        "temporary files left"
    );
}

#[test]
fn command_line_convert_and_info_json() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_pcimg");
    let input = synth(dir.path(), "s.las", 200_000);
    let out = dir.path().join("s.pcimg");
    let o = Command::new(exe)
        .args(["convert", "--memory", "48MiB", "--compression", "zstd"])
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("200,000 points"), "{text}");
    let o = Command::new(exe)
        .args(["info", "--json"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["points"], 200_000);
    let parts = v["parts"].as_array().unwrap();
    assert!(parts.len() >= 2);
    assert_eq!(parts[0]["levels"][0]["compression"], "zstd");
    assert_eq!(parts[0]["bands"][3]["name"], "intensity");
    // A missing input is a clear error with a non-zero exit.
    let o = Command::new(exe)
        .args(["convert", "nope.las"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope.las"));
}

/// Every byte under `path` (a dataset directory, or one file).
fn bytes_under(path: &Path) -> u64 {
    if path.is_file() {
        return std::fs::metadata(path).unwrap().len();
    }
    std::fs::read_dir(path)
        .unwrap()
        .map(|e| bytes_under(&e.unwrap().path()))
        .sum()
}

/// Issue 40's storage target on the real airborne fixture: the default
/// dataset, pyramid, index and heads included, at most twice the LAZ; and
/// `--zstd-level`.
#[test]
fn the_default_keeps_autzen_trim_within_twice_its_laz() {
    let dir = tempfile::tempdir().unwrap();
    let laz = fixture("autzen_trim.laz");
    // `pcimg convert ARGS -o OUT autzen_trim.laz`.
    let convert = |args: &[&str], out: &Path| {
        Command::new(env!("CARGO_BIN_EXE_pcimg"))
            .arg("convert")
            .args(args)
            .arg("-o")
            .arg(out)
            .arg(&laz)
            .output()
            .unwrap()
    };
    // What the summary says of the tiles' codec.
    let said = |o: &std::process::Output| {
        let all = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        all.lines()
            .find_map(|l| l.trim().strip_prefix("tiles: ").map(str::to_string))
            .unwrap_or_else(|| panic!("no tiles line in:\n{all}"))
    };
    let out = dir.path().join("autzen.pcimg");
    let o = convert(&[], &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A small input: Zstd's level 6, and the flag that trades it.
    let line = said(&o);
    assert!(
        line.starts_with("zstd, level 6:") && line.contains("--zstd-level 1"),
        "{line}"
    );
    let (ours, theirs) = (bytes_under(&out), bytes_under(&laz));
    let ratio = ours as f64 / theirs as f64;
    eprintln!("autzen_trim: {ours} bytes, {ratio:.3}× its LAZ ({theirs})");
    assert!(ratio <= 2.0, "{ours} bytes: {ratio:.3}× the LAZ's {theirs}");
    // `--zstd-level 1`, the level large inputs get, writes more; a level for
    // another codec is refused before anything is written.
    let fast = dir.path().join("fast.pcimg");
    let o = convert(&["--zstd-level", "1"], &fast);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(said(&o), "zstd, level 1 (--zstd-level)");
    assert!(
        bytes_under(&fast) > ours,
        "{} vs {ours}",
        bytes_under(&fast)
    );
    let refused = dir.path().join("refused.pcimg");
    let o = convert(&["--zstd-level", "3", "--compression", "deflate"], &refused);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--zstd-level 3") && err.contains("deflate"),
        "{err}"
    );
    assert!(!refused.exists());
}

#[test]
fn force_replaces_only_what_pcimg_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_pcimg");
    let sb = dir.path().join("sb");
    std::fs::create_dir(&sb).unwrap();
    pcimg::synth::write_text(&sb.join("in.xyz"), 2_000, 1).unwrap();
    std::fs::write(sb.join("other.txt"), "keep").unwrap();
    pcimg::synth::write_text(&dir.path().join("top.xyz"), 2_000, 1).unwrap();
    let docs = sb.join("docs");
    std::fs::create_dir(&docs).unwrap();
    std::fs::write(docs.join("important.txt"), "keep").unwrap();
    let run = |args: &[&str]| {
        let o = Command::new(exe)
            .current_dir(&sb)
            .args(["convert", "-q", "--force"])
            .args(args)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let before = entries(&sb);
    for (args, want) in [
        (&["in.xyz", "-o", "."][..], "name the output"),
        (&["../top.xyz", "-o", "../sb"][..], "working directory"),
        (&["in.xyz", "-o", "docs/."][..], "not a pcimg dataset"),
        (&["in.xyz", "-o", "docs"][..], "not a pcimg dataset"),
        (&["in.xyz", "-o", "in.xyz"][..], "not .xyz"),
        (&["in.xyz", "-o", "../sb"][..], "holds the input"),
        (&["in.xyz", "-o", "other.txt"][..], "not .txt"),
    ] {
        let (ok, err) = run(args);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
        assert_eq!(entries(&sb), before, "{args:?} changed the directory");
        assert_eq!(entries(&docs), ["important.txt"]);
    }
    // A dataset pcimg wrote is replaced.
    for _ in 0..2 {
        let (ok, err) = run(&["in.xyz", "-o", "out.pcimg"]);
        assert!(ok, "{err}");
    }
    assert_eq!(
        entries(&sb.join("out.pcimg")),
        ["part-00000.tif", "pcimg-index.json"]
    );
}

/// The colour scale is decided on the file's first 65,536 points, whatever
/// `--memory` makes of the reader's windows: parts of a small budget scale as one
/// part does (before, the first window decided, and its size followed the budget).
#[test]
fn colour_scale_does_not_depend_on_memory() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("rgb.xyz");
    let mut text = String::from("x y z red green blue\n");
    for i in 0..400_000u32 {
        let c = if i < 100_000 { 200 } else { 60_000 };
        writeln!(text, "{} {} {} {c} {c} {c}", i % 700, i / 700, i % 3).unwrap();
    }
    std::fs::write(&input, &text).unwrap();
    let red = |memory: u64| -> (f64, f64) {
        let out = dir.path().join(format!("m{memory}.pcimg"));
        let s = convert::convert(
            &input,
            &common::convert_options(out.clone(), memory),
            &Quiet,
        )
        .unwrap();
        // Every channel of the 300,000 later points was clamped, and is counted.
        assert_eq!(s.clamped_colours, 900_000);
        let ds = Dataset::open(&out).unwrap();
        ds.parts()
            .unwrap()
            .into_iter()
            .map(|p| {
                p.bands
                    .iter()
                    .find(|b| b.name == "red")
                    .unwrap()
                    .range
                    .unwrap()
            })
            .fold((f64::MAX, f64::MIN), |a, r| (a.0.min(r.0), a.1.max(r.1)))
    };
    let one = red(1 << 30);
    let many = red(32 << 20);
    assert_eq!(one, many);
    // The first 65,536 points say 8-bit; later values beyond 255 are clamped.
    assert_eq!(one, (200.0, 255.0));
}

/// Notes reach stderr when it is not a terminal (a log, a pipe); an input wider
/// than pcimg stores is refused by name.
#[test]
fn notes_reach_a_piped_stderr_and_wide_inputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_pcimg");
    let input = dir.path().join("s.xyz");
    pcimg::synth::write_text(&input, 50_000, 1).unwrap();
    let o = Command::new(exe)
        .args(["convert", "--memory", "8MiB"])
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--memory 8.0 MiB is below 64.0 MiB"), "{err}");
    let wide = dir.path().join("wide.xyz");
    std::fs::write(&wide, format!("1 2 3{}\n", " 4".repeat(65))).unwrap();
    let o = Command::new(exe)
        .arg("convert")
        .arg(&wide)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("wide.xyz: 65 attribute columns"),
        "{err}"
    );
    assert!(!dir.path().join("wide.pcimg").exists());
}

/// Several files (a survey's tiles) become one dataset: every point of every file
/// once, in disjoint spatial parts, through a sampled first pass that runs across
/// the files; mixed formats with the same attributes are fine.
#[test]
fn several_files_become_one_dataset() {
    use pcimg::synth::Order;
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.xyz");
    pcimg::synth::write_text_in_order(&whole, 300_000, 7, Order::Scan).unwrap();
    // Three text tiles cut at arbitrary lines, and two LAS files.
    let text = std::fs::read(&whole).unwrap();
    let line_after = |at: usize| at + text[at..].iter().position(|&c| c == b'\n').unwrap() + 1;
    let cuts = [
        0,
        line_after(text.len() * 31 / 100),
        line_after(text.len() * 77 / 100),
        text.len(),
    ];
    let mut tiles = Vec::new();
    for (k, w) in cuts.windows(2).enumerate() {
        let p = dir.path().join(format!("tile{k}.xyz"));
        std::fs::write(&p, &text[w[0]..w[1]]).unwrap();
        tiles.push(p);
    }
    let las: Vec<PathBuf> = [("a.las", 150_000), ("b.laz", 250_000)]
        .iter()
        .map(|(name, n)| {
            let p = dir.path().join(name);
            pcimg::synth::write_las_in_order(&p, *n, 3, Order::Scan).unwrap();
            p
        })
        .collect();
    for (files, n) in [(&tiles, 300_000u64), (&las, 400_000)] {
        let out = dir.path().join("out.pcimg");
        let mut o = common::convert_options(out.clone(), 64 << 20);
        o.sample_points = 20_000;
        let notes = Notes::default();
        let s = convert::convert_files(files, &o, &notes).unwrap();
        let notes = notes.0.into_inner().unwrap();
        assert!(notes.iter().any(|l| l.starts_with("about ")), "{notes:?}");
        assert_eq!(s.points, n);
        assert_eq!(s.inputs, *files);
        assert!(s.parts.len() >= 2, "{} parts", s.parts.len());
        assert!(s.parts.iter().all(|p| p.points <= s.points_per_part));
        let mut want: Vec<[i64; 3]> = files.iter().flat_map(|f| file_points(f)).collect();
        want.sort();
        assert!(worst_offset(&dataset_points(&out), &want) <= 1);
        assert_parts_disjoint(&out);
        // The parts name the files they come from.
        let ds = Dataset::open(&out).unwrap();
        let source = ds.parts().unwrap()[0]
            .meta
            .source
            .clone()
            .unwrap_or_default();
        assert!(
            source.contains(&format!("({} files)", files.len())),
            "{source}"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }
}

/// Files that cannot make one dataset are refused before any work, naming both
/// files; a bad line in a later file names that file and its line.
#[test]
fn several_files_that_disagree_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let xyzi = d.join("a.xyz");
    std::fs::write(&xyzi, "1 2 3 10\n4 5 6 20\n").unwrap();
    let xyz = d.join("b.xyz");
    std::fs::write(&xyz, "1 2 3\n4 5 6\n").unwrap();
    let out = d.join("out.pcimg");
    let e = convert::convert_files(
        &[xyzi.clone(), xyz.clone()],
        &common::convert_options(out.clone(), 1 << 30),
        &Quiet,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("b.xyz") && e.contains("a.xyz") && e.contains("attributes"),
        "{e}"
    );
    let e = convert::convert_files(
        &[xyzi.clone(), d.join(".").join("a.xyz")],
        &common::convert_options(out.clone(), 1 << 30),
        &Quiet,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("given twice"), "{e}");
    let bad = d.join("c.xyz");
    std::fs::write(&bad, "1 2 3 10\n4 5 six 20\n").unwrap();
    let e = convert::convert_files(
        &[xyzi.clone(), bad],
        &common::convert_options(out.clone(), 1 << 30),
        &Quiet,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("c.xyz: line 2"), "{e}");
    assert!(!out.exists());
    assert_eq!(entries(d), ["a.xyz", "b.xyz", "c.xyz"]);
}

/// The command line takes several files or a directory (its point-cloud files,
/// hidden ones and others left out); a directory's dataset goes beside it, and
/// several files need -o.
#[test]
fn command_line_takes_files_and_directories() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_pcimg");
    let tiles = dir.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    std::fs::write(tiles.join("t1.xyz"), "1 2 3 10\n4 5 6 20\n").unwrap();
    std::fs::write(tiles.join("t2.XYZ"), "7 8 9 30\n").unwrap();
    std::fs::write(tiles.join(".hidden.xyz"), "not a point\n").unwrap();
    // An empty tile holds no points: left out.
    std::fs::write(tiles.join("t0.xyz"), "").unwrap();
    std::fs::write(tiles.join("notes.md"), "# survey\n").unwrap();
    let run = |args: &[&str]| {
        Command::new(exe)
            .current_dir(dir.path())
            .args(args)
            .output()
            .unwrap()
    };
    let o = run(&["convert", "tiles/"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("3 points") && text.contains("3 files, 1 empty left out"),
        "{text}"
    );
    assert!(dir.path().join("tiles.pcimg").is_dir());
    let o = run(&["convert", "tiles/t1.xyz", "tiles/t2.XYZ"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("-o"));
    let o = run(&["convert", "tiles/t1.xyz", "tiles/t2.XYZ", "-o", "two.tif"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A directory's name is kept whole in its dataset's name.
    std::fs::create_dir(dir.path().join("survey.2020")).unwrap();
    std::fs::copy(tiles.join("t1.xyz"), dir.path().join("survey.2020/a.xyz")).unwrap();
    let o = run(&["convert", "survey.2020"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(dir.path().join("survey.2020.pcimg").is_dir());
    std::fs::create_dir(dir.path().join("empty")).unwrap();
    let o = run(&["convert", "empty"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no point-cloud files"));
}

/// Points far outside the rest (70 and 140 km off on one side) that the sample
/// does not see still get parts of their own: no part is refused for precision,
/// every point is kept to a millimetre, wherever the points lie in the file.
#[test]
fn far_points_the_sample_misses_get_their_own_parts() {
    let dir = tempfile::tempdir().unwrap();
    let base = dir.path().join("base.xyz");
    pcimg::synth::write_text(&base, 300_000, 11).unwrap();
    let text = std::fs::read_to_string(&base).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // (The first ~190,000 points fill pass 1's first part and are all in the
    // sample; the sample only misses points after them.)
    let mut repartitioned = 0;
    for at in [200_500, 230_001, 260_002, 298_000] {
        let mut body = lines[..at].join("\n");
        body.push_str("\n777000.000 6011000.000 20.000 50\n");
        body.push_str(&lines[at..at + 500].join("\n"));
        body.push_str("\n707000.000 6011000.000 20.000 50\n");
        body.push_str(&lines[at + 500..].join("\n"));
        body.push('\n');
        let input = dir.path().join("far.xyz");
        std::fs::write(&input, body).unwrap();
        let out = dir.path().join("far.pcimg");
        let mut o = common::convert_options(out.clone(), 64 << 20);
        o.sample_points = 20_000;
        let notes = Notes::default();
        let s = convert::convert(&input, &o, &notes).unwrap();
        let notes = notes.0.into_inner().unwrap();
        repartitioned += notes.iter().any(|n| n.contains("partitioning again")) as usize;
        assert_eq!(s.points, 300_002);
        assert!(
            s.max_quantization_error < 0.001,
            "{}",
            s.max_quantization_error
        );
        assert!(worst_offset(&dataset_points(&out), &file_points(&input)) <= 1);
        let ds = Dataset::open(&out).unwrap();
        for x in [707_000.0, 777_000.0] {
            assert!(
                ds.parts()
                    .unwrap()
                    .into_iter()
                    .any(|p| p.meta.bounds.min[0] == x && p.meta.point_count == 1),
                "the point at x = {x} has no part of its own"
            );
        }
        std::fs::remove_dir_all(&out).unwrap();
    }
    assert!(
        repartitioned > 0,
        "the sample saw the far points every time"
    );
}

/// A point 54,000 km off (a digit too many in one y, found by `tests/fuzz.rs`)
/// among a small scan: its spatial region's origin loses more than 0.1 mm where
/// the centre of its own bounds would not, which once made the conversion read
/// the input again, choose the same origins, and fail with "the points reach too
/// far from the origin chosen while reading". A region's origin is final: the
/// part is written when f32 keeps its points to 1 mm from it.
#[test]
fn one_wild_coordinate_gets_a_part_of_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wild.xyz");
    pcimg::synth::write_text(&input, 1500, 1).unwrap();
    let mut text = std::fs::read_to_string(&input).unwrap();
    text.push_str("637148.132 60111178.540 18.000 104\n");
    std::fs::write(&input, &text).unwrap();
    let out = dir.path().join("wild.pcimg");
    let s = convert::convert(
        &input,
        &common::convert_options(out.clone(), 8 << 20),
        &convert::Quiet,
    )
    .unwrap();
    assert_eq!(s.points, 1501);
    assert!(
        s.max_quantization_error < 1e-3,
        "{}",
        s.max_quantization_error
    );
    assert!(worst_offset(&dataset_points(&out), &file_points(&input)) <= 10);
    let ds = Dataset::open(&out).unwrap();
    assert!(
        ds.parts()
            .unwrap()
            .into_iter()
            .any(|p| p.meta.bounds.min[1] > 6e7 && p.meta.point_count == 1),
        "the wild point has no part of its own"
    );
}

/// Files whose attribute offsets differ widely (GPS times a month apart) are
/// stored around one offset; the precision that costs is said. An empty LAS tile
/// (no points, zero bounds) does not make its header bounds count.
#[test]
fn several_files_note_what_one_offset_costs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (a, b) = (d.join("a.xyz"), d.join("b.xyz"));
    let lines = |t0: f64| -> String {
        (0..100)
            .map(|i| format!("{} 2 3 {:.6}\n", i, t0 + i as f64 * 0.001))
            .collect()
    };
    std::fs::write(&a, format!("x y z gps_time\n{}", lines(3.0e8))).unwrap();
    std::fs::write(&b, format!("x y z gps_time\n{}", lines(3.026e8))).unwrap();
    let notes = Notes::default();
    let s = convert::convert_files(
        &[a.clone(), b.clone()],
        &common::convert_options(d.join("ab.tif"), 1 << 30),
        &notes,
    )
    .unwrap();
    assert_eq!(s.points, 200);
    let notes = notes.0.into_inner().unwrap();
    assert!(
        notes
            .iter()
            .any(|n| n.starts_with("gps_time: the input files' values lie up to 2,600,")),
        "{notes:?}"
    );
    // Close offsets: nothing to say.
    let notes = Notes::default();
    std::fs::write(&b, format!("x y z gps_time\n{}", lines(3.0e8 + 60.0))).unwrap();
    convert::convert_files(
        &[a, b],
        &common::convert_options(d.join("ab2.tif"), 1 << 30),
        &notes,
    )
    .unwrap();
    let notes = notes.0.into_inner().unwrap();
    assert!(!notes.iter().any(|n| n.contains("offset")), "{notes:?}");
    // An empty LAS tile between two others.
    let z1 = synth(d, "z1.las", 20_000);
    let z2 = synth(d, "z2.las", 20_000);
    let z0 = d.join("z0.las");
    let mut h = las::Builder::from((1, 2));
    h.point_format = las::point::Format::new(1).unwrap();
    let w = las::Writer::from_path(&z0, h.into_header().unwrap()).unwrap();
    drop(w);
    // Its header's bounds: all zero, as writers leave them.
    let mut bytes = std::fs::read(&z0).unwrap();
    bytes[179..227].fill(0);
    std::fs::write(&z0, bytes).unwrap();
    let notes = Notes::default();
    let s = convert::convert_files(
        &[z1, z0, z2],
        &common::convert_options(d.join("z.tif"), 1 << 30),
        &notes,
    )
    .unwrap();
    assert_eq!(s.points, 40_000);
    let notes = notes.0.into_inner().unwrap();
    assert!(!notes.iter().any(|n| n.contains("again")), "{notes:?}");
}

/// An uncompressed LAS part takes its attribute rows from the input's memory map
/// (`RowSource`) instead of a copy, in either layout; LAZ is decoded into a copy as
/// before. The same points from either give the same values in every band of every
/// level, in the Hilbert layout and in the paper's, with compressed tiles too.
#[test]
fn las_rows_read_from_the_input_match_a_held_copy() {
    use pcimg::synth::Order;
    let dir = tempfile::tempdir().unwrap();
    let n = 150_000;
    let las = dir.path().join("scan.las");
    let laz = dir.path().join("scan.laz");
    pcimg::synth::write_las_in_order(&las, n, 11, Order::Scan).unwrap();
    pcimg::synth::write_las_in_order(&laz, n, 11, Order::Scan).unwrap();
    for (layout, compression) in [
        (Layout::Hilbert, Compression::None),
        (Layout::Paper, Compression::None),
        (Layout::Hilbert, Compression::Zstd),
    ] {
        let read = |input: &Path| {
            let out = dir.path().join(format!(
                "{}-{}-{compression:?}.tif",
                input.file_name().unwrap().to_string_lossy(),
                layout.name()
            ));
            let mut o = common::convert_options(out.clone(), 1 << 30);
            o.layout = layout;
            o.compression = compression;
            let s = convert::convert(input, &o, &Quiet).unwrap();
            let las = input.extension().is_some_and(|e| e == "las");
            assert_eq!(s.parts[0].rows_from_input, las, "{input:?} {layout:?}");
            let ds = Dataset::open(&out).unwrap();
            assert_eq!(ds.part_count(), 1);
            let p = &ds.parts().unwrap()[0];
            let bands: Vec<usize> = (0..p.bands.len()).collect();
            assert_eq!(
                p.bands.len(),
                15,
                "x y z, nine attributes and the three that make GPS time exact"
            );
            (0..p.levels.len())
                .map(|l| {
                    let pts = p.read_level(l, &bands).unwrap();
                    let bits: Vec<Vec<u32>> = pts
                        .columns
                        .iter()
                        .map(|c| c.iter().map(|v| v.to_bits()).collect())
                        .collect();
                    (pts.offsets, bits)
                })
                .collect::<Vec<_>>()
        };
        let (a, b) = (read(&las), read(&laz));
        assert!(a.len() >= 2, "{layout:?}: levels");
        assert_eq!(a[0].1[0].len(), n as usize);
        assert!(a == b, "{layout:?}: LAS and LAZ conversions differ");
    }
}

/// A 1 mm lattice over 40 km (UTM-sized coordinates, text with 3 decimals):
/// the parts are cut at most 16.8 km wide (2^24 steps: the store keeps whole
/// numbers of steps in Float32), so every part keeps the lattice exactly,
/// where parts 65 km wide (f32's 1 mm reach) could not.
#[test]
fn a_millimetre_lattice_over_40_km_is_kept_in_narrower_parts() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wide.xyz");
    let mut text = String::from("x y z\n");
    let mut r = pcimg_core::rng::Rng::new(11);
    for _ in 0..30_000 {
        let mut k = |n: f64| (r.f64() * n) as u64;
        let (x, y, z) = (
            500_000_000 + k(40e6),
            4_000_000_000 + k(1e5),
            100_000 + k(5e4),
        );
        text.push_str(&format!(
            "{}.{:03} {}.{:03} {}.{:03}\n",
            x / 1000,
            x % 1000,
            y / 1000,
            y % 1000,
            z / 1000,
            z % 1000
        ));
    }
    std::fs::write(&input, text).unwrap();
    let out = dir.path().join("wide.pcimg");
    let o = common::cli::pcimg()
        .args([
            "convert",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let said = common::cli::ok(&o, "convert");
    assert!(
        said.contains("every part's coordinates kept exactly on the input's lattice (steps 0.001"),
        "{said}"
    );
    let ds = Dataset::open(&out).unwrap();
    let parts = ds.parts().unwrap();
    assert!(parts.len() >= 3, "{} parts", parts.len());
    for p in &parts {
        let l = p.meta.lattice.expect("every part on the lattice");
        assert_eq!(l.step, [0.001; 3]);
        let e = p.meta.bounds.extent();
        assert!(e[0] < 16_777.216, "a part {} m wide", e[0]);
    }
    assert_parts_disjoint(&out);
    // The points come back on the lattice: the same to 0.1 mm (f32 at up to
    // 8.4 km from a part's origin: within 0.5 mm; rounded to the lattice, exact).
    let mut got: Vec<[i64; 3]> = dataset_points(&out)
        .into_iter()
        .map(|p| p.map(|v| (v as f64 / 10.0).round() as i64 * 10))
        .collect();
    got.sort();
    assert_eq!(got, file_points(&input));
    // One file (one part) cannot be cut: the summary says why the lattice is
    // not kept, and what keeps it.
    let one = dir.path().join("one.tif");
    let o = common::cli::pcimg()
        .args([
            "convert",
            input.to_str().unwrap(),
            "-o",
            one.to_str().unwrap(),
        ])
        .arg("--allow-lossy")
        .output()
        .unwrap();
    let said = common::cli::ok(&o, "convert to one file");
    assert!(
        said.contains(
            "1 of 1 parts' coordinates not on the input's lattice (steps 0.001, 0.001, 0.001; \
             stored as 32-bit floats instead): they spread wider than 2^24 of its steps"
        ) && said.contains("a directory output (-o DIR)"),
        "{said}"
    );
    // A point with more decimals than the lines the lattice was read from.
    let off = dir.path().join("off.xyz");
    let mut text = String::from("x y z\n");
    for i in 0..5000 {
        text.push_str(&format!("{}.{:02} 2000.25 10.5\n", 1000 + i % 50, i % 100));
    }
    text.push_str("1010.005 2000.25 10.5\n");
    std::fs::write(&off, text).unwrap();
    let o = common::cli::pcimg()
        .args(["convert", off.to_str().unwrap(), "-o"])
        .arg(dir.path().join("off.pcimg"))
        .output()
        .unwrap();
    let said = common::cli::ok(&o, "convert a point off the lattice");
    assert!(
        said.contains("1 of 1 parts' coordinates not on the input's lattice (steps 0.01")
            && said.contains("they hold points off it"),
        "{said}"
    );
}

/// A text file's coordinates lie on the lattice of its decimals: the default
/// codec keeps them as whole numbers on it (`LATTICE`, GDAL's band scale) and
/// says so; `--precision` rounds them to a coarser step, within half of it,
/// and is refused with a codec that keeps floats.
#[test]
fn text_decimals_are_a_lattice_and_precision_rounds_to_another() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("pts.xyz");
    let mut text = String::from("x y z intensity\n");
    let mut seed = 3u64;
    let mut next = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..20_000 {
        let (x, y, z) = (
            1000.0 + next() * 50.0,
            2000.0 + next() * 50.0,
            10.0 + next() * 5.0,
        );
        text.push_str(&format!(
            "{x:.3} {y:.3} {z:.2} {}\n",
            (next() * 255.0) as u32
        ));
    }
    std::fs::write(&input, text).unwrap();
    let convert = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "convert",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = common::cli::pcimg().args(&args).output().unwrap();
        (out, o)
    };
    let (exact, o) = convert("exact.tif", &[]);
    let said = common::cli::ok(&o, "convert");
    assert!(
        said.contains("kept exactly on the input's lattice (steps 0.001"),
        "{said}"
    );
    assert!(
        said.contains("coordinates read as 32-bit floats (drawing, picking) within"),
        "{said}"
    );
    let part = pcimg::store::Part::open(&exact).unwrap();
    assert_eq!(part.meta.format_version, 2);
    let l = part.meta.lattice.expect("a lattice");
    assert_eq!(l.step, [0.001, 0.001, 0.01]);
    // `info` says the same, and writes the coordinates' ranges at the lattice's
    // decimals (the f64 sums would print as 1000.0370000000001).
    let o = common::cli::pcimg()
        .args(["info", exact.to_str().unwrap()])
        .output()
        .unwrap();
    let info = common::cli::ok(&o, "info");
    assert!(
        info.contains(
            "stored coordinates exactly on the source's lattice (steps 0.001 units, 0.001 units, 0.01 units)"
        ),
        "{info}"
    );
    let x = info
        .lines()
        .find(|l| l.trim_start().starts_with("1  x"))
        .unwrap_or_else(|| panic!("{info}"));
    let (lo, hi) = (
        part.bands[0].range.unwrap().0,
        part.bands[0].range.unwrap().1,
    );
    assert!(
        x.contains(&format!("range {lo:.3} .. {hi:.3} ")),
        "{x} ({lo} {hi})"
    );
    assert_ne!(
        format!("{lo} {hi}"),
        format!("{lo:.3} {hi:.3}"),
        "the plain f64s print as the decimals already, so this test would not tell"
    );
    // Every point read back is the source's to f32 precision.
    assert_eq!(dataset_points(&exact), file_points(&input));
    let (rounded, o) = convert("rounded.tif", &["--precision", "0.05"]);
    let said = common::cli::ok(&o, "convert --precision");
    assert!(
        said.contains("rounded to whole multiples of --precision"),
        "{said}"
    );
    let part = pcimg::store::Part::open(&rounded).unwrap();
    assert_eq!(part.meta.lattice.unwrap().step, [0.05; 3]);
    // The part says it was rounded (`LATTICE_ROUNDED`), and `info` does not
    // call it exact.
    assert!(part.meta.lattice_rounded);
    assert!(
        !pcimg::store::Part::open(&exact)
            .unwrap()
            .meta
            .lattice_rounded
    );
    let o = common::cli::pcimg()
        .args(["info", rounded.to_str().unwrap()])
        .output()
        .unwrap();
    let info = common::cli::ok(&o, "info");
    assert!(
        info.contains("stored coordinates rounded onto a lattice (steps 0.05 units")
            && !info.contains("exactly"),
        "{info}"
    );
    let got = part.read_level(0, &[0, 1, 2]).unwrap();
    let src = file_points(&input);
    assert_eq!(got.len(), src.len());
    for i in 0..got.len() {
        for a in 0..3 {
            let v = got.offsets[a] + got.columns[a][i] as f64;
            let k = v / 0.05;
            assert!(
                (k - k.round()).abs() < 1e-3,
                "{v} is not a multiple of 0.05"
            );
        }
    }
    // Rounding moves each coordinate by at most half a step (in 0.1 mm units;
    // rounding keeps the order of each axis's values, so sorted axes pair up).
    let (a, b) = (dataset_points(&rounded), &src);
    for axis in 0..3 {
        let sorted = |v: &[[i64; 3]]| {
            let mut s: Vec<i64> = v.iter().map(|p| p[axis]).collect();
            s.sort();
            s
        };
        let (x, y) = (sorted(&a), sorted(b));
        let worst = x.iter().zip(&y).map(|(p, q)| (p - q).abs()).max().unwrap();
        assert!(worst <= 251, "axis {axis}: moved {worst} tenths of a mm");
    }
    let (_, o) = convert(
        "none.tif",
        &["--precision", "0.05", "--compression", "none"],
    );
    let e = common::cli::err(&o, "convert --precision --compression none");
    assert!(
        e.contains("--precision 0.05 keeps coordinates as whole numbers"),
        "{e}"
    );
}
