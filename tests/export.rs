//! `pcimg export` and `pcimg stats` (issue 41): points back out as LAS, LAZ,
//! PLY, CSV and XYZ, and statistics of their bands.
//! A LAS/LAZ converted and exported is checked against its source by laspy
//! (`tests/python/export_matches_las.py`): the same points, every attribute
//! pcimg keeps, coordinates on the same integers; a clipped or class-filtered
//! export equals the source filtered the same way; PLY and CSV read back
//! through `pcimg convert` give the same points; an existing output is
//! refused without `--force`, and a failed export leaves nothing behind; from
//! the S3 test server a clip fetches less than the dataset; `stats --exact`
//! equals numpy over laspy's points. With CI=true a missing python3 with
//! laspy or weed is a failure, else a skip.

mod common;

use common::cli::{convert, err, info_json, ok, pcimg};
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/autzen_trim.laz")
}

/// A python3 that imports laspy and lazrs (the system one, where CI installs
/// them), or `None` outside CI.
fn laspy() -> Option<&'static str> {
    common::python_with("laspy, lazrs, numpy")
}

/// `pcimg info --json` of a dataset, without where it is.
fn info(ds: &Path) -> serde_json::Value {
    info_json(&ok(
        &pcimg().args(["info", "--json"]).arg(ds).output().unwrap(),
        "info",
    ))
}

/// `pcimg export DATASET -o OUT ARGS…`; its standard error (the summary).
fn export(ds: &Path, out: &Path, args: &[&str]) -> String {
    let o = pcimg()
        .arg("export")
        .arg(ds)
        .arg("-o")
        .arg(out)
        .args(args)
        .output()
        .unwrap();
    ok(&o, "export");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn check(py: &str, source: &Path, exported: &Path, args: &[&str]) -> String {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/export_matches_las.py");
    let o = Command::new(py)
        .arg(script)
        .arg(source)
        .arg(exported)
        .args(args)
        .output()
        .unwrap();
    let said = ok(&o, "export_matches_las.py");
    eprintln!("{}: {said}", exported.display());
    said
}

#[test]
fn a_las_converted_and_exported_is_its_source_again_in_laspy() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    for name in ["back.laz", "back.las"] {
        let out = dir.path().join(name);
        let said = export(&ds, &out, &[]);
        assert!(said.contains("the source's"), "{said}");
        let checked = check(py, &fixture(), &out, &[]);
        assert!(checked.starts_with("110000 points equal"), "{checked}");
    }
}

/// A LAS 1.4 source in an extended format (7: colour, time), its overlap
/// flags, scanner channels and fine scan angles set, comes back in an
/// extended format with all of them, as laspy reads them.
#[test]
fn an_extended_format_source_keeps_its_flags_channels_and_fine_angles() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let las = dir.path().join("f7.las");
    let o = Command::new(py)
        .args(["-c", EXTENDED])
        .arg(fixture())
        .arg(&las)
        .output()
        .unwrap();
    ok(&o, "laspy: the fixture as point format 7");
    let ds = dir.path().join("f7.pcimg");
    convert(&las, &ds, &[]);
    let out = dir.path().join("back.laz");
    let said = export(&ds, &out, &[]);
    assert!(said.contains("LAS 1.4 point format 7"), "{said}");
    let checked = check(py, &las, &out, &[]);
    assert!(checked.starts_with("110000 points equal"), "{checked}");
}

/// The fixture as LAS 1.4 point format 7, with overlap flags, scanner
/// channels and scan angles in 0.006° steps that whole degrees cannot hold.
const EXTENDED: &str = r#"
import sys, laspy, numpy as np
src = laspy.read(sys.argv[1])
las = laspy.convert(src, point_format_id=7, file_version="1.4")
n = len(las.points)
i = np.arange(n)
las.overlap = (i % 3 == 0).astype(np.uint8)
las.scanner_channel = (i % 4).astype(np.uint8)
las.scan_angle = ((i % 20001) - 10000).astype(np.int16)
las.write(sys.argv[2])
"#;

#[test]
fn a_clipped_or_class_filtered_export_is_the_source_filtered_the_same_way() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // Real airborne LAS in several parts (the fixture tiled with jitter, as
    // the benchmarks make it), so the clip skips parts and tiles.
    let las = dir.path().join("tiled.las");
    let root = env!("CARGO_MANIFEST_DIR");
    let o = Command::new(py)
        .arg(format!("{root}/bench/autzen_tiled.py"))
        .arg(&las)
        .arg("600000")
        .arg(fixture())
        .output()
        .unwrap();
    ok(&o, "bench/autzen_tiled.py");
    let ds = dir.path().join("tiled.pcimg");
    convert(&las, &ds, &["--memory", "64MiB"]);
    let info = info(&ds);
    let b = &info["bounds"];
    let v = |k: &str, a: usize| b[k][a].as_f64().unwrap();
    // The box: the middle third across x and y, every height.
    let (x0, x1) = (v("min", 0), v("max", 0));
    let (y0, y1) = (v("min", 1), v("max", 1));
    let clip = format!(
        "{},{},{},{},{},{}",
        x0 + (x1 - x0) / 3.0,
        y0 + (y1 - y0) / 3.0,
        v("min", 2) - 1.0,
        x0 + 2.0 * (x1 - x0) / 3.0,
        y0 + 2.0 * (y1 - y0) / 3.0,
        v("max", 2) + 1.0
    );
    let out = dir.path().join("clip.laz");
    let said = export(&ds, &out, &["--clip", &clip]);
    // Tiles outside the box were not read.
    let read: Vec<usize> = said
        .split("read ")
        .nth(1)
        .and_then(|s| s.split(" tiles").next())
        .map(|s| s.split(" of ").map(|n| n.trim().parse().unwrap()).collect())
        .unwrap_or_default();
    assert!(read.len() == 2 && read[0] < read[1], "{said}");
    check(py, &las, &out, &["--clip", &clip]);
    // --bounds is the same box seen from above.
    let flat: Vec<&str> = clip.split(',').collect();
    let bounds = format!("{},{},{},{}", flat[0], flat[1], flat[3], flat[4]);
    let out2 = dir.path().join("bounds.las");
    export(&ds, &out2, &["--bounds", &bounds]);
    check(py, &las, &out2, &["--clip", &clip]);
    // Classes: the fixture's ground.
    let autzen = dir.path().join("autzen.pcimg");
    convert(&fixture(), &autzen, &[]);
    let ground = dir.path().join("ground.laz");
    export(&autzen, &ground, &["--classes", "2"]);
    let said = check(py, &fixture(), &ground, &["--classes", "2"]);
    assert!(!said.starts_with("0 points"), "{said}");
}

#[test]
fn a_level_is_an_even_sample_of_the_levels_points() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    let info = info(&ds);
    let level1 = info["parts"][0]["levels"][1]["points"].as_u64().unwrap();
    let out = dir.path().join("light.csv");
    export(&ds, &out, &["--level", "1"]);
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(
            "x,y,z,intensity,return_number,number_of_returns,classification,gps_time,red,green,blue,\
             scan_angle,user_data,point_source_id,las_flags"
        )
    );
    assert_eq!(lines.count() as u64, level1);
    // A level past the parts' is refused, naming the levels there are.
    let o = pcimg()
        .arg("export")
        .arg(&ds)
        .args(["-o"])
        .arg(dir.path().join("x.las"))
        .args(["--level", "99"])
        .output()
        .unwrap();
    assert!(err(&o, "--level 99").contains("levels 0 to"));
}

/// PLY and CSV exports read back by pcimg's own readers give the dataset's
/// points: the same count and bounds, the same bands (GPS time as one band: a
/// text or PLY source's has no whole numbers that make it exact).
#[test]
fn ply_csv_and_xyz_exports_convert_back_to_the_same_points() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    let facts = |p: &Path| {
        let i = info(p);
        let bands: Vec<String> = i["parts"][0]["bands"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b["name"].as_str().unwrap().to_string())
            .filter(|b| !pcimg::time::is_exact_band(b))
            .collect();
        (i["points"].as_u64().unwrap(), i["bounds"].clone(), bands)
    };
    let (n, bounds, bands) = facts(&ds);
    for name in ["back.ply", "back.csv", "back.xyz"] {
        let out = dir.path().join(name);
        export(&ds, &out, &[]);
        let again = dir.path().join(format!("{name}.pcimg"));
        convert(&out, &again, &[]);
        let (n2, bounds2, bands2) = facts(&again);
        assert_eq!(n2, n, "{name}");
        for k in ["min", "max"] {
            for a in 0..3 {
                let (p, q) = (
                    bounds[k][a].as_f64().unwrap(),
                    bounds2[k][a].as_f64().unwrap(),
                );
                assert!((p - q).abs() < 1e-6, "{name}: {k}[{a}] {p} against {q}");
            }
        }
        if name != "back.xyz" {
            assert_eq!(bands2, bands, "{name}");
        }
    }
}

/// Classes above 31 (here from a CSV) need LAS 1.4's extended formats: the
/// export takes one, and laspy reads every class back.
#[test]
fn classes_above_31_are_exported_in_an_extended_format() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("classes.csv");
    let mut text = String::from("x,y,z,classification\n");
    for i in 0..3000 {
        text += &format!(
            "{},{},{},{}\n",
            i % 60,
            i / 60,
            i % 7,
            [2, 31, 64, 200][i % 4]
        );
    }
    std::fs::write(&csv, text).unwrap();
    let ds = dir.path().join("classes.pcimg");
    convert(&csv, &ds, &[]);
    let out = dir.path().join("classes.las");
    let said = export(&ds, &out, &[]);
    assert!(said.contains("point format 6"), "{said}");
    let o = Command::new(py)
        .args([
            "-c",
            "import sys, laspy, numpy as np; c = laspy.read(sys.argv[1]).classification; \
             print(dict(zip(*[a.tolist() for a in np.unique(np.asarray(c), return_counts=True)])))",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let said = ok(&o, "laspy");
    assert_eq!(said.trim(), "{2: 750, 31: 750, 64: 750, 200: 750}");
}

#[test]
fn an_existing_output_is_refused_and_a_failed_export_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let out = out_dir.join("a.laz");
    std::fs::write(&out, b"mine").unwrap();
    let run = |args: &[&str]| {
        pcimg()
            .arg("export")
            .arg(&ds)
            .arg("-o")
            .arg(&out)
            .args(args)
            .output()
            .unwrap()
    };
    let e = err(&run(&[]), "export over an existing file");
    assert!(e.contains("exists") && e.contains("--force"), "{e}");
    assert_eq!(std::fs::read(&out).unwrap(), b"mine");
    ok(&run(&["--force", "-q"]), "export --force");
    assert!(std::fs::metadata(&out).unwrap().len() > 1000);
    // A failure after the output was begun (an unknown --where band is found
    // before; a missing part file only when its tiles are read).
    let e = err(
        &run(&["--force", "--where", "nosuch=1..2"]),
        "--where nosuch",
    );
    assert!(e.contains("nosuch"), "{e}");
    let part = std::fs::read_dir(&ds)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "tif"))
        .unwrap();
    std::fs::rename(&part, dir.path().join("moved.tif")).unwrap();
    let gone = out_dir.join("b.las");
    let o = pcimg()
        .arg("export")
        .arg(&ds)
        .arg("-o")
        .arg(&gone)
        .output()
        .unwrap();
    let _ = err(&o, "export of a dataset whose part went away");
    let left: Vec<_> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["a.laz"], "nothing half-written is left");
    // An unknown extension names the ones there are.
    let o = pcimg()
        .arg("export")
        .arg(dir.path().join("moved.tif"))
        .arg("-o")
        .arg(out_dir.join("c.tif"))
        .output()
        .unwrap();
    assert!(err(&o, "export to .tif").contains(".las, .laz, .ply, .csv or .xyz"));
}

/// From the S3 test server (SeaweedFS), a clipped export reads only the tiles
/// it needs: fewer bytes than the whole dataset, the same points as the local
/// export of the same dataset.
#[test]
fn a_clipped_export_from_s3_fetches_less_than_the_dataset() {
    let Some(weed) = common::servers::Weed::start() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let las = dir.path().join("scan.las");
    ok(
        &pcimg()
            .args(["synth", "-n", "400000", "-o"])
            .arg(&las)
            .output()
            .unwrap(),
        "synth",
    );
    let conv = ["convert", "-q", "--memory", "1MiB"];
    let ds = dir.path().join("scan.pcimg");
    convert(&las, &ds, &conv[2..]);
    let url = format!("s3://{}/scan.pcimg", common::servers::WEED_BUCKET);
    ok(
        &weed
            .pcimg(
                &weed.endpoint(),
                &[&conv[..], &[las.to_str().unwrap(), "-o", &url]].concat(),
            )
            .output()
            .unwrap(),
        "convert -o s3://",
    );
    let info = info(&ds);
    let b = &info["bounds"];
    let v = |k: &str, a: usize| b[k][a].as_f64().unwrap();
    let bounds = format!(
        "{},{},{},{}",
        v("min", 0),
        v("min", 1),
        v("min", 0) + (v("max", 0) - v("min", 0)) / 4.0,
        v("min", 1) + (v("max", 1) - v("min", 1)) / 4.0
    );
    let local = dir.path().join("local.csv");
    export(&ds, &local, &["--bounds", &bounds, "-q"]);
    let remote = dir.path().join("remote.csv");
    let o = weed
        .pcimg(
            &weed.endpoint(),
            &[
                "export",
                &url,
                "-o",
                remote.to_str().unwrap(),
                "--bounds",
                &bounds,
                "--net-stats",
            ],
        )
        .output()
        .unwrap();
    ok(&o, "export s3://");
    let said = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(
        std::fs::read(&local).unwrap(),
        std::fs::read(&remote).unwrap(),
        "the same points from S3"
    );
    let fetched: u64 = said
        .split("requests, ")
        .nth(1)
        .and_then(|s| s.split(" bytes").next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no network counters in: {said}"));
    let total: u64 = info["bytes"].as_u64().unwrap();
    assert!(
        fetched < total / 2,
        "fetched {fetched} of {total} bytes: {said}"
    );
    eprintln!("a sixteenth of the area: {fetched} of {total} bytes fetched");
}

/// `pcimg stats --exact` against numpy over laspy's points
/// (`tests/python/stats_match_las.py`): every band's count, range, mean,
/// deviation, percentiles and histogram total, and the class counts.
#[test]
fn exact_stats_equal_numpys_over_the_source_points() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    let o = pcimg()
        .args(["stats", "--exact", "--json"])
        .arg(&ds)
        .output()
        .unwrap();
    let json = dir.path().join("stats.json");
    std::fs::write(&json, ok(&o, "stats --exact --json")).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/stats_match_las.py");
    let o = Command::new(py)
        .arg(script)
        .arg(fixture())
        .arg(&json)
        .output()
        .unwrap();
    let said = ok(&o, "stats_match_las.py");
    assert!(said.starts_with("15 bands and 2 classes equal"), "{said}");
}

/// A level is an even sample: `stats --level 1` reads that level's points and
/// says so; the density map is a PNG 512 cells across; an unknown band is
/// refused naming the ones there are.
#[test]
fn stats_of_a_level_say_the_sample_and_draw_the_density() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("autzen.pcimg");
    convert(&fixture(), &ds, &[]);
    let info = info(&ds);
    let level1 = info["parts"][0]["levels"][1]["points"].as_u64().unwrap();
    let png = dir.path().join("density.png");
    let o = pcimg()
        .args(["stats", "--level", "1", "--band", "z", "-o"])
        .arg(&png)
        .arg(&ds)
        .output()
        .unwrap();
    let text = ok(&o, "stats --level 1");
    assert!(
        text.contains(&format!(
            "from level 1, an even sample of {}",
            grouped(level1)
        )),
        "{text}"
    );
    assert!(text.contains("\nz ") && text.contains("density:"), "{text}");
    let img = image::open(&png).unwrap();
    assert_eq!(img.width(), 512);
    let o = pcimg()
        .args(["stats", "--band", "nosuch"])
        .arg(&ds)
        .output()
        .unwrap();
    let e = err(&o, "stats --band nosuch");
    assert!(e.contains("nosuch") && e.contains("intensity"), "{e}");
}

/// `n` with thousands separators, as pcimg prints counts.
fn grouped(n: u64) -> String {
    let d = n.to_string();
    let mut out = String::new();
    for (i, c) in d.chars().enumerate() {
        if i > 0 && (d.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Bands LAS has no field for go in as extra bytes: the CGAL PLY's `label`
/// (an int property) read back by laspy by name, point for point with the
/// PLY's own values (read with numpy from its binary body).
#[test]
fn bands_las_has_no_field_for_are_extra_bytes_laspy_reads_by_name() {
    let Some(py) = laspy() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ply = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/cgal_b9_training.ply");
    let ds = dir.path().join("b9.pcimg");
    convert(&ply, &ds, &[]);
    let out = dir.path().join("b9.las");
    let said = export(&ds, &out, &[]);
    assert!(said.contains("extra bytes (doubles): label"), "{said}");
    let check = r#"
import sys, laspy, numpy as np
ply, las = sys.argv[1], sys.argv[2]
raw = open(ply, "rb").read()
body = raw[raw.index(b"end_header\n") + len(b"end_header\n"):]
t = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("r", "u1"), ("g", "u1"), ("b", "u1"), ("label", "<i4")])
p = np.frombuffer(body, dtype=t)
e = laspy.read(las)
assert "label" in e.point_format.extra_dimension_names, e.point_format.extra_dimension_names
assert len(p) == len(e.points), (len(p), len(e.points))
# The PLY's doubles are kept as Float32 offsets (no lattice), so each
# coordinate is on the export's millimetre grid within one step.
grid = [np.round((p[k] - o) / s).astype(np.int64) for k, o, s in zip("xyz", e.header.offsets, e.header.scales)]
ints = [np.asarray(e.X), np.asarray(e.Y), np.asarray(e.Z)]
for k in range(3):
    assert np.abs(np.sort(grid[k]) - np.sort(ints[k])).max() <= 1, "xyz"[k]
# The labels: the same multiset, and each label on the same points (their
# count and mean position).
label = np.asarray(e["label"])
assert np.array_equal(np.sort(p["label"]).astype(np.float64), np.sort(label)), "labels differ"
for v in np.unique(p["label"]):
    a, b = p["label"] == v, label == v
    for k in range(3):
        assert abs(grid[k][a].mean() - ints[k][b].mean()) <= 1, (v, "xyz"[k])
print(f"{len(p)} labels equal")
"#;
    let o = Command::new(py)
        .args(["-c", check])
        .arg(&ply)
        .arg(&out)
        .output()
        .unwrap();
    let said = ok(&o, "laspy reads the extra bytes");
    assert!(said.starts_with("22300 labels equal"), "{said}");
}

/// Text coordinates carry the decimals of the lattice's points, its offset's
/// included: a LAS file at 0.01 from 636000.005 exports 636000.005, not
/// 636000.01 (2 decimals, half a step off).
#[test]
fn text_export_writes_an_odd_offsets_decimals() {
    let dir = tempfile::tempdir().unwrap();
    let las = dir.path().join("odd.las");
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    let t = |o| las::Transform {
        scale: 0.01,
        offset: o,
    };
    b.transforms = las::Vector {
        x: t(636_000.005),
        y: t(848_000.0),
        z: t(0.0),
    };
    let mut w = las::Writer::from_path(&las, b.into_header().unwrap()).unwrap();
    for i in 0..1000u32 {
        w.write_point(las::Point {
            x: 636_000.005 + f64::from(i) * 0.01,
            y: 848_000.0 + f64::from(i % 37) * 0.01,
            z: f64::from(i % 11) * 0.01,
            gps_time: Some(f64::from(i)),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let ds = dir.path().join("odd.pcimg");
    let csv = dir.path().join("odd.csv");
    for args in [
        vec!["convert", las.to_str().unwrap(), "-o", ds.to_str().unwrap()],
        vec!["export", ds.to_str().unwrap(), "-o", csv.to_str().unwrap()],
    ] {
        let o = common::cli::pcimg().args(&args).output().unwrap();
        common::cli::ok(&o, args[0]);
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut xs: Vec<&str> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    xs.sort_unstable();
    assert_eq!(xs.len(), 1000);
    assert_eq!(xs[0], "636000.005");
    assert_eq!(xs[999], "636009.995");
}
